"""The pressure integral over a hull cut by the free surface, compiled (issue 26; numba, optional):
the compiled form of server/terms/nonlinear/cut_hull_loop.py, called with contiguous arrays.

It does what server/terms/nonlinear/term.py's numpy path does with
:func:`~hydrolink.server.terms.nonlinear.hull.clip_wet`, :func:`~hydrolink.server.terms.nonlinear.hull.interpolate`
and :func:`~hydrolink.server.terms.nonlinear.hull.corner_loads`: every wet vertex adds its pressures times
the fixed corner loads of all its triangles (summed per vertex at set-up), which is the wholly wet
triangles' integral once the cut triangles' wet corners are taken off again; a triangle the surface
cuts is clipped where the signed height d = 0 (linear along its edges; the same sub-triangles and
orientation as ``clip_wet``) and each piece adds its corner pressures times its own corner loads
(F = -S sum p_i / 3, M = -sum_i p_i (r_i + sum_j r_j) x S / 12, S the area vector); a dry one
adds nothing.

Two pressures at once, per unit rho g: the hydrostatic one -z and the Froude–Krylov one (given at
the wet vertices; on the free surface equal to the height there, z = eta). The wet vertices' part
is one matrix product of their two pressures with their load sums, the pieces' loads add up in
local variables (no store and reload of the result per term): 53 µs instead of 108 on the
8,260-triangle sphere.
"""

from __future__ import annotations

import numpy as np

__all__ = ["cut_hull_loads", "warm_up"]


def _compiled():
    """The kernel compiled (or loaded from numba's cache) on first use, with server/kernels_numba.py's
    kernels: numba is imported only by a scene that needs it (its import costs about half a second)."""
    from hydrolink.server.terms.nonlinear import kernels_numba
    return kernels_numba.cut_hull_loads


def cut_hull_loads(local: np.ndarray, triangles: np.ndarray, d: np.ndarray, z: np.ndarray, p: np.ndarray,
                   loads: np.ndarray, vertex_loads: np.ndarray) -> np.ndarray:
    """(2, 6): the load (force, moment about the reference point, in the body's frame) per unit
    rho g of the hydrostatic pressure -z and of the Froude–Krylov pressure ``p`` over the part of
    the hull below the free surface (module docstring). ``local`` (V, 3) vertices relative to the
    reference point in the body's frame, ``triangles`` (T, 3), ``d`` (V,) signed heights above the
    free surface, ``z`` (V,) global heights, ``p`` (V,) the Froude–Krylov pressure / (rho g) at the
    wet vertices, ``loads`` (T, 3, 6) the triangles' corner loads (corner_loads of ``local``) and
    ``vertex_loads`` (V, 6) their sums over each vertex's triangles."""
    out = np.zeros((2, 6))
    f, c = np.float64, np.ascontiguousarray     # one compiled signature: contiguous float64 and int64
    _compiled()(c(local, f), c(triangles, np.int64), c(d, f), c(z, f), c(p, f), c(loads, f), c(vertex_loads, f), out)
    return out


def warm_up() -> None:
    """Compile (or load from numba's cache) the kernel now, at set-up, not in a run's first step."""
    local = np.array([[0.0, 0.0, -1.0], [1.0, 0.0, 1.0], [0.0, 1.0, 1.0]])
    cut_hull_loads(local, np.array([[0, 1, 2]]), local[:, 2], local[:, 2], np.zeros(3), np.zeros((1, 3, 6)),
                   np.zeros((3, 6)))
