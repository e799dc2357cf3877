"""Wave components, ramp, elevation and excitation against hand-written formulas."""

from __future__ import annotations

import numpy as np
import pytest

from hydrolink.protocol.scene import IrregularWave, RegularWave, StillWater
from hydrolink.server.sea.headings import interpolate_excitation
from hydrolink.server.sea.waves import WaveError, WaveForcing, elevation, jonswap, pierson_moskowitz, ramp_factor, wave_components


def test_ramp():
    t = np.array([-1.0, 0.0, 5.0, 10.0, 20.0])
    np.testing.assert_allclose(ramp_factor(t, 10.0), [0.0, 0.0, 0.5, 1.0, 1.0], atol=1e-15)
    assert ramp_factor(2.5, 10.0) == pytest.approx(0.5 * (1 - np.cos(np.pi / 4)))
    assert ramp_factor(0.0, 0.0) == 1.0


@pytest.mark.parametrize("spectrum,gamma", [("jonswap", 3.3), ("jonswap", 1.0), ("pierson-moskowitz", 1.0)])
def test_irregular_components_hs_and_peak(spectrum, gamma):
    w = IrregularWave(type="irregular", spectrum=spectrum, hs=2.5, tp=9.0, gamma=gamma, seed=7, components=600)
    c = wave_components(w, 0.05, 4.0)
    m0 = np.sum(c.amplitude ** 2 / 2)
    assert c.energy_outside < 2e-3
    assert 4 * np.sqrt(m0) == pytest.approx(2.5 * np.sqrt(1 - c.energy_outside), rel=1e-3)
    assert 4 * np.sqrt(m0) == pytest.approx(2.5, rel=2e-3)
    dw = c.omega[1] - c.omega[0]
    assert np.allclose(np.diff(c.omega), dw) and c.omega[0] == pytest.approx(0.05 + dw / 2)
    assert abs(c.omega[np.argmax(c.amplitude)] - 2 * np.pi / 9.0) <= dw
    rng = np.random.default_rng(7)
    np.testing.assert_array_equal(c.phase, rng.uniform(0, 2 * np.pi, 600))


def test_pm_closed_form_and_narrow_range():
    hs, tp = 3.0, 10.0
    wp = 2 * np.pi / tp
    w = np.linspace(0.2, 3.0, 7)
    np.testing.assert_allclose(pierson_moskowitz(w, hs, tp),
                               5 / 16 * hs ** 2 * wp ** 4 / w ** 5 * np.exp(-1.25 * (wp / w) ** 4))
    np.testing.assert_allclose(jonswap(w, hs, tp, 1.0), pierson_moskowitz(w, hs, tp), rtol=1e-6)
    # a range cut at 0.8 rad/s: closed-form PM CDF  int_0^W S = hs^2/16 exp(-5/4 (wp/W)^4)
    c = wave_components(IrregularWave(type="irregular", spectrum="pierson-moskowitz", hs=hs, tp=tp), 0.01, 0.8)
    assert c.energy_outside == pytest.approx(1 - np.exp(-1.25 * (wp / 0.8) ** 4), rel=1e-6)


def test_regular_elevation_after_ramp():
    w = RegularWave(type="regular", height=2.0, period=7.0, ramp=14.0)
    c = wave_components(w, 0.1, 5.0)
    t = np.linspace(14.0, 60.0, 500)
    np.testing.assert_allclose(elevation(c, t), 1.0 * np.cos(2 * np.pi / 7.0 * t), atol=1e-12)
    tr = np.linspace(0, 14, 50)
    np.testing.assert_allclose(elevation(c, tr), 0.5 * (1 - np.cos(np.pi * tr / 14)) * np.cos(2 * np.pi / 7 * tr),
                               atol=1e-12)
    c2 = wave_components(RegularWave(type="regular", height=2.0, period=7.0, phase=30.0), 0.1, 5.0)
    np.testing.assert_allclose(elevation(c2, t), np.cos(2 * np.pi / 7 * t - np.pi / 6), atol=1e-12)


def test_regular_excitation_equals_re_axe():
    omega = np.linspace(0.2, 3.0, 30)
    dirs = np.deg2rad([0.0, 30.0, 60.0])
    x = ((1 + 2j) * np.exp(-omega)[:, None, None] * (1 + np.cos(dirs))[None, :, None]
         * np.array([1.0, -2.0, 3.0])[None, None, :])
    w = RegularWave(type="regular", height=3.0, period=2 * np.pi / 1.0, direction=45.0, phase=20.0)
    c = wave_components(w, omega[0], omega[-1])
    xc = interpolate_excitation(omega, dirs, x, c.omega, c.direction)
    # hand interpolation: w = 1.0 between grid points, heading halfway between 30 and 60 deg
    i = np.searchsorted(omega, 1.0) - 1
    s = (1.0 - omega[i]) / (omega[i + 1] - omega[i])
    xw = (1 - s) * x[i] + s * x[i + 1]
    x_ref = 0.5 * (xw[1] + xw[2])
    np.testing.assert_allclose(xc[0], x_ref, rtol=1e-12)
    forcing = WaveForcing(c, xc)
    for t in (0.0, 0.37, 5.0, 41.3):
        f, eta = forcing(t)
        np.testing.assert_allclose(f, np.real(1.5 * x_ref * np.exp(1j * np.pi / 9) * np.exp(-1j * t)), atol=1e-9)
        assert eta == pytest.approx(1.5 * np.cos(t - np.pi / 9))


def test_irregular_forcing_matches_elevation_and_sum():
    c = wave_components(IrregularWave(type="irregular", spectrum="jonswap", hs=2.0, tp=8.0, components=50,
                                      ramp=5.0), 0.2, 3.0)
    xc = (np.cos(c.omega) + 1j * np.sin(2 * c.omega))[:, None] * np.array([1.0, 0.5])
    forcing = WaveForcing(c, xc)
    for t in (1.0, 3.3, 12.0):
        f, eta = forcing(t)
        r = 0.5 * (1 - np.cos(np.pi * t / 5.0)) if t < 5 else 1.0
        ref = sum(np.real(a * xc[i] * np.exp(1j * p - 1j * w * t))
                  for i, (a, w, p) in enumerate(zip(c.amplitude, c.omega, c.phase)))
        np.testing.assert_allclose(f, r * ref, atol=1e-12)
        assert eta == pytest.approx(elevation(c, t)[0])


def test_errors_name_the_key():
    with pytest.raises(WaveError, match="waves.period"):
        wave_components(RegularWave(type="regular", height=1.0, period=100.0), 0.1, 5.0)
    omega = np.linspace(0.2, 3.0, 5)
    x = np.ones((5, 2, 6), complex)
    with pytest.raises(WaveError, match="waves.direction"):
        interpolate_excitation(omega, np.deg2rad([0.0, 90.0]), x, omega, np.deg2rad(180.0))
    # the same heading written as -360 deg, and 45 deg between 0 and 90: accepted
    interpolate_excitation(omega, np.deg2rad([0.0, 90.0]), x, omega, np.deg2rad(-360.0))
    interpolate_excitation(omega, np.deg2rad([0.0, 90.0]), x, omega, np.deg2rad(45.0))
    assert wave_components(StillWater(type="still"), 0.1, 5.0).size == 0


def test_omega_range_is_the_band_the_components_span():
    """waves.omega_range: the components span the stated band (inside the HDB's range), the energy
    outside it (PM closed-form CDF exp(-5/4 (wp/W)^4)) is left out; a band beyond the HDB's range is
    an error naming the key, and low >= high is refused by the scene model."""
    hs, tp = 3.0, 10.0
    wp = 2 * np.pi / tp
    w = IrregularWave(type="irregular", spectrum="pierson-moskowitz", hs=hs, tp=tp, components=100,
                      omega_range=(0.3, 1.5))
    c = wave_components(w, 0.1, 4.0)
    dw = 1.2 / 100
    np.testing.assert_allclose(c.omega, 0.3 + dw * (np.arange(100) + 0.5))
    cdf = lambda x: np.exp(-1.25 * (wp / x) ** 4)  # noqa: E731 - fraction of m0 below x
    assert c.energy_outside == pytest.approx(1 - (cdf(1.5) - cdf(0.3)), rel=1e-6)
    with pytest.raises(WaveError, match=r"waves.omega_range.*outside the HDB's range"):
        wave_components(w, 0.5, 4.0)
    with pytest.raises(ValueError, match="low < high"):
        IrregularWave(type="irregular", spectrum="jonswap", hs=1.0, tp=8.0, omega_range=(1.0, 0.5))
