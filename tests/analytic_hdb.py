"""Analytic hydrodynamic data with closed-form IRF and A(w) (test helper, independent of the code).

B(w) = b0 x^2 exp(-x^2), x = w/w0 has
    K(t) = b0 w0 k(w0 t),  k(s) = (1/sqrt(pi)) (1/2 - s^2/4) exp(-s^2/4)
    A(w) = A_inf + (b0/w0) (1 - 2 x F(x)) / sqrt(pi)        (F: Dawson's integral)
(Kramers-Kronig pair: A(w) - A_inf = -(1/w) int_0^inf K(t) sin(w t) dt.)
"""

from __future__ import annotations

import numpy as np
from scipy.special import dawsn

from hydrolink.protocol.hdb.schema import make_hdb


def damping(w, b0=1.0, w0=1.0):
    x = np.asarray(w, float) / w0
    return b0 * x ** 2 * np.exp(-x ** 2)


def irf(t, b0=1.0, w0=1.0):
    s = w0 * np.asarray(t, float)
    return b0 * w0 * (0.5 - s ** 2 / 4) * np.exp(-s ** 2 / 4) / np.sqrt(np.pi)


def added_mass(w, a_inf, b0=1.0, w0=1.0):
    x = np.asarray(w, float) / w0
    return a_inf + (b0 / w0) * (1 - 2 * x * dawsn(x)) / np.sqrt(np.pi)


# Per-DOF parameters of a single test body: (A_inf, b0, w0) and hydrostatic diagonal
DOF_PARAMS = {
    0: (2.0e5, 3.0e4, 1.2), 1: (2.0e5, 3.0e4, 1.2), 2: (3.0e5, 8.0e4, 1.0),
    3: (4.0e6, 1.0e5, 1.5), 4: (4.0e6, 1.0e5, 1.5), 5: (1.0e6, 1.0e4, 1.4),
}


def make_body_hdb(omega=None, directions=(0.0,), rho=1000.0, g=9.81, depth=np.inf,
                  name="float", with_inf=True, ref=(0.0, 0.0, 0.0), exc=None, hydrostatics=None, params=None):
    """One body, diagonal A and B per DOF from the analytic pair above; excitation ``exc(w, beta)``
    -> (n_w, 6) complex (default: a smooth made-up transfer function); ``params`` overrides
    DOF_PARAMS."""
    omega = np.linspace(0.02, 8.0, 400) if omega is None else np.asarray(omega, float)
    nw = omega.size
    a = np.zeros((nw, 6, 6))
    b = np.zeros((nw, 6, 6))
    ainf = np.zeros((6, 6))
    for d, (ai, b0, w0) in (params or DOF_PARAMS).items():
        a[:, d, d] = added_mass(omega, ai, b0, w0)
        b[:, d, d] = damping(omega, b0, w0)
        ainf[d, d] = ai
    dirs = np.asarray(directions, float)
    if exc is None:
        def exc(w, beta):
            base = np.array([1e4, 1e4, 3e5, 2e5, 2e5, 1e4])
            rot = np.array([np.cos(beta), np.sin(beta), 1.0, np.sin(beta), np.cos(beta), 0.5 * np.sin(2 * beta)])
            return (base * rot)[None, :] * np.exp(-0.3 * w[:, None] ** 2) * np.exp(1j * (0.4 + 0.8 * w[:, None]))
    x = np.stack([exc(omega, bb) for bb in dirs], axis=1)
    c = np.diag([0.0, 0.0, 7.7e5, 4e6, 4e6, 0.0]) if hydrostatics is None else hydrostatics
    return make_hdb(bodies=[name], omega=omega, wave_direction=dirs, added_mass=a, radiation_damping=b,
                    excitation_force=x, hydrostatic_stiffness=c, reference_point=np.array([ref], float),
                    rho=rho, g=g, water_depth=depth, source="analytic",
                    added_mass_inf=ainf if with_inf else None)
