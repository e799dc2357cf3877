"""server/kinematics.py: Airy particle velocity and acceleration of the incident wave against the
closed forms written here (dispersion solved with brentq), finite and deep water, a heading and
a point off the origin; acceleration = time derivative of the velocity."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.optimize import brentq

from hydrolink.protocol.scene import RegularWave
from hydrolink.server.kinematics import Kinematics
from hydrolink.server.waves import wave_components


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
        np.testing.assert_allclose(kin.acceleration(t), num, atol=1e-7)
