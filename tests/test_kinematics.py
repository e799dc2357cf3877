"""server/sea/kinematics.py: Airy particle velocity and acceleration of the incident wave against the
closed forms written here (dispersion solved with brentq), finite and deep water, a heading and
a point off the origin; acceleration = time derivative of the velocity."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.optimize import brentq

from hydrolink.protocol.scene import RegularWave
from hydrolink.server.sea.kinematics import Kinematics
from hydrolink.server.sea.waves import wave_components


@pytest.mark.parametrize("depth", [10.0, math.inf])
def test_particle_velocity_against_airy(depth):
    g, height, period, heading = 9.81, 1.2, 7.0, 30.0
    comps = wave_components(RegularWave(type="regular", height=height, period=period, direction=heading, phase=20.0),
                            0.1, 3.0)
    w = 2 * math.pi / period
    k = w ** 2 / g if math.isinf(depth) else brentq(lambda k: g * k * math.tanh(k * depth) - w ** 2, 1e-6, 10.0)
    point = np.array([3.0, -2.0, -2.5])
    kin = Kinematics(comps, point[None, :], g, depth)
    b, a, phi = math.radians(heading), height / 2, math.radians(20.0)
    z = point[2]
    ch = math.exp(k * z) if math.isinf(depth) else math.cosh(k * (z + depth)) / math.sinh(k * depth)
    sh = math.exp(k * z) if math.isinf(depth) else math.sinh(k * (z + depth)) / math.sinh(k * depth)
    for t in np.linspace(0.0, 2 * period, 29):
        theta = k * (point[0] * math.cos(b) + point[1] * math.sin(b)) - w * t + phi     # eta = a cos(theta)
        uh, uz = a * w * ch * math.cos(theta), a * w * sh * math.sin(theta)
        np.testing.assert_allclose(kin.velocity(t)[0], [uh * math.cos(b), uh * math.sin(b), uz], atol=1e-12)
        dt = 1e-5
        num = (kin.velocity(t + dt) - kin.velocity(t - dt)) / (2 * dt)
        np.testing.assert_allclose(kin.velocity_acceleration(t)[1], num, atol=1e-7)


def test_irregular_sea_in_finite_depth_is_the_sum_of_its_components():
    """300 components in 30 m of water, from long waves to ones a thousand times shorter than the
    depth: finite everywhere (no cosh overflow) and equal to the sum of each component's closed
    form at a point below the surface."""
    from hydrolink.protocol.scene import IrregularWave
    g, depth = 9.81, 30.0
    comps = wave_components(IrregularWave(type="irregular", spectrum="jonswap", hs=2.0, tp=8.0), 0.2, 6.0)
    point = np.array([[5.0, 1.0, -4.0]])
    kin = Kinematics(comps, point, g, depth)
    t = 12.3
    total = np.zeros(3)
    for w, a, phi in zip(comps.omega, comps.amplitude, comps.phase):
        k = brentq(lambda k: g * k * math.tanh(k * depth) - w ** 2, 1e-8, 100.0)
        z = point[0, 2]
        ch = math.cosh(k * (z + depth)) / math.sinh(k * depth) if k * depth < 300 else math.exp(k * z)
        sh = math.sinh(k * (z + depth)) / math.sinh(k * depth) if k * depth < 300 else math.exp(k * z)
        theta = k * point[0, 0] - w * t + phi
        total += [a * w * ch * math.cos(theta), 0.0, a * w * sh * math.sin(theta)]
    got = kin.velocity(t)[0]
    assert np.all(np.isfinite(got)) and np.all(np.isfinite(kin.velocity_acceleration(t)[1]))
    np.testing.assert_allclose(got, total, atol=1e-10)


def test_deep_points_leave_out_only_what_is_below_round_off():
    """A JONSWAP sea of 300 components at points 5-25 m deep (deep water): the short waves' e^{kz}
    and the spectrum's tails vanish there, so components are left out, and the velocity and
    acceleration still equal the closed-form sum over all 300 components (written here) to
    round-off of the terms' magnitudes."""
    from hydrolink.protocol.scene import IrregularWave
    g = 9.81
    comps = wave_components(IrregularWave(type="irregular", spectrum="jonswap", hs=2.0, tp=8.0), 0.05, 12.0)
    points = np.array([[0.0, 0.0, -5.0], [3.0, -1.0, -12.0], [0.0, 0.0, -25.0]])
    kin = Kinematics(comps, points, g, math.inf)
    assert comps.size == 300 and kin.omega.size < 250
    for t in (0.0, 37.3, 1234.5):
        vel, acc = kin.velocity_acceleration(t)
        for p, (x, y, z) in enumerate(points):
            k = comps.omega ** 2 / g
            theta = k * x - comps.omega * t + comps.phase          # heading 0
            amp = comps.amplitude * comps.omega * np.exp(k * z)
            u = np.array([amp * np.cos(theta), 0.0 * theta, amp * np.sin(theta)])
            du = np.array([amp * comps.omega * np.sin(theta), 0.0 * theta, -amp * comps.omega * np.cos(theta)])
            np.testing.assert_allclose(vel[p], u.sum(axis=1), rtol=0, atol=1e-13 * np.abs(u).sum())
            np.testing.assert_allclose(acc[p], du.sum(axis=1), rtol=0, atol=1e-13 * np.abs(du).sum())
