"""A nonlinear body's two reply rows from its hull loads (server/terms/nonlinear/term.py): plain code
that runs as it is on the numpy path and compiled by server/terms/nonlinear/kernels_numba.py on the compiled one
(one implementation; loops, not numpy calls, so that the compiled form has no call overhead).

    nonlinear_hydrostatic   = R F_hs + F_weight(R) - (net buoyancy e_z - C (x - x_eq))
    nonlinear_froude_krylov = R F_FK - F_FK,lin(t)

F_hs, F_FK the loads per unit rho g in the body's frame (force, moment about the reference
point), R the pose's rotation; the weight acts at the centre of mass, R times its lever.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

__all__ = ["BodyConstants", "reply_rows"]


class BodyConstants(NamedTuple):
    """A nonlinear body's fixed inputs to :func:`reply_rows` (float64 arrays, contiguous)."""
    rg: float                  # rho g [N/m^3]: the loads are per unit rho g
    lever: np.ndarray          # (3,) centre of mass minus reference point at equilibrium [m]
    weight: float              # m g [N]
    stiffness: np.ndarray      # (6, 6) the linear model's hydrostatic stiffness (active DOFs only)
    reference: np.ndarray      # (6,) the linear model's equilibrium pose
    linear_net: float          # its net buoyancy [N]
    active: np.ndarray         # (6,) 1.0 on active DOFs, else 0.0


def reply_rows(loads: np.ndarray, fk_linear: np.ndarray, rot: np.ndarray, pose: np.ndarray, body: BodyConstants,
               hs: np.ndarray, fk: np.ndarray) -> None:
    """Writes the rows ``hs`` and ``fk`` (6,) (zero on inactive DOFs): ``loads`` (2, 6) the
    hydrostatic and Froude–Krylov loads per unit rho g in the body's frame, ``fk_linear`` (6,) [N]
    the linear Froude–Krylov force now, ``rot`` (3, 3) the rotation of the ``pose`` (6,)."""
    rg, lever, weight, stiffness = body.rg, body.lever, body.weight, body.stiffness
    reference, linear_net, active = body.reference, body.linear_net, body.active
    for j in range(6):
        hs[j] = 0.0
        fk[j] = 0.0
    for i in range(3):
        for j in range(3):
            hs[i] += rg * rot[i, j] * loads[0, j]
            hs[3 + i] += rg * rot[i, j] * loads[0, 3 + j]
            fk[i] += rg * rot[i, j] * loads[1, j]
            fk[3 + i] += rg * rot[i, j] * loads[1, 3 + j]
    arm_x = rot[0, 0] * lever[0] + rot[0, 1] * lever[1] + rot[0, 2] * lever[2]
    arm_y = rot[1, 0] * lever[0] + rot[1, 1] * lever[1] + rot[1, 2] * lever[2]
    hs[2] -= weight + linear_net
    hs[3] -= arm_y * weight          # arm x (0, 0, -m g)
    hs[4] += arm_x * weight
    for i in range(6):
        for j in range(6):
            hs[i] += stiffness[i, j] * (pose[j] - reference[j])
    for j in range(6):
        hs[j] *= active[j]
        fk[j] = (fk[j] - fk_linear[j]) * active[j]
