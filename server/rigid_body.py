"""A rigid body's 6x6 mass matrix about a reference point (the HDB's), the centre of mass off it:
what every multibody client and the HDB builder's natural periods put beside A-infinity."""

from __future__ import annotations

import numpy as np

__all__ = ["rigid_body_mass_matrix", "skew"]


def skew(r: np.ndarray) -> np.ndarray:
    """The cross-product matrix [r]× (so that [r]× b = r × b)."""
    x, y, z = r
    return np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])


def rigid_body_mass_matrix(mass: float, inertia_com: np.ndarray, com_offset: np.ndarray) -> np.ndarray:
    """6×6 mass matrix about a reference point, the centre of mass at ``com_offset`` from it."""
    s = skew(np.asarray(com_offset, float))
    m = np.zeros((6, 6))
    m[:3, :3] = mass * np.eye(3)
    m[:3, 3:] = -mass * s
    m[3:, :3] = mass * s
    m[3:, 3:] = np.asarray(inertia_com, float) - mass * s @ s
    return m
