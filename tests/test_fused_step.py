"""The fused, compiled linear step (server/fused/) against the model's numpy path, its reference:
RM3 (WAMIT, float + spar, every radiation option and the sparse kernel) and the Task-10 sphere
(regular, irregular and convolution excitation, still water), the same states in, the same forces
out to round-off, through iterations (replace_last) and a rollback (state/set_state)."""

from __future__ import annotations

import numpy as np
import pytest

from conftest import SPHERE_WATER, irregular_waves, joint, regular_waves, rm3_float, rm3_spar, scene_toml, sphere_body
from hydrolink.protocol.scene import parse_scene
from hydrolink.server import compiler
from hydrolink.server.hdb.io import load_hdb
from hydrolink.server.model import HydroModel

pytestmark = pytest.mark.skipif(not (compiler.AVAILABLE and compiler.imports()), reason="numba not importable")

FIELDS = ("excitation", "radiation", "hydrostatic")


def _pair(text: str, hdbs: dict) -> tuple[HydroModel, HydroModel]:
    scene = parse_scene(text)
    fused, ref = HydroModel(scene, hdbs, compiled=True), HydroModel(scene, hdbs, compiled=False)
    assert fused._fused is not None and ref._fused is None
    return fused, ref


def _compare(fused: HydroModel, ref: HydroModel, steps: int = 60, seed: int = 0) -> None:
    """Random states, each step once sent and once re-sent (replace_last); a rollback halfway."""
    rng = np.random.default_rng(seed)
    n_b = len(ref.bodies)
    eq = ref.equilibrium_position
    ref.step(0.0, eq, np.zeros((n_b, 6)))
    fused.step(0.0, eq, np.zeros((n_b, 6)))
    saved = None
    k = 1
    while k < steps:
        x, v = eq + 0.1 * rng.standard_normal((n_b, 6)), rng.standard_normal((n_b, 6))
        for replace in (False, True):
            a, b = fused.step(k * ref.dt, x, v, replace_last=replace), ref.step(k * ref.dt, x, v, replace_last=replace)
            for name in FIELDS:
                scale = float(np.abs(b[name]).max())    # round-off of the sums, relative to their largest
                np.testing.assert_allclose(a[name], b[name], rtol=0, atol=1e-12 * scale, err_msg=f"{name} step {k}")
            assert a["wave_elevation"] == pytest.approx(b["wave_elevation"], rel=1e-12, abs=1e-14)
            x = x + 0.01
        if k == steps // 3:
            saved = fused.state(), ref.state(), k
        k += 1
        if k == 2 * steps // 3 and saved is not None:
            fs, rs, k0 = saved
            fused.set_state(fs)
            ref.set_state(rs)
            k, saved = k0 + 1, None


@pytest.fixture(scope="module")
def rm3(reference_data):
    ds = load_hdb(reference_data / "rm3_wamit" / "rm3.1")
    return {"float": ds, "spar": ds}


@pytest.mark.parametrize("hydro", [{"irf_duration": 20.0},
                                   {"irf_duration": 20.0, "radiation": "state-space"},
                                   {"irf_duration": 20.0, "radiation": "constant"},
                                   {"irf_duration": 20.0, "coupling_tolerance": 0.2}])
def test_rm3_every_radiation(rm3, hydro):
    """Two bodies of one HDB, full interaction; float heave + pitch, spar every DOF: dense and
    sparse kernels, state space with feedthrough-free fits, constant damping."""
    text = scene_toml(dt=0.05, duration=10, water={"density": 1000.0}, waves=regular_waves(2.5, 8.0, ramp=1.0),
                      hydro=hydro, bodies=[rm3_float("r.1", dofs=["heave", "pitch"]), rm3_spar("r.1")])
    fused, ref = _pair(text, rm3)
    if "coupling_tolerance" in hydro:
        assert ref._memories[0][1].sparse, "the pruned kernel is meant to be sparse here"
    _compare(fused, ref)


@pytest.mark.parametrize("waves, radiation", [
    (irregular_waves(2.0, 8.0, components=50, ramp=2.0, seed=3), "convolution"),
    (irregular_waves(2.0, 8.0, components=50, seed=3, excitation="convolution", excitation_irf_duration=10.0),
     "state-space"),
    (None, "state-space")])
def test_sphere(sphere, waves, radiation):
    """The Task-10 sphere in surge, heave and pitch: irregular waves summed by components or by
    the excitation IRF, and still water (decay)."""
    text = scene_toml(dt=0.015, duration=10, water=SPHERE_WATER, waves=waves,
                      hydro={"irf_duration": 10.0, "radiation": radiation},
                      bodies=[sphere_body("s.h5", mass=261800.0, dofs=["surge", "heave", "pitch"])])
    _compare(*_pair(text, {"sphere": sphere}))


def test_several_groups_take_the_numpy_path(rm3):
    """interaction = "none": one radiation group per body, which the fused step does not take."""
    text = scene_toml(dt=0.05, duration=10, water={"density": 1000.0}, hydro={"interaction": "none"},
                      bodies=[rm3_float("r.1", dofs=["heave"]), rm3_spar("r.1", dofs=["heave"])])
    assert HydroModel(parse_scene(text), rm3, compiled=True)._fused is None


@pytest.mark.parametrize("hydro", [{"irf_duration": 20.0}, {"irf_duration": 20.0, "coupling_tolerance": 0.2}])
def test_a_held_bodys_radiation_columns_are_left_out(rm3, hydro):
    """The spar held to ground by a fixed joint, the float on a hinge about y to it: the compiled
    step convolves the float's surge, heave and pitch columns only (the spar's velocity and the
    float's sway, roll and yaw are zero), dense and sparse, and gives the full computation's
    forces (the numpy path, every column) on every row, the spar's included, to round-off; the
    velocities it holds at zero are not read."""
    text = scene_toml(dt=0.05, duration=10, water={"density": 1000.0}, waves=regular_waves(2.5, 8.0, ramp=1.0),
                      hydro=hydro, bodies=[rm3_float("r.1"), rm3_spar("r.1")],
                      joints=[joint("revolute", "spar", "float", [0.0, 0.0, 0.0], axis=[0.0, 1.0, 0.0]),
                              joint("fixed", "ground", "spar", [0.0, 0.0, -21.29])])
    fused, ref = _pair(text, rm3)
    held = ref.held_dofs()
    assert list(held) == [False, True, False, True, False, True] + [True] * 6
    assert fused._fused._buf.shape[1] == 3                   # the float's three columns in the ring, not twelve
    rng = np.random.default_rng(1)
    eq, dt = ref.equilibrium_position, ref.dt
    moved = 0.0
    for k in range(60):
        x, v = eq.copy(), np.zeros((2, 6))
        x[0] += 0.1 * rng.standard_normal(6)
        v[0, [0, 2, 4]] = rng.standard_normal(3)
        a, b = fused.step(k * dt, x, v + held.reshape(2, 6)), ref.step(k * dt, x, v)
        for name in FIELDS:
            scale = float(np.abs(b[name]).max())
            np.testing.assert_allclose(a[name], b[name], rtol=0, atol=1e-12 * scale, err_msg=f"{name} step {k}")
        moved = max(moved, float(np.abs(b["radiation"][1]).max()))
    assert moved > 1e3                                         # the float's motion radiates onto the spar's rows
