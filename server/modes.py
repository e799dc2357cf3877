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
            mass.append(np.diag(spec.in_order("mass", hdb_modes)))
    return ModeLayout(tuple(scene.bodies[i].name for i in served), tuple(names),
                      np.concatenate(mass) if mass else np.zeros(0))
