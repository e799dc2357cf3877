"""The coupling schemes: how one exchange with the force server is taken (scene ``[coupling] scheme``).

Each takes exchange e (time e·H → (e+1)·H) given the server's sample at its start and returns the
sample the next exchange starts from. A∞ (what the setup calls ``added_mass``) is either in the
multibody code's mass matrix, or fed back as the force −A·a (``feedback``):

- :class:`Predictor` — ``"mass-matrix"`` (A in the matrix; an FMU takes it as parameters) and
  ``"explicit-predictor"`` (−A·a of the last step, lagged): the sample at (e+1)·H is asked for at the
  state predicted from e·H (x + H v + H²/2 a, v + H a), one pass;
- :class:`Staggered` — ``"explicit"``: the sample of the state at e·H held over the exchange, −A·a
  lagged: the classic added-mass instability above A/m = 1 (docs/stability.md);
- :class:`Iterated` — ``"implicit"``: −A·a at the end of each step and the sample at the state the
  exchange ends in, iterated to a fixed point with rollback (the multibody code's saved state and the
  server's ``iteration``, SPEC §5.3) and Aitken relaxation.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from hydrolink.clients.lockstep.relaxation import Aitken
from hydrolink.clients.lockstep.driver import CouplingError, Lockstep, Sample


def _times(loop: Lockstep, e: int, j: int) -> tuple[float, float]:
    """Start and end time of client step j (1..substeps) of exchange e."""
    h, kx = loop.mb.h, loop.mb.substeps
    t_e = e * kx * h
    return t_e + (j - 1) * h, t_e + j * h


@dataclass
class Predictor:
    """Forces at the end of the exchange from the predicted state; A in the matrix or lagged."""

    feedback: bool = False

    def exchange(self, loop: Lockstep, e: int, s_prev: Sample) -> Sample:
        mb, big_h = loop.mb, loop.big_h
        x, v, a = mb.state()
        meas = mb.measurements(loop.step)
        xp = x + big_h * v + 0.5 * big_h * big_h * a
        s_new = loop.link.sample(e + 1, xp, v + big_h * a, measurements=meas)
        mb.apply_control(loop.link.decisions)
        if loop.link.hydro_state is not None:   # A∞ and stiffness of the state the forces at (e+1) H are
            mb.apply_hydro_state(loop.link.hydro_state)
        s0 = s_prev
        for j in range(1, mb.substeps + 1):
            t0, t1 = _times(loop, e, j)
            s_j = loop.between_samples(s_prev, s_new, j)
            loop.client_step(t0, t1, mb.inputs(s0, s_j, mb.state()[2] if self.feedback else None, x, xp))
            if self.feedback:
                loop.watch.feedback(mb.state()[2], loop.step, t1)
            loop.write(t1, s_j)
            s0 = s_j
        return s_new


@dataclass
class Staggered:
    """Forces of the state at the exchange's start held (or extrapolated) over it; −A·a lagged."""

    n_exchanges: int
    feedback: bool = True
    s_old: Sample | None = None

    def exchange(self, loop: Lockstep, e: int, s_prev: Sample) -> Sample:
        mb = loop.mb
        s_old = s_prev if self.s_old is None else self.s_old
        for j in range(1, mb.substeps + 1):
            t0, t1 = _times(loop, e, j)
            x, _, a = mb.state()
            s_j = loop.between_samples(s_old, s_prev, j, extrapolate=True)
            loop.client_step(t0, t1, mb.inputs(s_j, s_j, a, x, x))
            loop.watch.feedback(mb.state()[2], loop.step, t1)
            loop.write(t1, s_j)
        if e + 1 == self.n_exchanges:
            return s_prev
        x, v, _ = mb.state()
        self.s_old = s_prev
        return loop.link.sample(e + 1, x, v)


@dataclass
class Iterated:
    """−A·a and the forces at the state the exchange ends in, to a fixed point (rollback + Aitken)."""

    tolerance: float
    max_iterations: int
    omega0: float = 0.5                      # Aitken's first relaxation (1 / (1 + A/m) is a good one)
    feedback: bool = True
    history: list = field(default_factory=list)   # the last two converged inputs (substeps, n_u)
    scale: float = 1e-300                    # largest interface load seen (the residual's scale)

    def __post_init__(self) -> None:
        self.aitken = Aitken(self.omega0)

    def _guess(self, loop: Lockstep, s_prev: Sample) -> np.ndarray:
        """Linear extrapolation of the last two converged inputs (the first: the current load)."""
        hist = self.history
        if len(hist) >= 2:
            return 2 * hist[-1] - hist[-2]
        if hist:
            return hist[-1].copy()
        x, _, a = loop.mb.state()
        return np.tile(loop.mb.inputs(s_prev, s_prev, a, x, x), (loop.mb.substeps, 1))

    def exchange(self, loop: Lockstep, e: int, s_prev: Sample) -> Sample:
        mb, kx = loop.mb, loop.mb.substeps
        saved, step0 = mb.save(), loop.step
        x0 = mb.state()[0]
        u = self._guess(loop, s_prev)
        self.aitken.restart()
        for it in range(self.max_iterations):
            if it:
                mb.restore(saved)
                loop.step = step0
            ends, snaps = [], []
            for j in range(1, kx + 1):
                t0, t1 = _times(loop, e, j)
                loop.client_step(t0, t1, u[j - 1], f"{mb.label} (implicit iteration {it})")
                ends.append(mb.state())
                snaps.append((t1, mb.snapshot()))
            x, v, _ = ends[-1]
            s_new = loop.link.sample(e + 1, x, v, iteration=it)
            s_sub = [loop.between_samples(s_prev, s_new, j) for j in range(1, kx + 1)]
            starts = [s_prev, *s_sub[:-1]]
            xs = [x0, *(end[0] for end in ends)]
            g = np.array([mb.inputs(starts[j], s_sub[j], ends[j][2], xs[j], xs[j + 1]) for j in range(kx)])
            res = float(np.abs(g - u).max(initial=0.0))
            self.scale = max(self.scale, float(np.abs(g).max(initial=0.0)))
            if res <= self.tolerance * self.scale:
                break
            u = self.aitken.update(u.reshape(-1), g.reshape(-1)).reshape(u.shape)
        else:
            t = _times(loop, e, kx)[1]
            raise CouplingError(
                f"the implicit coupling did not converge at step {loop.step} (t = {t:.6g} s) within "
                f"{self.max_iterations} iterations (residual {res:.3g} N, tolerance {self.tolerance:g} × "
                f"{self.scale:.3g} N); raise coupling.max_iterations or coupling.tolerance, or reduce "
                f"simulation.dt; the {e * kx} rows before it are saved", step=loop.step, time=t, rows=e * kx)
        loop.iterations.append(it + 1)
        self.history = [*self.history[-1:], u]
        for (t, snap), s in zip(snaps, s_sub):
            loop.write(t, s, snap)
        return s_new


def make_scheme(name: str, *, tolerance: float, max_iterations: int, ratio: float, n_exchanges: int):
    """The scheme object for ``[coupling] scheme`` (resolved: not "auto")."""
    if name == "mass-matrix":
        return Predictor(feedback=False)
    if name == "explicit-predictor":
        return Predictor(feedback=True)
    if name == "explicit":
        return Staggered(n_exchanges)
    if name == "implicit":
        return Iterated(tolerance, max_iterations, omega0=1.0 / (1.0 + ratio))
    raise ValueError(f"unknown coupling scheme {name!r}")
