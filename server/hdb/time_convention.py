"""Which time convention a file's complex amplitudes are in, told from the physics they hold.

A Capytaine-layout NetCDF file does not say whether its complex amplitudes mean exp(-iwt)
(Capytaine) or exp(+iwt) (WecOptTool 3.3's ``run_bem`` conjugates the Froude-Krylov, diffraction
and excitation forces and writes no mark). Added mass, damping and stiffness are the same in both;
the forces' phases are conjugated. Two long-wave limits fix those phases in exp(-iwt), with the
undisturbed wave eta = a exp(i(k.x - w t)) at the surface (x_r the body's reference point, C its
waterplane stiffness in heave, V its displaced volume):

* Froude-Krylov: over a body small against the wavelength the pressure rho g eta e^(kz) pushes
  horizontally with its gradient over the displaced volume and vertically with the waterplane
  (minus the vertical gradient over the volume): F_FK ~ eta(x_r) (-rho g V i k cos b,
  -rho g V i k sin b, C_33 - w^2 rho V). The ratio of surge (sway) to heave removes eta(x_r):
  predicted q = -i k cos b rho g V / (C_33 - w^2 rho V), pure imaginary to first order in k.
  (Roll and pitch are not used: their prediction needs the buoyancy + waterplane stiffness without
  gravity, which a file records only through its centre of mass and mass, not always those used.)
* Diffraction: a body small against the wavelength feels the fluid's heave motion eta as if it
  moved by -eta: F_D,3 ~ (-w^2 A_33 - i w B_33) eta, so F_D,3 / F_FK,3 ~ (-w^2 A_33 - i w B_33) / f_3
  (f_3 = C_33 - w^2 rho V),
  whose imaginary part has the sign of the radiated energy (B > 0): a heave-only body at the origin
  is checked too.

Each ratio r measured in the file is compared with the prediction p and with its conjugate:
d = |r - p| / |r - conj(p)|. At the frequencies where k l <= LONG_WAVE (l the body's size) and the
prediction has an imaginary part of at least MIN_PHASE of its modulus, d < 1 / CONCLUSIVE votes for
exp(-iwt), d > CONCLUSIVE for exp(+iwt); votes that disagree decide nothing. Measured on five
Capytaine solves (w 0.3-3 rad/s; a sphere floating off the origin, a vertical cylinder, a heave-only
cylinder at the origin, a submerged sphere, a box in 8 m of water): the ratios that voted had
d <= 0.15 in the true convention (medians 0-0.11), none voted for the other; conjugated, every
one of them voted exp(+iwt).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from hydrolink.server.sea.dispersion import wave_number

LONG_WAVE = 0.5       # k * body size up to which the long-wave limits are used
MIN_PHASE = 0.05      # |Im p| / |p| below which a prediction carries no phase information
CONCLUSIVE = 3.0      # d below 1/CONCLUSIVE or above CONCLUSIVE is a vote
_DOF_NAMES = ("surge", "sway", "heave", "roll", "pitch", "yaw")


@dataclass(frozen=True)
class ConventionEvidence:
    """What the forces' phases say: ``verdict`` "exp(-iwt)", "exp(+iwt)" or None (no vote, or
    votes that disagree); ``detail`` says on what."""

    verdict: str | None
    detail: str


def _votes(d: np.ndarray) -> tuple[int, int]:
    return int(np.sum(d < 1 / CONCLUSIVE)), int(np.sum(d > CONCLUSIVE))


def evidence(*, omega: np.ndarray, wave_direction: np.ndarray, bodies: list[str], offsets: list[int], rho: float, g: float,
             depth: float, added_mass: np.ndarray, radiation_damping: np.ndarray, stiffness: np.ndarray,
             volume: np.ndarray | None, froude_krylov: np.ndarray, diffraction: np.ndarray | None
             ) -> ConventionEvidence:
    """Judge the convention of ``froude_krylov`` (and ``diffraction``), as stored: (n_omega, n_beta,
    n_dof); the other arrays in exp(-iwt)-free schema layout ((n_omega,) n_dof x n_dof, stiffness buoyancy +
    waterplane only, volume (N,) or None); ``offsets``: each body's first DOF (its rigid six follow)."""
    k_all = wave_number(omega, g, depth)
    beta = np.asarray(wave_direction, float)
    minus = plus = 0
    used: list[str] = []
    for n, (body, at) in enumerate(zip(bodies, offsets)):
        o = slice(at, at + 6)
        c = stiffness[o, o]
        vol = float(volume[n]) if volume is not None else 0.0
        size = max(vol ** (1 / 3), np.sqrt(max(c[2, 2], 0.0) / (rho * g)))
        if size == 0:
            continue
        sel = np.flatnonzero(k_all * size <= LONG_WAVE)
        for i in sel:
            w, k = omega[i], k_all[i]
            fk = froude_krylov[i, :, o]                                   # (n_beta, 6)
            f3 = c[2, 2] - w**2 * rho * vol
            if f3 == 0 or not np.all(np.abs(fk[:, 2]) > 0):
                continue
            slope = 1j * k * np.stack([np.cos(beta), np.sin(beta)])           # (2, n_beta)
            pred = [(-rho * g * vol * slope[j] / f3, fk[:, j] / fk[:, 2], f"Froude-Krylov {_DOF_NAMES[j]}/heave")
                    for j in (0, 1)]
            if diffraction is not None:
                p = np.full(beta.size, (-w**2 * added_mass[i, at + 2, at + 2]
                                        - 1j * w * radiation_damping[i, at + 2, at + 2]) / f3)
                pred.append((p, diffraction[i, :, at + 2] / fk[:, 2], "diffraction/Froude-Krylov heave"))
            for p, r, what in pred:
                ok = (np.abs(p.imag) >= MIN_PHASE * np.abs(p)) & (np.abs(p) > 0) & (np.abs(r) > 0)
                if not np.any(ok):
                    continue
                d = np.abs(r[ok] - p[ok]) / np.maximum(np.abs(r[ok] - np.conj(p[ok])), 1e-300)
                m, pl = _votes(d)
                minus, plus = minus + m, plus + pl
                if m or pl:
                    used.append(f"{body} {what} at w={w:.3g} rad/s")
    where = "; ".join(dict.fromkeys(used[:4])) + (" ..." if len(used) > 4 else "")
    if minus and plus:
        return ConventionEvidence(None, f"the force phases disagree ({minus} ratios fit exp(-iwt), {plus} "
                                        f"exp(+iwt): {where})")
    if minus or plus:
        verdict = "exp(-iwt)" if minus else "exp(+iwt)"
        return ConventionEvidence(verdict, f"{minus or plus} long-wave phase ratios fit {verdict} ({where})")
    return ConventionEvidence(None, "no long-wave phase ratio could be checked (needs the Froude-Krylov force and "
                                    f"a frequency with k*size <= {LONG_WAVE})")
