"""Mechanism (clients/exudyn/mechanism.py) through the Exudyn client on dry scenes — no force server: a
scene without wet bodies runs the mechanism alone. Every joint type against an analytic result."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import xarray as xr

import exudyn as exu

from conftest import body, joint, scene_toml

from hydrolink.clients.exudyn.client import build_model, result_bodies, run
from hydrolink.clients.exudyn.mechanism import BodyHandle, build_mechanism, marker_at
from hydrolink.clients.lockstep.results import ResultWriter
from hydrolink.protocol.scene import SceneError, parse_scene

G = 9.81


def simulate(tmp_path: Path, *, dt: float = 0.001, duration: float = 1.0, **sections) -> xr.Dataset:
    """Run a dry scene (``sections`` as scene_toml takes them) through the client (no server) and read
    its results file."""
    text = scene_toml(dt=dt, duration=duration, progress=False, **sections)
    scene = parse_scene(text)
    names, ref = result_bodies(scene, None)
    out = tmp_path / "run.nc"
    with ResultWriter(out, scene=scene, scene_text=text, dt=dt, bodies=names,
                      equilibrium_position=ref) as writer:
        run(scene, text, None, None, writer, progress=False)
    return xr.load_dataset(out)


def zero_crossing_period(t: np.ndarray, x: np.ndarray) -> float:
    x = x - x.mean()
    i = np.flatnonzero((x[:-1] < 0) & (x[1:] >= 0))
    tc = t[i] - x[i] * (t[i + 1] - t[i]) / (x[i + 1] - x[i])
    return float(np.diff(tc).mean())


def pendulum_start(d: float, th: float) -> list[float]:
    """Initial displacement of a body hanging at distance d below a pivot on y, pitched by th."""
    return [-d * math.sin(th), 0.0, d - d * math.cos(th), 0.0, th, 0.0]


def test_revolute_pendulum_period_and_hanging_reaction(tmp_path):
    m, d, ic, th = 2.0, 1.0, 0.02, 0.05
    ds = simulate(tmp_path, dt=0.002, duration=6.0,
                  bodies=[body("bob", mass=m, center_of_mass=[0, 0, -d], inertia=[ic, ic, ic],
                               initial_displacement=pendulum_start(d, th))],
                  joints=[joint("revolute", "ground", "bob", [0, 0, 0], name="pivot", axis=[0, 1, 0])])
    period = zero_crossing_period(ds.time.values, ds.position.sel(body="bob", dof="pitch").values)
    expected = 2 * math.pi * math.sqrt((ic + m * d * d) / (m * G * d)) * (1 + th ** 2 / 16)
    assert period == pytest.approx(expected, rel=2e-5)
    assert float(ds.joint_violation.max()) < 1e-8
    assert list(ds.joint.values) == ["pivot"]


def test_static_hanging_body_reaction_is_its_weight(tmp_path):
    ds = simulate(tmp_path, duration=0.1,
                  bodies=[body("w", mass=3.0, center_of_mass=[0.2, 0.1, -1.0], inertia=[0.1, 0.2, 0.3])],
                  joints=[joint("spherical", "w", "ground", [0.2, 0.1, 0.0])])
    f = ds.joint_force.sel(joint="joints[0]").values
    # reaction on body2 (ground) from body1: the weight, downwards; no moment at a ball joint
    np.testing.assert_allclose(f[:, :3], np.tile([0.0, 0.0, -3.0 * G], (len(f), 1)), atol=1e-9)
    np.testing.assert_allclose(f[:, 3:], 0.0, atol=1e-9)


def test_spherical_conical_pendulum_rate(tmp_path):
    # isotropic central inertia drops out of the steady precession: Omega^2 = g / (L cos alpha)
    length, alpha = 1.0, 0.3
    om = math.sqrt(G / (length * math.cos(alpha)))
    ds = simulate(tmp_path, duration=3.0,
                  bodies=[body("bob", mass=1.0, center_of_mass=[0, 0, -length], inertia=[0.05, 0.05, 0.05],
                               initial_displacement=[0, length * math.sin(alpha), length * (1 - math.cos(alpha)),
                                                     alpha, 0, 0],
                               initial_velocity=[-om * length * math.sin(alpha), 0, 0, 0, om * math.sin(alpha),
                                                 om * math.cos(alpha)])],
                  joints=[joint("spherical", "ground", "bob", [0, 0, 0])])
    p = ds.position.sel(body="bob").values
    azimuth = np.unwrap(np.arctan2(p[:, 1], p[:, 0]))
    rate = np.polyfit(ds.time.values, azimuth, 1)[0]
    assert rate == pytest.approx(om, rel=1e-5)
    assert np.ptp(p[:, 2]) < 1e-6                      # steady: the bob stays at its height


def test_prismatic_slider_on_incline(tmp_path):
    a = 0.4
    axis = np.array([math.cos(a), 0.0, -math.sin(a)])
    ds = simulate(tmp_path, bodies=[body("s", mass=3.0, center_of_mass=[0, 0, 0], inertia=[0.1, 0.2, 0.3])],
                  joints=[joint("prismatic", "ground", "s", [0, 0, 0], axis=axis.tolist())])
    t, x = ds.time.values, ds.position.sel(body="s").values
    s = x[:, :3] @ axis
    np.testing.assert_allclose(s, 0.5 * G * math.sin(a) * t ** 2, rtol=1e-9, atol=1e-12)
    assert np.abs(x[:, :3] - np.outer(s, axis)).max() < 1e-9
    assert np.abs(x[:, 3:]).max() < 1e-9
    # normal reaction m g cos(a) (on ground from the slider: into the incline)
    assert np.linalg.norm(ds.joint_force.values[-1, 0, :3]) == pytest.approx(3 * G * math.cos(a), rel=1e-5)
    assert float(ds.joint_violation.max()) < 1e-9


def test_cylindrical_slides_and_spins_independently(tmp_path):
    ds = simulate(tmp_path, bodies=[body("c", mass=3.0, center_of_mass=[0, 0, 0], inertia=[0.1, 0.2, 0.3],
                                          initial_velocity=[0, 0, 0, 0, 0, 2.0])],
                  joints=[joint("cylindrical", "ground", "c", [0, 0, 0], axis=[0, 0, 1])])
    t, x = ds.time.values, ds.position.sel(body="c").values
    np.testing.assert_allclose(x[:, 2], -0.5 * G * t ** 2, atol=1e-9)
    np.testing.assert_allclose(x[:, 5], 2.0 * t, atol=1e-9)
    assert np.abs(x[:, [0, 1, 3, 4]]).max() < 1e-9


def test_planar_motion_stays_in_the_plane(tmp_path):
    b = 0.5
    n = np.array([0.0, math.sin(b), math.cos(b)])
    down = np.array([0.0, math.cos(b), -math.sin(b)])
    ds = simulate(tmp_path, bodies=[body("p", mass=3.0, center_of_mass=[0, 0, 0], inertia=[0.1, 0.2, 0.3],
                                          initial_velocity=[1.0, 0, 0, 0, 0, 0])],
                  joints=[joint("planar", "ground", "p", [0, 0, 0], axis=n.tolist())])
    t, x = ds.time.values, ds.position.sel(body="p").values
    assert np.abs(x[:, :3] @ n).max() < 1e-9
    np.testing.assert_allclose(x[:, :3] @ down, 0.5 * G * math.sin(b) * t ** 2, atol=1e-9)
    np.testing.assert_allclose(x[:, 0], t, atol=1e-9)


def test_universal_transmits_rotation_about_the_third_axis(tmp_path):
    # a vertical shaft driven at 3 rad/s (velocity constraint on yaw, revolute to ground) drives a
    # body hanging from it on a universal joint (free axes x on the shaft, y on the body)
    ds = simulate(tmp_path,
                  bodies=[body("shaft", mass=1.0, center_of_mass=[0, 0, 0], inertia=[0.1, 0.1, 0.05]),
                          body("load", mass=2.0, center_of_mass=[0, 0, -0.5], inertia=[0.1, 0.1, 0.2],
                               initial_velocity=[0, 0, 0, 0, 0, 3.0])],
                  joints=[joint("revolute", "ground", "shaft", [0, 0, 0], axis=[0, 0, 1]),
                          joint("universal", "shaft", "load", [0, 0, -0.2], name="cross", axis=[1, 0, 0],
                                axis2=[0, 1, 0])],
                  constraints=[{"body": "shaft", "dof": "yaw", "type": "velocity", "value": 3.0}])
    t = ds.time.values
    np.testing.assert_allclose(ds.position.sel(body="load", dof="yaw").values, 3.0 * t, atol=1e-9)
    np.testing.assert_allclose(ds.velocity.sel(body="load", dof="yaw").values[1:], 3.0, atol=1e-9)
    assert float(ds.joint_violation.max()) < 1e-9 and float(ds.joint_rotation_violation.max()) < 1e-9


def test_universal_swings_about_both_axes_but_not_the_third(tmp_path):
    ds = simulate(tmp_path, duration=2.0,
                  bodies=[body("load", mass=2.0, center_of_mass=[0, 0, -0.5], inertia=[0.1, 0.15, 0.2],
                               initial_velocity=[-0.5, 0.4, 0, 0.8, 1.0, 0])],
                  joints=[joint("universal", "ground", "load", [0, 0, 0], axis=[1, 0, 0], axis2=[0, 1, 0])])
    x = ds.position.sel(body="load").values
    assert np.ptp(x[:, 3]) > 0.1 and np.ptp(x[:, 4]) > 0.1
    # Rxyz angles: roll about the ground x axis, then pitch about the body's y axis: no yaw
    assert np.abs(x[:, 5]).max() < 1e-8
    assert float(ds.joint_rotation_violation.max()) < 1e-8


def test_fixed_joint_two_bodies_swing_as_one(tmp_path):
    th = 0.05
    ds = simulate(tmp_path, dt=0.002, duration=6.0,
                  bodies=[body("a", mass=1.0, center_of_mass=[0, 0, -0.5], inertia=[0.01, 0.01, 0.01],
                               initial_displacement=pendulum_start(0.5, th)),
                          body("b", mass=2.0, center_of_mass=[0, 0, -1.0], inertia=[0.02, 0.03, 0.02],
                               initial_displacement=pendulum_start(1.0, th))],
                  joints=[joint("revolute", "ground", "a", [0, 0, 0], axis=[0, 1, 0]),
                          joint("fixed", "a", "b", [0, 0, -0.75])])
    inertia = 0.01 + 1.0 * 0.25 + 0.03 + 2.0 * 1.0
    period = zero_crossing_period(ds.time.values, ds.position.sel(body="a", dof="pitch").values)
    assert period == pytest.approx(2 * math.pi * math.sqrt(inertia / ((0.5 + 2.0) * G)) * (1 + th ** 2 / 16), rel=2e-5)
    np.testing.assert_allclose(ds.position.sel(body="b", dof="pitch"), ds.position.sel(body="a", dof="pitch"), atol=1e-9)


FOUR_BAR = dict(
    bodies=[body("crank", mass=1.0, center_of_mass=[0.15, 0, 0.5], inertia=[0.1, 0.1, 0.01]),
            body("coupler", mass=1.0, center_of_mass=[1.15, 0, 1.1], inertia=[0.01, 0.2, 0.2]),
            body("rocker", mass=1.0, center_of_mass=[2.1, 0, 0.6], inertia=[0.1, 0.1, 0.01])],
    joints=[joint("revolute", "ground", "crank", [0, 0, 0], axis=[0, 1, 0]),
            joint("revolute", "crank", "coupler", [0.3, 0, 1], axis=[0, 1, 0]),
            joint("revolute", "coupler", "rocker", [2, 0, 1.2], axis=[0, 1, 0]),
            joint("revolute", "rocker", "ground", [2.2, 0, 0], name="rocker_pivot", axis=[0, 1, 0])])


def test_four_bar_loop_is_reduced_and_stays_closed(tmp_path):
    text = scene_toml(dt=0.001, duration=1.0, **FOUR_BAR)
    scene = parse_scene(text)
    sc = exu.SystemContainer()
    mbs = sc.AddSystem()
    mech = build_mechanism(mbs, scene, {})
    assert len(mech.reductions) == 1 and mech.reductions[0].startswith("joints[3]: closes a planar loop")
    assert mbs.ComputeSystemDegreeOfFreedom()["degreeOfFreedom"] == 1
    ds = simulate(tmp_path, duration=3.0, **FOUR_BAR)
    assert np.ptp(ds.position.sel(body="crank", dof="pitch").values) > 1.0    # it really swings
    assert float(ds.joint_violation.max()) < 1e-6
    assert float(ds.joint_rotation_violation.max()) < 1e-6


def test_friction_slider_decelerates_at_force_over_mass(tmp_path):
    ds = simulate(tmp_path, bodies=[body("s", mass=2.0, center_of_mass=[0, 0, 0], inertia=[0.1, 0.2, 0.3],
                                          initial_velocity=[1.0, 0, 0, 0, 0, 0])],
                  joints=[joint("prismatic", "ground", "s", [0, 0, 0], axis=[1, 0, 0],
                                friction={"force": 4.0, "velocity": 1e-3})])
    t, v = ds.time.values, ds.velocity.sel(body="s", dof="surge").values
    x = ds.position.sel(body="s", dof="surge").values
    k = int(np.searchsorted(t, 0.3))
    assert (v[0] - v[k]) / t[k] == pytest.approx(4.0 / 2.0, rel=1e-6)
    assert x[-1] == pytest.approx(1.0 ** 2 * 2.0 / (2 * 4.0), abs=1e-5)     # stops after m v0^2 / 2F
    assert abs(v[-1]) < 1e-6


def test_velocity_constraint_and_dry_gravity(tmp_path):
    ds = simulate(tmp_path, bodies=[body("s", mass=2.0, center_of_mass=[0, 0, 0], inertia=[0.1, 0.2, 0.3],
                                          buoyancy_volume=0.001)],
                  constraints=[{"body": "s", "dof": "surge", "type": "velocity", "value": 0.5}])
    t, x = ds.time.values, ds.position.sel(body="s").values
    np.testing.assert_allclose(x[:, 0], 0.5 * t, atol=1e-12)
    acc = -G + 1025.0 * G * 0.001 / 2.0                                   # weight minus buoyancy
    np.testing.assert_allclose(x[:, 2], 0.5 * acc * t ** 2, atol=1e-12)


def test_point_mass_on_a_body_marker(tmp_path):
    # interface used by PTOs/moorings: markers on rigid bodies, point masses and ground
    text = scene_toml(dt=0.01, duration=0.1, bodies=[body("b", mass=1.0, center_of_mass=[1, 2, 3], inertia=[1, 1, 1])],
                      point_masses=[{"name": "p", "mass": 0.5, "position": [0, 0, -5]}])
    scene = parse_scene(text)
    sc = exu.SystemContainer()
    mbs = sc.AddSystem()
    mech = build_mechanism(mbs, scene, {})
    assert mech.handles["b"] == BodyHandle("b", "rigid", mech.handles["b"].node, mech.handles["b"].object, (1.0, 2.0, 3.0))
    assert mech.handles["p"].kind == "point" and mech.handles["ground"].kind == "ground"
    markers = [marker_at(mbs, mech.handles[n], [1.0, 2.5, 3.0]) for n in ("b", "p", "ground")]
    mbs.Assemble()
    pos = [np.asarray(mbs.GetMarkerOutput(m, exu.OutputVariableType.Position)) for m in markers]
    np.testing.assert_allclose(pos[0], [1.0, 2.5, 3.0])
    np.testing.assert_allclose(pos[1], [0.0, 0.0, -5.0])
    np.testing.assert_allclose(pos[2], [1.0, 2.5, 3.0])


# ---------------------------------------------------------------------------------- errors

def dry_scene(*joints: dict, **body_keys) -> str:
    """Body "a" (1 kg at the origin, unit inertia unless ``body_keys`` say otherwise) and ``joints``."""
    return scene_toml(dt=0.01, duration=0.1, joints=list(joints),
                      bodies=[body("a", mass=1.0, center_of_mass=[0, 0, 0], **{"inertia": [1, 1, 1], **body_keys})])


def test_joint_to_a_missing_body_is_a_schema_error():
    with pytest.raises(SceneError, match=r"joints\[0\]\.body2: no body named 'nope'"):
        parse_scene(dry_scene(joint("spherical", "a", "nope", [0, 0, 0])))


def test_bad_axis_names_the_key():
    with pytest.raises(SceneError, match=r"joints\[0\]\.axis: must be a non-zero vector"):
        parse_scene(dry_scene(joint("revolute", "a", "ground", [0, 0, 0], axis=[0, 0, 0])))


def test_singular_mechanism_names_the_joints():
    text = dry_scene(joint("fixed", "ground", "a", [0, 0, 0]), joint("spherical", "a", "ground", [0, 0, 1]))
    with pytest.raises(SceneError, match=r"joints\[1\]: singular mechanism: joints\[0\] and joints\[1\] constrain"):
        build_model(parse_scene(text), None)


def test_joint_far_from_its_bodies_warns_and_inconsistent_start_is_refused():
    text = dry_scene(joint("spherical", "a", "ground", [100, 0, 0]))
    model = build_model(parse_scene(text), None)
    assert any(w.startswith("joints[0].point: far from") for w in model.mechanism.warnings)
    hinge = joint("revolute", "ground", "a", [0, 0, 1], axis=[0, 1, 0])
    with pytest.raises(SceneError, match=r"joints\[0\]: the bodies' initial displacements violate"):
        build_model(parse_scene(dry_scene(hinge, initial_displacement=[0.1, 0, 0, 0, 0, 0])), None)
    with pytest.raises(SceneError, match=r"joints\[0\]: the bodies' initial velocities violate"):
        build_model(parse_scene(dry_scene(hinge, initial_velocity=[0.1, 0, 0, 0, 0, 0])), None)


def test_tiny_inertia_is_refused():
    text = dry_scene(inertia=[1e-20, 1, 1])
    with pytest.raises(SceneError, match=r"bodies\[0\]\.inertia: the body's mass matrix is numerically singular"):
        build_model(parse_scene(text), None)
