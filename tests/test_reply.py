"""The force-reply contract (protocol/reply.py): SPEC §5.2's `forces` table, no more, no less, and
what a client reads of a reply."""

from __future__ import annotations

import re
from importlib import resources

import numpy as np
import pytest

from hydrolink.protocol import codec
from hydrolink.protocol.capabilities import FEATURES
from hydrolink.protocol.codec import ProtocolError
from hydrolink.protocol.reply import OPTIONAL_FORCES, REPLY_FIELDS, REQUIRED_FORCES, read_forces, reply_field


def spec_rows() -> dict[str, str]:
    """SPEC §5.2's reply table: field -> its type cell."""
    spec = resources.files("hydrolink.protocol").joinpath("SPEC.md").read_text()
    table = spec.split("Reply `forces`", 1)[1].split("#### Force contract", 1)[0]
    return dict(re.findall(r"^\| `(\w+)` +\| ([^|]+?) *\|", table, re.M))


def test_every_reply_field_is_in_the_spec_table():
    """SPEC §5.2 lists each reply field with its type, 'optional' exactly for the optional ones,
    and lists nothing the contract lacks."""
    rows = spec_rows()
    assert list(rows) == [f.name for f in REPLY_FIELDS]
    for f in REPLY_FIELDS:
        cell = rows[f.name]
        assert cell.removesuffix(", optional") == f.wire, f.name
        assert ("optional" in cell) == (not f.required and f.array), f.name


def test_the_force_contract_names_every_part_of_the_load():
    """The force contract's "applied force, each step" row names exactly the load fields."""
    spec = resources.files("hydrolink.protocol").joinpath("SPEC.md").read_text()
    row = next(line for line in spec.splitlines() if line.startswith("| applied force, each step"))
    what = row.split("|")[2]    # the "what" column; the "from" column names the message
    named = set(re.findall(r"\w+", " ".join(re.findall(r"`([^`]+)`", what))))
    assert named == {f.name for f in REPLY_FIELDS if f.load}
    assert REQUIRED_FORCES == ("excitation", "radiation", "hydrostatic")


def test_optional_forces_come_from_features_and_carry_results_variables():
    """Every optional force is brought by some scene feature and has results variables with
    dims, units and a description; every feature's fields are optional forces."""
    brought = {f for feature in FEATURES.values() for f in feature.reply_fields}
    assert brought == set(OPTIONAL_FORCES)
    names = [v.name for f in OPTIONAL_FORCES for v in reply_field(f).variables]
    assert len(names) == len(set(names))
    for f in OPTIONAL_FORCES:
        for v in reply_field(f).variables:
            assert v.dims in (("body", "dof"), ("body",)) and v.units and v.description, v.name


def test_read_forces_checks_each_present_force_and_names_it():
    n = 2
    ok = {k: codec.encode_array(np.ones((n, 6))) for k in REQUIRED_FORCES}
    reply = {**ok, "morison": codec.encode_array(np.full((n, 6), 2.0)), "wave_elevation": 0.5}
    read_forces(reply, (n, 6))
    assert reply["morison"].shape == (n, 6) and float(reply["morison"][1, 5]) == 2.0
    assert "viscous" not in reply
    bad = {**ok, "nonlinear_hydrostatic": codec.encode_array(np.ones((n, 5)))}
    with pytest.raises(ProtocolError, match=r"shape must be \(2, 6\)") as err:
        read_forces(bad, (n, 6))
    assert err.value.field == "nonlinear_hydrostatic"
    with pytest.raises(ProtocolError) as err:
        read_forces({k: v for k, v in ok.items() if k != "radiation"}, (n, 6))
    assert err.value.field == "radiation"


def test_a_hydro_state_change_crosses_the_wire_and_bad_ones_are_named():
    """A reply's hydro_state (revision 1.14) packed and unpacked by the codec reads back equal; a wrong
    shape or a missing name is a ProtocolError naming hydro_state.<field>."""
    from hydrolink.protocol.reply import HydroStateChange
    n, rng = 2, np.random.default_rng(5)
    change = HydroStateChange("float", "sunk", rng.normal(size=(12, 12)), rng.normal(size=(12, 12)),
                              rng.normal(size=n), rng.normal(size=(n, 6)), rng.normal(size=(12, 12)))
    wire = codec.unpack(codec.pack(codec.message("forces", 1, None, hydro_state=change.to_wire())))["hydro_state"]
    back = HydroStateChange.from_wire(wire, n)
    assert (back.body, back.state) == ("float", "sunk")
    for key in ("added_mass", "hydrostatic_stiffness", "net_buoyancy", "equilibrium_position", "radiation_feedthrough"):
        np.testing.assert_array_equal(getattr(back, key), getattr(change, key))
    with pytest.raises(ProtocolError) as err:
        HydroStateChange.from_wire({**change.to_wire(), "added_mass": np.ones((6, 6))}, n)
    assert err.value.field == "hydro_state.added_mass"
    with pytest.raises(ProtocolError) as err:
        HydroStateChange.from_wire({k: v for k, v in change.to_wire().items() if k != "state"}, n)
    assert err.value.field == "hydro_state.state"
