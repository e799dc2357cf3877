"""The interface of a force term beyond the linear core (excitation, radiation, hydrostatics).

A term is one module holding one :class:`ForceTerm` subclass that states:

- its ``name``, the scene keys that configure it (``scene_keys``) and the scene features it
  implements (``features``, protocol/capabilities.py: which tools can run it);
- the reply fields it fills (``fields``; their shapes, units and results variables are
  protocol/reply.py's, so clients never import server/);
- what it adds to the setup (``added_mass``, ``stiffness``, ``feedthrough``: (6N, 6N) over the
  served bodies, zero outside the active DOFs; None: nothing) and its setup warnings;
- what it reads each step (``needs``) and its :meth:`force`;
- whether it keeps state between steps (``stateless``; else :meth:`state` / :meth:`set_state`
  for the session rollback, SPEC §5.9);
- how ``hydrolink steady`` evaluates it (``steady``: ``"jacobian"`` pointwise at the collocation
  nodes with :meth:`velocity_jacobian`, ``"pointwise"`` there with dF/dv by differences, or None:
  steady cannot take it).

:meth:`ForceTerm.build` returns None when the scene has no such term: a term costs nothing unused.
server/terms/registry.py holds the registry that builds a scene's terms; :class:`HydroModel`
(server/model.py) loops over them. docs/force-terms.md is the recipe for adding one.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from typing import Any, Callable, ClassVar, Literal, Mapping

import numpy as np
import xarray as xr

from hydrolink.protocol.capabilities import FEATURES
from hydrolink.protocol.reply import OPTIONAL_FORCES
from hydrolink.protocol.scene import Scene
from hydrolink.server.sea.waves import WaveComponents, WavePhases
from hydrolink.server.terms.hulls import Hull

#: what a term may read each step (ForceTerm.needs)
STEP_INPUTS = frozenset({"time", "position", "velocity"})


@dataclass(frozen=True)
class TermContext:
    """What a term's build reads: the scene and the linear core's setup, over the N served bodies
    (scene indices ``wet``, in the server's body order)."""

    scene: Scene
    wet: list[int]
    active: np.ndarray                 # (N, 6) bool
    active_index: np.ndarray           # the active DOFs' positions in the 6N vector
    waves: WaveComponents
    equilibrium: np.ndarray            # (N, 6) the reference points at rest, zero angles
    hydrostatic_stiffness: np.ndarray  # (6N, 6N) the linear core's, gravity included
    net_buoyancy: list[float | None]   # per body, rho g V - m g (None: the HDB gives no volume)
    hulls: Mapping[str, Hull]          # the closed hulls the hello brought, by body name
    hdbs: Mapping[str, xr.Dataset] = field(default_factory=dict)  # each wet body's HDB, by body name
    phases: WavePhases | None = None   # the step's [cos wt; sin wt] of ``waves``, shared (None: a term's own)
    # the heading (rad) the waves are read at this step for the passive-yaw body at a row (server/sea/
    # passive_yaw.py PassiveYaw.heading; None: no such body)
    yaw_heading: Callable[[int], float] | None = None

    @property
    def n_bodies(self) -> int:
        return len(self.wet)


class ForceTerm(ABC):
    """One force term (module docstring). Subclasses set the class attributes and ``fields``."""

    name: ClassVar[str]
    scene_keys: ClassVar[tuple[str, ...]]
    features: ClassVar[tuple[str, ...]]
    needs: ClassVar[frozenset[str]]
    steady: ClassVar[Literal["jacobian", "pointwise"] | None]
    stateless: ClassVar[bool] = True

    fields: tuple[str, ...]                  # the reply fields :meth:`force` fills, in its order
    added_mass: np.ndarray | None = None     # (6N, 6N) into setup.added_mass (the client's mass matrix)
    stiffness: np.ndarray | None = None      # (6N, 6N) into setup.hydrostatic_stiffness
    feedthrough: np.ndarray | None = None    # (6N, 6N) into setup.radiation_feedthrough (dF/dv)
    warnings: tuple[str, ...] = ()

    def __init_subclass__(cls, **kw: Any) -> None:
        super().__init_subclass__(**kw)
        if getattr(cls, "__abstractmethods__", None):
            return
        unknown = set(cls.features) - set(FEATURES)
        if unknown:
            raise TypeError(f"{cls.__name__}.features: {sorted(unknown)} are not in protocol/capabilities.py")
        if not cls.needs <= STEP_INPUTS:
            raise TypeError(f"{cls.__name__}.needs: {sorted(cls.needs - STEP_INPUTS)} is not a step input")
        if (cls.steady == "jacobian") != (cls.velocity_jacobian is not ForceTerm.velocity_jacobian):
            raise TypeError(f"{cls.__name__}: steady = 'jacobian' goes with a velocity_jacobian, and only then")
        if not cls.stateless and (cls.state is ForceTerm.state or cls.set_state is ForceTerm.set_state):
            raise TypeError(f"{cls.__name__} keeps state: it needs state() and set_state() for rollback")

    def __init__(self, fields: tuple[str, ...]):
        unknown = set(fields) - set(OPTIONAL_FORCES)
        if unknown:
            raise TypeError(f"{type(self).__name__}: reply fields {sorted(unknown)} are not in protocol/reply.py")
        self.fields = fields

    @classmethod
    @abstractmethod
    def build(cls, ctx: TermContext) -> "ForceTerm | None":
        """The scene's term, or None when the scene has none (nothing is computed then)."""

    @abstractmethod
    def force(self, t: float, position: np.ndarray, velocity: np.ndarray) -> tuple[np.ndarray, ...]:
        """One fresh (N, 6) array per reply field (``fields`` order) at time ``t`` for the absolute
        poses and velocities (N, 6) of the served bodies; zero in inactive DOFs."""

    def velocity_jacobian(self, t: float, position: np.ndarray, velocity: np.ndarray) -> np.ndarray:
        """dF/dv (6N, 6N) of the fields' sum at that state (terms with ``steady = "jacobian"``)."""
        raise NotImplementedError(f"{self.name} has no velocity Jacobian")

    def setup_entries(self, bodies: tuple[str, ...]) -> dict[str, Any]:
        """Setup fields this term reports (protocol/setup.py), e.g. ``nonlinear``; none by default."""
        return {}

    def state(self) -> Any:
        """What :meth:`force` changes, copied (stateful terms only)."""
        return None

    def set_state(self, state: Any) -> None:
        """Back to a :meth:`state` of this term (stateful terms only)."""
