"""The steady current of a scene (``[current]``, issue 23): its velocity at any depth.

The water moves horizontally at ``speed`` towards ``direction`` (degrees from the x axis, the
waves' heading convention) with the depth profile

- ``"uniform"``: U(z) = U0 at every depth (WEC-Sim's depth-independent current);
- ``"power"``: U(z) = U0 (1 + z/d)^(1/7) down to ``depth`` d, zero below (1/7 power law);
- ``"linear"``: U(z) = U0 (1 + z/d) down to d, zero below;

z up from the still water line; points above it get the surface value (no stretching, as the wave
kinematics of server/sea/kinematics.py). Time-independent: the waves' ramp does not apply. Shared by the
server's force terms (relative drag, Morison members) and the MoorDyn client (its ``Currents``
grid), so it lives at protocol level. ``doppler = true``: the waves' frequencies are their own,
relative to the water, and a fixed point sees them Doppler-shifted to w + k U cos(beta - theta_c)
with the surface speed U (server/sea/doppler.py); by default no wave-current interaction. The
current never changes the radiation.
"""

from __future__ import annotations

import math
from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, model_validator

from hydrolink.protocol.scene_bounds import DEPTH_RANGE, AngleDeg, CurrentSpeed, ProfileDepth

#: m, the deepest a profile reaches (the deepest water a scene can hold)
MAX_DEPTH = DEPTH_RANGE[1]


class Current(BaseModel):
    """``[current]``: speed (m/s), direction (deg, towards), profile and, for the power and linear
    profiles, the depth (m) they reach (module docstring)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    speed: CurrentSpeed
    direction: AngleDeg = 0.0
    profile: Literal["uniform", "power", "linear"] = "uniform"
    depth: ProfileDepth | None = None
    doppler: bool = False

    @model_validator(mode="after")
    def _depth_with_profile(self) -> "Current":
        if self.profile == "uniform" and self.depth is not None:
            raise ValueError('depth: only with profile = "power" or "linear" (a uniform current has no depth)')
        if self.profile != "uniform" and self.depth is None:
            raise ValueError(f'depth: required with profile = "{self.profile}" (the depth where the current '
                             "falls to zero)")
        return self

    @property
    def heading(self) -> np.ndarray:
        """(3,) unit vector the water moves along."""
        b = math.radians(self.direction)
        return np.array([math.cos(b), math.sin(b), 0.0])

    def speed_at(self, z: np.ndarray) -> np.ndarray:
        """The current's speed (m/s) at heights ``z`` (any shape; above the still water line: the
        surface value)."""
        z = np.minimum(np.asarray(z, float), 0.0)
        if self.profile == "uniform":
            return np.full(z.shape, self.speed)
        s = 1.0 + np.maximum(z, -self.depth) / self.depth       # in [0, 1]: no overflow for a tiny depth
        return self.speed * (s ** (1.0 / 7.0) if self.profile == "power" else s)

    def velocity(self, z: np.ndarray) -> np.ndarray:
        """(P, 3) current velocity (m/s) at the heights ``z`` (P,) of P points."""
        return self.speed_at(np.asarray(z, float).reshape(-1))[:, None] * self.heading[None, :]
