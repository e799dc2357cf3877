"""Reader for WEC-Sim BEMIO HDF5 files (``writeBEMIOH5`` layout).

BEMIO stores coefficients normalised like WAMIT (A/rho, B/(rho w), X/(rho g), K_hs/(rho g)) in the
exp(+i w t) convention; this reader multiplies back with the file's own rho and g and conjugates
the excitation into the internal exp(-i w t). Only the ``all``/``re``/``im`` datasets are read.

Generalized modes (issue 38): a body's ``properties/dof`` (WEC-Sim: 6 + N) sizes its rows; the N
beyond the rigid six are named ``mode1``..``modeN`` (the file names none).

Mean drift: ``bodyN/hydro_coeffs/mean_drift/{momentum_conservation|control_surface|
pressure_integration}/val``, laid out like the excitation (h5py: (6, n_beta, n_w)) and normalised
like it, by rho g: the coefficient is rho g val per unit amplitude squared (real). A method is read
when every body has it. QTFs: the difference QTF of the ``excitation/QTF<k>/Diff<dof>`` groups
(:mod:`.bemio_qtf`, which says why the ``Sum<dof>`` groups are left out).

Reference point: ``bodyN/properties/cg``. WEC-Sim applies every hydrodynamic force of a body at its
centre of gravity and expects the BEM run to be set up about it (BEMIO's readWAMIT takes ``cg`` from
the WAMIT run's body origin); the Task-10 sphere confirms it: its surge-pitch coupling A15 = 2 A11
and A55 = 4 A11 are exactly those of a sphere (no rotational added mass about its centre at z = 0)
referred to cg z = -2 m.
"""

from __future__ import annotations

import math
from pathlib import Path

import h5py
import numpy as np
import xarray as xr

from hydrolink.protocol.hdb.layout import BodyDofs, HDBError
from hydrolink.protocol.hdb.schema import make_hdb
from hydrolink.protocol.hdb.second_order import MeanDrift
from hydrolink.server.hdb.bemio_qtf import read_bemio_qtf

# BEMIO's mean drift groups (hydro_coeffs/mean_drift/<group>/val) and the schema's method names
DRIFT_GROUPS = {"momentum_conservation": "momentum", "control_surface": "control-surface",
                "pressure_integration": "pressure"}


class _H5:
    """Dataset access that names the file and the HDF5 path on every error."""

    def __init__(self, fh: h5py.File, source: Path):
        self.fh, self.source = fh, source

    def has(self, name: str) -> bool:
        return name in self.fh and isinstance(self.fh[name], h5py.Dataset)

    def get(self, name: str, shape: tuple[int, ...] | None = None) -> np.ndarray:
        if not self.has(name):
            raise HDBError(self.source, name, "missing dataset")
        value = self.fh[name][()]
        if shape is not None and np.shape(value) != shape:
            raise HDBError(self.source, name, f"shape must be {shape}, got {np.shape(value)}")
        return value

    def vector3(self, name: str) -> np.ndarray:
        """A point stored as (3, 1), (1, 3) or (3,)."""
        value = np.asarray(self.get(name), float)
        if value.size != 3:
            raise HDBError(self.source, name, f"must hold 3 coordinates, got shape {value.shape}")
        return value.ravel()

    def number(self, name: str) -> float:
        value = np.asarray(self.get(name))
        if value.size != 1:
            raise HDBError(self.source, name, f"must be a single number, got shape {value.shape}")
        try:
            return float(value.ravel()[0])
        except (TypeError, ValueError):
            raise HDBError(self.source, name, f"must be a number, got {value.ravel()[0]!r}") from None

    def text(self, name: str) -> str:
        value = np.asarray(self.get(name)).ravel()[0]
        return value.decode(errors="replace") if isinstance(value, bytes) else str(value)


def _water_depth(h5: _H5) -> float:
    """Water depth; BEMIO writes 'infinite' (or a non-positive number) for deep water."""
    name = "simulation_parameters/water_depth"
    raw = np.asarray(h5.get(name)).ravel()[0]
    if isinstance(raw, (bytes, str)):
        word = raw.decode() if isinstance(raw, bytes) else raw
        if word.strip().lower().startswith("inf"):
            return math.inf
        try:
            raw = float(word)
        except ValueError:
            raise HDBError(h5.source, name, f"must be a number or 'infinite', got {word!r}") from None
    depth = float(raw)
    return math.inf if not depth > 0 else depth


def _body_groups(h5: _H5) -> list[str]:
    """``body1``, ``body2``... in numeric order."""
    groups = [k for k in h5.fh.keys() if k.startswith("body") and k[4:].isdigit()]
    if not groups:
        raise HDBError(h5.source, "body1", "no bodyN groups in the file")
    return sorted(groups, key=lambda k: int(k[4:]))


def read_bemio(path: str | Path) -> xr.Dataset:
    """Read a BEMIO .h5 file into the internal HDB layout."""
    path = Path(path)
    if not path.is_file():
        raise HDBError(path, "file", "not found")
    try:
        fh = h5py.File(path, "r")
    except OSError as exc:
        raise HDBError(path, "file", f"not a readable HDF5 file ({exc})") from None
    with fh:
        return _read(_H5(fh, path))


def _read(h5: _H5) -> xr.Dataset:
    rho = h5.number("simulation_parameters/rho")
    g = h5.number("simulation_parameters/g")
    omega = np.asarray(h5.get("simulation_parameters/w"), float).ravel()
    betas = np.deg2rad(np.asarray(h5.get("simulation_parameters/wave_dir"), float).ravel())
    depth = _water_depth(h5)
    groups = _body_groups(h5)
    n_b, n_w, n_beta = len(groups), omega.size, betas.size
    names = [h5.text(f"{grp}/properties/name").replace(".", "_") if h5.has(f"{grp}/properties/name") else grp
             for grp in groups]
    if len(set(names)) != len(names):
        names = [f"{name}{n + 1}" for n, name in enumerate(names)]
    dofs = BodyDofs(tuple(names), tuple(_modes(h5, grp) for grp in groups))
    n_dof = dofs.size
    order = np.argsort(omega, kind="stable")

    added_mass = np.zeros((n_w, n_dof, n_dof))
    damping = np.zeros_like(added_mass)
    excitation = np.zeros((n_w, n_beta, n_dof), complex)
    stiffness = np.zeros((n_dof, n_dof))
    a_inf = np.zeros((n_dof, n_dof))
    reference, cb = np.zeros((n_b, 3)), np.zeros((n_b, 3))
    volume = np.zeros(n_b)
    have_inf = have_cb = have_vol = True
    for n, (grp, at, count) in enumerate(zip(groups, dofs.offsets, dofs.counts)):
        props, coeffs = f"{grp}/properties", f"{grp}/hydro_coeffs"
        rows = slice(at, at + count)
        a = h5.get(f"{coeffs}/added_mass/all", (count, n_dof, n_w))
        b = h5.get(f"{coeffs}/radiation_damping/all", (count, n_dof, n_w))
        added_mass[:, rows, :] = rho * np.moveaxis(a, 2, 0)
        damping[:, rows, :] = rho * omega[:, None, None] * np.moveaxis(b, 2, 0)
        re = h5.get(f"{coeffs}/excitation/re", (count, n_beta, n_w))
        im = h5.get(f"{coeffs}/excitation/im", (count, n_beta, n_w))
        excitation[:, :, rows] = rho * g * np.transpose(re - 1j * im, (2, 1, 0))
        stiffness[rows, rows] = rho * g * h5.get(f"{coeffs}/linear_restoring_stiffness", (count, count))
        if h5.has(f"{coeffs}/added_mass/inf_freq"):
            a_inf[rows, :] = rho * h5.get(f"{coeffs}/added_mass/inf_freq", (count, n_dof))
        else:
            have_inf = False
        reference[n] = h5.vector3(f"{props}/cg")
        if h5.has(f"{props}/cb"):
            cb[n] = h5.vector3(f"{props}/cb")
        else:
            have_cb = False
        if h5.has(f"{props}/disp_vol"):
            volume[n] = h5.number(f"{props}/disp_vol")
        else:
            have_vol = False
    drift = _mean_drift(h5, groups, dofs, rho * g, omega, betas, order)
    return make_hdb(
        bodies=names, omega=omega[order], wave_direction=betas,
        added_mass=added_mass[order], radiation_damping=damping[order],
        excitation_force=excitation[order], hydrostatic_stiffness=stiffness,
        reference_point=reference, rho=rho, g=g, water_depth=depth, source=str(h5.source),
        added_mass_inf=a_inf if have_inf else None,
        displaced_volume=volume if have_vol else None,
        center_of_buoyancy=cb if have_cb else None, mean_drift=drift,
        qtf=read_bemio_qtf(h5.fh, groups, h5.source, dofs), modes=dofs.mode_map(),
    )


def _modes(h5: _H5, grp: str) -> tuple[str, ...]:
    """A body's generalized modes (issue 38): ``properties/dof`` beyond the rigid 6 (WEC-Sim's
    count; none when absent), named ``mode1``..``modeN`` (BEMIO stores no names)."""
    name = f"{grp}/properties/dof"
    if not h5.has(name):
        return ()
    count = h5.number(name)
    if count != int(count) or count < 6:
        raise HDBError(h5.source, name, f"{count:g} DOFs for this body: must be a whole number >= 6 (the rigid 6, "
                                        "then the generalized modes)")
    return tuple(f"mode{k}" for k in range(1, int(count) - 5))


def _mean_drift(h5: _H5, groups: list[str], dofs: BodyDofs, rho_g: float, omega: np.ndarray, betas: np.ndarray,
                order: np.ndarray) -> MeanDrift | None:
    """The mean drift methods every body has, in SI (rho g val), on the file's sorted grid."""
    n_w, n_beta, n_dof = omega.size, betas.size, dofs.size
    methods, values = [], []
    for group, method in DRIFT_GROUPS.items():
        names = [f"{grp}/hydro_coeffs/mean_drift/{group}/val" for grp in groups]
        have = [h5.has(name) for name in names]
        if not any(have):
            continue
        if not all(have):
            raise HDBError(h5.source, names[have.index(False)], f"missing while other bodies have {group} drift")
        val = np.zeros((n_w, n_beta, n_dof))
        for name, at, count in zip(names, dofs.offsets, dofs.counts):
            raw = np.asarray(h5.get(name, (count, n_beta, n_w)))
            if np.iscomplexobj(raw):
                raise HDBError(h5.source, name, "must be real (the mean drift per unit amplitude squared)")
            val[:, :, at:at + count] = rho_g * np.transpose(raw, (2, 1, 0))
        methods.append(method)
        values.append(val[order][:, np.argsort(betas)])
    if not methods:
        return None
    return MeanDrift(tuple(methods), omega[order], np.sort(betas), np.stack(values))
