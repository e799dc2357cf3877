"""IRF and Ogilvie A_inf against closed forms (analytic_hdb) and the Task-10 sphere's own A_inf."""

from __future__ import annotations

import numpy as np
import pytest

import analytic_hdb as an
from hydrolink.server.radiation.irf import aliasing_time, irf_report, ogilvie_added_mass_inf, ogilvie_estimates, radiation_irf, trapezoid_weights


def test_trapezoid_weights_integrate_exactly_linear():
    x = np.array([0.0, 0.3, 1.0, 1.7, 3.0])
    assert np.sum(trapezoid_weights(x) * (2 * x + 1)) == pytest.approx(3.0 ** 2 + 3.0)


def test_irf_matches_closed_form():
    omega = np.linspace(0.01, 8.0, 800)
    t = np.linspace(0.0, 30.0, 601)
    b = np.zeros((omega.size, 2, 2))
    b[:, 0, 0] = an.damping(omega, 5.0, 1.0)
    b[:, 1, 1] = an.damping(omega, 2.0, 1.7)
    b[:, 0, 1] = b[:, 1, 0] = an.damping(omega, 0.5, 1.3)
    k = radiation_irf(omega, b, t)
    assert k.shape == (t.size, 2, 2)
    for (i, j), (b0, w0) in {(0, 0): (5.0, 1.0), (1, 1): (2.0, 1.7), (0, 1): (0.5, 1.3), (1, 0): (0.5, 1.3)}.items():
        exact = an.irf(t, b0, w0)
        assert np.max(np.abs(k[:, i, j] - exact)) < 1e-5 * np.abs(exact).max()


def test_irf_rational_slow_tail():
    # B = 2 c a w^2 / (a^2 + w^2)^2  <->  K = c (1 - a t) exp(-a t)  (B(0) = 0, slow 1/w^2 tail:
    # the truncation at w_max leaves an O(1/(w_max^2 t)) error, checked away from t = 0)
    c, a = 2.0, 0.8
    omega = np.linspace(0.005, 200.0, 40000)
    t = np.linspace(0.5, 12.0, 24)
    b = 2 * c * a * omega ** 2 / (a ** 2 + omega ** 2) ** 2
    k = radiation_irf(omega, b[:, None, None], t)[:, 0, 0]
    np.testing.assert_allclose(k, c * (1 - a * t) * np.exp(-a * t), rtol=0, atol=1e-4 * c)


def test_ogilvie_recovers_analytic_a_inf():
    omega = np.linspace(0.05, 6.0, 300)
    t = np.arange(0, 40.0 + 1e-9, 0.01)
    a_inf, b0, w0 = 3.0e5, 8.0e4, 1.0
    a = an.added_mass(omega, a_inf, b0, w0)[:, None, None]
    k = radiation_irf(omega, an.damping(omega, b0, w0)[:, None, None], t)
    est = ogilvie_estimates(omega, a, t, k)[:, 0, 0]
    assert np.max(np.abs(est - a_inf)) < 1e-3 * a_inf  # every frequency is a fair estimate here
    assert ogilvie_added_mass_inf(omega, a, t, k)[0, 0] == pytest.approx(a_inf, rel=1e-5)


def test_ogilvie_ignores_truncated_irf_at_low_frequency():
    # A short IRF (T = 3 s, K(T) not yet decayed for w0 = 0.5) spoils the low-frequency estimates;
    # the combination must still find A_inf.
    omega = np.linspace(0.05, 4.0, 200)
    t = np.arange(0, 8.0 + 1e-9, 0.01)
    a_inf, b0, w0 = 1.0, 0.5, 0.5
    a = an.added_mass(omega, a_inf, b0, w0)[:, None, None]
    k = radiation_irf(omega, an.damping(omega, b0, w0)[:, None, None], t)
    est = ogilvie_estimates(omega, a, t, k)[:, 0, 0]
    assert np.max(np.abs(est - a_inf)) > 1e-2
    assert ogilvie_added_mass_inf(omega, a, t, k)[0, 0] == pytest.approx(a_inf, rel=2e-3)


def test_irf_report_exact_vs_truncated():
    omega = np.linspace(0.02, 6.0, 300)
    b = an.damping(omega, 1.0, 1.0)[:, None, None]
    t = np.arange(0, 30.0 + 1e-9, 0.01)
    good = irf_report(omega, b, t, an.irf(t)[:, None, None])
    assert good["worst"] < 1e-4
    t_short = t[t <= 2.0]
    bad = irf_report(omega, b, t_short, an.irf(t_short)[:, None, None])
    assert bad["worst"] > 0.05
    assert aliasing_time(omega) == pytest.approx(np.pi / 0.02)


def test_sphere_ogilvie_matches_hdb_a_inf(reference_data):
    io = pytest.importorskip("hydrolink.server.hdb.io")
    ds = io.load_hdb(reference_data / "sphere_task10" / "sphere.h5")
    omega = ds["omega"].values
    t = np.arange(0, 40.0 + 1e-9, 0.01)
    k = radiation_irf(omega, ds["radiation_damping"].values, t)
    a_inf = ogilvie_added_mass_inf(omega, ds["added_mass"].values, t, k)
    ref = ds["added_mass_inf"].values
    for i in range(5):  # surge..pitch (yaw has no added mass)
        assert a_inf[i, i] == pytest.approx(ref[i, i], rel=5e-3), i
    assert irf_report(omega, ds["radiation_damping"].values, t, k)["rel_error"][2, 2] < 5e-3
