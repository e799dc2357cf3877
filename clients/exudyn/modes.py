"""The generalized (flexible) modes of the wet bodies in the Exudyn model (issue 38).

A session with modes (``setup.modes``, SPEC revision 1.15) has its matrices over the 6N rigid DOFs
then every body's modes (M). The modes' coordinates are one ``NodeGenericODE2`` of M coordinates,
taken by the same ``ObjectGenericODE2`` as the rigid nodes: its mass matrix holds the full A∞
(rigid–mode coupling included) plus the modes' structural mass, its stiffness the hydrostatic
stiffness plus the structural one, its damping the structural damping (the scene's
``bodies[i].modes``), so the modes are integrated implicitly with the rigid DOFs as they are.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from exudyn.itemInterface import NodeGenericODE2

from hydrolink.protocol.scene import Scene, SceneError
from hydrolink.protocol.setup import Setup


@dataclass(frozen=True)
class ModalStructure:
    """The modes' structural matrices (M × M, block-diagonal by body) in ``setup.modes`` order."""

    labels: tuple[str, ...]     # "body.mode"
    initial: np.ndarray         # (M,) the coordinates at t = 0
    mass: np.ndarray
    stiffness: np.ndarray
    damping: np.ndarray
    pto_stiffness: np.ndarray   # (M,) the modal PTOs (0: none)
    pto_damping: np.ndarray

    @property
    def size(self) -> int:
        return len(self.labels)

    @property
    def has_pto(self) -> bool:
        return bool(self.pto_stiffness.any() or self.pto_damping.any())

    @property
    def pto_index(self) -> np.ndarray:
        """The modes that carry a PTO (a stiffness or damping), in ``labels`` order."""
        return np.flatnonzero((self.pto_stiffness != 0) | (self.pto_damping != 0))

    @property
    def pto_names(self) -> list[str]:
        """The modal PTOs' names in the results' ``pto`` dim: their modes' labels ("body.mode")."""
        return [self.labels[i] for i in self.pto_index]

    def pto_outputs(self, q: np.ndarray, rate: np.ndarray, mechanism: dict) -> dict:
        """The mechanism's outputs with the modal PTOs after its PTOs in ``pto_force`` (the generalized
        force k q + c q̇ the PTO resists its mode with), ``pto_velocity`` (q̇), ``pto_power`` (their
        product: > 0 into the PTO, as a line PTO's) and ``total_pto_power`` over both."""
        i = self.pto_index
        force = self.pto_stiffness[i] * q[i] + self.pto_damping[i] * rate[i]
        power = force * rate[i]
        none = np.zeros(0)
        return {**mechanism, "pto_force": np.concatenate((mechanism.get("pto_force", none), force)),
                "pto_velocity": np.concatenate((mechanism.get("pto_velocity", none), rate[i])),
                "pto_power": np.concatenate((mechanism.get("pto_power", none), power)),
                "total_pto_power": mechanism.get("total_pto_power", 0.0) + power.sum()}


def modal_structure(scene: Scene, setup: Setup | None) -> ModalStructure:
    """The scene's ``bodies[i].modes`` for the setup's modes (none: an empty structure); a body the
    setup gives modes and the scene no structure, or other names → SceneError naming the key."""
    modes = (setup.modes or {}) if setup is not None else {}
    blocks: dict[str, list[np.ndarray]] = {"mass": [], "stiffness": [], "damping": []}
    initial: list[float] = []
    pto: dict[str, list[float]] = {"pto_stiffness": [], "pto_damping": []}
    for name in (setup.bodies if setup is not None else ()):
        names = modes.get(name, [])
        if not names:
            continue
        i, body = next((i, b) for i, b in enumerate(scene.bodies) if b.name == name)
        spec = body.modes
        if spec is None or set(spec.names) != set(names):
            raise SceneError("scene", f"bodies[{i}].modes", f"the force server gives body {name!r} the modes "
                             f"{names}; the scene's bodies[{i}].modes names {None if spec is None else spec.names}")
        for key in blocks:
            blocks[key].append(spec.in_order(key, names))
        initial += spec.per_mode("initial_displacement", names)
        for key, values in pto.items():
            values += spec.per_mode(key, names)
    empty = np.zeros((0, 0))
    if initial:   # a body with modes: scipy.linalg here, not at the top (~0.4 s of every run's start-up)
        import scipy.linalg
    return ModalStructure(setup.mode_labels if setup is not None else (), np.asarray(initial, float),
                          *(scipy.linalg.block_diag(*b) if b else empty for b in blocks.values()),
                          *(np.asarray(v, float) for v in pto.values()))


def add_modal_node(mbs, structure: ModalStructure) -> int:
    """The modes' coordinates as one Exudyn node (their ``initial_displacement``, at rest)."""
    m = structure.size
    return mbs.AddNode(NodeGenericODE2(name="generalized_modes", numberOfODE2Coordinates=m,
                                       referenceCoordinates=np.zeros(m), initialCoordinates=structure.initial,
                                       initialCoordinates_t=np.zeros(m)))
