"""Undisturbed incident-wave kinematics (linear Airy theory) at points, for the forces that need
the fluid's own motion (relative drag, Morison elements; issue 10).

With the elevation eta = Re(sum_c a_c e^{i(k_c (x cos b_c + y sin b_c) - w_c t + phi_c)}) of
server/waves.py (the ramp multiplies it), the particle velocity at (x, y, z <= 0) is
u_h = Re(w a C e^{i theta}) (along the heading), u_z = Re(-i w a S e^{i theta}) with
C = cosh(k (z + h)) / sinh(k h), S = sinh(k (z + h)) / sinh(k h) in depth h, both e^{k z} in deep
water, and the acceleration its time derivative (-i w times the phasor). Points above the still
water line are given the kinematics at z = 0 (no stretching).

The scene's steady current (protocol/current.py), when given, adds its velocity at each point's
depth to the particle velocity (not to the acceleration, nor ramped): the fluid velocity the
relative-velocity terms see is u_wave + u_current."""

from __future__ import annotations

import math

import numpy as np

from hydrolink.protocol.current import Current
from hydrolink.server.waves import WaveComponents, ramp_at


def wave_number(omega: float, gravity: float, depth: float) -> float:
    """k of w^2 = g k tanh(k h) (deep water: w^2 / g)."""
    k_deep = omega ** 2 / gravity
    if math.isinf(depth) or k_deep * depth > 20.0:
        return k_deep
    k = k_deep / math.sqrt(math.tanh(k_deep * depth))      # a good start, then Newton
    for _ in range(50):
        t = math.tanh(k * depth)
        f = gravity * k * t - omega ** 2
        df = gravity * t + gravity * k * depth * (1 - t * t)
        step = f / df
        k -= step
        if abs(step) < 1e-14 * k:
            break
    return k


class Kinematics:
    """Particle velocity and acceleration of the incident wave, plus the steady ``current`` (its
    velocity only), at fixed points (P, 3)."""

    def __init__(self, comps: WaveComponents, points: np.ndarray, gravity: float, depth: float,
                 current: Current | None = None, normal_to: np.ndarray | None = None):
        """``normal_to`` (P, 3) unit vectors: give only the components normal to them (a Morison
        member's axis at each point), projected once here rather than every step."""
        pts = np.asarray(points, float).reshape(-1, 3)
        self.n_points = len(pts)
        axis = None if normal_to is None else np.asarray(normal_to, float).reshape(-1, 3)
        self.steady = np.zeros((self.n_points, 3)) if current is None else current.velocity(pts[:, 2])
        if axis is not None:
            self.steady = self.steady - axis * (self.steady * axis).sum(axis=1)[:, None]
        self.ramp = comps.ramp
        self.omega = comps.omega.copy()
        self.still = comps.size == 0
        if self.still:
            return
        k = np.array([wave_number(float(w), gravity, depth) for w in comps.omega])
        beta = comps.heading_of()
        z = np.minimum(pts[:, 2], 0.0)[:, None]                       # (P, 1)
        # cosh(k(z+h)) / sinh(kh) and sinh(k(z+h)) / sinh(kh) in a form that cannot overflow:
        # (e^{kz} +- e^{-k(z+2h)}) / (1 - e^{-2kh}); deep water (h = inf): e^{kz}
        kz = k[None, :] * z
        far = np.exp(-k[None, :] * (z + 2 * depth)) if not math.isinf(depth) else 0.0
        norm = 1.0 - (np.exp(-2 * k * depth)[None, :] if not math.isinf(depth) else 0.0)
        ch, sh = (np.exp(kz) + far) / norm, (np.exp(kz) - far) / norm
        theta = k[None, :] * (pts[:, 0:1] * np.cos(beta)[None, :] + pts[:, 1:2] * np.sin(beta)[None, :])
        c = comps.amplitude * np.exp(1j * comps.phase) * self.omega    # w a e^{i phi}
        base = c[None, :] * np.exp(1j * theta)                          # (P, n_c)
        # velocity phasors, one row per point and axis (3P, n_c): horizontal along each heading, vertical
        rows = np.stack([base * ch * np.cos(beta)[None, :], base * ch * np.sin(beta)[None, :],
                         -1j * base * sh], axis=1)                     # (P, 3, n_c)
        if axis is not None:
            rows = rows - axis[:, :, None] * np.einsum("pi,pic->pc", axis, rows)[:, None, :]
        rows = rows.reshape(-1, self.omega.size)
        # Re(R e^{-iwt}) = Re(R) cos(wt) + Im(R) sin(wt): velocity rows then acceleration rows (R times
        # -iw), one real (6P, 2 n_c) matrix over [cos wt; sin wt] (no complex exponential per step)
        acc = -1j * rows * self.omega[None, :]
        self._m = np.ascontiguousarray(np.vstack([np.hstack([rows.real, rows.imag]),
                                                  np.hstack([acc.real, acc.imag])]))
        self._trig = np.empty(2 * self.omega.size)

    def _product(self, t: float, n_rows: int) -> np.ndarray:
        """The first ``n_rows`` rows of the real matrix times [cos wt; sin wt], ramp included."""
        n = self.omega.size
        np.multiply(self.omega, t, out=self._trig[:n])
        np.sin(self._trig[:n], out=self._trig[n:])
        np.cos(self._trig[:n], out=self._trig[:n])
        return (self._m[:n_rows] @ self._trig) * ramp_at(t, self.ramp)

    def velocity(self, t: float) -> np.ndarray:
        """(P, 3) fluid velocity at time t [m/s]: the wave's (ramp included) plus the current."""
        if self.still:
            return self.steady.copy()
        return self._product(t, 3 * self.n_points).reshape(-1, 3) + self.steady

    def velocity_acceleration(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """(P, 3) fluid velocity (as :meth:`velocity`) and acceleration [m/s^2] at time t, both
        from one product (the acceleration without the ramp's own rate)."""
        if self.still:
            return self.steady.copy(), np.zeros((self.n_points, 3))
        both = self._product(t, 6 * self.n_points).reshape(2, -1, 3)
        return both[0] + self.steady, both[1]
