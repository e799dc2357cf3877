"""The linear pressure on every hull panel of a body over a run (``bodies[i].pressure_output``, WEC-Sim
PR #1596): what an FE model of the hull takes. On the mean (body-fixed) mesh, per panel at its centre:

    p(t) = -rho g (z + dz(t)) + e(t) + p_rad(t)

the hydrostatic pressure at rest and its change with the panel's rise dz = xi_3 + theta_1 (y - y_r) -
theta_2 (x - x_r), the incident + diffracted pressure of the model's wave components and the radiation
pressure of the recorded motion (server/loads/water.py). The water's force on the body's DOF i is
-sum p (V_i . n) dS: its wave and radiation parts are the model's excitation and radiation forces
(A-infinity's included), its hydrostatic part the body-axes change of the buoyancy (the HDB's C less
the buoyancy's turning with the body, theta x rho g V e_z)."""

from __future__ import annotations

import numpy as np

from hydrolink.protocol.scene import Scene
from hydrolink.server.allocation import require_size
from hydrolink.server.hdb.build.panels import PanelPressures
from hydrolink.server.loads.water import RecordedMotion, linear_rows, water_series
from hydrolink.server.sea.waves import WaveComponents


def still_pressure(ps: PanelPressures, rho: float, g: float) -> np.ndarray:
    """(P,) the hydrostatic pressure at rest at each panel's centre."""
    return -rho * g * ps.center[:, 2]


def panel_series(ps: PanelPressures, motion: RecordedMotion, scene: Scene, waves: WaveComponents, body: str,
                 key: str) -> np.ndarray:
    """(T, P) the dynamic pressure on each panel over the recorded rows (module docstring; the still
    part :func:`still_pressure` not included); the size checked first, naming ``key``."""
    require_size(key, "the panel pressures over the run (rows x panels)", (motion.time.size, ps.panels),
                 hint="fewer rows (a shorter run or a coarser results step) or a coarser mesh")
    rho_g = scene.water.density * scene.water.gravity
    ref = ps.reference_point
    rise = np.c_[np.zeros((ps.panels, 2)), np.ones(ps.panels), ps.center[:, 1] - ref[1], -(ps.center[:, 0] - ref[0]),
                 np.zeros(ps.panels)]                                                      # (P, 6)
    return water_series(linear_rows(ps, None), ps, motion, scene, waves, body) - rho_g * motion.displacement @ rise.T
