"""The ``hydro_state`` field of a ``forces`` reply (SPEC §5.2, revision 1.14): a body's switch to
another hydrodynamic state (server/hydro_states.py) and what the client's matrices take from it.

At the step where a switch acts, the reply carries the new state's matrices in the setup's layout
(6N body-major over the wet bodies): the client replaces its mass matrix's A∞ part (``added_mass``,
never fed back as −A∞·a), its stiffness matrix (``hydrostatic_stiffness``) and its constant heave
forces (``net_buoyancy``, and −C_s (x_eq,0 − x_eq,s) where the state's ``equilibrium_position``
differs from the setup's: the body rests elsewhere in that state, its node being the same point of
the body) before it integrates the step that ends at that reply's time; the reply's forces are
already the new state's. An ``iteration`` > 0 of that step repeats it.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from hydrolink.protocol import codec
from hydrolink.protocol.codec import Code, ProtocolError


@dataclass(frozen=True)
class HydroStateChange:
    """One switch: the body, the state it enters and that state's matrices (setup's layout)."""

    body: str
    state: str
    added_mass: np.ndarray              # (6N, 6N): replaces setup.added_mass in the mass matrix
    hydrostatic_stiffness: np.ndarray   # (6N, 6N): replaces setup.hydrostatic_stiffness
    net_buoyancy: np.ndarray            # (N,): replaces setup.net_buoyancy (rho g V - m g on heave)
    equilibrium_position: np.ndarray    # (N, 6): the state's rest pose of each reference point
    radiation_feedthrough: np.ndarray   # (6N, 6N): replaces setup.radiation_feedthrough

    def to_wire(self) -> dict[str, Any]:
        """The reply's ``hydro_state`` map (arrays as numpy; the codec packs them)."""
        return {"body": self.body, "state": self.state, "added_mass": self.added_mass,
                "hydrostatic_stiffness": self.hydrostatic_stiffness, "net_buoyancy": self.net_buoyancy,
                "equilibrium_position": self.equilibrium_position,
                "radiation_feedthrough": self.radiation_feedthrough}

    @classmethod
    def from_wire(cls, value: Any, n: int) -> "HydroStateChange":
        """Read and check a reply's ``hydro_state`` over ``n`` wet bodies; ProtocolError naming
        ``hydro_state.<field>``."""
        if not isinstance(value, dict):
            raise ProtocolError(Code.BAD_VALUE, "hydro_state", "must be a map")
        data = codec.decode_tree(value, "hydro_state")
        names = {}
        for key in ("body", "state"):
            if not isinstance(data.get(key), str):
                raise ProtocolError(Code.BAD_VALUE, f"hydro_state.{key}", "must be a str")
            names[key] = data[key]
        square = (6 * n, 6 * n)
        arrays = {key: codec.require_array(data, key, shape, path=f"hydro_state.{key}")
                  for key, shape in (("added_mass", square), ("hydrostatic_stiffness", square),
                                     ("net_buoyancy", (n,)), ("equilibrium_position", (n, 6)),
                                     ("radiation_feedthrough", square))}
        return cls(**names, **arrays)
