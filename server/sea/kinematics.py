"""Undisturbed incident-wave kinematics (linear Airy theory) at points, for the forces that need
the fluid's own motion (relative drag, Morison elements; issue 10).

With the elevation eta = Re(sum_c a_c e^{i(k_c (x cos b_c + y sin b_c) - w_c t + phi_c)}) of
server/sea/waves.py (the ramp multiplies it), the particle velocity at (x, y, z <= 0) is
u_h = Re(w a C e^{i theta}) (along the heading), u_z = Re(-i w a S e^{i theta}) with
C = cosh(k (z + h)) / sinh(k h), S = sinh(k (z + h)) / sinh(k h) in depth h, both e^{k z} in deep
water, and the acceleration its time derivative (-i w times the phasor). Points above the still
water line are given the kinematics at z = 0 (no stretching).

The scene's steady current (protocol/current.py), when given, adds its velocity at each point's
depth to the particle velocity (not to the acceleration, nor ramped): the fluid velocity the
relative-velocity terms see is u_wave + u_current.

Per step the kinematics are one real product over the components' [cos wt; sin wt] (no complex
exponential): rows [Re R, Im R] of the velocity phasors R, then the same of the acceleration's
-i w R. Components whose share of every row is below round-off are left
out at set-up (:func:`_significant`): deep below the surface the short waves' e^{kz} and the
spectrum's far tails vanish, a third of a JONSWAP sea of 300 components at a Morison member 5-25 m
deep; what is left out is below 2^-53 of each row's sum of magnitudes, under the product's own
rounding bound (its length times 2^-53 of that sum)."""

from __future__ import annotations

import math

import numpy as np

from hydrolink.protocol.current import Current
from hydrolink.server.sea.waves import WaveComponents, WavePhases, ramp_at


def _significant(weights: np.ndarray) -> slice:
    """The band of components (columns of ``weights`` (R, n_c) >= 0, each the magnitudes a
    component contributes to the output rows) to keep: those outside it, dropped smallest share
    first, sum to at most 2^-53 of every row's total (the band spans every component kept)."""
    total = weights.sum(axis=1, keepdims=True)
    share = np.divide(weights, total, out=np.zeros_like(weights), where=total > 0)
    order = np.argsort(share.max(axis=0), kind="stable")
    fits = np.all(np.cumsum(weights[:, order], axis=1) <= 2.0 ** -53 * total, axis=0)
    n_drop = int(np.argmin(fits)) if not fits.all() else fits.size
    kept = np.sort(order[n_drop:])
    return slice(int(kept[0]), int(kept[-1]) + 1) if kept.size else slice(0, 0)


class Kinematics:
    """Particle velocity and acceleration of the incident wave, plus the steady ``current`` (its
    velocity only), at fixed points (P, 3): per point the components along x, y, z, or along the
    point's own unit vectors ``along`` (P, m, 3)."""

    def __init__(self, comps: WaveComponents, points: np.ndarray, gravity: float, depth: float,
                 current: Current | None = None, along: np.ndarray | None = None,
                 phases: WavePhases | None = None, extra: int = 0):
        """``along`` (P, m, 3) orthonormal rows: give the velocity and acceleration along them (a
        Morison member's two directions normal to its axis), projected once here rather than every
        step. ``phases``: the step's [cos wt; sin wt] of ``comps`` shared with the linear
        excitation (None: its own). ``extra``: columns :attr:`rhs` has after the trig rows, for a
        caller's own terms of the same product."""
        if phases is not None and not np.array_equal(phases.omega, comps.omega):
            raise ValueError("Kinematics: the shared phases are not those of the wave components")
        self._phases = WavePhases(comps.omega) if phases is None else phases
        pts = np.asarray(points, float).reshape(-1, 3)
        self.n_points = len(pts)
        basis = None if along is None else np.asarray(along, float).reshape(self.n_points, -1, 3)
        self.n_axes = 3 if basis is None else basis.shape[1]
        steady = np.zeros((self.n_points, 3)) if current is None else current.velocity(pts[:, 2])
        #: (P, m) the current's velocity at the points
        self.steady = steady if basis is None else np.einsum("pmi,pi->pm", basis, steady)
        self.ramp = comps.ramp
        n_rows = self.n_points * self.n_axes
        self._band = slice(0, 0)
        self.omega, self.matrix = np.zeros(0), np.zeros((0, 2 * n_rows))
        if comps.size > 0:
            self._set_matrix(comps, pts, gravity, depth, basis)
        n_all, band = comps.size, self._band
        # the band's cos and sin in the shared phases (views: they follow each step's values)
        self._cos_in = self._phases.values[band]
        self._sin_in = self._phases.values[n_all + band.start:n_all + band.stop]
        n = self.omega.size
        #: (2n + extra,) the ramped [cos wt, sin wt] :meth:`trig` writes, then the caller's ``extra`` entries
        self.rhs = np.zeros(2 * n + extra)
        self._cos, self._sin, self._trig = self.rhs[:n], self.rhs[n:2 * n], self.rhs[:2 * n]
        self._velocity_columns = self.matrix[:, :n_rows]

    def _set_matrix(self, comps: WaveComponents, pts: np.ndarray, gravity: float, depth: float,
                    basis: np.ndarray | None) -> None:
        """The velocity phasors R (one row per point and axis) of the band of components that
        matters (:func:`_significant`), as the real :attr:`matrix`."""
        k = comps.wave_numbers(gravity, depth)
        beta = comps.heading_of()
        z = np.minimum(pts[:, 2], 0.0)[:, None]                       # (P, 1)
        # cosh(k(z+h)) / sinh(kh) and sinh(k(z+h)) / sinh(kh) in a form that cannot overflow:
        # (e^{kz} +- e^{-k(z+2h)}) / (1 - e^{-2kh}); deep water (h = inf): e^{kz}
        kz = k[None, :] * z
        far = np.exp(-k[None, :] * (z + 2 * depth)) if not math.isinf(depth) else 0.0
        norm = 1.0 - (np.exp(-2 * k * depth)[None, :] if not math.isinf(depth) else 0.0)
        ch, sh = (np.exp(kz) + far) / norm, (np.exp(kz) - far) / norm
        theta = k[None, :] * (pts[:, 0:1] * np.cos(beta)[None, :] + pts[:, 1:2] * np.sin(beta)[None, :])
        c = comps.amplitude * np.exp(1j * comps.phase) * comps.omega   # w a e^{i phi}
        base = c[None, :] * np.exp(1j * theta)                          # (P, n_c)
        # velocity phasors per point and axis: horizontal along each heading, vertical
        rows = np.stack([base * ch * np.cos(beta)[None, :], base * ch * np.sin(beta)[None, :],
                         -1j * base * sh], axis=1)                     # (P, 3, n_c)
        if basis is not None:
            rows = np.einsum("pmi,pic->pmc", basis, rows)
        rows = rows.reshape(-1, comps.size)
        size = np.abs(rows.real) + np.abs(rows.imag)
        self._band = _significant(np.vstack([size, size * comps.omega[None, :]]))
        rows = rows[:, self._band]
        #: (n,) the kept components' angular frequencies
        self.omega = comps.omega[self._band].copy()
        acc = -1j * rows * self.omega[None, :]
        #: (2n, 2mP): [cos wt; sin wt] @ matrix gives the velocities, Re(R e^{-iwt}) = Re(R) cos(wt) +
        #: Im(R) sin(wt), then the accelerations, the same of -iw R (without the ramp's own rate)
        self.matrix = np.ascontiguousarray(np.vstack([np.hstack([rows.real.T, acc.real.T]),
                                                      np.hstack([rows.imag.T, acc.imag.T])]))

    def trig(self, t: float) -> None:
        """Write the ramped [cos wt, sin wt] into ``rhs[:2n]``, the row :attr:`matrix` turns into
        velocities and accelerations."""
        self._phases.at(t)
        np.copyto(self._cos, self._cos_in)
        np.copyto(self._sin, self._sin_in)
        ramp = ramp_at(t, self.ramp)
        if ramp != 1.0:
            self._trig *= ramp

    def velocity(self, t: float) -> np.ndarray:
        """(P, m) fluid velocity at time t [m/s]: the wave's (ramp included) plus the current."""
        self.trig(t)
        return (self._trig @ self._velocity_columns).reshape(self.n_points, -1) + self.steady

    def velocity_acceleration(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """(P, m) fluid velocity (as :meth:`velocity`) and acceleration [m/s^2] at time t, both
        from one product (the acceleration without the ramp's own rate)."""
        self.trig(t)
        both = (self._trig @ self.matrix).reshape(2, self.n_points, -1)
        return both[0] + self.steady, both[1]
