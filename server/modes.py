"""Generalized (flexible) modes in a session's DOF vector (issue 38, docs/generalized-modes.md).

The force model's vector is the served bodies' 6N rigid DOFs, body-major as always, then every
body's modes in body order (M in all): a session without modes keeps its 6N vector unchanged. A
body's modes come from its HDB (protocol/hdb/layout.py ``BodyDofs``, in the HDB's order); the scene
gives their structure (``bodies[i].modes``: modal mass, stiffness, damping), which must name
exactly the HDB's modes. The structure is the multibody client's (as a rigid body's mass is); the
server uses the modal mass only to judge the radiation memory at each DOF's natural frequency.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import xarray as xr

from hydrolink.protocol.hdb.layout import DOF_NAMES
from hydrolink.protocol.hdb.schema import hdb_dofs
from hydrolink.protocol.scene import Scene
from hydrolink.server.errors import ModelError
from hydrolink.server.rigid_body import rigid_body_mass_matrix


@dataclass(frozen=True)
class ModeLayout:
    """Where each served body's modes sit in the model's vector, after the 6N rigid DOFs."""

    bodies: tuple[str, ...]              # the served bodies, in the model's order
    names: tuple[tuple[str, ...], ...]   # each body's modes, in its HDB's order
    modal_mass: np.ndarray               # (M,) each mode's own modal mass (the diagonal)

    @property
    def n_rigid(self) -> int:
        return 6 * len(self.bodies)

    @property
    def size(self) -> int:
        """M: the modes of every served body."""
        return sum(len(m) for m in self.names)

    @property
    def n(self) -> int:
        """The model's vector: 6N + M."""
        return self.n_rigid + self.size

    def mode_rows(self, k: int) -> np.ndarray:
        """Body ``k``'s modes' rows in the model's vector."""
        start = self.n_rigid + sum(len(m) for m in self.names[:k])
        return np.arange(start, start + len(self.names[k]))

    def rows(self, k: int) -> np.ndarray:
        """Body ``k``'s rows in the model's vector in its HDB's order: its six, then its modes."""
        return np.concatenate((6 * k + np.arange(6), self.mode_rows(k)))

    def labels(self) -> tuple[str, ...]:
        """Every row's ``body.dof`` label (``barge.heave``, ``barge.bend_z1``)."""
        rigid = [f"{b}.{d}" for b in self.bodies for d in DOF_NAMES]
        return tuple(rigid + [f"{b}.{m}" for b, names in zip(self.bodies, self.names) for m in names])

    def by_body(self) -> dict[str, list[str]]:
        """``{body: [modes]}`` of the bodies that have some (``setup.modes``, SPEC §5.1)."""
        return {b: list(m) for b, m in zip(self.bodies, self.names) if m}


def mode_layout(scene: Scene, served: list[int], hdbs: dict[str, xr.Dataset]) -> ModeLayout:
    """The served bodies' modes (``served``: their scene indices), each body's from its HDB checked
    against the scene's ``bodies[i].modes``: an HDB with modes and no structure for them, a structure
    for a body whose HDB has none, or names that differ → ModelError naming the key."""
    names, mass = [], []
    for i in served:
        body = scene.bodies[i]
        hdb_modes: tuple[str, ...] = ()
        if body.wet and body.name in hdbs:
            dofs = hdb_dofs(hdbs[body.name])
            if body.hdb_body_name in dofs.bodies:
                hdb_modes = tuple(dofs.of(body.hdb_body_name))
        spec = body.modes
        if hdb_modes and spec is None:
            raise ModelError(f"bodies[{i}].modes", f"body {body.name!r}'s HDB {body.hdb!r} has {len(hdb_modes)} "
                             f"generalized mode(s) {list(hdb_modes)} beyond its six rigid DOFs, and the scene gives "
                             "no modal mass for them: add [bodies.modes] with names, mass, stiffness (and damping) "
                             "for each (or give the body an HDB of its rigid DOFs)")
        if spec is not None and set(spec.names) != set(hdb_modes):
            extra = [m for m in spec.names if m not in hdb_modes]
            missing = [m for m in hdb_modes if m not in spec.names]
            raise ModelError(f"bodies[{i}].modes.names", f"{spec.names} do not match the modes of body "
                             f"{body.hdb_body_name!r} in its HDB {body.hdb!r}, {list(hdb_modes)}: "
                             + "; ".join(p for p in (f"{extra} not in the HDB" if extra else "",
                                                     f"{missing} missing" if missing else "") if p))
        names.append(hdb_modes)
        if hdb_modes:
            try:
                mass.append(np.diag(spec.in_order("mass", hdb_modes)))
            except ValueError as exc:       # a structure file whose matrices did not come
                raise ModelError(f"bodies[{i}].modes.{str(exc).partition(': ')[0]}", str(exc).partition(": ")[2]) from None
    return ModeLayout(tuple(scene.bodies[i].name for i in served), tuple(names),
                      np.concatenate(mass) if mass else np.zeros(0))


def structure_file_notes(scene: Scene, served: list[int], reference: np.ndarray) -> list[str]:
    """Setup warnings for each served body whose modes' structure file (``bodies[i].modes.mmx``)
    states the rigid body otherwise than the scene: a rigid 6 × 6 mass block other than the body's
    (``mass``, ``center_of_mass``, ``inertia`` about its HDB reference point ``reference[k]``) by
    more than 0.1 % of its largest entry — the run takes the scene's (the HDB's coefficients do not
    depend on it: a ballast study may keep the run's files), the WAMIT run's own motions were for
    the file's; a zero block (the file gives the modes alone) states nothing — and a rigid external
    damping or stiffness, which the run does not apply (the scene's ``linear_damping`` and moorings
    give those)."""
    notes = []
    for k, i in enumerate(served):
        body = scene.bodies[i]
        block = body.modes.file_matrices if body.modes is not None else None
        if block is None:
            continue
        key, name = f"bodies[{i}]", body.modes.mmx
        given = block.rigid("mass")
        if given.any():
            ref = reference[k]
            r_own = body.com_or(ref) - ref
            own = rigid_body_mass_matrix(body.mass, body.inertia_matrix, r_own)
            # the mass within 0.1 %, the centre of mass (m [r]x over the mass) within 1 mm, the
            # inertia about the reference point within 0.1 % of its largest entry
            m = max(given[0, 0], 1e-300)
            r_given = np.array([given[5, 1], given[3, 2], given[4, 0]]) / m      # m [r]x's x, y, z entries
            off = [part for part, bad in (
                ("mass", np.abs(given[:3, :3] - own[:3, :3]).max() > 1e-3 * body.mass),
                ("center_of_mass", np.abs(r_given - r_own).max() > 1e-3),
                ("inertia", body.inertia is not None
                 and np.abs(given[3:, 3:] - own[3:, 3:]).max() > 1e-3 * np.abs(own[3:, 3:]).max())) if bad]
            if off:
                notes.append(f"{key}.{off[0]}: the rigid mass matrix of {name} (about the HDB's reference point; "
                             f"diagonal {np.round(np.diag(given), 6).tolist()}) differs from the scene's body "
                             f"({np.round(np.diag(own), 6).tolist()}) in its {', '.join(off)} block(s): the run "
                             "takes the scene's, the WAMIT run's motions were for the file's; set the body's "
                             f"{', '.join(off)} to the file's if that is not meant")
        unapplied = [m for m in ("damping", "stiffness") if block.rigid(m).any()]
        if unapplied:
            notes.append(f"{key}.modes.mmx: {name} gives the rigid DOFs an external {' and '.join(unapplied)}, which "
                         "the run does not apply: give them as the body's linear_damping or a linear mooring")
    return notes
