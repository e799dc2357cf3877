"""Each coupling scheme (clients/lockstep/coupling_schemes.py) driven by the lockstep loop (clients/lockstep/driver.py)
against the real force server, with a multibody code written here: one heaving sphere integrated by
the average-acceleration Newmark rule in numpy — no Exudyn. References: the monolithic Cummins
integration of tests/test_stability.py, and the added-mass instability's known threshold A∞/m = 1."""

from __future__ import annotations

import numpy as np
import pytest

from hydrolink.clients.lockstep.connection import ServerConnection
from hydrolink.clients.lockstep.coupling_schemes import Iterated, Predictor, Staggered, make_scheme
from hydrolink.clients.lockstep.driver import DivergenceWatch, ForceLink, Lockstep, SimulationDiverged, run
from hydrolink.clients.lockstep.results import ResultWriter
from hydrolink.clients.lockstep.summary import CouplingReport
from hydrolink.server.service.force_server import ForceServer
from test_stability import HEAVE, a33, c33, decay_reference, scene_text, sphere  # noqa: F401 (fixtures)

DT, DURATION, X0 = 0.01, 8.0, 0.5


class HeaveBody:
    """A rigid body in heave only: (m [+ A∞]) a + C x = u at the end of each step (Newmark β = 1/4)."""

    label = "the body state"
    substeps = 1

    def __init__(self, setup, mass: float, feedback: bool, h: float):
        self.h = h
        self.c = float(setup.hydrostatic_stiffness[HEAVE, HEAVE])
        self.a_inf = setup.added_mass
        self.m = mass + (0.0 if feedback else float(setup.added_mass[HEAVE, HEAVE]))
        self.x, self.v, self.a = np.zeros(6), np.zeros(6), np.zeros(6)
        self.x[HEAVE] = X0
        self.rows: list[float] = []

    def begin(self, s0, feedback: bool) -> int:
        """Initial acceleration consistent with −A∞·a0 when A∞ is fed back (solved directly here)."""
        m0 = self.m + (float(self.a_inf[HEAVE, HEAVE]) if feedback else 0.0)
        self.a[HEAVE] = (s0.load[HEAVE] - self.c * self.x[HEAVE]) / m0
        return 0

    def state(self):
        return self.x, self.v, self.a

    def extent(self, limit: float) -> float:
        return max(float(np.abs(self.x).max()), float(np.abs(self.v).max()))

    def inputs(self, s0, s1, acc, x0, x1):
        return s1.load if acc is None else s1.load - self.a_inf @ acc

    def advance(self, t0: float, t1: float, u) -> None:
        h, x, v, a = self.h, self.x[HEAVE], self.v[HEAVE], self.a[HEAVE]
        xb, vb = x + h * v + 0.25 * h * h * a, v + 0.5 * h * a
        a1 = (u[HEAVE] - self.c * xb) / (self.m + 0.25 * h * h * self.c)
        self.x, self.v, self.a = self.x.copy(), self.v.copy(), self.a.copy()
        self.x[HEAVE], self.v[HEAVE], self.a[HEAVE] = xb + 0.25 * h * h * a1, vb + 0.5 * h * a1, a1

    def save(self):
        return self.x.copy(), self.v.copy(), self.a.copy()

    def restore(self, saved) -> None:
        self.x, self.v, self.a = (s.copy() for s in saved)

    def snapshot(self):
        return float(self.x[HEAVE])

    def write(self, t, s, snap, *, writer=None) -> None:
        self.rows.append(snap)

    def measurements(self, step: int):
        return None

    def apply_control(self, decisions) -> None:
        pass


class Rows:
    """The loop's writer: counts rows and records the final status (the body keeps the values)."""

    path = "memory"

    def __init__(self, body: HeaveBody):
        self.body, self.status = body, "running"

    @property
    def rows(self) -> int:
        return len(self.body.rows)

    rows_written = rows

    def finish(self, status: str) -> None:
        self.status = status


def drive(sphere, scheme, mass: float, feedback: bool, duration: float = DURATION):
    """Free decay of the sphere from X0 under ``scheme``: (heave (n + 1,), loop, writer)."""
    text = scene_text(mass, dt=DT, duration=duration, x0=X0)
    with ServerConnection(ForceServer(None)) as conn:
        setup = conn.hello(text, {"sphere.h5": sphere})
        body = HeaveBody(setup, mass, feedback, DT)
        writer = Rows(body)
        loop = Lockstep(body, ForceLink(conn, setup, writer), writer, DivergenceWatch())
        run(loop, scheme, int(round(duration / DT)), CouplingReport(type(scheme).__name__, added_mass_ratio=0.0))  # (not reported here)
    return np.array(body.rows), loop, writer


def test_predictor_with_added_mass_in_the_matrix_matches_monolithic(sphere, a33, c33):
    mass = 2.0 * a33
    z, loop, writer = drive(sphere, Predictor(feedback=False), mass, feedback=False)
    ref = decay_reference(sphere, mass, a33, c33, DT, DURATION, 20.0, x0=X0)
    err = float(np.abs(z - ref).max()) / X0
    print(f"mass-matrix predictor vs monolithic: {err:.2e}")
    assert writer.status == "complete" and z.size == ref.size
    assert err < 3e-3


def test_iterated_converges_in_few_iterations_and_matches_monolithic(sphere, a33, c33):
    mass = 0.5 * a33                      # A∞/m = 2: explicit feedback would diverge
    scheme = Iterated(1e-8, 50, omega0=1.0 / 3.0)
    z, loop, _ = drive(sphere, scheme, mass, feedback=True)
    ref = decay_reference(sphere, mass, a33, c33, DT, DURATION, 20.0, x0=X0)
    err = float(np.abs(z - ref).max()) / X0
    its = np.asarray(loop.iterations)
    print(f"implicit at A/m = 2 vs monolithic: {err:.2e}, iterations {its.mean():.2f} (max {its.max()})")
    assert err < 3e-3
    assert its.mean() <= 3.0 and its.max() <= 6


@pytest.mark.parametrize("scheme_name", ["explicit", "explicit-predictor"])
def test_lagged_feedback_is_stable_below_one_and_stopped_above(sphere, a33, c33, scheme_name):
    """The added-mass instability: −A∞·a one step late multiplies an acceleration error by −A∞/m."""
    n_ex = int(round(DURATION / DT))
    stable, _, _ = drive(sphere, make_scheme(scheme_name, tolerance=1e-8, max_iterations=50, ratio=0.5,
                                             n_exchanges=n_ex), 2.0 * a33, feedback=True)
    ref = decay_reference(sphere, 2.0 * a33, a33, c33, DT, DURATION, 20.0, x0=X0)
    assert float(np.abs(stable - ref).max()) / X0 < 0.05        # stable, first order in the lag
    with pytest.raises(SimulationDiverged, match="added-mass instability") as err:
        drive(sphere, make_scheme(scheme_name, tolerance=1e-8, max_iterations=50, ratio=2.0, n_exchanges=n_ex),
              0.5 * a33, feedback=True)
    assert err.value.step < 200                                 # caught early, not after a blow-up


def test_staggered_holds_the_sample_of_the_step_start(sphere, a33):
    """Exchange e of the staggered scheme applies the server's sample of the state at e·H: with one
    step the first load applied is exactly the t = 0 sample (no prediction)."""
    applied = []

    class Spy(HeaveBody):
        def advance(self, t0, t1, u):
            applied.append(u[HEAVE] + float(self.a_inf[HEAVE, HEAVE] * self.a[HEAVE]))
            super().advance(t0, t1, u)

    text = scene_text(2.0 * a33, dt=DT, duration=3 * DT, x0=X0)
    with ServerConnection(ForceServer(None)) as conn:
        setup = conn.hello(text, {"sphere.h5": sphere})
        first = conn.step(0, 0.0, setup.equilibrium_position + np.eye(6)[HEAVE] * X0, np.zeros((1, 6)))
    with ServerConnection(ForceServer(None)) as conn:
        setup = conn.hello(text, {"sphere.h5": sphere})
        body = Spy(setup, 2.0 * a33, True, DT)
        writer = Rows(body)
        run(Lockstep(body, ForceLink(conn, setup, writer), writer, DivergenceWatch()), Staggered(3), 3,
            CouplingReport("Staggered", added_mass_ratio=0.0))
    assert applied[0] == pytest.approx(first["excitation"][0, HEAVE] + first["radiation"][0, HEAVE], abs=1e-9)


def test_unknown_scheme_is_refused():
    with pytest.raises(ValueError, match="unknown coupling scheme 'leapfrog'"):
        make_scheme("leapfrog", tolerance=1e-8, max_iterations=50, ratio=0.0, n_exchanges=1)

