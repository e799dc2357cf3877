"""Linear restoring stiffness about equilibrium: buoyancy/waterplane (HDB) plus gravity.

Gravity terms, derived for one body with mass m, centre of gravity G and reference point R
(d = G - R, global frame at equilibrium), small rotation theta about R:
the weight W = (0, 0, -m g) acts at R + xi + theta x d, so its moment about the moved reference
point changes by dM = (theta x d) x W. With theta x d = (th5 dz - th6 dy, th6 dx - th4 dz,
th4 dy - th5 dx) and a x (0,0,-mg) = -m g (a_y, -a_x, 0):
    dM_x =  m g dz th4 - m g dx th6,     dM_y = m g dz th5 - m g dy th6,     dM_z = 0.
As restoring stiffness (F = -C x):
    C44 -= m g dz,  C55 -= m g dz,  C46 += m g dx,  C56 += m g dy
(asymmetric, as in WAMIT's external stiffness). The weight's force does not change (no
translational terms). The hydrostatic force is F_hs = -C (x - x_eq).

These are added once, here: the HDB's stiffness holds none (its readers take out what the files
include: WAMIT's -m g VCG in C44/C55 when the run's VCG != 0, server/hdb/wamit/reader.py; Capytaine's
gravity terms, server/hdb/capytaine_io.py).
"""

from __future__ import annotations

import numpy as np


def gravity_stiffness(mass: float, center_of_mass: np.ndarray, reference_point: np.ndarray,
                      g: float) -> np.ndarray:
    """6x6 gravity contribution for one body (see module docstring)."""
    dx, dy, dz = np.asarray(center_of_mass, float) - np.asarray(reference_point, float)
    c = np.zeros((6, 6))
    mg = mass * g
    c[3, 3] = c[4, 4] = -mg * dz
    c[3, 5] = mg * dx
    c[4, 5] = mg * dy
    return c


def total_stiffness(c_hydro: np.ndarray, masses: np.ndarray, centers_of_mass: np.ndarray,
                    reference_points: np.ndarray, g: float) -> np.ndarray:
    """(6N, 6N) HDB hydrostatic stiffness (already in the scene's rho, g) plus each body's gravity
    block on its diagonal."""
    c = np.array(c_hydro, float, copy=True)
    for i, (m, cg, ref) in enumerate(zip(masses, np.asarray(centers_of_mass, float),
                                         np.asarray(reference_points, float))):
        c[6 * i:6 * i + 6, 6 * i:6 * i + 6] += gravity_stiffness(m, cg, ref, g)
    return c
