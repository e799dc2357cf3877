"""The force-reply contract: ``forces`` (SPEC §5.2) as typed metadata, as :mod:`.setup` is §5.1.

Each field of the reply is one :class:`ReplyField`: its wire type, units, whether every reply
carries it, whether it is part of the load the client applies, and — for the optional forces of
the terms beyond linear potential flow (server/terms/registry.py) — the results variables a client
writes for it (:class:`ResultVariable`). A test holds SPEC §5.2's table against
:data:`REPLY_FIELDS`. Clients read the reply's forces with :func:`read_forces`; they never import
server/.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Literal

import numpy as np

from hydrolink.protocol import codec
from hydrolink.protocol.codec import Code, ProtocolError

FORCE_UNITS = "N (surge, sway, heave); N m (roll, pitch, yaw)"
MODAL_UNITS = "generalized force: the work per unit modal coordinate (N for a mode shape in metres)"


@dataclass(frozen=True)
class ResultVariable:
    """A results-file variable a client writes for an optional force: dims after ``time``, the
    value (``"force"``: the field over every scene body, zero for the bodies the server does not
    serve; ``"dissipated_power"``: −force·velocity summed over a body's DOFs)."""

    name: str
    dims: tuple[str, ...]
    units: str
    description: str
    value: Literal["force", "dissipated_power"] = "force"


@dataclass(frozen=True)
class ReplyField:
    """One field of the ``forces`` reply (a row of SPEC §5.2's table)."""

    name: str
    wire: str                       # the SPEC's type column, e.g. "array (N, 6)"
    units: str
    required: bool                  # False: only for scenes with the term that fills it
    load: bool = False              # part of the load the client applies each step (force contract)
    variables: tuple[ResultVariable, ...] = ()

    @property
    def array(self) -> bool:
        """An (N, 6) array over the served bodies."""
        return self.wire == "array (N, 6)"


def _force(name: str, description: str) -> ResultVariable:
    return ResultVariable(name, ("body", "dof"), FORCE_UNITS, description)


#: the reply's fields in SPEC §5.2's order; the optional forces in the order they are added to the load
REPLY_FIELDS: tuple[ReplyField, ...] = (
    ReplyField("seq", "int", "", True),
    ReplyField("iteration", "int", "", True),
    ReplyField("time", "float", "s", True),
    ReplyField("excitation", "array (N, 6)", FORCE_UNITS, True, load=True),
    ReplyField("radiation", "array (N, 6)", FORCE_UNITS, True, load=True),
    ReplyField("hydrostatic", "array (N, 6)", FORCE_UNITS, True),
    ReplyField("viscous", "array (N, 6)", FORCE_UNITS, False, load=True, variables=(
        _force("viscous_force", "viscous damping force -B_lin v - B_quad v|v| about the reference point (server)"),
        ResultVariable("viscous_power", ("body",), "W", "power dissipated by the viscous damping, -viscous_force . "
                       "velocity (>= 0 for positive damping)", "dissipated_power"))),
    ReplyField("morison", "array (N, 6)", FORCE_UNITS, False, load=True, variables=(
        _force("morison_force", "Morison elements' force and moment about the reference point (server)"),)),
    ReplyField("nonlinear_hydrostatic", "array (N, 6)", FORCE_UNITS, False, load=True, variables=(
        _force("nonlinear_hydrostatic_force",
               "nonlinear minus linear hydrostatics (server): pressure -rho g z on the instantaneous wetted surface "
               "plus the weight, minus net buoyancy and the linear restoring force (hydrostatic_force); total "
               "restoring = hydrostatic_force + net buoyancy + this"),)),
    ReplyField("nonlinear_froude_krylov", "array (N, 6)", FORCE_UNITS, False, load=True, variables=(
        _force("nonlinear_froude_krylov_force",
               "nonlinear minus linear Froude-Krylov force (server): the incident wave's pressure on the "
               "instantaneous wetted surface under the wave, minus its linear value on the mean wetted surface "
               "(part of excitation_force)"),)),
    ReplyField("drift", "array (N, 6)", FORCE_UNITS, False, load=True, variables=(
        _force("drift_force", "second-order wave force applied (server): mean drift, Newman slow drift or the "
               "difference-frequency QTF force, plus the sum-frequency force where asked, at the reference point"),)),
    # generalized modes (revision 1.15): the modal forces, (M,) in setup.modes order; their sum
    # excitation + radiation is the modes' load as excitation + radiation is the rigid DOFs'
    ReplyField("modal_excitation", "array (M,)", MODAL_UNITS, False),
    ReplyField("modal_radiation", "array (M,)", MODAL_UNITS, False),
    ReplyField("modal_hydrostatic", "array (M,)", MODAL_UNITS, False),
    ReplyField("wave_elevation", "float", "m", True),
    ReplyField("compute_us", "float", "µs", True),
    ReplyField("control", "map", "", False),
    ReplyField("hydro_state", "map", "", False),
)

_BY_NAME = {f.name: f for f in REPLY_FIELDS}
#: the (N, 6) forces every reply carries
REQUIRED_FORCES: tuple[str, ...] = tuple(f.name for f in REPLY_FIELDS if f.array and f.required)
#: the (N, 6) forces of the terms beyond linear potential flow, each part of the load when present
OPTIONAL_FORCES: tuple[str, ...] = tuple(f.name for f in REPLY_FIELDS if f.array and not f.required)
#: the generalized modes' forces (M,) of a session with modes (SPEC §5.2, revision 1.15)
MODAL_FORCES: tuple[str, ...] = tuple(f.name for f in REPLY_FIELDS if f.wire == "array (M,)")


def reply_field(name: str) -> ReplyField:
    """The contract of the reply field ``name`` (KeyError for a name the contract lacks)."""
    return _BY_NAME[name]


def read_forces(reply: dict[str, Any], shape: tuple[int, int]) -> None:
    """Check the reply's force arrays in place: the required ones and the optional ones present,
    each float64 of ``shape`` (the state's), read-only views of the wire bytes; ProtocolError
    naming the field when one is wrong. Values are the caller's to judge (non-finite = diverged)."""
    for k in REQUIRED_FORCES:
        reply[k] = codec.require_array(reply, k, shape, finite=False)
    for k in OPTIONAL_FORCES:
        if reply.get(k) is not None:
            reply[k] = codec.require_array(reply, k, shape, finite=False)
    for k in MODAL_FORCES:
        if reply.get(k) is not None:
            reply[k] = codec.require_array(reply, k, (None,), finite=False)
    eta = reply.get("wave_elevation")
    if isinstance(eta, dict):
        reply["wave_elevation"] = codec.decode_array(eta, "wave_elevation")


def dissipated_power(force: np.ndarray, velocity: np.ndarray) -> np.ndarray:
    """−force·velocity per body, (B,) from (B, 6) arrays (ResultVariable value "dissipated_power")."""
    return -(force * velocity).sum(axis=1)

# -- The ``hydro_state`` field of a ``forces`` reply (SPEC §5.2, revision 1.14): a body's switch to
# another hydrodynamic state (server/hydro_states.py) and what the client's matrices take from it.
#
# At the step where a switch acts, the reply carries the new state's matrices in the setup's layout
# (6N body-major over the wet bodies): the client replaces its mass matrix's A∞ part (``added_mass``,
# never fed back as −A∞·a), its stiffness matrix (``hydrostatic_stiffness``) and its constant heave
# forces (``net_buoyancy``, and −C_s (x_eq,0 − x_eq,s) where the state's ``equilibrium_position``
# differs from the setup's: the body rests elsewhere in that state, its node being the same point of
# the body) before it integrates the step that ends at that reply's time; the reply's forces are
# already the new state's. An ``iteration`` > 0 of that step repeats it.


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
