"""The typed session contract (protocol/setup.py): what the SPEC §5.1 table lists, no more, no less."""

from __future__ import annotations

import re
from dataclasses import fields
from importlib import resources

import numpy as np
import pytest

from conftest import SPHERE_WATER, regular_waves, scene_toml, sphere_body

from hydrolink.protocol import codec
from hydrolink.protocol.codec import ProtocolError
from hydrolink.protocol.scene import parse_scene
from hydrolink.protocol.setup import Setup, StateSpaceReport
from hydrolink.server.model import HydroModel

SCENE = scene_toml(dt=0.05, duration=1.0, water=SPHERE_WATER, waves=regular_waves(1.0, 5.0),
                   bodies=[sphere_body("sphere.h5", mass=261800.0, dofs=["heave", "pitch"])])


@pytest.fixture(scope="module")
def setup(sphere) -> Setup:
    return HydroModel(parse_scene(SCENE), {"sphere": sphere}).setup_info()


def wire(setup: Setup) -> dict:
    """What a client receives: the map packed and unpacked by the codec."""
    return codec.unpack(codec.pack(codec.message("welcome", 1, None, setup=setup.to_wire())))["setup"]


def test_every_field_is_in_the_spec_table():
    """SPEC §5.1 lists each Setup field by name, and lists nothing the type lacks."""
    spec = resources.files("hydrolink.protocol").joinpath("SPEC.md").read_text()
    table = spec.split("#### `setup`", 1)[1].split("force contract", 1)[0]
    listed = set(re.findall(r"^\| `(\w+)` ", table, re.M))
    assert listed == {f.name for f in fields(Setup)}


def test_the_spec_states_the_water_defaults_and_that_clients_show_the_warnings():
    """SPEC §5.1 states the scene's [water] defaults as protocol/scene.py has them (a client writer
    who assumes fresh water, 1000 kg/m^3, otherwise gets a 2.5 % force difference with a warning
    they were not told to show), and makes showing setup.warnings a must."""
    from hydrolink.protocol.scene import Water
    spec = resources.files("hydrolink.protocol").joinpath("SPEC.md").read_text()
    hello = spec.split("### 5.1 `hello`", 1)[1].split("#### `setup`", 1)[0]
    defaults = {k: f.default for k, f in Water.model_fields.items()}
    assert defaults["density"] == 1025.0
    assert f"`[water] density = {defaults['density']!r}` kg/m³" in hello
    assert f"`gravity = {defaults['gravity']!r}` m/s²" in hello and f'`depth = "{defaults["depth"]}"`' in hello
    (row,) = [line for line in spec.split("#### `setup`", 1)[1].splitlines() if line.startswith("| `warnings` ")]
    assert "A client **must** show every one to its user" in row and "naming the key to change" in row


def test_round_trip_over_the_wire_is_exact(setup, sphere):
    back = Setup.from_wire(wire(setup))
    for f in fields(Setup):
        a, b = getattr(setup, f.name), getattr(back, f.name)
        if isinstance(a, np.ndarray):
            assert a.dtype == b.dtype and np.array_equal(a, b), f.name
        else:
            assert a == b, f.name
    # and it carries the physics: the HDB's A∞ and ρgπR² for the heave stiffness of a 5 m sphere
    assert back.added_mass_inf[2, 2] == pytest.approx(float(sphere["added_mass_inf"].values[2, 2]), rel=1e-12)
    assert back.hydrostatic_stiffness[2, 2] == pytest.approx(1000 * 9.81 * np.pi * 25, rel=1e-3)
    assert back.active.tolist() == [[False, False, True, False, True, False]]


@pytest.mark.parametrize("name", ["added_mass", "equilibrium_position", "net_buoyancy", "dt", "bodies"])
def test_a_missing_field_is_named(setup, name):
    data = wire(setup)
    del data[name]
    with pytest.raises(ProtocolError) as err:
        Setup.from_wire(data)
    assert err.value.field == f"setup.{name}" and err.value.code == codec.Code.MISSING_FIELD


def test_a_wrong_shape_or_type_is_named(setup):
    data = wire(setup)
    data["added_mass"] = np.zeros((5, 5))
    with pytest.raises(ProtocolError, match=r"shape must be \(6, 6\)") as err:
        Setup.from_wire(data)
    assert err.value.field == "setup.added_mass"
    data = wire(setup)
    data["irf_processing"]["taper"] = "wide"
    with pytest.raises(ProtocolError) as err:
        Setup.from_wire(data)
    assert err.value.field == "setup.irf_processing.taper"
    data = wire(setup)
    data["equilibrium_position"] = [[0.0, 0.0, float("nan"), 0.0, 0.0, 0.0]]
    with pytest.raises(ProtocolError, match="NaN"):
        Setup.from_wire(data)


def test_fields_a_newer_server_adds_are_ignored(setup):
    data = wire(setup)
    data["some_future_field"] = {"x": 1}
    assert Setup.from_wire(data).bodies == ("sphere",)


def test_state_space_report_is_typed():
    data = {"states": 12, "pairs": 3, "max_order": 6, "max_fit_error": 0.004, "unmet": 0,
            "worst_pair": "(sphere.heave, sphere.heave)"}
    from hydrolink.protocol.setup import _state_space
    assert _state_space(data) == StateSpaceReport(12, 3, 6, 0.004, 0, "(sphere.heave, sphere.heave)")  # older server
    assert _state_space({**data, "fitted_pairs": 0}).fitted_pairs == 0
    with pytest.raises(ProtocolError) as err:
        _state_space({**data, "states": 1.5})
    assert err.value.field == "setup.state_space.states"
