"""The force-term interface (server/terms/base.py) and its registry (server/terms/registry.py): what
each term declares agrees with the reply contract and the tools' capabilities; HydroModel adds a
term's setup contributions, loops over its force and rolls its state back."""

from __future__ import annotations

import numpy as np
import pytest

from conftest import SPHERE_WATER, regular_waves, scene_toml, sphere_body

from hydrolink.protocol.capabilities import CORE_FEATURES, FEATURES, OUTPUT_FEATURES, TOOLS
from hydrolink.protocol.reply import OPTIONAL_FORCES
from hydrolink.protocol.scene import parse_scene
from hydrolink.server.terms.base import ForceTerm, TermContext
from hydrolink.server.terms.registry import TERMS
from hydrolink.server.model import HydroModel

SCENE = scene_toml(dt=0.05, duration=2.0, water=SPHERE_WATER, waves=regular_waves(1.0, 6.0),
                   bodies=[sphere_body("sphere.h5", mass=261800.0, dofs=["surge", "heave", "pitch"])])


def test_the_registry_covers_the_contract_and_the_features():
    """Every optional reply field and every scene feature but the linear core's and the run's outputs belongs to a
    registered term, in the contract's order; steady's and the rollback's capabilities are what the terms declare."""
    classes = {cls: cls.__name__ for cls in TERMS}
    assert [cls.name for cls in classes] == ["viscous", "morison", "nonlinear_hydrostatics", "second_order"]   # = reply order
    assert [f for f in OPTIONAL_FORCES] == ["viscous", "morison", "nonlinear_hydrostatic", "nonlinear_froude_krylov",
                                     "drift"]
    features = [f for cls in TERMS for f in cls.features]
    assert sorted(features) == sorted(set(FEATURES) - CORE_FEATURES - OUTPUT_FEATURES) and len(features) == len(set(features))
    assert TOOLS["steady"].supports == {f for cls in TERMS if cls.steady is not None for f in cls.features}
    assert TOOLS["save_restore"].supports == set(FEATURES)     # stateless, or state()/set_state()
    assert all(cls.stateless or cls.state is not ForceTerm.state for cls in TERMS)


def test_a_term_must_declare_what_it_is():
    with pytest.raises(TypeError, match="not in protocol/capabilities.py"):
        type("Bad", (ForceTerm,), {"name": "bad", "scene_keys": (), "features": ("tides",), "needs": frozenset(),
                                   "steady": None, "build": classmethod(lambda c, x: None),
                                   "force": lambda s, t, x, v: ()})
    with pytest.raises(TypeError, match="needs state\\(\\) and set_state\\(\\)"):
        type("Bad", (ForceTerm,), {"name": "bad", "scene_keys": (), "features": (), "needs": frozenset(),
                                   "steady": None, "stateless": False, "build": classmethod(lambda c, x: None),
                                   "force": lambda s, t, x, v: ()})
    with pytest.raises(TypeError, match="velocity_jacobian"):
        type("Bad", (ForceTerm,), {"name": "bad", "scene_keys": (), "features": (), "needs": frozenset(),
                                   "steady": "jacobian", "build": classmethod(lambda c, x: None),
                                   "force": lambda s, t, x, v: ()})


class LaggedSpring(ForceTerm):
    """A test term: a spring k on heave held in the client's stiffness matrix, a mass m_a in its
    mass matrix, a feedthrough d (dF/dv = -d on heave), and a first-order lagged force
    g_k = a g_{k-1} + (1 - a) (-d v_k) sent as ``viscous``: it keeps state."""

    name = "lagged_spring"
    scene_keys = ()
    features = ()
    needs = frozenset({"velocity"})
    steady = None
    stateless = False
    K, M, D, A = 5.0e4, 1.0e3, 2.0e3, 0.5

    def __init__(self, n: int):
        super().__init__(("viscous",))
        self.n, self.g = n, np.zeros((n // 6, 6))
        e = np.zeros((n, n))
        e[2, 2] = 1.0
        self.stiffness, self.added_mass, self.feedthrough = self.K * e, self.M * e, -self.D * e

    @classmethod
    def build(cls, ctx: TermContext) -> "LaggedSpring":
        return cls(6 * ctx.n_bodies)

    def force(self, t, position, velocity):
        g = np.zeros_like(self.g)
        g[:, 2] = self.A * self.g[:, 2] + (1 - self.A) * (-self.D * velocity[:, 2])
        self.g = g
        return (g.copy(),)

    def state(self):
        return self.g.copy()

    def set_state(self, state) -> None:
        self.g = state.copy()


def test_the_model_adds_a_terms_contributions_loops_its_force_and_rolls_it_back(sphere):
    scene = parse_scene(SCENE)
    core = HydroModel(scene, {"sphere": sphere})
    assert core.terms == [] and "viscous" not in core.step(0.0, core.equilibrium_position, np.zeros((1, 6)))
    model = HydroModel(scene, {"sphere": sphere}, term_types=(LaggedSpring,))
    s0, s1 = core.setup_info(), model.setup_info()
    e = np.zeros((6, 6))
    e[2, 2] = 1.0
    np.testing.assert_array_equal(s1.hydrostatic_stiffness, s0.hydrostatic_stiffness + LaggedSpring.K * e)
    np.testing.assert_array_equal(s1.added_mass, s0.added_mass + LaggedSpring.M * e)
    np.testing.assert_array_equal(s1.radiation_feedthrough, s0.radiation_feedthrough - LaggedSpring.D * e)
    eq = s1.equilibrium_position
    x = eq + np.array([[0.1, 0.0, 0.2, 0.0, 0.01, 0.0]])
    velocities = [np.array([[0.0, 0.0, v, 0.0, 0.0, 0.0]]) for v in (0.3, -0.2, 0.5, 0.1)]
    g, expected = 0.0, []
    for v in velocities:                     # the lag written out by hand
        g = LaggedSpring.A * g + (1 - LaggedSpring.A) * (-LaggedSpring.D * v[0, 2])
        expected.append(g)
    replies = []
    for k, v in enumerate(velocities):
        replies.append(model.step(k * model.dt, x, v))
        if k == 1:
            saved = model.state()
    assert [r["viscous"][0, 2] for r in replies] == pytest.approx(expected, rel=1e-15)
    # the reply's hydrostatic force holds the term's stiffness: -(C + k e) (x - x_eq)
    np.testing.assert_allclose(replies[0]["hydrostatic"].reshape(-1),
                               -(s0.hydrostatic_stiffness + LaggedSpring.K * e) @ (x - eq).reshape(-1), rtol=1e-12)
    model.set_state(saved)                   # back to after step 1: steps 2 and 3 again, bit for bit
    for k in (2, 3):
        again = model.step(k * model.dt, x, velocities[k])
        for name in ("excitation", "radiation", "hydrostatic", "viscous"):
            np.testing.assert_array_equal(again[name], replies[k][name])
