"""The far-field mean drift of an ``hdb build`` (``[second_order] mean_drift = "far-field"``):
Capytaine's Kochin-function formulation (``capytaine.post_pro.mean_drift_force``) of the solved
diffraction and radiation problems, as the schema's :class:`MeanDrift` (surge, sway, yaw; N/m^2
and N m/m^2 per unit amplitude squared; the wave heading's own drift, k = l).

The Kochin functions are sampled on ``kochin_directions`` equal steps over [0, 2 pi] (the range
Capytaine integrates over), continued beyond each end to hold every heading of the spec with a few
steps to spare (Capytaine differentiates in theta and wants the headings inside, not on, the range).
Motions: the body held fixed (RAO 0, the diffraction drift), or free: Capytaine's RAO
(``capytaine.post_pro.rao``) of the body's mass matrix and full hydrostatic stiffness (gravity
included) on the solved grid, whose radiated waves then enter the Kochin functions.
"""

from __future__ import annotations

import numpy as np

from hydrolink.protocol.hdb.second_order import MeanDrift

DRIFT_DOFS = {"Surge": 0, "Sway": 1, "Yaw": 5}
_EXTRA = 4   # Kochin samples beyond each end of [0, 2 pi]


def kochin_angles(n: int, headings: np.ndarray) -> np.ndarray:
    """``n`` equal steps over [0, 2 pi] (both ends exact), continued beyond each end far enough
    to hold every heading with _EXTRA steps to spare."""
    step = 2 * np.pi / n
    below = _EXTRA + int(np.ceil(max(0.0, -float(np.min(headings))) / step))
    above = _EXTRA + int(np.ceil(max(0.0, float(np.max(headings)) - 2 * np.pi) / step))
    return np.concatenate([-step * np.arange(below, 0, -1), np.linspace(0.0, 2 * np.pi, n + 1),
                           2 * np.pi + step * np.arange(1, above + 1)])


def far_field_drift(results: list, cds, n_directions: int, motion: tuple[np.ndarray, np.ndarray] | None
                    ) -> MeanDrift:
    """Mean drift of the finite-frequency results (solved with ``keep_details``) of one body;
    ``cds`` is their assembled Capytaine dataset (for the grid and the DOF names). ``motion``:
    None for the body held fixed, else its (mass matrix, hydrostatic stiffness with gravity), 6x6
    about the reference point in Capytaine's DOF order, for a body floating freely."""
    from capytaine.post_pro.rao import rao as capytaine_rao

    import xarray as xr
    from capytaine.io.xarray import kochin_data_array
    from capytaine.post_pro.mean_drift_force import far_field_mean_drift_force

    # omega = inf is a Capytaine SymbolicMultiplication, which numpy cannot test: float() first
    finite = [r for r in results if np.isfinite(float(r.omega)) and float(r.omega) > 0]
    theta = xr.DataArray(kochin_angles(n_directions, cds["wave_direction"].values), dims=("theta",))
    kochin = kochin_data_array(finite, theta)
    grid = cds.sel(omega=cds["omega"].values[np.isfinite(cds["omega"].values)])
    data = kochin.assign_coords(wavenumber=grid["wavenumber"])
    if motion is None:
        rao = xr.zeros_like(grid["excitation_force"]).rename(influenced_dof="radiating_dof")
    else:
        dofs = {"influenced_dof": grid["influenced_dof"].values, "radiating_dof": grid["radiating_dof"].values}
        rao = capytaine_rao(grid.assign(inertia_matrix=xr.DataArray(motion[0], dims=tuple(dofs), coords=dofs),
                                        hydrostatic_stiffness=xr.DataArray(motion[1], dims=tuple(dofs), coords=dofs)))
    rao = rao.transpose("omega", "wave_direction", "radiating_dof")
    drift = far_field_mean_drift_force(rao, data)
    omega = drift["omega"].values
    beta = drift["wave_direction_k"].values
    order_w, order_b = np.argsort(omega), np.argsort(beta)
    values = np.zeros((1, omega.size, beta.size, 6))
    for name, dof in DRIFT_DOFS.items():
        da = drift[f"drift_force_{name.lower()}"].transpose("omega", "wave_direction_k", "wave_direction_l").values
        values[0, :, :, dof] = np.real(np.diagonal(da, axis1=1, axis2=2))
    how = "body fixed" if motion is None else "body floating freely (its RAO)"
    return MeanDrift(("far-field",), omega[order_w], beta[order_b], values[:, order_w][:, :, order_b],
                     note=f"Capytaine far-field (Kochin), {how}", body_fixed=motion is None)
