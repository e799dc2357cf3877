"""The incident-wave evaluation of the nonlinear Froude–Krylov force (issue 26): the elevation by
the Jacobi–Anger expansion (server/terms/nonlinear/elevation_series.py) against the direct sum of cosines, and the
whole force over a moving hull in irregular seas, many steps, against a direct evaluation written
here (complex exponentials per point and component, cosh depth factor, the wet part cut where
z = eta)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from conftest import SPHERE_WATER, irregular_waves, scene_toml, sphere_body
from hydrolink.protocol.scene import parse_scene
from hydrolink.server.terms.nonlinear import kernels, pressure_boxes, term as nonlinear_term
from hydrolink.server.hdb.io import load_hdb
from hydrolink.server.compiler import AVAILABLE
from hydrolink.server.sea.dispersion import wave_number
from hydrolink.server.model import HydroModel
from hydrolink.server.terms.nonlinear.elevation_series import PhaseExpansion
from hydrolink.server.sea.waves import WaveComponents, ramp_factor
from hydrolink.server.terms.hulls import Hull, closed_hull
from hydrolink.server.terms.nonlinear.hull import clip_wet, corner_loads, interpolate, pressure_load, rotation_xyz

cpt = pytest.importorskip("capytaine")
RHO, G = 1000.0, 9.81


@pytest.mark.parametrize("compiled", [True, False] if AVAILABLE else [False])
@pytest.mark.parametrize("radius, k_max, headings", [(7.0, 14.7, [0.3]), (3.0, 2.0, [-0.8, 0.1, 1.2])])
def test_expansion_elevation_is_the_direct_sum(radius, k_max, headings, compiled):
    rng = np.random.default_rng(3)
    n = 120
    k = rng.uniform(0.004, k_max, n)
    heading = np.asarray(headings)[rng.integers(0, len(headings), n)]
    amp, psi = rng.uniform(0.0, 1.0, n), rng.uniform(-50.0, 50.0, n)
    r = radius * np.sqrt(rng.uniform(0.0, 1.0, 400))
    a = rng.uniform(0.0, 2 * np.pi, 400)
    offsets = np.column_stack([r * np.cos(a), r * np.sin(a)])
    reference = np.array([123.4, -56.7])
    got = PhaseExpansion(k, heading, radius, compiled=compiled).elevation(offsets, reference, psi, amp)
    pts = reference + offsets
    direct = np.cos(np.outer(pts[:, 0], k * np.cos(heading)) + np.outer(pts[:, 1], k * np.sin(heading)) + psi) @ amp
    np.testing.assert_allclose(got, direct, rtol=0, atol=1e-12 * amp.sum())


def _direct_fk(hull, pose: np.ndarray, t: float, amp: np.ndarray, k: np.ndarray, beta: np.ndarray,
               phase: np.ndarray, omega: np.ndarray, ramp: float, depth: float) -> np.ndarray:
    """F_p,FK (global axes, about the reference point) by the direct formulas."""
    rot = rotation_xyz(pose[3:])
    verts = pose[:3] + hull.vertices @ rot.T
    e = ramp_factor(t, ramp) * amp * np.exp(1j * (np.outer(verts[:, 0], k * np.cos(beta))
                                                   + np.outer(verts[:, 1], k * np.sin(beta)) + phase - omega * t))
    eta = e.sum(axis=1).real
    d = verts[:, 2] - eta
    z_s = np.minimum(depth * (verts[:, 2] - eta) / (depth + eta), 0.0)
    depth_factor = np.exp(np.outer(z_s, k)) * (1 + np.exp(-2 * np.outer(z_s + depth, k))) / (1 + np.exp(-2 * k * depth))
    p_v = np.where(d <= 0.0, (e * depth_factor).sum(axis=1).real, 0.0)
    tris = hull.triangles
    pts, cut = clip_wet(verts[tris], d[tris])
    p_c = interpolate(p_v[tris], cut)
    p_c[cut.s < 1.0] = pts[..., 2][cut.s < 1.0]        # on the free surface p_FK = rho g eta
    return RHO * G * pressure_load(pts - pose[:3], p_c)


def _sphere_froude_krylov(sphere_path, hydro: dict, ramp: float, resolution: tuple[int, int]):
    """The Task-10 sphere with nonlinear Froude-Krylov forces on a Capytaine sphere hull in a
    JONSWAP sea (Hs 3 m, Tp 8 s, 300 components to 12 rad/s): the model and its nonlinear term."""
    text = scene_toml(dt=0.05, duration=100.0, water={**SPHERE_WATER, "gravity": G},
                      waves=irregular_waves(3.0, 8.0, ramp=ramp, seed=5), hydro={"nonlinear": "froude-krylov", **hydro},
                      bodies=[sphere_body(str(sphere_path), mass=261.724e3)])
    mesh = cpt.mesh_sphere(radius=5.0, resolution=resolution)
    mesh = mesh.merged() if hasattr(mesh, "merged") else mesh
    model = HydroModel(parse_scene(text), {"sphere": load_hdb(sphere_path)},
                       hulls={"sphere": closed_hull(mesh.vertices, mesh.faces)})
    return model, next(term.model for term in model.terms if term.name == "nonlinear_hydrostatics")


@pytest.mark.parametrize("compiled", [True, False] if AVAILABLE else [False])
@pytest.mark.parametrize("energy", [1.0, 0.99])
def test_nonlinear_froude_krylov_equals_the_direct_evaluation(sphere_path, energy, compiled, monkeypatch):
    """300 components over the HDB's whole range (to 12 rad/s), a hull moving in all six DOFs,
    150 steps through the ramp (the HDB has one heading: several are the expansion test's). With
    ``froude_krylov_energy`` < 1: the direct evaluation over the fewest most energetic components
    holding that share of the variance, and a warning naming the key. ``compiled``: with the
    compiled kernels (the short waves' pressure by recurrences, the others by boxes' series) or
    numpy alone."""
    monkeypatch.setattr(nonlinear_term, "AVAILABLE", compiled)
    model, nl = _sphere_froude_krylov(sphere_path, {"froude_krylov_energy": energy}, ramp=4.0, resolution=(16, 20))
    # compiled: the shorter waves of the 300 evenly spaced by the recurrence, the others by boxes
    if compiled and energy == 1:
        by = [len(r.columns) for r in nl.split.recurrences], [len(g.columns) for g in nl.split.boxes]
        assert all(by) and sum(by[0]) + sum(by[1]) == 300 and not len(nl.split.direct)
    assert nl.split is None if not compiled else True
    comps, body = model.waves, nl.bodies[0]
    energy_c = comps.amplitude ** 2
    kept = np.full(comps.size, True) if energy == 1 else energy_c >= np.sort(energy_c)[::-1][np.searchsorted(np.cumsum(np.sort(energy_c)[::-1]), energy * energy_c.sum() * (1 - 1e-12))]
    warned = [w for w in model.warnings if w.startswith("hydro.froude_krylov_energy")]
    assert (len(warned) == 1 and f"the {kept.sum()} most energetic of 300" in warned[0]) if energy < 1 else not warned
    assert energy_c[kept].sum() >= energy * energy_c.sum() * (1 - 1e-12) and (kept.all() if energy == 1 else kept.sum() < 300)
    comps = replace(comps, omega=comps.omega[kept], amplitude=comps.amplitude[kept], phase=comps.phase[kept])
    depth = nl.depth
    k = np.array([wave_number(float(w), G, depth) for w in comps.omega])
    eq = model.setup_info().equilibrium_position
    got, want = [], []
    for step in range(150):
        t = 0.05 * step
        pose = eq.copy()
        pose[0, :3] += [1.5 * np.sin(0.2 * t), 0.5 * np.cos(0.3 * t), 2.0 * np.sin(0.7 * t)]
        pose[0, 3:] += [0.15 * np.sin(0.4 * t), 0.3 * np.sin(0.5 * t), 0.5 * np.sin(0.1 * t)]
        _, fk = nl.force(t, pose)
        direct = _direct_fk(body.hull, pose[0], t, comps.amplitude, k, comps.heading_of(), comps.phase,
                            comps.omega, comps.ramp, depth)
        direct -= np.real(body.fk_linear @ (ramp_factor(t, comps.ramp) * np.exp(-1j * comps.omega * t)))
        got.append(fk[0])
        want.append(direct)
    got, want = np.array(got), np.array(want)
    scale = np.abs(want).max(axis=0)          # per DOF over the run (the ramp starts from zero)
    assert np.all(scale > 0)
    np.testing.assert_array_less(np.abs(got - want).max(axis=0), 1e-9 * scale)


@pytest.mark.skipif(not AVAILABLE, reason="numba not installed")
@pytest.mark.parametrize("depth, headings, count, scattered, split", [
    (200.0, [-0.7, 0.9], 150, 0, "recurrences"), (200.0, [-0.7, 0.9], 150, 0, "boxes"),
    (30.0, [-0.7, 0.2, 1.4], 60, 7, "recurrences"), (30.0, [-0.7, 0.2, 1.4], 60, 7, "direct")])
def test_compiled_pass_in_finite_depth_and_a_spread_sea(depth, headings, count, scattered, split, monkeypatch):
    """Headings of ``count`` evenly spaced components each (to 6 rad/s), and ``scattered`` ones of random
    frequency and heading, a hull 8.5 m from the origin moving in six DOFs: the compiled pass
    against the direct evaluation, 1e-9 of each DOF's largest value over 120 steps. Each way of
    the split's made to carry the load in turn by its cost: ``recurrences`` (one per heading; the
    long waves, k h < 20, and the scattered ones by boxes), ``boxes`` (all of them), ``direct`` (no
    box grid feasible: the long and scattered ones one by one)."""
    if split == "recurrences":
        monkeypatch.setattr(nonlinear_term, "_RECURRENCE_POINT", 0.0)
        monkeypatch.setattr(nonlinear_term, "_RECURRENCE_PAIR", 1e-6)
    elif split == "boxes":
        monkeypatch.setattr(nonlinear_term, "_RECURRENCE_POINT", 1e9)
    else:
        monkeypatch.setattr(pressure_boxes, "_MAX_ORDERS", 1)
    rng = np.random.default_rng(21)
    grid = np.linspace(6.0 / count, 6.0, count)
    omega = np.concatenate([np.tile(grid, len(headings)), rng.uniform(0.4, 5.0, scattered)])
    heading = np.concatenate([np.repeat(headings, count), rng.uniform(-np.pi, np.pi, scattered)])
    amplitude = rng.uniform(0.2, 1.0, omega.size) / (1.0 + omega ** 2)
    amplitude *= 0.6 / np.sqrt(0.5 * np.sum(amplitude ** 2))      # an RMS elevation of 0.6 m
    phase = rng.uniform(0.0, 2 * np.pi, omega.size)
    waves = WaveComponents(omega, amplitude, phase, 0.0, 0.0, 0.0, "irregular", heading)
    ref = np.array([8.0, -3.0, -0.5])
    mesh = cpt.mesh_sphere(radius=2.5, center=(8.0, -3.0, 0.0), resolution=(12, 16))
    mesh = mesh.merged() if hasattr(mesh, "merged") else mesh
    closed = closed_hull(mesh.vertices, mesh.faces)
    hull = Hull(closed.vertices - ref, closed.triangles, closed.volume)
    nl = nonlinear_term.NonlinearHydro([], waves, RHO, G, depth, 1, compiled=True)
    loads = corner_loads(hull.vertices[hull.triangles])
    body = nonlinear_term.NonlinearBody(
        index=0, mode="froude-krylov", hull=hull, loads=loads, vertex_loads=nonlinear_term._vertex_sums(hull, loads),
        reference=np.concatenate([ref, np.zeros(3)]), weight=0.0, lever=np.zeros(3), linear_net=0.0,
        stiffness=np.zeros((6, 6)), fk_linear=nl.fk_linear_phasors(hull, ref), active=np.ones(6))
    nl.prepare([body])
    ways = len(nl.split.recurrences), len(nl.split.boxes), len(nl.split.direct)
    assert ways == {"recurrences": (len(headings), len(headings) + scattered, 0),
                    "boxes": (0, len(headings) + scattered, 0)}[split] if split != "direct" else \
        (ways[0] == len(headings) and not ways[1] and ways[2] > 80)
    k = np.array([wave_number(float(w), G, depth) for w in omega])
    got, want = [], []
    for step in range(120):
        t = 0.1 * step
        pose = np.concatenate([ref, np.zeros(3)])
        pose[:3] += [1.5 * np.sin(0.2 * t), 0.5 * np.cos(0.3 * t), 1.0 * np.sin(0.7 * t)]
        pose[3:] += [0.2 * np.sin(0.4 * t), 0.3 * np.sin(0.5 * t), 0.6 * np.sin(0.1 * t)]
        got.append(nl.force(t, pose[None])[1][0])
        direct = _direct_fk(hull, pose, t, amplitude, k, heading, phase, omega, 0.0, depth)
        want.append(direct - np.real(body.fk_linear @ np.exp(-1j * omega * t)))
    got, want = np.array(got), np.array(want)
    scale = np.abs(want).max(axis=0)
    assert np.all(scale > 0)
    np.testing.assert_array_less(np.abs(got - want).max(axis=0), 1e-9 * scale)


@pytest.mark.parametrize("compiled", [True, False] if AVAILABLE else [False])
def test_a_hull_sent_below_the_seabed_gets_finite_forces(sphere_path, compiled, monkeypatch):
    """A pose within the server's coordinate bound but below the 200 m seabed: the incident-wave
    pressure there is the seabed's (the depth factor used to overflow into NaN forces)."""
    monkeypatch.setattr(nonlinear_term, "AVAILABLE", compiled)
    model, nl = _sphere_froude_krylov(sphere_path, {}, ramp=0.0, resolution=(8, 10))
    for heave in (-1e3, -1e5):
        pose = model.setup_info().equilibrium_position.copy()
        pose[0, 2] = heave
        hs, fk = nl.force(1.0, pose)
        assert np.all(np.isfinite(hs)) and np.all(np.isfinite(fk)), heave


@pytest.mark.skipif(not AVAILABLE, reason="numba not installed")
def test_a_numba_that_does_not_import_leaves_the_numpy_paths(sphere_path, monkeypatch):
    """numba installed but failing to import (built for another numpy): the set-up takes the numpy
    paths, which give the compiled ones' force to round-off."""
    _, compiled = _sphere_froude_krylov(sphere_path, {}, ramp=0.0, resolution=(8, 10))
    monkeypatch.setattr(nonlinear_term, "imports", lambda: False)
    model, fallback = _sphere_froude_krylov(sphere_path, {}, ramp=0.0, resolution=(8, 10))
    assert compiled.compiled and not fallback.compiled
    pose = model.setup_info().equilibrium_position.copy()
    pose[0, 2] += 0.7
    pose[0, 4] += 0.1
    for got, want in zip(fallback.force(3.0, pose), compiled.force(3.0, pose)):
        np.testing.assert_allclose(got, want, rtol=0, atol=1e-9 * np.abs(want).max())
