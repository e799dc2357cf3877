"""Joint friction (clients/exudyn/mechanism.py: the regularised Coulomb law F tanh(v / v_reg) on a
revolute or prismatic joint's free coordinate, an Exudyn symbolic user function) on dry scenes, no
force server: the motion against the free coordinate's own equation solved in closed form, and
``joint_force`` — the load on body2 from body1 — carrying the friction beside the constraint's
reaction.

One free coordinate u (an angle about a principal axis through the centre of mass, or a slide),
inertia I (moment of inertia or mass), friction F: I u'' = -F tanh(u' / v_reg), separable:

    u'(t) = v_reg asinh(sinh(u'(0) / v_reg) exp(-F t / (I v_reg)))

— the constant deceleration F / I while |u'| >> v_reg, then the exponential stop.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import xarray as xr

import exudyn as exu

from conftest import body, joint, scene_toml

from hydrolink.clients.exudyn.client import result_bodies, run
from hydrolink.clients.exudyn.mechanism import build_mechanism
from hydrolink.clients.lockstep.results import ResultWriter
from hydrolink.protocol.scene import parse_scene

G = 9.81
DT = 1e-3


def simulate(tmp_path: Path, duration: float, **sections) -> xr.Dataset:
    """A dry scene (``sections`` as scene_toml takes them) run through the Exudyn client alone."""
    text = scene_toml(dt=DT, duration=duration, progress=False, **sections)
    scene = parse_scene(text)
    names, ref = result_bodies(scene, None)
    out = tmp_path / "run.nc"
    with ResultWriter(out, scene=scene, scene_text=text, dt=DT, bodies=names, equilibrium_position=ref) as writer:
        run(scene, text, None, None, writer, progress=False)
    return xr.load_dataset(out)


def closed_form(t: np.ndarray, u0: float, inertia: float, force: float, v_reg: float) -> np.ndarray:
    """u'(t) of I u'' = -F tanh(u' / v_reg) (module docstring)."""
    return v_reg * np.arcsinh(np.sinh(u0 / v_reg) * np.exp(-force * t / (inertia * v_reg)))


def check_free_coordinate(t, u, u0, inertia, force, v_reg):
    """The free coordinate's rate ``u``: deceleration F / I while |u'| > 10 v_reg, the whole decay
    (the tanh zone and the stop too) the closed form's to the integrator's error."""
    fast = np.flatnonzero(np.abs(u) > 10 * v_reg)[-1]
    assert (u[0] - u[fast]) / t[fast] == pytest.approx(math.copysign(force / inertia, u0), rel=1e-7)
    assert np.abs(u - closed_form(t, u0, inertia, force, v_reg)).max() < 2e-3 * v_reg
    assert abs(u[-1]) < 1e-6 * v_reg                                         # stopped


# a disc spinning about a principal axis through its centre of mass (gravity has no moment about it)
COM = [0.4, -0.3, 1.0]
SPIN = {"z": (2, [0.3, 0.5, 0.4]), "x": (0, [0.4, 0.3, 0.5])}   # axis: (its index, principal inertia)


@pytest.mark.parametrize("reversed_", [False, True], ids=["ground-disc", "disc-ground"])
@pytest.mark.parametrize("axis", list(SPIN))
def test_revolute_spin_down(tmp_path, axis, reversed_):
    """A disc on a revolute joint to ground spins down at F / I, then stops as the closed form
    does; ``joint_force``'s moment about the axis is the friction torque on body2 from body1 —
    −F tanh(ω / v_reg) on the disc, its opposite on ground — and the rest is the constraint's:
    the disc's weight carried, no moment about the other axes."""
    mass, force, v_reg, w0 = 3.0, 1.5, 0.05, 2.0
    k, inertia = SPIN[axis]
    e = np.eye(3)[k]
    ends = ("disc", "ground") if reversed_ else ("ground", "disc")
    ds = simulate(tmp_path, 1.0,
                  bodies=[body("disc", mass=mass, center_of_mass=COM, inertia=inertia,
                               initial_velocity=[0.0, 0.0, 0.0, *(w0 * e)])],
                  joints=[joint("revolute", *ends, COM, axis=e.tolist(),
                                friction={"force": force, "velocity": v_reg})])
    t = ds.time.values
    w = ds.velocity.sel(body="disc").values[:, 3 + k]     # about one global axis: the angle's rate is ω
    check_free_coordinate(t, w, w0, inertia[k], force, v_reg)
    f = ds.joint_force.values[:, 0]
    sign = 1.0 if reversed_ else -1.0                       # on the disc from ground: against ω
    np.testing.assert_allclose(f[:, 3 + k], sign * force * np.tanh(w / v_reg), rtol=0, atol=1e-9 * force)
    fast = np.abs(w) > 10 * v_reg
    np.testing.assert_allclose(f[fast, 3 + k], sign * force, rtol=1e-8)    # 1 - tanh(10) = 4e-9
    weight = mass * G * np.array([0.0, 0.0, 1.0])
    np.testing.assert_allclose(f[:, :3], np.tile(-sign * weight, (len(t), 1)), atol=1e-8 * mass * G)
    others = [3 + i for i in range(3) if i != k]
    assert np.abs(f[:, others]).max() < 1e-8 * force


def test_two_discs_on_a_common_axle(tmp_path):
    """Two discs falling freely, joined by a revolute joint with friction on their common axis and
    spinning opposite ways: their relative rate decays as the closed form with the reduced inertia
    1 / (1/I₁ + 1/I₂), the total angular momentum stays, and ``joint_force`` (marker 0's frame turning
    with disc 1) is the friction torque on disc 2 alone — no force between bodies in free fall."""
    i1, i2, force, v_reg, w1, w2 = 0.4, 0.6, 1.0, 0.05, 1.0, -1.5
    ds = simulate(tmp_path, 1.0,
                  bodies=[body("d1", mass=3.0, center_of_mass=COM, inertia=[0.3, 0.5, i1],
                               initial_velocity=[0.0, 0.0, 0.0, 0.0, 0.0, w1]),
                          body("d2", mass=2.0, center_of_mass=COM, inertia=[0.35, 0.4, i2],
                               initial_velocity=[0.0, 0.0, 0.0, 0.0, 0.0, w2])],
                  joints=[joint("revolute", "d1", "d2", COM, axis=[0.0, 0.0, 1.0],
                                friction={"force": force, "velocity": v_reg})])
    t = ds.time.values
    yaw = ds.velocity.sel(dof="yaw")
    r1, r2 = yaw.sel(body="d1").values, yaw.sel(body="d2").values
    check_free_coordinate(t, r2 - r1, w2 - w1, 1.0 / (1.0 / i1 + 1.0 / i2), force, v_reg)
    np.testing.assert_allclose(i1 * r1 + i2 * r2, i1 * w1 + i2 * w2, rtol=0, atol=1e-12)
    f = ds.joint_force.values[:, 0]
    np.testing.assert_allclose(f[:, 5], -force * np.tanh((r2 - r1) / v_reg), rtol=0, atol=1e-9 * force)
    assert np.abs(f[:, :5]).max() < 1e-9 * force


@pytest.mark.parametrize("reversed_", [False, True], ids=["ground-slider", "slider-ground"])
@pytest.mark.parametrize("direction", [[1.0, 0.0, 0.0], [0.6, 0.8, 0.0]], ids=["x", "oblique"])
def test_prismatic_slide_down(tmp_path, direction, reversed_):
    """A mass sliding on a horizontal prismatic joint slows at F / m and stops as the closed form
    does; ``joint_force``'s force along the axis is the friction on body2 from body1 (−F tanh(v /
    v_reg) along the motion on the slider), the rest the weight carried; on the slider about its
    centre of mass no moment, on ground (reversed) the weight's moment about the joint point the
    slider has left."""
    mass, force, v_reg, v0 = 2.0, 4.0, 0.02, 1.0
    a = np.asarray(direction)
    ends = ("slider", "ground") if reversed_ else ("ground", "slider")
    ds = simulate(tmp_path, 0.8,
                  bodies=[body("slider", mass=mass, center_of_mass=COM, inertia=[0.1, 0.2, 0.3],
                               initial_velocity=[*(v0 * a), 0.0, 0.0, 0.0])],
                  joints=[joint("prismatic", *ends, COM, axis=a.tolist(), friction={"force": force, "velocity": v_reg})])
    t = ds.time.values
    d = ds.position.sel(body="slider").values[:, :3] - np.asarray(COM)
    v = ds.velocity.sel(body="slider").values[:, :3] @ a
    check_free_coordinate(t, v, v0, mass, force, v_reg)
    f = ds.joint_force.values[:, 0]
    on_slider = -force * np.tanh(v / v_reg)[:, None] * a + mass * G * np.array([0.0, 0.0, 1.0])
    load = -on_slider if reversed_ else on_slider          # on body2 from body1
    np.testing.assert_allclose(f[:, :3] @ a, load @ a, rtol=0, atol=1e-12 * force)   # the friction, to round-off
    fast = np.abs(v) > 10 * v_reg
    np.testing.assert_allclose(f[fast, :3] @ a, (1.0 if reversed_ else -1.0) * force, rtol=1e-8)
    # the constraint's part: the multipliers carry the trapezoidal rule's step-to-step alternation
    # (measured up to 3.6e-7 m g across an oblique axis in 0.8 s)
    np.testing.assert_allclose(f[:, :3], load, rtol=0, atol=1e-6 * mass * G)
    moment = np.cross(d, load) if reversed_ else np.zeros_like(d)     # about marker 1's point (module docstring)
    np.testing.assert_allclose(f[:, 3:], moment, rtol=0, atol=1e-6 * mass * G)


def test_the_law_is_evaluated_by_exudyn():
    """The friction connector's user function is an Exudyn symbolic one (evaluated in C++: no Python
    call in the step), the law with the scene's F and v_reg on the free axis (its torque, in the
    joint frame, at a few spin rates of a disc on a revolute joint about z)."""
    for w in (0.02, -0.3, 4.0):
        text = scene_toml(dt=DT, duration=0.01,
                          bodies=[body("disc", mass=3.0, center_of_mass=COM, inertia=[0.3, 0.5, 0.4],
                                       initial_velocity=[0.0, 0.0, 0.0, 0.0, 0.0, w])],
                          joints=[joint("revolute", "ground", "disc", COM, axis=[0.0, 0.0, 1.0],
                                        friction={"force": 1.5, "velocity": 0.05})])
        sc = exu.SystemContainer()
        mbs = sc.AddSystem()
        mech = build_mechanism(mbs, parse_scene(text), {})
        fobj = mech.joints[0].friction_object
        assert mbs.GetObject(fobj)["springForceTorqueUserFunction"]["type"] == "Symbolic"
        torque = mbs.GetObjectOutput(fobj, exu.OutputVariableType.TorqueLocal)
        frame = mech.joints[0].frame                  # joint z = the axis
        np.testing.assert_allclose(frame @ torque, [0.0, 0.0, 1.5 * math.tanh(w / 0.05)], rtol=1e-15, atol=1e-15)
