"""Viscous damping of wet bodies, beyond potential flow (issue 10; HydroDyn's AddBLin / AddBQuad):
F = -B_lin v - B_quad (v |v|) per body, 6x6 about the body's reference point, absolute velocity,
in the body DOF order. Built only when some body has it (no term costs anything unused); the
force is the reply's ``viscous`` field (SPEC §5.2) over the active DOFs."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from hydrolink.protocol.scene import Scene


@dataclass(frozen=True)
class ViscousDamping:
    """The wet bodies' added damping restricted to their active DOFs (``idx`` of the 6N vector)."""

    linear: np.ndarray | None      # (n_active, n_active)
    quadratic: np.ndarray | None   # (n_active, n_active)

    def force(self, v: np.ndarray) -> np.ndarray:
        """The damping force on the active DOFs for their velocities ``v``."""
        f = np.zeros_like(v)
        if self.linear is not None:
            f -= self.linear @ v
        if self.quadratic is not None:
            f -= self.quadratic @ (v * np.abs(v))
        return f

    def feedthrough(self) -> np.ndarray:
        """dF/dv at v = 0 (the linear part; the quadratic part's slope is 0 there)."""
        n = (self.linear if self.linear is not None else self.quadratic).shape[0]
        return -self.linear if self.linear is not None else np.zeros((n, n))


def build_viscous(scene: Scene, wet: list[int], idx: np.ndarray) -> ViscousDamping | None:
    """The damping of the scene's wet bodies (scene indices ``wet``, in the server's body order)
    over the active DOFs ``idx`` of their 6N vector; None when no body has any."""
    bodies = [scene.bodies[i] for i in wet]
    parts = {}
    for key in ("linear_damping", "quadratic_damping"):
        if all(b.damping_matrix(key) is None for b in bodies):
            parts[key] = None
            continue
        full = np.zeros((6 * len(bodies), 6 * len(bodies)))
        for k, b in enumerate(bodies):
            m = b.damping_matrix(key)
            if m is not None:
                full[6 * k:6 * k + 6, 6 * k:6 * k + 6] = m
        parts[key] = np.ascontiguousarray(full[np.ix_(idx, idx)])
    if parts["linear_damping"] is None and parts["quadratic_damping"] is None:
        return None
    return ViscousDamping(parts["linear_damping"], parts["quadratic_damping"])
