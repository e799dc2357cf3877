"""The joints' reaction moments (``joint_force[..., 3:]``: on body2 from body1, global, about the joint
point) against statics and Newton-Euler written here, for each joint type the mechanism builds
(clients/exudyn/mechanism.py, clients/exudyn/kernels/joint_moments.py): a dry body hanging at rest from a joint
to ground, the joint's frame turned off the global axes, the joint in either order (body1 the bob:
marker 0's frame on the moving body); a pendulum far from its reference orientation (the revolute's
moment follows the joint angle) against Newton-Euler at its angle and rate; a bob swinging in 3D on a
universal joint against Newton-Euler from its motion alone (finite differences). The compiled kernel (``JointOutputs.compiled``) equals the numpy path
bit for bit: tests/test_compiled_exchange.py (hinged, hinged-full).

Statics of a body of weight W = (0, 0, -m g) whose CoG is r from the joint point, at rest: the
reaction on it is (-W, -r x W); on the other body, minus that.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import xarray as xr

from conftest import body, joint, scene_toml

from hydrolink.clients.exudyn.client import result_bodies, run
from hydrolink.clients.lockstep.results import ResultWriter
from hydrolink.protocol.scene import parse_scene

G = 9.81
MASS = 2.0
INERTIA = [0.05, 0.08, 0.03]
POINT = np.array([0.2, -0.1, 0.3])
TILT = np.array([1.0, 2.0, 2.0]) / 3.0            # a revolute's free axis off every global axis


def horizontal(angle_deg: float) -> list[float]:
    a = np.radians(angle_deg)
    return [float(np.cos(a)), float(np.sin(a)), 0.0]


def run_scene(tmp_path: Path, name: str, joints: list[dict], com, *, duration: float, dt: float,
              client: dict | None = None) -> xr.Dataset:
    """A dry bob (2 kg) with its CoG at ``com`` and these joints, run from rest."""
    text = scene_toml(dt=dt, duration=duration, progress=False, joints=joints, client=client,
                      bodies=[body("bob", mass=MASS, center_of_mass=list(map(float, com)), inertia=INERTIA)])
    scene = parse_scene(text)
    names, ref = result_bodies(scene, None)
    out = tmp_path / f"{name}.nc"
    with ResultWriter(out, scene=scene, scene_text=text, dt=dt, bodies=names, equilibrium_position=ref) as writer:
        run(scene, text, None, None, writer, progress=False)
    return xr.load_dataset(out)


# (type, axis keys, CoG offset r from the joint point): r chosen so the weight's moment about the
# joint's free rotation axes is zero (r = s axis + t z for one free axis; under the point for none)
# "fixed": the bob held (out of Exudyn's system, its reaction from its own equation); "fixed_full": an
# Exudyn joint ([client] reduce = false)
CASES = {
    "fixed": ("fixed", {}, [0.3, 0.2, -0.5]),
    "fixed_full": ("fixed", {}, [0.3, 0.2, -0.5]),
    "revolute_y": ("revolute", {"axis": [0.0, 1.0, 0.0]}, [0.0, 0.5, -1.0]),
    "revolute_tilted": ("revolute", {"axis": TILT.tolist()}, (0.5 * TILT + [0.0, 0.0, -1.0]).tolist()),
    "prismatic": ("prismatic", {"axis": horizontal(30.0)}, [0.3, -0.2, -0.6]),
    "cylindrical": ("cylindrical", {"axis": horizontal(-45.0)},
                    (0.4 * np.array(horizontal(-45.0)) + [0.0, 0.0, -0.7]).tolist()),
    "planar": ("planar", {"axis": [0.0, 0.0, 1.0]}, [0.4, 0.3, -0.2]),
    "universal": ("universal", {"axis": horizontal(60.0), "axis2": [0.0, 0.0, 1.0]},
                  (0.5 * np.array(horizontal(60.0)) + [0.0, 0.0, -1.0]).tolist()),
    "spherical": ("spherical", {}, [0.0, 0.0, -0.8]),
}


@pytest.mark.parametrize("reversed_", [False, True], ids=["ground-bob", "bob-ground"])
@pytest.mark.parametrize("case", list(CASES))
def test_hanging_body_reaction_is_statics(tmp_path, case, reversed_):
    """A bob at rest on one joint to ground: the reaction on it carries its weight and the weight's
    moment about the joint point; with the bob as body1 the reported reaction (on ground) is minus
    that."""
    kind, keys, r = CASES[case]
    pair = ("bob", "ground") if reversed_ else ("ground", "bob")
    ds = run_scene(tmp_path, case, [joint(kind, *pair, POINT.tolist(), **keys)], POINT + r, duration=0.01, dt=0.002,
                   client={"type": "exudyn", "reduce": False} if case == "fixed_full" else None)
    q = ds["position"].sel(body="bob").values
    np.testing.assert_allclose(q, np.tile(q[0], (len(q), 1)), atol=1e-10)     # at rest: statics hold
    w = np.array([0.0, 0.0, -MASS * G])
    on_bob = np.concatenate((-w, -np.cross(r, w)))
    expected = -on_bob if reversed_ else on_bob
    np.testing.assert_allclose(ds["joint_force"].values[:, 0], np.tile(expected, (ds.sizes["time"], 1)),
                               atol=1e-9 * MASS * G)


PENDULUM_R0 = np.array([1.0, 0.4, 0.0])     # CoG from the hinge at t = 0 (horizontal: it swings down)


def pendulum_reaction(phi: float, rate: float) -> np.ndarray:
    """Newton-Euler: the reaction (force, moment about the hinge) on the bob of a pendulum on a hinge
    about y, at angle ``phi`` about y and rate ``rate``; its angular acceleration from its one-DOF
    equation (J = I_yy + m (x0^2 + z0^2) about the hinge)."""
    c, s = np.cos(phi), np.sin(phi)
    rot = np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])
    r = rot @ PENDULUM_R0
    w = np.array([0.0, 0.0, -MASS * G])
    accel = np.cross(r, w)[1] / (INERTIA[1] + MASS * (PENDULUM_R0[0] ** 2 + PENDULUM_R0[2] ** 2))
    omega, alpha = np.array([0.0, rate, 0.0]), np.array([0.0, accel, 0.0])
    inertia = rot @ np.diag(INERTIA) @ rot.T
    a_cog = np.cross(alpha, r) + np.cross(omega, np.cross(omega, r))
    force = MASS * a_cog - w
    moment = inertia @ alpha + np.cross(omega, inertia @ omega) + np.cross(r, force)   # about the CoG: M - r x F = dH/dt
    return np.concatenate((force, moment))


@pytest.mark.parametrize("reversed_", [False, True], ids=["ground-bob", "bob-ground"])
def test_pendulum_reaction_is_newton_euler(tmp_path, reversed_):
    """A pendulum swinging from horizontal through large angles: the hinge's reaction at each step
    against Newton-Euler at the step's angle and rate, to 1e-4 of its largest component over two
    steps' mean (the multipliers carry a step-to-step alternation of the undamped trapezoidal rule:
    up to 0.3 N of 57 N after 1 s with the bob as body1, its mean error 6e-4 N)."""
    pair = ("bob", "ground") if reversed_ else ("ground", "bob")
    ds = run_scene(tmp_path, f"pendulum{reversed_}", [joint("revolute", *pair, [0.0, 0.0, 0.0], axis=[0.0, 1.0, 0.0])],
                   PENDULUM_R0, duration=1.0, dt=0.001)
    phi = ds["position"].sel(body="bob", dof="pitch").values
    rate = ds["velocity"].sel(body="bob", dof="pitch").values
    assert np.ptp(phi) > 1.5                                   # far from its reference orientation
    expected = np.array([pendulum_reaction(p, v) for p, v in zip(phi, rate)]) * (-1.0 if reversed_ else 1.0)
    got = ds["joint_force"].values[:, 0]
    scale, error = np.abs(expected).max(), got - expected
    assert np.abs(error[1:-1] + error[2:]).max() / 2 <= 1e-4 * scale
    assert np.abs(expected[:, 3:]).max() > 0.1 * scale        # the moment is not ~0 (CoG off the plane)


def rxyz(angles: np.ndarray) -> np.ndarray:
    """R = Rx Ry Rz of Tait-Bryan xyz angles (the results' rotation entries: README, Conventions)."""
    (cx, cy, cz), (sx, sy, sz) = np.cos(angles), np.sin(angles)
    rx = np.array([[1.0, 0.0, 0.0], [0.0, cx, -sx], [0.0, sx, cx]])
    ry = np.array([[cy, 0.0, sy], [0.0, 1.0, 0.0], [-sy, 0.0, cy]])
    rz = np.array([[cz, -sz, 0.0], [sz, cz, 0.0], [0.0, 0.0, 1.0]])
    return rx @ ry @ rz


def newton_euler(ds: xr.Dataset, point: np.ndarray, dt: float) -> np.ndarray:
    """The reaction (force, moment about ``point``) on the bob at steps 1..n-2 from its motion alone:
    F = m a - W, M = dH/dt + r x F (H = R I R' w about the CoG, r from ``point`` to the CoG), the
    derivatives as central differences of the positions and orientations."""
    x = ds["position"].sel(body="bob").values
    rot = np.array([rxyz(a) for a in x[:, 3:]])
    spin = np.einsum("kij,kjl->kil", rot[2:] - rot[:-2], np.transpose(rot[1:-1], (0, 2, 1))) / (2 * dt)
    omega = np.stack((spin[:, 2, 1], spin[:, 0, 2], spin[:, 1, 0]), axis=1)        # w~ = dR/dt R'
    h = np.einsum("kij,jl,kml,km->ki", rot[1:-1], np.diag(INERTIA), rot[1:-1], omega)
    accel = (x[2:, :3] - 2 * x[1:-1, :3] + x[:-2, :3]) / dt**2
    force = MASS * accel - [0.0, 0.0, -MASS * G]
    moment = np.gradient(h, dt, axis=0) + np.cross(x[1:-1, :3] - point, force)
    return np.concatenate((force, moment), axis=1)[1:-1]            # steps 2..n-3: dH/dt central too


@pytest.mark.parametrize("reversed_", [False, True], ids=["ground-bob", "bob-ground"])
def test_universal_joint_reaction_is_newton_euler(tmp_path, reversed_):
    """A bob falling from rest on a universal joint (free axes x on body1, y on body2, both
    horizontal; CoG off both): a 3D swing (1.6 rad about x, 0.2 rad about y in 0.6 s) in which the
    locked axis (x × y of the moving frames) tilts, its moment nonzero; the reaction against
    Newton-Euler from the bob's motion alone, to 1e-4 of its largest component over two steps' mean
    (central differences at dt 1 ms; measured 1.1e-5; the code before 62f2a98: fails)."""
    dt, point = 0.001, np.array([0.1, 0.2, 0.0])
    pair = ("bob", "ground") if reversed_ else ("ground", "bob")
    ds = run_scene(tmp_path, f"universal{reversed_}", [joint("universal", *pair, point.tolist(), axis=[1.0, 0.0, 0.0],
                                                             axis2=[0.0, 1.0, 0.0])],
                   point + [0.3, 0.4, -0.2], duration=0.6, dt=dt)
    angles = ds["position"].sel(body="bob").values[:, 3:]
    assert np.abs(angles[:, :2]).max(axis=0).min() > 0.15              # it swings about both free axes
    expected = newton_euler(ds, point, dt) * (-1.0 if reversed_ else 1.0)
    got = ds["joint_force"].values[2:-2, 0]
    scale, error = np.abs(expected).max(), got - expected
    assert np.abs(expected[:, 3:]).max() > 0.02 * scale               # about 1.4 N m against 41 N
    assert np.abs(error[:-1] + error[1:]).max() / 2 <= 1e-4 * scale
