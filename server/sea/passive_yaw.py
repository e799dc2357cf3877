"""Passive yaw: the excitation of a body that turns, at each wave's direction relative to its heading.

A body with ``bodies[i].passive_yaw = true`` (WEC-Sim's passive yaw) yawed by psi (the ``rz`` of its
position in the step, SPEC §5.2) meets a wave travelling towards beta (global) at the relative
heading beta - psi: the HDB's excitation there, X(w, beta - psi), is the force in the body's axes;
turned into the global frame by the yaw, and with its phase referred to the wave at the body's
reference point r0 (which the yaw turns about) rather than at the HDB's origin:

    X_psi(w, beta) = R(psi) X(w, beta - psi) exp(i k r0 . (e(beta) - e(beta - psi))),

R(psi) the rotation about z of the force and of the moment (surge/sway and roll/pitch mix, heave
and yaw stay), e(b) = (cos b, sin b), k the wave number. At psi = 0 it is X(w, beta). Roll and
pitch do not turn the excitation (as WEC-Sim): only the yaw does.

Cost: the excitation is tabulated at set-up on a grid of yaw angles psi_j = j 2 pi / n (n =
``YAW_POINTS``: 1 deg) for every wave component, in the form the fixed-heading step sums (rows of
[Re; Im] coefficients over [cos wt; sin wt], server/sea/waves.py ``WaveForcing``): a step reads the
two tables around the body's yaw, sums each over the components and blends the two sums linearly in
psi. The table at psi_0 = 0 is the fixed-heading one itself, so a body whose yaw stays 0 gets the
fixed-heading excitation bit for bit. The error of the blend: the rotation's, below (2 pi / n)^2 / 8
= 4e-5 of the force at 1 deg, and where an HDB heading falls between two grid angles, the kink of
the HDB's linear heading interpolation rounded over 1 deg.

The yaw read: the instantaneous one, or with ``bodies[i].passive_yaw_filter`` its low-passed value
(:class:`PassiveYaw`). The mean and Newman drift and the QTF turn the same way (server/terms/second_order.py,
which reads the same heading).

Not turned (setup warning where the body is not symmetric about its yaw axis, unless the scene
states ``passive_yaw_coefficients = "initial-heading"``): added mass, radiation damping and
hydrostatic stiffness stay those of the body at its initial heading.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from hydrolink.server.allocation import require_size
from hydrolink.server.sea.headings import heading_weights
from hydrolink.server.sea.waves import WaveComponents, WaveForcing, ramp_at

YAW_POINTS = 360   # yaw angles tabulated around the circle (1 deg)


def yaw_grid(points: int = YAW_POINTS) -> np.ndarray:
    """The tabulated yaw angles psi_j = j 2 pi / points (rad)."""
    return np.arange(points) * (2 * np.pi / points)


def rotate_yaw(x: np.ndarray, psi: np.ndarray) -> np.ndarray:
    """Forces and moments ``x`` (..., n_psi, n_c, 6) given in a body's axes turned into the global
    frame by the yaw ``psi`` (n_psi,): R(psi) on (surge, sway) and on (roll, pitch)."""
    c, s = np.cos(psi)[:, None], np.sin(psi)[:, None]
    out = x.copy()
    for a, b in ((0, 1), (3, 4)):
        out[..., a] = c * x[..., a] - s * x[..., b]
        out[..., b] = s * x[..., a] + c * x[..., b]
    return out


def yawed_excitation(omega_hdb: np.ndarray, directions: np.ndarray, x_hdb: np.ndarray, waves: WaveComponents,
                     wave_number: np.ndarray, reference: np.ndarray, psi: np.ndarray, key: str) -> np.ndarray:
    """(n_psi, n_c, 6) complex: X_psi(w_c, beta_c) of the module docstring for each component c and
    yaw psi; ``x_hdb`` (n_w, n_h, 6) the body's HDB excitation over ``omega_hdb`` and ``directions``
    (rad), ``reference`` its reference point (the HDB's), ``wave_number`` (n_c,). Linear in w, and in
    heading around the circle (server/sea/headings.py; a heading the HDB leaves out: WaveError(key))."""
    w = waves.hdb_omega
    xw = np.empty((w.size, directions.size, 6), complex)    # X at the components' frequencies, each HDB heading
    for h in range(directions.size):
        for d in range(6):
            xw[:, h, d] = np.interp(w, omega_hdb, x_hdb[:, h, d].real) + 1j * np.interp(w, omega_hdb, x_hdb[:, h, d].imag)
    heads = waves.heading_of()
    out = np.empty((psi.size, w.size, 6), complex)
    for beta in np.unique(heads):
        on = heads == beta
        weights = heading_weights(directions, beta - psi, key, "the HDB's headings (the body yawing)")
        out[:, on] = np.tensordot(weights, xw[on], axes=(1, 1))
    beta = heads[None, :]
    shift = reference[0] * (np.cos(beta) - np.cos(beta - psi[:, None])) + \
        reference[1] * (np.sin(beta) - np.sin(beta - psi[:, None]))
    return rotate_yaw(out, psi) * np.exp(1j * wave_number[None, :] * shift)[:, :, None]


@dataclass(frozen=True)
class YawingBody:
    """One passive-yaw body of the step: ``yaw`` its yaw's position in the 6N state, ``rows`` its
    active DOFs' positions among the forcing rows, ``dofs`` which DOFs (0..5) those are,
    ``excitation`` (n_psi, n_c, 6) its excitation at the tabulated yaws (:func:`yawed_excitation`)
    and ``filter`` (s) the time constant of the low-pass its yaw is read through (0: none)."""

    yaw: int
    rows: np.ndarray
    dofs: np.ndarray
    excitation: np.ndarray
    filter: float = 0.0


def yaw_tables(forcing: WaveForcing, bodies: list[YawingBody], key: str) -> np.ndarray:
    """(n_b, n_psi, n + 1, 2 n_c): per body and tabulated yaw, the forcing matrix (every active DOF's
    rows then the elevation's, server/sea/waves.py ``WaveForcing.matrix``) with that body's rows at
    that yaw; the one at psi = 0 is the fixed-heading matrix itself."""
    comps = forcing.comps
    base = np.asarray(forcing.matrix)
    points = bodies[0].excitation.shape[0]
    require_size(key, "the passive-yaw excitation tables", (len(bodies), points, base.shape[0], base.shape[1]),
                 hint="fewer wave components")
    c = comps.amplitude * np.exp(1j * comps.phase)
    tables = np.repeat(np.repeat(base[None, None], points, axis=1), len(bodies), axis=0)
    for k, body in enumerate(bodies):
        coef = np.transpose(body.excitation[1:, :, body.dofs], (0, 2, 1)) * c[None, None, :]  # (n_psi - 1, rows, n_c)
        tables[k][1:, body.rows] = np.concatenate([coef.real, coef.imag], axis=2)
    return tables


def grid_position(psi: float, points: int) -> tuple[int, int, float]:
    """The two tabulated yaws around ``psi`` (rad, any turn) and the blend weight of the second."""
    u = (psi * (points / (2 * math.pi))) % points
    j = int(u)
    if j >= points:       # a tiny negative angle rounds to a whole turn
        return 0, 1 % points, 0.0
    return j, (j + 1) % points, u - j


class PassiveYaw:
    """The excitation rows of the passive-yaw bodies, from their tables at the headings the waves are
    read at (module docstring): each body's yaw, or with ``filter`` > 0 its yaw low-passed, one
    backward-Euler step of dpsi_f/dt = (psi - psi_f) / filter per server step (psi_f starts at the
    yaw of step 0), so that the wave-frequency yaw does not turn the excitation (its effect on the
    mean force is second order, the drift's). The headings are this object's state (the session
    rollback: :meth:`state`). :meth:`apply` is the numpy path's; the compiled step reads
    :attr:`headings` (server/fused/loops.py ``yaw_excitation``)."""

    def __init__(self, forcing: WaveForcing, bodies: list[YawingBody], dt: float, key: str):
        self.forcing, self.bodies = forcing, bodies
        self.tables = yaw_tables(forcing, bodies, key)     # (n_b, n_psi, n + 1, 2 n_c)
        self.points = self.tables.shape[1]
        self._alpha = np.array([dt / (b.filter + dt) for b in bodies])
        self._filtered = np.array([b.filter > 0 for b in bodies])
        self._yaw = np.array([b.yaw for b in bodies], np.int64)
        self.headings = np.zeros(len(bodies))    # (n_b,) the yaws the waves are read at, this step
        self._previous = np.zeros(len(bodies))   # ... and at the step before (for a step recomputed)
        self._steps = 0

    def follow(self, x: np.ndarray, replace_last: bool) -> np.ndarray:
        """The headings of the step whose state is ``x`` (6N,) (``replace_last``: the newest step
        again, with a new state), written into :attr:`headings` (the array the compiled step holds)."""
        yaw = x[self._yaw]
        if not self._filtered.any():
            self.headings[:] = yaw
            return self.headings
        if not replace_last:
            self._previous[:] = self.headings
            self._steps += 1
        first = self._steps <= 1
        low = yaw if first else self._previous + self._alpha * (yaw - self._previous)
        self.headings[:] = np.where(self._filtered, low, yaw)
        return self.headings

    def heading(self, row: int) -> float:
        """The heading the waves are read at for the body at ``row`` among the served bodies."""
        return float(self.headings[int(np.flatnonzero(self._yaw == 6 * row + 5)[0])])

    def state(self) -> tuple:
        return self.headings.copy(), self._previous.copy(), self._steps

    def set_state(self, state: tuple) -> None:
        headings, previous, self._steps = state
        np.copyto(self.headings, headings)
        np.copyto(self._previous, previous)

    def apply(self, t: float, f_ex: np.ndarray) -> None:
        """Overwrite the passive-yaw bodies' rows of ``f_ex`` (the forcing rows at ``t``, ramped) for
        the step's :attr:`headings`."""
        ramp = ramp_at(t, self.forcing.comps.ramp)
        for body, tables, psi in zip(self.bodies, self.tables, self.headings):
            j0, j1, s = grid_position(float(psi), self.points)
            out = (1.0 - s) * self.forcing.sum(t, tables[j0]) + s * self.forcing.sum(t, tables[j1])
            out *= ramp
            f_ex[body.rows] = out[body.rows]

    def fused_inputs(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """What the compiled step takes (server/fused/step.py): the tables (n_b, n_psi, n + 1, 2 n_c),
        the headings (n_b,) (this object's array: :meth:`follow` fills it before each call), and
        each passive row's forcing row and body (n_rows,)."""
        rows = np.concatenate([b.rows for b in self.bodies]).astype(np.int64)
        owner = np.concatenate([np.full(b.rows.size, k) for k, b in enumerate(self.bodies)]).astype(np.int64)
        return self.tables, self.headings, rows, owner
