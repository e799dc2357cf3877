"""The Doppler shift of waves in a current (server/sea/doppler.py, ``[current] doppler``) against
the closed form written here: in deep water a wave of intrinsic frequency w, k = w^2/g, is seen
at a fixed point at w + k U cos(beta - theta_c): faster in a following current, slower in an
opposing one (the sign WEC-Sim #1534 got wrong for its current). The excitation keeps X(w) at the
intrinsic frequency; wave blocking and the convolution are refused naming the key."""

from __future__ import annotations

import numpy as np
import pytest

from analytic_hdb import make_body_hdb
from conftest import body, irregular_waves, regular_waves, scene_toml

from hydrolink.protocol.scene import parse_scene
from hydrolink.server.errors import ModelError
from hydrolink.server.model import HydroModel
from hydrolink.server.sea.probes import WaveProbes

G = 9.81
PERIOD, A, PHASE = 8.0, 0.75, 40.0


def _model(current: dict | None, waves: dict | None = None) -> HydroModel:
    ds = make_body_hdb(omega=np.linspace(0.05, 4.0, 300), directions=np.deg2rad(np.arange(-180.0, 180.0, 15.0)))
    text = scene_toml(dt=0.1, duration=20.0, water={"density": 1000.0, "gravity": G},
                      waves=waves or regular_waves(2 * A, PERIOD, direction=30.0, phase=PHASE),
                      current=current,
                      bodies=[body("float", hdb="h", mass=3.0e5, center_of_mass=[0, 0, 0], inertia=[1e6] * 3)])
    return HydroModel(parse_scene(text), {"float": ds})


@pytest.mark.parametrize("towards, sign", [(30.0, 1.0), (210.0, -1.0), (120.0, 0.0)])
def test_encounter_frequency_sign_and_elevation(towards, sign):
    u = 1.2
    m = _model({"speed": u, "direction": towards, "doppler": True})
    w = 2 * np.pi / PERIOD
    k = w ** 2 / G
    we = w + sign * k * u                      # cos(beta - theta_c) = 1, -1, 0
    x0 = m.setup_info().equilibrium_position
    for n in range(5):
        t = 0.1 * n
        eta = m.step(t, x0, np.zeros_like(x0))["wave_elevation"]
        assert eta == pytest.approx(A * np.cos(we * t - np.deg2rad(PHASE)), abs=1e-9)
    # the wave keeps its length: a probe 40 m along the wave sees k(w) x, not k(w_e) x
    p = np.array([[40.0 * np.cos(np.deg2rad(30.0)), 40.0 * np.sin(np.deg2rad(30.0))]])
    probe = WaveProbes(m.waves, p, np.zeros(0), G, float("inf"))
    for t in (0.0, 2.3, 17.9):
        assert probe(t)[0, 0] == pytest.approx(A * np.cos(k * 40.0 - we * t + np.deg2rad(PHASE)), abs=1e-9)
    # the excitation phasor is X at the intrinsic frequency, as without a current
    still = _model(None)
    np.testing.assert_allclose(m.excitation_phasors()[1], still.excitation_phasors()[1], rtol=1e-12)
    assert m.excitation_phasors()[0][0] == pytest.approx(we, rel=1e-12)
    assert _model({"speed": u}).excitation_phasors()[0][0] == pytest.approx(w, rel=1e-12)   # off by default


def test_blocking_and_convolution_are_refused():
    short = regular_waves(0.2, 2.0)                       # c_g = g / (2 w) = 1.56 m/s
    with pytest.raises(ModelError) as err:
        _model({"speed": 2.0, "direction": 180.0, "doppler": True}, short)
    assert err.value.key == "current.doppler" and "blocking" in err.value.why
    _model({"speed": 1.0, "direction": 180.0, "doppler": True}, short)
    with pytest.raises(ModelError) as err:
        _model({"speed": 1.0, "doppler": True}, irregular_waves(1.0, 8.0, components=10, excitation="convolution"))
    assert err.value.key == "current.doppler"
