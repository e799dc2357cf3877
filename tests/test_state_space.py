"""State-space fits (server/radiation/state_space.py) against closed-form rational kernels, and their cache
(server/radiation/state_space_cache.py): hits return the stored fit without refitting, damaged entries are
refitted with a setup warning, keys follow the fit's inputs, identical kernels are fitted once and an
unwritable folder only costs the caching."""

from __future__ import annotations

import numpy as np
import pytest

import analytic_hdb as an
from hydrolink.protocol.scene import parse_scene
from hydrolink.server.model import HydroModel
from hydrolink.server.radiation.state_space import StateSpaceRadiation, fit_pairs, impulse_response
from hydrolink.server.radiation.state_space_cache import FitCache, FitSettings, default_cache_dir, fit_key
from conftest import body, scene_toml

OMEGA = np.linspace(0.0, 6.0, 120)
# (poles p_r, residues c_r) of K(t) = sum_r 2 Re(c_r exp(p_r t)), one kernel per pair
KERNELS = [
    (np.array([-0.4 + 1.1j]), np.array([0.8 - 0.3j])),
    (np.array([-0.25 + 0.7j, -0.9 + 2.6j]), np.array([0.5 + 0.2j, -0.3 + 0.6j])),
    (np.array([-0.15 + 1.9j, -0.6 + 0.5j, -1.2 + 3.8j]), np.array([0.2 - 0.1j, 0.4 + 0.3j, 0.25 - 0.5j])),
]


def transfer(poles, residues, w):
    """H(iw) = int_0^inf K(t) exp(-iwt) dt = sum_r c_r/(iw - p_r) + conj(c_r)/(iw - conj(p_r)) (closed form)."""
    s = 1j * np.asarray(w)[:, None]
    return (residues / (s - poles) + np.conj(residues) / (s - np.conj(poles))).sum(axis=1)


def kernel(poles, residues, t):
    return 2 * (residues[None, :] * np.exp(poles[None, :] * np.asarray(t)[:, None])).real.sum(axis=1)


def samples(kernels=KERNELS):
    h = np.array([transfer(p, c, OMEGA) for p, c in kernels])
    return h, np.abs(h).max(axis=1)


SETTINGS = FitSettings(tolerance=1e-6, order=None, max_order=10, enforce_stability=True)


def fit(cache: FitCache, h, scale, settings=SETTINGS):
    p = np.arange(h.shape[0])
    return cache.fit_pairs(OMEGA, h, p, p, scale, settings)


# ------------------------------------------------------------------------------ the fit itself

def test_fit_recovers_known_rational_kernels():
    """Kernels that are exactly sums of 1, 2, 3 damped oscillations: the order search stops at
    2, 4, 6 (their true orders), the poles and residues are the known ones, and B(w) = Re H,
    A(w) - A_inf = Im H / w and K(t) of the realisation match the closed forms on a grid 5x finer
    than (and reaching past) the fitted one."""
    h, scale = samples()
    fits = fit_pairs(OMEGA, h, np.arange(3), np.arange(3), scale, tolerance=1e-6, max_order=10)
    np.testing.assert_array_equal(fits.orders, [2, 4, 6])
    w = np.linspace(0.01, 8.0, 600)
    t = np.linspace(0.0, 30.0, 301)
    for k, (p_true, c_true) in enumerate(KERNELS):
        order = np.argsort(fits.poles[k].imag)
        np.testing.assert_allclose(fits.poles[k][order], p_true[np.argsort(p_true.imag)], rtol=1e-6)
        np.testing.assert_allclose(fits.residues[k][order], c_true[np.argsort(p_true.imag)], rtol=1e-5)
        assert abs(fits.d[k]) < 1e-6 * scale[k]
        fit_h = transfer(fits.poles[k], fits.residues[k], w) + fits.d[k]
        ref_h = transfer(p_true, c_true, w)
        np.testing.assert_allclose(fit_h.real, ref_h.real, atol=1e-6 * scale[k])          # B(w)
        np.testing.assert_allclose(fit_h.imag / w, ref_h.imag / w, atol=1e-4 * scale[k])  # A(w) - A_inf
        np.testing.assert_allclose(impulse_response(t, fits.poles[k][None], fits.residues[k][None])[0],
                                   kernel(p_true, c_true, t), atol=1e-6 * np.abs(c_true).sum())
    assert fits.error.max() <= 1e-6


def test_identical_kernels_are_fitted_once_and_shared():
    """Five pairs, two of them repeats: three fits, the repeats get the very same numbers."""
    h, scale = samples()
    rows = np.array([0, 1, 2, 0, 2])
    fits = fit_pairs(OMEGA, h[rows], np.arange(5), np.arange(5), scale[rows], tolerance=1e-6, max_order=10)
    assert fits.fitted == 3
    for a, b in ((0, 3), (2, 4)):
        np.testing.assert_array_equal(fits.poles[a], fits.poles[b])
        np.testing.assert_array_equal(fits.residues[a], fits.residues[b])
        assert fits.d[a] == fits.d[b] and fits.error[a] == fits.error[b]
    alone = fit_pairs(OMEGA, h[1:2], np.arange(1), np.arange(1), scale[1:2], tolerance=1e-6, max_order=10)
    np.testing.assert_array_equal(fits.poles[1], alone.poles[0])  # pairs do not influence each other


# ------------------------------------------------------------------------------ the cache

def test_cache_hit_returns_the_stored_fit_without_refitting(tmp_path):
    h, scale = samples()
    first = FitCache(tmp_path)
    a = fit(first, h, scale)
    files = list(tmp_path.glob("fit-*.npz"))
    assert first.fitted == 3 and first.hits == 0 and len(files) == 1
    assert not list(tmp_path.glob("*.tmp"))
    stamp = files[0].stat().st_mtime_ns
    second = FitCache(tmp_path)                      # a new setup: nothing in memory
    b = fit(second, h, scale)
    assert second.fitted == 0 and second.hits == 1 and files[0].stat().st_mtime_ns == stamp
    for x, y in zip(a.poles + a.residues, b.poles + b.residues):
        np.testing.assert_array_equal(x, y)
    np.testing.assert_array_equal(a.d, b.d)
    np.testing.assert_array_equal(a.error, b.error)
    # the realised model is the same
    v = np.random.default_rng(1).standard_normal((20, 3))
    ra, rb = StateSpaceRadiation(3, a, 0.05), StateSpaceRadiation(3, b, 0.05)
    for vk in v:
        np.testing.assert_array_equal(ra.push(vk), rb.push(vk))


def test_damaged_cache_entry_is_refitted_with_a_warning(tmp_path):
    h, scale = samples()
    ref = fit(FitCache(tmp_path), h, scale)
    (entry,) = tmp_path.glob("fit-*.npz")
    entry.write_bytes(b"not a fit")
    cache = FitCache(tmp_path)
    again = fit(cache, h, scale)
    (warning,) = cache.warnings
    assert warning.startswith(f"ignoring unreadable cached state-space fit {entry}")
    assert cache.fitted == 3
    np.testing.assert_array_equal(np.concatenate(again.poles), np.concatenate(ref.poles))
    fresh = FitCache(tmp_path)                       # rewritten: a hit again
    fit(fresh, h, scale)
    assert fresh.hits == 1 and fresh.fitted == 0


def test_key_follows_every_fit_input_and_nothing_else():
    h, scale = samples()
    base = fit_key(OMEGA, h, scale, SETTINGS)
    assert fit_key(OMEGA.copy(), h.copy(), scale.copy(), FitSettings(1e-6, None, 10, True)) == base
    changed = [
        fit_key(OMEGA * 1.01, h, scale, SETTINGS),
        fit_key(OMEGA, h * (1 + 1e-12), scale, SETTINGS),
        fit_key(OMEGA, h[:2], scale[:2], SETTINGS),
        fit_key(OMEGA, h, 2 * scale, SETTINGS),
        fit_key(OMEGA, h, scale, FitSettings(1e-5, None, 10, True)),
        fit_key(OMEGA, h, scale, FitSettings(1e-6, None, 12, True)),
        fit_key(OMEGA, h, scale, FitSettings(1e-6, 4, 10, True)),
        fit_key(OMEGA, h, scale, FitSettings(1e-6, None, 10, False)),
    ]
    assert len({base, *changed}) == len(changed) + 1


def test_default_folder_priority(monkeypatch, tmp_path):
    monkeypatch.setenv("HYDROLINK_STATE_SPACE_CACHE", str(tmp_path / "own"))
    monkeypatch.setenv("HYDROLINK_CACHE", str(tmp_path / "shared"))
    assert default_cache_dir() == tmp_path / "own"
    monkeypatch.delenv("HYDROLINK_STATE_SPACE_CACHE")
    assert default_cache_dir() == tmp_path / "shared" / "state_space"
    monkeypatch.delenv("HYDROLINK_CACHE")
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    assert default_cache_dir() == tmp_path / "xdg" / "hydrolink" / "state_space"


# ------------------------------------------------------------------------------ through the model

def _model(n_bodies=1, *, dt=0.05, irf=20.0, tol=0.01, interaction="full"):
    """n copies of one analytic body 50 m apart (surge, heave, pitch), state-space radiation."""
    scene = parse_scene(scene_toml(
        dt=dt, duration=10.0,
        hydro={"irf_duration": irf, "radiation": "state-space", "ss_tolerance": tol, "interaction": interaction},
        bodies=[body(f"b{k}", hdb="x.nc", hdb_body="float", mass=3e5, center_of_mass=[50.0 * k, 0, 0],
                     inertia=[1e6, 1e6, 1e6], dofs=["surge", "heave", "pitch"]) for k in range(n_bodies)]))
    ds = an.make_body_hdb()
    return HydroModel(scene, {f"b{k}": ds for k in range(n_bodies)})


def _fitted(m) -> int:
    return m.setup_info().state_space.fitted_pairs


def _forces(m, steps=30):
    v = np.random.default_rng(3).standard_normal((steps, len(m.bodies), 6))
    pos = m.setup_info().equilibrium_position
    return np.array([m.step(k * m.dt, pos, v[k]) for k in range(steps)], dtype=object)


def test_model_setup_uses_the_cache_and_refits_on_changed_inputs(monkeypatch, tmp_path):
    """Same scene twice: the second setup fits nothing. A changed irf_duration (other samples) or
    ss_tolerance refits; a changed dt does not (the fit is in continuous time) and its realisation
    equals a cold fit's at that dt."""
    monkeypatch.setenv("HYDROLINK_STATE_SPACE_CACHE", str(tmp_path))
    cold = _model()
    assert _fitted(cold) == 3
    assert len(list(tmp_path.glob("fit-*.npz"))) == 1
    assert _fitted(_model()) == 0
    assert _fitted(_model(irf=15.0)) == 3
    assert _fitted(_model(tol=0.003)) == 3
    cached = _model(dt=0.02)
    assert _fitted(cached) == 0
    monkeypatch.setenv("HYDROLINK_STATE_SPACE_CACHE", str(tmp_path / "other"))
    fresh = _model(dt=0.02)
    assert _fitted(fresh) == 3
    a, b = _forces(cached), _forces(fresh)
    for x, y in zip(a, b):
        np.testing.assert_array_equal(x["radiation"], y["radiation"])


def test_identical_bodies_are_fitted_once(monkeypatch, tmp_path):
    """Three bodies naming the same HDB body (separate groups: a repeated HDB body starts a new one)
    and, with interaction "none", the same: one body's pairs are fitted, even without a disk cache."""
    monkeypatch.setenv("HYDROLINK_STATE_SPACE_CACHE", str(tmp_path))
    full = _model(3)
    assert _fitted(full) == 3
    assert full.setup_info().state_space.pairs == 9
    monkeypatch.setenv("HYDROLINK_STATE_SPACE_CACHE", str(tmp_path / "none"))
    assert _fitted(_model(3, interaction="none")) == 3
    blocked = tmp_path / "a-file"
    blocked.write_text("")
    monkeypatch.setenv("HYDROLINK_STATE_SPACE_CACHE", str(blocked / "cache"))
    m = _model(3)
    assert sum("could not write the state-space fit cache" in w for w in m.setup_info().warnings) == 1  # once
    st = m.setup_info().state_space
    assert st.fitted_pairs == 3 and st.pairs == 9


def test_unwritable_cache_folder_does_not_fail_the_run(monkeypatch, tmp_path):
    blocked = tmp_path / "a-file"
    blocked.write_text("")
    monkeypatch.setenv("HYDROLINK_STATE_SPACE_CACHE", str(blocked))
    m = _model()
    assert any("going on without a disk cache" in w for w in m.setup_info().warnings)
    monkeypatch.setenv("HYDROLINK_STATE_SPACE_CACHE", str(tmp_path / "ok"))
    ref = _model()
    assert not any("cache" in w for w in ref.setup_info().warnings)
    for x, y in zip(_forces(m), _forces(ref)):
        np.testing.assert_array_equal(x["radiation"], y["radiation"])
