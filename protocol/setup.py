"""The session contract: ``welcome.setup`` (SPEC §5.1) as one typed object.

The force server's model builds a :class:`Setup`; the wire carries :meth:`Setup.to_wire`; every
client reads it back with :meth:`Setup.from_wire`, which checks each field's presence, type and
shape and names the field (``setup.<name>``) when one is wrong. Fields a newer server adds are
ignored (SPEC §3.1: additions within protocol version 1 are optional fields). Matrices are
(6N, 6N) body-major over the wet bodies, per-body arrays (N, 6) in ``bodies`` order; with
generalized modes (``modes``, revision 1.15) the matrices are over the 6N rigid DOFs then every
body's modes in ``bodies`` order (6N + M).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields
from typing import Any

import numpy as np

from hydrolink.protocol import codec
from hydrolink.protocol.codec import Code, ProtocolError


@dataclass(frozen=True)
class IRFProcessing:
    """How the radiation IRF was processed (scene ``[hydro]``)."""

    domega: float | None            # irf_domega resampling step [rad/s], or None
    taper: float                    # irf_taper fraction
    tail: str                       # irf_tail option
    tail_exponent: dict[str, float]  # per HDB: fitted high-frequency decay exponent of B(ω)


@dataclass(frozen=True)
class StateSpaceReport:
    """The state-space radiation fit (``radiation = "state-space"``)."""

    states: int
    pairs: int
    max_order: int
    max_fit_error: float
    unmet: int                      # DOF pairs whose fit misses the tolerance
    worst_pair: str | None = None   # "(body.dof, body.dof)" of max_fit_error
    fitted_pairs: int | None = None  # pairs fitted in this setup, the rest from the fit cache (None: not told)


@dataclass(frozen=True)
class Setup:
    """What a multibody client needs to build its side of a session (SPEC §5.1 lists each field)."""

    # -- the bodies and what the client puts in its matrices
    bodies: tuple[str, ...]             # wet bodies, scene order = row order of every (N, 6) array
    dofs: tuple[str, ...]               # surge, sway, heave, roll, pitch, yaw
    active: np.ndarray                  # (N, 6) bool: DOFs the server applies forces in
    added_mass: np.ndarray              # (6N, 6N): goes in the client's mass matrix
    added_mass_inf: np.ndarray          # (6N, 6N): A∞ (equals added_mass unless radiation "constant")
    added_mass_inf_source: dict[str, str]   # per body: where A∞ came from
    hydrostatic_stiffness: np.ndarray   # (6N, 6N): goes in the client's stiffness matrix
    equilibrium_position: np.ndarray    # (N, 6): reference points at rest, zero angles
    net_buoyancy: np.ndarray            # (N,): ρgV − mg [N] on heave, a constant force (0: unknown V)
    dt: float                           # the server's step (= exchange_every × simulation.dt)
    # -- hydrodynamic interaction
    interaction: str                    # "full" | "none"
    hydro_groups: tuple[tuple[str, ...], ...]
    coupled_blocks: int
    radiation_kernel_entries: int
    # -- radiation
    radiation: str                      # "convolution" | "state-space" | "constant" | "off"
    radiation_frequency: float | None   # ω0 with "constant"
    irf_samples: int
    irf_duration: float
    irf_fit_error: dict[str, float]
    irf_added_mass_error: dict[str, float]
    irf_processing: IRFProcessing
    coupling_tolerance: float
    radiation_pairs: int
    dropped_pair_fraction: float
    dropped_blocks: int
    dropped_block_fraction: float
    state_space: StateSpaceReport | None
    # -- waves and excitation
    wave_components: int
    wave_energy_outside_hdb: float
    ramp: float
    excitation: str                     # "superposition" | "convolution"
    excitation_irf_duration: float
    excitation_irf_error: float
    wave_headings: tuple[float, ...]    # degrees
    elevation_resampled: bool
    elevation_start: float
    warnings: tuple[str, ...]
    # -- the run's extent and the force's direct dependence on the state (None from older servers)
    last_seq: int | None = None                  # the last step index accepted (seq * dt reaches the duration)
    radiation_feedthrough: np.ndarray | None = None  # (6N, 6N): dF_radiation/dv of the velocity sent
    # bodies with nonlinear hydrostatics: name -> "hydrostatic" | "froude-krylov" (reply fields
    # nonlinear_hydrostatic / nonlinear_froude_krylov; empty from older servers and linear scenes)
    nonlinear: dict[str, str] | None = None
    # the sea's variance share per 30-degree direction band, by band centre ("+30"); None from older servers
    wave_energy_by_direction: dict[str, float] | None = None
    # {body: [mode names]} of the bodies with generalized modes, after the 6N rigid DOFs in every
    # matrix (revision 1.15); None: none (and from older servers)
    modes: dict[str, list[str]] | None = None
    # variable hydrodynamics (revision 1.14): {body: the state it starts in}; None without hydro_states.
    # A reply's hydro_state (protocol/reply.py HydroStateChange) changes the matrices at a switch
    hydro_state: dict[str, str] | None = None

    @property
    def n(self) -> int:
        """Number of wet bodies."""
        return len(self.bodies)

    @property
    def mode_labels(self) -> tuple[str, ...]:
        """The modes' ``body.mode`` labels in the matrices' order after the 6N rigid DOFs (M)."""
        modes = self.modes or {}
        return tuple(f"{b}.{m}" for b in self.bodies for m in modes.get(b, ()))

    @property
    def n_dofs(self) -> int:
        """The matrices' size: 6N + M."""
        return 6 * self.n + len(self.mode_labels)

    def to_wire(self) -> dict[str, Any]:
        """The ``welcome.setup`` map (arrays as numpy; the codec packs them)."""
        out = asdict(self)
        for name in ("bodies", "dofs", "warnings", "wave_headings"):
            out[name] = list(out[name])
        out["hydro_groups"] = [list(g) for g in self.hydro_groups]
        return out

    @classmethod
    def from_wire(cls, data: Any) -> "Setup":
        """Read and check a ``welcome.setup`` map; ProtocolError naming ``setup.<field>`` if wrong."""
        if not isinstance(data, dict):
            raise ProtocolError(Code.BAD_VALUE, "setup", "must be a map")
        r = _Reader(codec.decode_tree(data))
        bodies = r.strs("bodies")
        n = len(bodies)
        modes = _modes(r.data.get("modes"), bodies)
        nd = 6 * n + sum(len(m) for m in (modes or {}).values())   # the matrices: 6N + M
        ss = r.get("state_space", optional=True)
        proc = r.map("irf_processing")
        sub = _Reader(proc, "setup.irf_processing.")
        return cls(
            bodies=bodies, dofs=r.strs("dofs"),
            active=r.array("active", (n, 6), "b"),
            added_mass=r.array("added_mass", (nd, nd)),
            added_mass_inf=r.array("added_mass_inf", (nd, nd)),
            added_mass_inf_source={str(k): str(v) for k, v in r.map("added_mass_inf_source").items()},
            hydrostatic_stiffness=r.array("hydrostatic_stiffness", (nd, nd)),
            equilibrium_position=r.array("equilibrium_position", (n, 6)),
            net_buoyancy=r.array("net_buoyancy", (n,)),
            dt=r.number("dt"),
            interaction=r.str("interaction"),
            hydro_groups=tuple(tuple(str(b) for b in g) for g in r.list("hydro_groups")),
            coupled_blocks=r.int("coupled_blocks"),
            radiation_kernel_entries=r.int("radiation_kernel_entries"),
            radiation=r.str("radiation"),
            radiation_frequency=r.number("radiation_frequency", optional=True),
            irf_samples=r.int("irf_samples"), irf_duration=r.number("irf_duration"),
            irf_fit_error=r.numbers("irf_fit_error"),
            irf_added_mass_error=r.numbers("irf_added_mass_error"),
            irf_processing=IRFProcessing(
                domega=sub.number("domega", optional=True), taper=sub.number("taper"),
                tail=sub.str("tail"), tail_exponent=sub.numbers("tail_exponent")),
            coupling_tolerance=r.number("coupling_tolerance"),
            radiation_pairs=r.int("radiation_pairs"),
            dropped_pair_fraction=r.number("dropped_pair_fraction"),
            dropped_blocks=r.int("dropped_blocks"),
            dropped_block_fraction=r.number("dropped_block_fraction"),
            state_space=None if ss is None else _state_space(ss),
            wave_components=r.int("wave_components"),
            wave_energy_outside_hdb=r.number("wave_energy_outside_hdb"),
            ramp=r.number("ramp"),
            excitation=r.str("excitation"),
            excitation_irf_duration=r.number("excitation_irf_duration"),
            excitation_irf_error=r.number("excitation_irf_error"),
            wave_headings=tuple(float(x) for x in r.array("wave_headings", (None,))),
            elevation_resampled=r.bool("elevation_resampled"),
            elevation_start=r.number("elevation_start"),
            warnings=r.strs("warnings"),
            last_seq=r.int("last_seq") if r.data.get("last_seq") is not None else None,
            radiation_feedthrough=(r.array("radiation_feedthrough", (nd, nd))
                                   if r.data.get("radiation_feedthrough") is not None else None),
            nonlinear=({str(k): str(v) for k, v in r.map("nonlinear").items()}
                       if r.data.get("nonlinear") is not None else None),
            wave_energy_by_direction=(r.numbers("wave_energy_by_direction")
                                      if r.data.get("wave_energy_by_direction") is not None else None),
            modes=modes,
            hydro_state=({str(k): str(v) for k, v in r.map("hydro_state").items()}
                         if r.data.get("hydro_state") is not None else None))


def _modes(data: Any, bodies: tuple[str, ...]) -> dict[str, list[str]] | None:
    """``setup.modes``: {body: [mode names]} over ``bodies`` (nil or absent: None)."""
    if data is None:
        return None
    if not isinstance(data, dict) or not all(isinstance(k, str) and isinstance(v, (list, tuple))
                                             and all(isinstance(m, str) for m in v) for k, v in data.items()):
        raise ProtocolError(Code.BAD_VALUE, "setup.modes", "must be a map of body names to lists of mode names")
    unknown = [k for k in data if k not in bodies]
    if unknown:
        raise ProtocolError(Code.BAD_VALUE, "setup.modes", f"names bodies {unknown} not in setup.bodies {list(bodies)}")
    return {b: list(data[b]) for b in bodies if b in data}


def _state_space(data: Any) -> StateSpaceReport:
    if not isinstance(data, dict):
        raise ProtocolError(Code.BAD_VALUE, "setup.state_space", "must be a map or nil")
    s = _Reader(data, "setup.state_space.")
    return StateSpaceReport(states=s.int("states"), pairs=s.int("pairs"), max_order=s.int("max_order"),
                            max_fit_error=s.number("max_fit_error"), unmet=s.int("unmet"),
                            worst_pair=data.get("worst_pair"),
                            fitted_pairs=s.int("fitted_pairs") if "fitted_pairs" in data else None)


SETUP_FIELDS = tuple(f.name for f in fields(Setup))


class _Reader:
    """Typed field access on one decoded map; errors name ``<prefix><field>``."""

    def __init__(self, data: dict, prefix: str = "setup."):
        self.data, self.prefix = data, prefix

    def _bad(self, name: str, why: str) -> ProtocolError:
        return ProtocolError(Code.BAD_VALUE, self.prefix + name, why)

    def get(self, name: str, optional: bool = False) -> Any:
        if name not in self.data or (self.data[name] is None and not optional):
            raise ProtocolError(Code.MISSING_FIELD, self.prefix + name, f"required field {name!r} is missing")
        return self.data[name]

    def number(self, name: str, optional: bool = False) -> float | None:
        v = self.get(name, optional)
        if v is None:
            return None
        if isinstance(v, bool) or not isinstance(v, (int, float, np.floating, np.integer)):
            raise self._bad(name, f"must be a number, got {type(v).__name__}")
        return float(v)

    def int(self, name: str) -> int:
        v = self.get(name)
        if isinstance(v, bool) or not isinstance(v, (int, np.integer)):
            raise self._bad(name, f"must be an int, got {type(v).__name__}")
        return int(v)

    def _typed(self, name: str, kinds: type | tuple[type, ...], label: str) -> Any:
        v = self.get(name)
        if not isinstance(v, kinds):
            raise self._bad(name, f"must be {label}, got {type(v).__name__}")
        return v

    def bool(self, name: str) -> bool:
        return bool(self._typed(name, (bool, np.bool_), "a bool"))

    def str(self, name: str) -> str:
        return self._typed(name, str, "a str")

    def list(self, name: str) -> list:
        return list(self._typed(name, (list, tuple), "a list"))

    def map(self, name: str) -> dict:
        return self._typed(name, dict, "a map")

    def strs(self, name: str) -> tuple[str, ...]:
        v = self.list(name)
        if not all(isinstance(s, str) for s in v):
            raise self._bad(name, "must be a list of str")
        return tuple(v)

    def numbers(self, name: str) -> dict[str, float]:
        """A map of names to finite numbers."""
        out = {}
        for k, v in self.map(name).items():
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                raise self._bad(f"{name}.{k}", f"must be a finite number, got {v!r}")
            out[str(k)] = float(v)
        return out

    def array(self, name: str, shape: tuple[int | None, ...], kind: str = "f") -> np.ndarray:
        arr = codec.decode_array(self.get(name), self.prefix + name, kind)
        if arr.ndim != len(shape) or any(w is not None and w != s for w, s in zip(shape, arr.shape)):
            raise self._bad(name, f"shape must be {shape}, got {tuple(arr.shape)}")
        if kind == "f" and not np.isfinite(arr).all():
            raise self._bad(name, "contains NaN or inf")
        return np.array(arr, dtype=bool if kind == "b" else float)
