"""Capabilities declared once: the scene features that not every tool can take, and what each
tool takes.

``Scene.features()`` reports the features a scene uses, each with the key that turns it on; each
tool (:data:`TOOLS`) lists the features it supports; :func:`refuse_unsupported` refuses a scene
before anything runs, naming the key and the tool. A feature added here is unsupported by every
tool until the tool's entry says otherwise (and tests/test_capabilities.py runs it there), so no
tool drops a term silently.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable, Protocol

from hydrolink.protocol.reply import OPTIONAL_FORCES


class UsesFeatures(Protocol):
    """What a tool is checked on: a scene (protocol/scene.py ``Scene``, which imports this module)."""

    def features(self) -> dict[str, str]:
        """The optional features it uses (names of :data:`FEATURES`), each with the key turning it on."""


@dataclass(frozen=True)
class Feature:
    """A scene feature: what it is (for messages) and the optional reply fields it brings
    (protocol/reply.py)."""

    description: str
    reply_fields: tuple[str, ...]


FEATURES: dict[str, Feature] = {
    "linear_damping": Feature("viscous forces (linear damping)", ("viscous",)),
    "quadratic_damping": Feature("viscous forces (quadratic damping)", ("viscous",)),
    "drag": Feature("viscous forces (quadratic drag)", ("viscous",)),
    "morison": Feature("Morison elements", ("morison",)),
    "nonlinear_hydrostatics": Feature("nonlinear hydrostatics", ("nonlinear_hydrostatic",)),
    "nonlinear_froude_krylov": Feature("nonlinear Froude-Krylov forces",
                                       ("nonlinear_hydrostatic", "nonlinear_froude_krylov")),
    "second_order": Feature("second-order wave forces (mean and slow drift)", ("drift",)),
    # no reply field of its own: it changes what ``excitation`` holds (SPEC §5.2, revision 1.10)
    "passive_yaw": Feature("passive yaw (the excitation at the body's instantaneous heading)", ()),
    # no optional reply field: the modal forces travel in modal_excitation/radiation/hydrostatic (SPEC 1.15)
    "generalized_modes": Feature("generalized (flexible) modes", ()),
    # no force field of its own: a reply carries ``hydro_state`` at a switch (SPEC §5.2, revision 1.14)
    "hydro_states": Feature("variable hydrodynamics (a body switching between HDBs)", ()),
    # outputs computed by the run from its rows after the last step (server/loads/): no reply field
    "sectional_loads": Feature("the loads along a body (sections)", ()),
    "panel_pressures": Feature("the panel pressures over the run (pressure_output)", ()),
}

#: features of the linear core itself (server/model.py, server/sea/), not of a force term (server/terms/)
CORE_FEATURES = frozenset({"passive_yaw", "generalized_modes", "hydro_states"})
#: outputs of ``hydrolink run`` made from a run's rows (server/loads/, clients/lockstep/section_results.py)
OUTPUT_FEATURES = frozenset({"sectional_loads", "panel_pressures"})

_POINTWISE = frozenset({"linear_damping", "quadratic_damping", "drag", "morison"})
_YAW = ("{what} needs the body's yaw sent to the force server each step and its excitation to follow it, "
        "which {tool} does not do; run the scene with hydrolink run")
_MODES = ("{what} need their modal coordinates sent to the force server each step and integrated with the rigid "
          "ones, which {tool} does not do (its bodies have six DOFs); run the scene with hydrolink run")
_SWITCH = ("{what} changes the client's mass and stiffness matrices during the run (a new A-infinity and "
           "hydrostatic stiffness at each switch), which {tool} does not do; run the scene with hydrolink run")
_OUTPUT = ("{what} are computed by hydrolink run from the run's rows after its last step, which {tool} does not "
           "do; run the scene with hydrolink run")
_PERIODIC_OUTPUT = ("{what} are computed from a run's rows, which {tool}'s periodic solution does not write yet; "
                    "run the scene with hydrolink run")
_HULLS = ("nonlinear hydrostatics need the bodies' hulls in the hello, which {tool} does not carry yet; use the "
          "Exudyn client (hydrolink run)")


@dataclass(frozen=True)
class Tool:
    """A hydrolink tool that runs scenes: its name in messages, the features it supports and why
    it refuses the others (``{tool}`` is replaced by its name)."""

    name: str
    supports: frozenset[str]
    refusal: str
    reasons: dict[str, str] = field(default_factory=dict)   # feature -> its own refusal (else ``refusal``)


TOOLS: dict[str, Tool] = {
    "exudyn": Tool("the Exudyn client (hydrolink run)", frozenset(FEATURES), ""),
    "fmu_master": Tool("the FMU master", frozenset(),
                       "{tool} does not apply {what} yet (its force ports carry excitation, radiation and "
                       "hydrostatics); use the Exudyn client", {"passive_yaw": _YAW, "generalized_modes": _MODES,
                                                                 "hydro_states": _SWITCH, "sectional_loads": _OUTPUT, "panel_pressures": _OUTPUT}),
    # steady: the second-order force of its regular wave (mean A^2 T(w, w), with sum_frequency the 2w
    # force) pointwise at the nodes like any time-dependent load
    "steady": Tool("hydrolink steady", _POINTWISE | {"second_order"},
                   "{what} are not part of {tool}'s model yet (its Newton needs their Jacobian in position); "
                   "run the scene with hydrolink run",
                   {"passive_yaw": "{what} makes the excitation depend on the motion (the heading), which {tool}'s "
                                   "periodic solution does not model; run the scene with hydrolink run",
                    "generalized_modes": "{what} are not in {tool}'s periodic model (its unknowns are six DOFs a body); "
                                         "run the scene with hydrolink run",
                    "hydro_states": "{what} switches the coefficients during the run, which {tool}'s periodic "
                                    "solution does not model; run the scene with hydrolink run (or one state's "
                                    "HDB as the body's hdb)",
                    "sectional_loads": _PERIODIC_OUTPUT, "panel_pressures": _PERIODIC_OUTPUT}),
    # linearize: the device as a linear plant about rest (clients/analysis/plant.py)
    "linearize": Tool("hydrolink linearize", frozenset({"linear_damping"}),
                      "{what} have no linear model about rest in {tool} (quadratic drag's slope is zero there; "
                      "nonlinear hydrostatics and Froude–Krylov have no single linearisation; second-order forces "
                      "are quadratic in the wave): use their linear counterparts (an equivalent linear_damping, "
                      "hydro.nonlinear = \"none\", second_order = \"none\") for the plant",
                      {"passive_yaw": "{what} has no linear model about rest in {tool} (the excitation's heading "
                                      "follows the yaw: a wave-dependent stiffness); the plant is that of the fixed "
                                      "heading: drop bodies[i].passive_yaw for it",
                       "generalized_modes": "{what} are not in {tool}'s plant (its states are six DOFs a body); "
                                            "the modes' linear model is the frequency-domain one of "
                                            "docs/generalized-modes.md",
                       "hydro_states": "{what} has no single linear plant in {tool} (each state is its own); give "
                                       "the state's HDB as the body's hdb and drop bodies[i].hydro_states",
                       "sectional_loads": _OUTPUT, "panel_pressures": _OUTPUT}),
    "native_fmu": Tool("the native FMU", _POINTWISE, _HULLS, {"passive_yaw": _YAW, "generalized_modes": _MODES,
                                                              "hydro_states": _SWITCH, "sectional_loads": _OUTPUT,
                                                              "panel_pressures": _OUTPUT}),
    "python_fmu": Tool("the exported Python FMU", _POINTWISE, _HULLS, {"passive_yaw": _YAW,
                                                                       "generalized_modes": _MODES,
                                                                       "hydro_states": _SWITCH,
                                                                       "sectional_loads": _OUTPUT,
                                                                       "panel_pressures": _OUTPUT}),
    # the server's session rollback (SPEC §5.9): every force term's state can be saved (stateless
    # or ForceTerm.state/set_state; tests/test_capabilities.py checks the server's terms)
    "save_restore": Tool("the session rollback (save/restore)", frozenset(FEATURES), ""),
}


def reply_fields(scene: UsesFeatures) -> tuple[str, ...]:
    """The optional forces (protocol/reply.py) the replies of a session of ``scene`` carry, in
    reply order: those its features bring."""
    brought = {f for feature in scene.features() for f in FEATURES[feature].reply_fields}
    return tuple(f for f in OPTIONAL_FORCES if f in brought)


def unsupported(scene: UsesFeatures, tool: str) -> dict[str, str]:
    """The features ``scene`` uses that ``tool`` cannot take, feature -> key (empty: it can run)."""
    supports = TOOLS[tool].supports
    return {f: key for f, key in scene.features().items() if f not in supports}


def refuse_unsupported(scene: UsesFeatures, tool: str, error: Callable[[str, str], Exception]) -> None:
    """Raise ``error(key, why)`` (the tool's keyed error) for the first feature ``scene`` uses
    that ``tool`` cannot take, naming its key and the tool (and any further ones in the why)."""
    missing = unsupported(scene, tool)
    if not missing:
        return
    t = TOOLS[tool]
    (feature, key), *more = missing.items()
    why = t.reasons.get(feature, t.refusal).format(tool=t.name, what=FEATURES[feature].description)
    if more:
        why += "; it cannot take " + ", ".join(f"{FEATURES[f].description} ({k})" for f, k in more) + " either"
    raise error(key, why)
