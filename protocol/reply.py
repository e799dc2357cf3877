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

FORCE_UNITS = "N (surge, sway, heave); N m (roll, pitch, yaw)"


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
    eta = reply.get("wave_elevation")
    if isinstance(eta, dict):
        reply["wave_elevation"] = codec.decode_array(eta, "wave_elevation")


def dissipated_power(force: np.ndarray, velocity: np.ndarray) -> np.ndarray:
    """−force·velocity per body, (B,) from (B, 6) arrays (ResultVariable value "dissipated_power")."""
    return -(force * velocity).sum(axis=1)
