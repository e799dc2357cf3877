"""Variable hydrodynamics: a body that switches between HDBs (its hydrodynamic states) during a run.

A body's ``hdb`` is its state ``hydro_state``; ``hydro_states`` adds more, each its own HDB (a
draft, a ballast case, an operating mode); ``[[hydro_switches]]`` rules switch them (at a time, or
while a DOF's displacement is below/above a value). One :class:`~hydrolink.server.model.HydroModel`
is built per state (the scene with the body's HDB replaced by the state's) and **every model steps
at every step** with the state the client sent, so that each keeps its own radiation memory. The
memory across a switch is ``bodies[i].hydro_memory``:

- ``"current-kernel"`` (default): every state's memory is fed the body's velocity all along and the
  force is the active state's: F(t) = Σ_j K_s(t)(t − t_j) v_j — the active state's impulse response
  over the whole velocity history (WEC-Sim's default, its ``ConvolutionIntegral_interp``). A state
  held longer than the memory is exactly that state's own model, whenever it was entered.
- ``"kernel-at-emission"``: a state's memory is fed the velocity only at the steps the body is in
  it (zero otherwise) and the force is the sum of every state's memory: F(t) = Σ_j K_{s(t_j)}(t − t_j) v_j
  — each velocity sample radiates with the kernel of the state it was sent in (WEC-Sim PR #1411's
  "IRF surface", issue #1394).

Both hold for the convolution and the state-space radiation alike: a state-space model's states are
driven the same way, so nothing is mapped or restarted at a switch. The excitation, the hydrostatic
force (−C_s (x − x_eq) with the state's stiffness and the body's one reference point) and A∞ switch
together: the reply of the step where a switch acts carries the state's A∞, stiffness, net buoyancy
and feedthrough (``hydro_state``, protocol/reply.py HydroStateChange) for the client's matrices. The body's mass
and centre of mass are the scene's in every state (a ballast case that changes the mass is not
modelled: as in WEC-Sim).

A rule is read at each step after t = 0, on the first ``iteration`` of the step (a sub-iteration
keeps the step's state), on the position sent; rules in scene order, the last that fires wins; a
``time`` rule fires once, at the first step with t ≥ time.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
import xarray as xr

from hydrolink.protocol.reply import HydroStateChange
from hydrolink.protocol.scene import DOF_NAMES, HydroSwitch, Scene
from hydrolink.protocol.setup import Setup
from hydrolink.server.errors import ModelError
from hydrolink.server.model import HydroModel

__all__ = ["SwitchingModel", "hydro_model", "state_datasets"]


@dataclass(frozen=True)
class _Rule:
    """One ``[[hydro_switches]]`` rule over the 6N state: the state it enters and when."""
    state: int               # index into the body's states
    time: float | None       # fires once at the first step with t >= time
    row: int                 # the DOF's row in the 6N vector (threshold rules)
    below: float | None
    above: float | None

    def fires(self, t: float, x: np.ndarray, eq: np.ndarray, fired: bool, tol: float) -> bool:
        """At time ``t`` with the absolute state ``x`` (equilibrium ``eq``); ``fired``: a time rule fired before."""
        if self.time is not None:
            return not fired and t >= self.time - tol
        if self.below is not None:
            return x[self.row] - eq[self.row] < self.below
        return x[self.row] - eq[self.row] > self.above


def _moved(scene: Scene, i: int, first: xr.Dataset, ds: xr.Dataset) -> Scene:
    """The scene for a state whose HDB puts body ``i``'s reference point elsewhere than the first
    state's (the body rests there in that state, e.g. sunk deeper): its centre of mass moved with it."""
    body = scene.bodies[i]
    name = body.hdb_body_name
    if body.center_of_mass is None or name not in [str(b) for b in ds["body"].values]:
        return scene      # (a missing body is the model's error, naming the key)
    shift = ds["reference_point"].sel(body=name).values - first["reference_point"].sel(body=name).values
    if not shift.any():
        return scene
    moved = body.model_copy(update={"center_of_mass": (np.asarray(body.center_of_mass) + shift).tolist()})
    return scene.model_copy(update={"bodies": [moved if b is body else b for b in scene.bodies]})


def state_datasets(scene: Scene, by_hdb: dict[str, xr.Dataset]) -> dict[str, dict[str, xr.Dataset]]:
    """The switching body's states' HDBs (body name -> state -> dataset) from the scene's HDBs keyed
    by their ``hdb`` strings (what ``hydro_model`` takes as ``state_hdbs``)."""
    return {b.name: {s.name: by_hdb[s.hdb] for s in b.hydro_states} for b in scene.bodies if b.hydro_states}


def hydro_model(scene: Scene, hdbs: dict[str, xr.Dataset], state_hdbs: dict[str, dict[str, xr.Dataset]],
                wave_elevation: tuple[np.ndarray, np.ndarray] | None = None, *, hulls: dict | None = None,
                compiled: bool | None = None) -> "HydroModel | SwitchingModel":
    """The session's model: a :class:`HydroModel`, or a :class:`SwitchingModel` for a scene with
    ``hydro_states`` (``state_hdbs``: the switching body's states' HDBs, body name -> state -> dataset)."""
    if not any(b.hydro_states for b in scene.bodies):
        return HydroModel(scene, hdbs, wave_elevation, hulls=hulls, compiled=compiled)
    return SwitchingModel(scene, hdbs, state_hdbs, wave_elevation, hulls=hulls, compiled=compiled)


class SwitchingModel:
    """The forces of a scene whose body switches between hydrodynamic states (module docstring).

    It answers as a :class:`HydroModel` does (step, state, set_state, setup_info); what does not
    depend on the state (bodies, dt, waves, ...) is the first state's model's."""

    def __init__(self, scene: Scene, hdbs: dict[str, xr.Dataset], state_hdbs: dict[str, dict[str, xr.Dataset]],
                 wave_elevation: tuple[np.ndarray, np.ndarray] | None = None, *, hulls: dict | None = None,
                 compiled: bool | None = None):
        i = next(i for i, b in enumerate(scene.bodies) if b.hydro_states)
        body = scene.bodies[i]
        self.body, self.states = body.name, body.state_names()
        self.emission = body.hydro_memory == "kernel-at-emission"
        given = state_hdbs.get(body.name, {})
        self.models: list[HydroModel] = []
        for j, state in enumerate(self.states):
            key = f"bodies[{i}].hdb" if j == 0 else f"bodies[{i}].hydro_states[{j - 1}].hdb"
            if j and state not in given:
                raise ModelError(key, f"no HDB loaded for state {state!r} of body {body.name!r}")
            try:
                model = HydroModel(_moved(scene, i, hdbs[body.name], given[state]) if j else scene,
                                   {**hdbs, body.name: given[state]} if j else hdbs, wave_elevation,
                                   hulls=hulls, compiled=compiled)
            except ModelError as exc:
                if not j or not exc.key.startswith(f"bodies[{i}]"):
                    raise
                raise ModelError(key, f"state {state!r}: {exc.why}") from None
            if j:
                self._check_like(self.models[0], model, key, state)
            self.models.append(model)
        first = self.models[0]
        self.scene, self.dt, self.n, self.bodies = scene, first.dt, first.n, first.bodies
        self.last_seq, self.waves, self.hdbs, self.active = first.last_seq, first.waves, first.hdbs, first.active
        self.terms, self.modes = first.terms, first.modes   # modes: none (a body with modes has one HDB: protocol/scene.py)
        self.warnings = list(dict.fromkeys(w for m in self.models for w in m.warnings))
        k = first.bodies.index(body.name)
        self._rules = tuple(self._rule(r, 6 * k) for r in scene.hydro_switches)
        self._eq = first.equilibrium_position.reshape(-1)
        self._changes = [HydroStateChange(body.name, state, s.added_mass, s.hydrostatic_stiffness, s.net_buoyancy,
                                          s.equilibrium_position, s.radiation_feedthrough).to_wire()
                         for state, s in zip(self.states, (m.setup_info() for m in self.models))]
        self._current, self._fired, self._switch = 0, frozenset(), None   # switch: (seq, state) of the newest
        self._step = -1

    def _rule(self, rule: HydroSwitch, row0: int) -> _Rule:
        """A scene rule over the 6N state (``row0``: the body's first row)."""
        return _Rule(self.states.index(rule.state), rule.time,
                     row0 + DOF_NAMES.index(rule.dof) if rule.dof is not None else -1, rule.below, rule.above)

    def _check_like(self, first: HydroModel, model: HydroModel, key: str, state: str) -> None:
        """A state's model takes the bodies as the first state's does: the same interaction groups, and
        only the switching body's reference point may move; else ModelError naming the state's HDB key."""
        if model.groups != first.groups:
            raise ModelError(key, f"state {state!r} makes the bodies interact as {model.groups}, state "
                                  f"{self.states[0]!r} as {first.groups}: every state's HDB must hold the body "
                                  "with the same bodies it interacts with")
        k = first.bodies.index(self.body)
        moved = np.abs(model.equilibrium_position - first.equilibrium_position).max(axis=1) > 0
        moved[k] = False
        if moved.any():
            other = first.bodies[int(np.argmax(moved))]
            raise ModelError(key, f"state {state!r}'s HDB moves body {other!r}'s reference point, which does not "
                                  f"switch (only {self.body!r} does)")

    @property
    def hydro_state(self) -> str:
        """The state the body is in after the newest step."""
        return self.states[self._current]

    # -- the session's interface ---------------------------------------------------------------
    def setup_info(self) -> Setup:
        """The first state's setup (the state the body starts in), all states' warnings, and
        ``hydro_state`` = {body: state}."""
        return replace(self.models[0].setup_info(), warnings=tuple(self.warnings),
                       hydro_state={self.body: self.states[0]})

    def excitation_phasors(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The active state's wave components and excitation phasors (see HydroModel)."""
        return self.models[self._current].excitation_phasors()

    def _decide(self, k: int, x: np.ndarray, commanded: dict[str, str] | None) -> None:
        """Apply the rules at step ``k`` (state ``x`` absolute, 6N), then a controller's command."""
        if k == 0:
            return
        t, fired, state = k * self.dt, self._fired, self._current
        for n, rule in enumerate(self._rules):
            if rule.fires(t, x, self._eq, n in fired, 1e-9 * self.dt):
                state = rule.state
                if rule.time is not None:
                    fired = fired | {n}
        self._fired = fired
        if commanded and self.body in commanded:
            state = self.states.index(commanded[self.body])
        if state != self._current:
            self._current, self._switch = state, (k, state)

    def step(self, time: float, position: np.ndarray, velocity: np.ndarray, *, replace_last: bool = False,
             commanded: dict[str, str] | None = None) -> dict:
        """The active state's forces at ``time`` (radiation per ``hydro_memory``), with
        ``hydro_state`` at the step where a switch acts (and its sub-iterations); ``commanded``: a
        controller's {body: state} for this step (after the rules: it wins)."""
        k = self._step if replace_last else self._step + 1
        x = np.asarray(position, float).reshape(-1)
        before = self._current, self._fired, self._switch
        if not replace_last and x.size == self.n:    # (a bad step is refused by the models below)
            self._decide(k, x, commanded)
        cur = self._current
        try:     # every model checks the step alike: the first refuses it before any other steps
            replies = [model.step(time, position, velocity, replace_last=replace_last,
                                  radiating=not self.emission or j == cur) for j, model in enumerate(self.models)]
        except ModelError:
            self._current, self._fired, self._switch = before
            raise
        self._step = k
        reply = dict(replies[cur])
        if self.emission:
            total = replies[0]["radiation"].copy()
            for r in replies[1:]:
                total += r["radiation"]
            total.flags.writeable = False
            reply["radiation"] = total
        if self._switch is not None and self._switch[0] == k:
            reply["hydro_state"] = self._changes[cur]
        return reply

    def state(self) -> tuple:
        """Every state model's state, the active state and the rules fired (SPEC §5.9)."""
        return self._step, self._current, self._fired, self._switch, tuple(m.state() for m in self.models)

    def set_state(self, state: tuple) -> None:
        self._step, self._current, self._fired, self._switch, models = state
        for model, saved in zip(self.models, models):
            model.set_state(saved)
