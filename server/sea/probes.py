"""Wave probes: the undisturbed incident elevation at points, now and at preview offsets (the
``wave_elevation`` measurements of controllers, SPEC §5.7).

A controller's preview is a window of elevations at the steps k, k + h, ..., k + n_h h (h the
preview step in simulation steps) that slides forward by the control period each control step:
:class:`WaveProbes` keeps the window's columns by step index and computes only the ones it has not
(each once along a run). The column of step n is ``Re(c) @ cos(w t) + Im(c) @ sin(w t)``, t = n dt
(real cosines and sines: numpy's complex exp is several times slower); a column h steps after the
one before turns its cosines and sines by the angle w h dt (four products a component), evaluated
afresh every REANCHOR turns so rounding does not add up along a run. A control step of a
100,000-component sea with a 30 s preview costs a column or two, not the whole window, and holds
n_probes x (n_h + 1) floats.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from hydrolink.server.sea.waves import WaveComponents, ramp_factor

__all__ = ["PreviewGrid", "WaveProbes"]

CHUNK_BYTES = 32 * 2**20   # the cosines and sines (components x times) one evaluation of __call__ holds at once
REANCHOR = 1000            # turned columns between two evaluated afresh


@dataclass(frozen=True)
class PreviewGrid:
    """Where and when a controller's probes look: ``points`` (n_p, 2) m, the simulation step ``dt``
    (s), and the preview at ``samples`` offsets of ``every`` steps each (offsets 0, every, ...)."""

    points: tuple[tuple[float, float], ...]
    dt: float
    every: int
    samples: int

    @property
    def offsets(self) -> np.ndarray:
        """The times after a measurement the columns are at (s): column 0 is now."""
        return np.arange(self.samples + 1) * self.every * self.dt


class WaveProbes:
    """Undisturbed incident elevation at probe points (x, y), now and at preview offsets.

    Same convention as :mod:`hydrolink.server.sea.waves`: a component a, phi, heading beta gives
    eta(x, y, t) = r(t) a cos(k (x cos beta + y sin beta) - w t + phi), beta the component's own
    heading (at the origin exactly the model's ``wave_elevation``)."""

    def __init__(self, comps: WaveComponents, points: np.ndarray, preview_times: np.ndarray, g: float,
                 depth: float):
        self.comps = comps
        self.points = np.asarray(points, float).reshape(-1, 2)
        self.offsets = np.r_[0.0, np.asarray(preview_times, float)]   # column 0: now
        self._columns: dict[int, np.ndarray] = {}   # step index -> elevation at the points (at_step)
        self.computed = 0   # columns computed by at_step (each at most once while the window slides)
        self.grid: PreviewGrid | None = None   # set by on_grid: what at_step evaluates
        self._top: tuple[int, int, np.ndarray, np.ndarray] | None = None   # newest column: n, turns, cos, sin
        self._turn: tuple[np.ndarray, np.ndarray] | None = None   # cos, sin of w x the grid's step
        if comps.size:
            k = comps.wave_numbers(g, depth)
            b = comps.heading_of()            # each component's own heading (spread and crossing seas)
            kx = np.outer(self.points[:, 0], k * np.cos(b)) + np.outer(self.points[:, 1], k * np.sin(b))
            c = comps.amplitude * np.exp(1j * (comps.phase + kx))   # (n_p, n_c)
            self._cr, self._ci = np.ascontiguousarray(c.real), np.ascontiguousarray(c.imag)

    @classmethod
    def on_grid(cls, comps: WaveComponents, grid: PreviewGrid, g: float, depth: float) -> "WaveProbes":
        """The probes of a controller's :class:`PreviewGrid` (evaluate them with :meth:`at_step`)."""
        probes = cls(comps, np.array(grid.points, float), grid.offsets[1:], g, depth)
        probes.grid = grid
        return probes

    def __call__(self, t: float) -> np.ndarray:
        """(n_p, 1 + n_h): elevation at t + offsets, the ramp included (evaluated afresh, the
        components' phasors a bounded chunk of times at a time)."""
        times = t + self.offsets
        if not self.comps.size:
            return np.zeros((self.points.shape[0], times.size))
        per = max(1, CHUNK_BYTES // (16 * self.comps.size))
        out = np.empty((self.points.shape[0], times.size))
        for i in range(0, times.size, per):
            wt = np.outer(self.comps.omega, times[i:i + per])   # (n_c, chunk)
            out[:, i:i + per] = self._cr @ np.cos(wt) + self._ci @ np.sin(wt)
        return out * ramp_factor(times, self.comps.ramp)

    def at_step(self, step: int) -> np.ndarray:
        """(n_p, 1 + n_h): the elevations of :meth:`__call__` at t = step dt on this probe's
        :class:`PreviewGrid`, from the columns already computed plus the new ones. The window only
        slides forward: an earlier step starts it afresh."""
        grid = self.grid
        if grid is None:
            raise ValueError("at_step needs probes made by WaveProbes.on_grid")
        wanted = [step + j * grid.every for j in range(grid.samples + 1)]
        if self._columns and step < min(self._columns):
            self._columns.clear()
            self._top = None
        for n in [n for n in self._columns if n < step]:
            del self._columns[n]
        missing = [n for n in wanted if n not in self._columns]
        if missing:
            self._compute(missing)
        return np.stack([self._columns[n] for n in wanted], axis=1)

    def _compute(self, steps: list[int]) -> None:
        """The columns of ``steps`` (increasing): one the grid's step after the newest turns its
        cosines and sines; any other is evaluated afresh."""
        grid = self.grid
        n_p = self.points.shape[0]
        if not self.comps.size:
            for n in steps:
                self._columns[n] = np.zeros(n_p)
            return
        omega = self.comps.omega
        if self._turn is None:
            angle = omega * (grid.every * grid.dt)
            self._turn = np.cos(angle), np.sin(angle)
        turn_cos, turn_sin = self._turn
        for n in steps:
            top = self._top
            if top is not None and n - top[0] == grid.every and top[1] < REANCHOR:
                cos = top[2] * turn_cos - top[3] * turn_sin   # cos(a + b), sin(a + b)
                sin = top[3] * turn_cos + top[2] * turn_sin
                turns = top[1] + 1
            else:
                wt = omega * (n * grid.dt)
                cos, sin, turns = np.cos(wt), np.sin(wt), 0
            if top is None or n > top[0]:
                self._top = (n, turns, cos, sin)
            # einsum, not BLAS: a (n_p, n_c) matvec in a threaded BLAS on a loaded machine costs ms
            column = np.einsum("pc,c->p", self._cr, cos) + np.einsum("pc,c->p", self._ci, sin)
            self._columns[n] = column * ramp_factor(n * grid.dt, self.comps.ramp)
            self.computed += 1
