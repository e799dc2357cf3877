"""The internal hydrodynamic database (HDB): one labelled xarray dataset, one convention.

Every reader converts its format into this layout once; everything downstream (IRF, forces,
``hdb info``, the wire) reads only this. Layout::

    dims    omega (n_w, strictly increasing, > 0), influenced_dof (n), radiating_dof (n),
            wave_direction (n_b, radians), body (N), xyz (3); n = sum over the bodies of 6 + N_b
    coords  omega [rad/s]; wave_direction [rad]; body (names);
            influenced_dof / radiating_dof: labels "<body>.<dof>", body-major: each body's six
            rigid DOFs in DOF_NAMES order, then its N_b >= 0 generalized modes (flexible modes,
            issue 38) by name ("<body>.bend1", "<body>.mode7"): :func:`body_dofs` reads them
    vars    added_mass            (omega, influenced_dof, radiating_dof)   kg, kg m, kg m^2
            radiation_damping     (omega, influenced_dof, radiating_dof)   N s/m, ...
            excitation_force      (omega, wave_direction, influenced_dof)  complex, per metre of wave
                                                                            amplitude, exp(-i w t)
            hydrostatic_stiffness (influenced_dof, radiating_dof)          buoyancy + waterplane only
                                                                            (no gravity terms)
            reference_point       (body, xyz)   point the rotational modes refer to, global frame
                                                at equilibrium (m)
            added_mass_inf        (influenced_dof, radiating_dof)   optional; absent -> Ogilvie
            displaced_volume      (body)        optional (m^3)
            center_of_buoyancy    (body, xyz)   optional (m)
            mass                  (body)        optional (kg): the body mass the file records
            center_of_mass        (body, xyz)   optional (m): the centre of gravity the file records
            mean_drift, difference_qtf, sum_qtf   optional second-order data: layout and
                                                  conventions in :mod:`.second_order`
    attrs   rho, g, water_depth (float, inf for deep water), time_convention = "exp(-iwt)",
            source (where it came from), hdb_schema_version = 2 (2: mean_drift_body_fixed required
            with mean_drift; hdb build's cache keys change with it), warnings (optional: a JSON
            list of str, what its reader or builder found doubtful; :func:`hdb_warnings`)

Time convention: a regular wave with elevation eta(t) = Re{a exp(-i w t)} at the origin gives the
excitation force Re{a X(w) exp(-i w t)} (Capytaine's convention). Readers of exp(+i w t) formats
(WAMIT, BEMIO/WEC-Sim) take the complex conjugate.

Row index = force component (influenced), column = motion (radiating): F = -A a - B v.
"""

from __future__ import annotations

import json
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from hydrolink.protocol.errors import KeyedError
from hydrolink.protocol.scene_bounds import DENSITY_RANGE, DEPTH_RANGE, GRAVITY_RANGE

DOF_NAMES: tuple[str, ...] = ("surge", "sway", "heave", "roll", "pitch", "yaw")
TIME_CONVENTION = "exp(-iwt)"
SCHEMA_VERSION = 2

REQUIRED_VARS = {
    "added_mass": ("omega", "influenced_dof", "radiating_dof"),
    "radiation_damping": ("omega", "influenced_dof", "radiating_dof"),
    "excitation_force": ("omega", "wave_direction", "influenced_dof"),
    "hydrostatic_stiffness": ("influenced_dof", "radiating_dof"),
    "reference_point": ("body", "xyz"),
}
DRIFT_METHODS: tuple[str, ...] = ("momentum", "control-surface", "pressure", "far-field")
QTF_KINDS: tuple[str, ...] = ("difference", "sum")
MEAN_DRIFT_DIMS = ("drift_method", "drift_omega", "drift_direction", "influenced_dof")
QTF_DIMS = ("qtf_omega_i", "qtf_omega_j", "qtf_heading", "influenced_dof")
SECOND_ORDER_VARS = {"mean_drift": MEAN_DRIFT_DIMS, "difference_qtf": QTF_DIMS, "sum_qtf": QTF_DIMS}
OPTIONAL_VARS = {
    "added_mass_inf": ("influenced_dof", "radiating_dof"),
    "displaced_volume": ("body",),
    "center_of_buoyancy": ("body", "xyz"),
    "mass": ("body",),
    "center_of_mass": ("body", "xyz"),
    **SECOND_ORDER_VARS,
}
COMPLEX_VARS = ("excitation_force", "difference_qtf", "sum_qtf")   # split into _re/_im in NetCDF
REQUIRED_ATTRS = ("rho", "g", "water_depth")
ATTR_RANGES = {"rho": DENSITY_RANGE, "g": GRAVITY_RANGE, "water_depth": DEPTH_RANGE}


class HDBError(KeyedError):
    """A hydrodynamic database that cannot be used; the message names the file and the field."""

    @property
    def field(self) -> str:
        """The file's field (variable, column, line) at fault: the error's key."""
        return self.key


MODE_NAME = re.compile(r"^[A-Za-z0-9_\-]+$")


def dof_labels(bodies: list[str], modes: Mapping[str, Sequence[str]] | None = None) -> list[str]:
    """DOF labels "<body>.<dof>" in the schema's order (body-major): each body's six rigid DOFs,
    then its generalized modes (``modes[body]``, none when absent)."""
    modes = modes or {}
    return [f"{b}.{d}" for b in bodies for d in (*DOF_NAMES, *modes.get(b, ()))]


@dataclass(frozen=True)
class BodyDofs:
    """The DOFs of an HDB's bodies: names, each body's generalized modes (after its six rigid
    DOFs) and its first DOF's position in the body-major DOF vector; computed once from the
    labels (:func:`body_dofs`)."""
    bodies: tuple[str, ...]
    modes: tuple[tuple[str, ...], ...]

    @property
    def counts(self) -> tuple[int, ...]:
        """Each body's DOF count, 6 + its modes."""
        return tuple(len(DOF_NAMES) + len(m) for m in self.modes)

    @property
    def offsets(self) -> tuple[int, ...]:
        """Each body's first DOF in the DOF vector."""
        return tuple(int(o) for o in np.concatenate([[0], np.cumsum(self.counts)[:-1]])) if self.bodies else ()

    @property
    def size(self) -> int:
        """All DOFs of all bodies."""
        return int(sum(self.counts))

    @property
    def has_modes(self) -> bool:
        return any(self.modes)

    def of(self, body: str) -> tuple[str, ...]:
        """The modes of ``body`` (KeyError when it is not one of the bodies)."""
        return self.modes[self.bodies.index(body)]

    def mode_map(self) -> dict[str, tuple[str, ...]]:
        return {b: m for b, m in zip(self.bodies, self.modes) if m}

    def labels(self) -> list[str]:
        return dof_labels(list(self.bodies), self.mode_map())

    def index(self, body: str, dof: int) -> int:
        """The position of DOF ``dof`` (0-5 rigid, 6 + k the body's mode k) of ``body``."""
        return self.offsets[self.bodies.index(body)] + dof


def body_dofs(bodies: Sequence[str], labels: Sequence[str], source, field: str = "influenced_dof") -> BodyDofs:
    """The bodies' DOFs from an HDB's labels (body-major; each body's six rigid DOFs in order,
    then its modes); HDBError naming ``field`` when the labels are not in that layout."""
    bodies, labels = [str(b) for b in bodies], [str(v) for v in labels]
    modes: list[tuple[str, ...]] = []
    at = 0
    for body in bodies:
        rigid = [f"{body}.{d}" for d in DOF_NAMES]
        if labels[at:at + 6] != rigid:
            raise HDBError(source, field, f"body {body!r}: labels {labels[at:at + 6]} at positions {at}..{at + 5} "
                                          f"must be its six rigid DOFs {rigid} (body-major, modes after them)")
        at += 6
        own = []
        while at < len(labels) and labels[at].startswith(f"{body}.") and labels[at][len(body) + 1:] not in DOF_NAMES:
            name = labels[at][len(body) + 1:]
            if not MODE_NAME.match(name) or name in own:
                why = "is repeated" if name in own else "must be <body>.<letters, digits, _ or ->"
                raise HDBError(source, field, f"body {body!r}: mode label {labels[at]!r} {why}")
            own.append(name)
            at += 1
        modes.append(tuple(own))
    if at != len(labels):
        raise HDBError(source, field, f"label {labels[at]!r} (position {at}) belongs to none of the bodies "
                                      f"{bodies} in order")
    return BodyDofs(tuple(bodies), tuple(modes))


WARNINGS_ATTR = "warnings"


def hdb_warnings(ds) -> tuple[str, ...]:
    """What the HDB's reader or builder found doubtful (attribute ``warnings``, a JSON list of str;
    none: ``()``). HDBError naming the attribute when it is not such a list."""
    raw = ds.attrs.get(WARNINGS_ATTR)
    if raw is None:
        return ()
    try:
        notes = json.loads(raw) if isinstance(raw, str) else None
    except ValueError:
        notes = None
    if not isinstance(notes, list) or not all(isinstance(n, str) for n in notes):
        raise HDBError(ds.attrs.get("source", "<hdb>"), WARNINGS_ATTR,
                       f"must be a JSON list of strings (the reader's warnings), got {raw!r:.80}")
    return tuple(notes)


def with_hdb_warnings(ds, notes) -> None:
    """Add ``notes`` (each once, in order) to the HDB's ``warnings`` attribute, in place."""
    kept = list(hdb_warnings(ds))
    kept += [n for n in dict.fromkeys(str(n) for n in notes) if n not in kept]
    if kept:
        ds.attrs[WARNINGS_ATTR] = json.dumps(kept)
