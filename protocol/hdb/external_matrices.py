"""One body's external (structural) mass, damping and stiffness from a structure file — a WAMIT
run's ``.mmx`` (issue 38, ``bodies[i].modes.mmx``): the matrices over the body's six rigid DOFs then
its generalized modes, in its HDB's order. The client reads the file and sends the block in
``hello.modal_structure`` (SPEC §5.1, revision 1.17); the scene's modes take their modal mass,
stiffness and damping from it (``BodyModes.with_file``)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Collection

import numpy as np

MATRICES = ("mass", "damping", "stiffness")


@dataclass(frozen=True)
class ExternalMatrices:
    """A body's block of a structure file: each matrix (6 + n) × (6 + n), the six rigid DOFs then
    the ``modes`` (the HDB's names and order)."""

    modes: tuple[str, ...]
    mass: np.ndarray
    damping: np.ndarray
    stiffness: np.ndarray

    def __post_init__(self) -> None:
        size = 6 + len(self.modes)
        for key in MATRICES:
            if getattr(self, key).shape != (size, size):
                raise ValueError(f"{key}: shape {getattr(self, key).shape} for 6 rigid DOFs and {len(self.modes)} "
                                 f"modes: expected ({size}, {size})")

    def modal(self, key: str, names: Collection[str]) -> np.ndarray:
        """Matrix ``key``'s block of the modes, rows and columns in the order of ``names``."""
        order = [6 + self.modes.index(m) for m in names]
        return getattr(self, key)[np.ix_(order, order)]

    def rigid(self, key: str) -> np.ndarray:
        """Matrix ``key``'s 6 × 6 rigid block (about the HDB's reference point, the body's axes)."""
        return getattr(self, key)[:6, :6]

    def coupled(self) -> list[str]:
        """The matrices whose rigid–mode blocks are not zero (a coupling a scene's modes cannot hold)."""
        return [k for k in MATRICES if np.any(getattr(self, k)[:6, 6:]) or np.any(getattr(self, k)[6:, :6])]
