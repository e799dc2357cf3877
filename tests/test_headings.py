"""Wave headings of HDB data (server/sea/headings.py): the same data labelled 0..345 deg, -165..180
deg, 0..360 deg (both ends) and as the half range 0..180 deg of a body symmetric about y = 0 give
the same excitation, mean drift and QTF force at 170, -170, 179 and 181 deg, each equal to the
linear interpolation around the circle written here from the closed-form data; headings the data
leave out are refused naming the key."""

from __future__ import annotations

import numpy as np
import pytest

from analytic_hdb import make_body_hdb
from conftest import body, irregular_waves, regular_waves, scene_toml

from hydrolink.protocol.hdb.second_order import QTF, MeanDrift
from hydrolink.protocol.hdb.schema import with_second_order
from hydrolink.protocol.scene import SceneError, parse_scene
from hydrolink.server.errors import ModelError
from hydrolink.server.model import HydroModel
from hydrolink.server.sea.headings import heading_weights
from hydrolink.server.sea.waves import WaveError

W_DRIFT = np.linspace(0.5, 2.0, 7)          # holds w = 1 exactly (the wave's frequency)


def excitation(w, beta):
    """X(w, beta) (n_w, 6): port-starboard symmetric (sway, roll, yaw odd in beta)."""
    base = np.array([1e4, 1e4, 3e5, 2e5, 2e5, 1e4])
    rot = np.array([np.cos(beta), np.sin(beta), 1.0, np.sin(beta), np.cos(beta), 0.5 * np.sin(2 * beta)])
    return (base * rot)[None, :] * np.exp(-0.3 * w[:, None] ** 2) * np.exp(1j * (0.4 + 0.8 * w[:, None]))


def drift(w, beta):
    """Mean drift T(w, beta) (n_w, 6), symmetric as the excitation (N/m^2, N m/m^2)."""
    v = np.array([np.cos(beta), np.sin(beta), 0.1, 0.05 * np.sin(beta), 0.02 * np.cos(beta), 0.3 * np.sin(2 * beta)])
    return 1e4 * np.exp(-np.asarray(w))[:, None] * v[None, :]


def qtf(w, beta):
    """Difference QTF T(w_i, w_j, beta, beta) (n, n, 6), real and symmetric in (w_i, w_j)."""
    v = np.array([np.cos(beta), np.sin(beta), 0.2, 0.1 * np.sin(beta), 0.05 * np.cos(beta), 0.4 * np.sin(2 * beta)])
    s = 1.0 + 0.1 * (w[:, None] + w[None, :])
    return 2e3 * s[:, :, None] * v[None, None, :]


def hdb(degrees):
    """The analytic HDB with its data at the headings ``degrees`` (as labelled)."""
    b = np.deg2rad(np.asarray(degrees, float))
    ds = make_body_hdb(omega=np.linspace(0.2, 3.0, 57), directions=b, exc=excitation)
    md = MeanDrift(("pressure",), W_DRIFT, b, np.stack([drift(W_DRIFT, x) for x in b], axis=1)[None], "analytic")
    t = np.stack([qtf(W_DRIFT, x) for x in b], axis=2).astype(complex)
    return with_second_order(ds, mean_drift=md, qtf=QTF(W_DRIFT, b, b, t, None, "analytic"))


LABELLINGS = {
    "0..345": (np.arange(0, 360, 15.0), "none"),
    "-165..180": (np.arange(-165, 181, 15.0), "none"),
    "0..360": (np.arange(0, 361, 15.0), "none"),
    "half 0..180": (np.arange(0, 181, 15.0), "xz"),
}


def _model(ds, direction: float, mode: str, symmetry: str = "none", waves=None) -> HydroModel:
    text = scene_toml(dt=0.1, duration=10.0, water={"density": 1000.0},
                      waves=waves or regular_waves(2.0, 2 * np.pi, direction=direction),
                      hydro={"second_order": mode},
                      bodies=[body("float", hdb="h", mass=3.0e5, center_of_mass=[0, 0, 0], inertia=[1e6] * 3,
                                   heading_symmetry=symmetry)])
    return HydroModel(parse_scene(text), {"float": ds})


def _figures(ds, direction: float, symmetry: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """X(1 rad/s, direction), the mean drift and the QTF force of a regular wave of amplitude 1."""
    out = []
    for mode in ("mean-drift", "qtf"):
        m = _model(ds, direction, mode, symmetry)
        x0 = m.setup_info().equilibrium_position
        out.append(m.step(0.0, x0, np.zeros_like(x0))["drift"][0])
    return m.excitation_phasors()[1][0], out[0], out[1]


def _circle_reference(f, direction: float) -> np.ndarray:
    """f at ``direction`` interpolated linearly between its neighbours on a 15-deg circle grid."""
    d = np.mod(direction, 360.0)
    lo = 15.0 * np.floor(d / 15.0)
    s = (d - lo) / 15.0
    return (1 - s) * f(np.deg2rad(lo)) + s * f(np.deg2rad(lo + 15.0))


@pytest.mark.parametrize("direction", [170.0, -170.0, 179.0, 181.0])
def test_every_labelling_gives_the_circle_interpolation(direction):
    one = np.array([1.0])
    refs = (_circle_reference(lambda b: excitation(one, b)[0], direction),
            _circle_reference(lambda b: drift(one, b)[0], direction),
            _circle_reference(lambda b: qtf(one, b)[0, 0], direction))
    for name, (degrees, symmetry) in LABELLINGS.items():
        got = _figures(hdb(degrees), direction, symmetry)
        for what, g, r in zip(("excitation", "mean drift", "QTF"), got, refs):
            np.testing.assert_allclose(g, r, rtol=1e-9, atol=1e-9 * np.abs(r).max(), err_msg=f"{name}: {what}")


def test_weights_split_coinciding_headings_and_refuse_the_gap():
    w = heading_weights(np.deg2rad([0.0, 90.0, 360.0]), np.deg2rad([-360.0, 45.0, 0.0]), "k")
    np.testing.assert_allclose(w, [[0.5, 0.0, 0.5], [0.25, 0.5, 0.25], [0.5, 0.0, 0.5]])
    with pytest.raises(WaveError) as err:        # 0..90: the gap 90..360 is left out
        heading_weights(np.deg2rad([0.0, 90.0]), np.deg2rad([180.0]), "waves.direction")
    assert err.value.key == "waves.direction" and "90...360" in err.value.why
    # a single heading serves only itself (in any labelling)
    np.testing.assert_allclose(heading_weights(np.array([np.pi]), np.array([-np.pi]), "k"), [[1.0]])


def test_half_range_without_symmetry_is_refused_naming_the_wave_key():
    ds = hdb(np.arange(0, 181, 15.0))
    with pytest.raises(ModelError) as err:
        _model(ds, -170.0, "none")
    assert err.value.key == "waves.direction" and "heading_symmetry" in err.value.why
    with pytest.raises(ModelError) as err:      # the drift's headings: the same rule, the same key
        _model(ds, -170.0, "mean-drift")
    assert err.value.key == "waves.direction"
    spread = irregular_waves(1.0, 8.0, components=20, direction=-170.0, spreading="cos2s", directions=5,
                             omega_range=[0.5, 2.0])
    with pytest.raises(ModelError) as err:
        _model(ds, 0.0, "none", waves=spread)
    assert err.value.key == "waves.spreading"
    _model(ds, 0.0, "mean-drift", "xz", waves=spread)      # the completed circle serves the spread sea


def test_symmetry_off_the_plane_or_of_a_dry_body_is_refused():
    b = np.deg2rad(np.arange(0, 181, 15.0))
    ds = make_body_hdb(omega=np.linspace(0.2, 3.0, 57), directions=b, exc=excitation, ref=(0.0, 3.0, 0.0))
    with pytest.raises(ModelError) as err:
        _model(ds, -170.0, "none", "xz")
    assert err.value.key == "bodies[0].heading_symmetry" and "y = 3" in err.value.why
    dry = scene_toml(dt=0.1, duration=1.0, bodies=[body("pole", mass=1.0, center_of_mass=[0, 0, 0], inertia=[1.0] * 3,
                                                        heading_symmetry="xz")])
    with pytest.raises(SceneError, match=r"bodies\[0\].*heading_symmetry"):
        parse_scene(dry)
