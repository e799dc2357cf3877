"""The radiation memory's cut judged by its effect (issue 40 item 12): how much the damping the
truncated (and tapered) kernel realises, B_K(w) = Re int_0^T tau(t) K(t) e^(-iwt) dt
(:func:`hydrolink.server.radiation.irf.irf_transfer`, in closed form), differs from the HDB's B(w)
at the frequencies the scene excites: its wave frequencies, and each DOF's natural frequency
(where a decay test or a resonance takes its damping).

Why not the kernel's tail alone: a kernel that has almost died out may still carry the
low-frequency part of B — a hinged flap's 0.43 % tail at a 30 s memory changed its decay damping by
~7 % — while a kernel still ringing at a frequency the scene never reaches harms nothing. The
change is measured relative to B(w) itself, or to CRITICAL_FLOOR of the DOF's critical damping
2 w (M + A(w)) where B is smaller (there the radiation damping is too small to shape the response,
and an error of that size is what matters).

Natural frequencies: per active DOF alone, w_n = sqrt(C / (M + A(w_n))) with the server's restoring
stiffness C (hydrostatics and gravity) and the scene's rigid-body mass about the reference point;
joints, PTOs and moorings are the client's and not counted, so each is judged over
w_n / NATURAL_SPREAD .. w_n NATURAL_SPREAD.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from hydrolink.server.radiation.irf import aliasing_time, irf_transfer, resample_damping

CUT_EFFECT_WARN = 0.02    # B_K off B by more than this (relative) near a scene frequency: warned
CRITICAL_FLOOR = 0.01     # ... relative to B, or to this share of critical damping where B is smaller
NATURAL_SPREAD = 1.25     # a natural frequency is judged over w_n / 1.25 .. 1.25 w_n (3 points)
LONGER = 1.25             # the suggested duration: the first of T 1.25^k (k = 1..MAX_STEPS) that meets it
MAX_STEPS = 12
MAX_WAVE_FREQUENCIES = 64   # an irregular sea is judged at this many of its components' frequencies at most


@dataclass(frozen=True)
class CutEffect:
    """The worst change of B by the cut: relative ``change`` of DOF ``dof`` (index in the group's
    active DOFs) at ``omega`` [rad/s], which is ``why`` (the wave frequency, a natural frequency)."""
    change: float
    dof: int
    omega: float
    why: str


def natural_frequencies(omega: np.ndarray, added_mass: np.ndarray, inertia: np.ndarray,
                        stiffness: np.ndarray) -> np.ndarray:
    """Each DOF's undamped natural frequency alone, w = sqrt(C / (M + A(w))) by fixed point on the
    HDB's A(w) (held constant beyond its grid); NaN where C <= 0 (no restoring of its own).
    ``added_mass`` (n_w, n) diagonals, ``inertia``, ``stiffness`` (n,)."""
    omega = np.asarray(omega, float)
    out = np.full(len(stiffness), np.nan)
    for i, (m, c) in enumerate(zip(inertia, stiffness)):
        if not (c > 0 and m > 0):
            continue
        w = np.sqrt(c / (m + added_mass[-1, i]))
        for _ in range(100):
            a = np.interp(w, omega, added_mass[:, i])
            new = np.sqrt(c / max(m + a, 1e-300))
            if abs(new - w) <= 1e-10 * new:
                break
            w = new
        out[i] = new
    return out


Judged = list[tuple[float, str, int]]   # (frequency [rad/s], what it is, the DOF judged there or -1: every DOF)


def judged_frequencies(omega: np.ndarray, waves: np.ndarray, natural: np.ndarray) -> Judged:
    """The frequencies the cut is judged at, inside the HDB's range: every DOF at the waves'; each
    DOF around its own natural frequency, at w_n / NATURAL_SPREAD, w_n, w_n NATURAL_SPREAD."""
    lo, hi = float(omega[0]), float(omega[-1])
    waves = np.unique(np.asarray(waves, float))
    if waves.size > MAX_WAVE_FREQUENCIES:   # a spectrum's thousands of components: its quantiles
        waves = np.quantile(waves, np.linspace(0.0, 1.0, MAX_WAVE_FREQUENCIES))
    out = [(float(w), f"at the wave frequency {float(w):.4g} rad/s", -1) for w in waves]
    for i, w_n in enumerate(natural):
        if np.isfinite(w_n):
            why = f"near its natural frequency {w_n:.4g} rad/s (period {2 * np.pi / w_n:.3g} s)"
            out += [(float(w_n * f), why, i) for f in (1 / NATURAL_SPREAD, 1.0, NATURAL_SPREAD)]
    return [j for j in out if lo <= j[0] <= hi]


def cut_effect(irf_omega: np.ndarray, irf_damping: np.ndarray, duration: float, taper: float,
               omega: np.ndarray, damping: np.ndarray, added_mass: np.ndarray, inertia: np.ndarray | None,
               judged: Judged) -> CutEffect | None:
    """The worst relative change of the diagonal B_ii at the ``judged`` frequencies between the
    kernel over ``duration`` (``taper``) built from ``irf_damping`` on ``irf_omega`` and the HDB's
    ``damping`` on ``omega`` (linear in between); ``added_mass``, ``damping`` and ``irf_damping``:
    the diagonals (n_w, n); ``inertia`` (n,) or None (no critical-damping floor). None without a
    judged frequency."""
    if not judged:
        return None
    w = np.array([f for f, _, _ in judged])
    n = damping.shape[1]
    diag = np.arange(n)
    realised = irf_transfer(irf_omega, irf_damping, duration, taper, w).real   # (n_e, n)
    b = np.stack([np.interp(w, omega, damping[:, i]) for i in diag], axis=1)
    a = np.stack([np.interp(w, omega, added_mass[:, i]) for i in diag], axis=1)
    floor = CRITICAL_FLOOR * 2 * w[:, None] * (a + (0.0 if inertia is None else np.asarray(inertia)[None, :]))
    scale = np.maximum(np.abs(b), np.maximum(floor, 1e-12 * max(float(np.abs(damping).max()), 1e-300)))
    change = np.abs(realised - b) / scale
    for e, (_, _, dof) in enumerate(judged):   # a natural frequency: its own DOF only
        if dof >= 0:
            change[e, np.arange(n) != dof] = 0.0
    e, i = np.unravel_index(int(np.argmax(change)), change.shape)
    return CutEffect(float(change[e, i]), int(i), float(w[e]), judged[e][1])


def longer_memory(omega: np.ndarray, damping: np.ndarray, duration: float, taper: float,
                  added_mass: np.ndarray, inertia: np.ndarray | None,
                  judged: Judged) -> tuple[float, float | None, float]:
    """The first duration T 1.25^k (k = 1..MAX_STEPS) whose cut changes B by at most
    CUT_EFFECT_WARN at the judged frequencies: (duration, the B(w) resampling step it needs (None:
    the HDB grid reaches it without aliasing), its change); the longest tried when none does.
    ``damping``, ``added_mass``: the diagonals (n_w, n)."""
    t_alias = aliasing_time(omega)
    tried = (duration, None, np.inf)
    for k in range(1, MAX_STEPS + 1):
        longer = duration * LONGER ** k
        step = None if longer <= t_alias else float(np.pi / longer)
        grid, b = (omega, damping) if step is None else resample_damping(omega, damping, step)
        effect = cut_effect(grid, b, longer, taper, omega, damping, added_mass, inertia, judged)
        tried = (longer, step, effect.change if effect is not None else 0.0)
        if tried[2] <= CUT_EFFECT_WARN:
            break
    return tried
