"""The radiated and diffracted waves on the free surface, from the Capytaine free-surface solution an
HDB build stores when its spec asks for it (``[free_surface]``, server/hdb/build/free_surface.py),
combined linearly with the run's motion.

A regular wave at one of the stored frequencies (w, incident amplitude A = a e^{i phi} at the origin, ramp r(t)): at each
frame the bodies' displacement from equilibrium x(t) - x_eq is fitted over the one wave period
around the frame by m + Re(xi e^{-i w t}) (least squares on [1, cos w t, sin w t]: exact for a
steady response), and

    eta_R(x, t) = Re(sum_{body, dof} xi eta_R,dof(x) e^{-i w t}),   eta_D(x, t) = Re(r(t) A eta_D(x) e^{-i w t})

with eta_R,dof per unit motion and eta_D per unit incident amplitude (Capytaine's solution at w).
Any other run (irregular and directional seas, component lists, a frequency between the stored
ones, transients): the radiated wave by convolution of the velocity history, the diffracted wave per
component (clients/view/convolved.py)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from hydrolink.clients.view.convolved import (ConvolvedField, diffraction_phasor, kernel_step, radiation_kernel,
                                              same_direction)
from hydrolink.clients.view.results import RunFile, read_rows
from hydrolink.clients.view.surface import Grid, PhasorField
from hydrolink.server.sea.waves import WaveComponents, ramp_factor


@dataclass
class DisturbedField:
    """A run's radiated and diffracted waves on the build's grid: ``radiated`` (B, 6, P) per unit
    motion of the results' bodies ``rows``, ``diffracted`` (P,) per unit incident amplitude."""
    omega: float
    amplitude: complex
    ramp: float
    rows: np.ndarray
    radiated: np.ndarray
    diffracted: np.ndarray
    _xi: np.ndarray | None = None     # (frames of the block, B, 6) fitted motion amplitudes

    def prepare(self, run: RunFile, chunk: np.ndarray) -> None:
        """Fit the motion amplitudes of the frames at ``chunk`` (one period around each row)."""
        period = 2 * np.pi / self.omega
        t = run.time
        lo = int(np.searchsorted(t, t[chunk[0]] - period / 2 - 1e-9))
        hi = int(np.searchsorted(t, t[chunk[-1]] + period / 2 + 1e-9, side="right"))
        span = np.arange(lo, hi)
        pos = read_rows(run.path, ["position"], span)["position"][:, self.rows]
        disp = (pos - run.equilibrium[self.rows][None]).reshape(span.size, -1)
        xi = []
        for row in chunk:
            a, b = window(t, row, period)
            a, b = max(a, lo), min(b, hi)
            tt = t[a:b]
            basis = np.column_stack([np.ones_like(tt), np.cos(self.omega * tt), np.sin(self.omega * tt)])
            coef = np.linalg.lstsq(basis, disp[a - lo:b - lo], rcond=None)[0]
            xi.append((coef[1] + 1j * coef[2]).reshape(self.rows.size, 6))
        self._xi = np.array(xi)

    def at(self, k: int, t: float) -> dict[str, np.ndarray]:
        """The radiated and diffracted elevation (P,) of the block's ``k``-th frame at time ``t``."""
        phase = np.exp(-1j * self.omega * t)
        radiated = np.real(np.tensordot(self._xi[k], self.radiated, axes=([0, 1], [0, 1])) * phase)
        r = float(ramp_factor(np.array([t]), self.ramp)[0])
        return {"radiated": radiated, "diffracted": np.real(r * self.amplitude * self.diffracted * phase)}


def window(t: np.ndarray, row: int, period: float) -> tuple[int, int]:
    """Rows [a, b) of the one period centred on ``row``, moved inside the file at its ends."""
    start = min(max(t[row] - period / 2, t[0]), max(t[-1] - period, t[0]))
    a = int(np.searchsorted(t, start - 1e-9))
    b = int(np.searchsorted(t, start + period + 1e-9, side="right"))
    return a, b


def _stored(run: RunFile) -> Path | None:
    """The free-surface file of the one build spec every wet body's HDB is, if it asks for one."""
    from hydrolink.protocol.scene import resolve_path
    from hydrolink.server.hdb.build.builder import build_hdb
    from hydrolink.server.hdb.build.spec import load_spec

    specs = {b.hdb for b in run.scene.bodies if b.wet}
    if len(specs) != 1 or not next(iter(specs)).endswith(".toml"):
        return None
    spec_path = resolve_path(run.scene_path, next(iter(specs)))
    if load_spec(spec_path).free_surface is None:
        return None
    return Path(build_hdb(spec_path, progress=False, free_surface=True).attrs["free_surface_file"])


def disturbed_field(run: RunFile, comps: WaveComponents,
                    wanted: bool = True) -> tuple[DisturbedField | ConvolvedField | None, Grid | None, str]:
    """The run's radiated and diffracted field and the build's grid, or None and a note saying why
    not (none stored: no note; not ``wanted``: the grid alone). A regular wave at a stored frequency:
    the fitted amplitudes (exact in the steady state); any other run: the convolution
    (clients/view/convolved.py)."""
    from hydrolink.server.hdb.build.free_surface import read_free_surface

    path = _stored(run)
    if path is None:
        return None, None, ""
    rad, dif = read_free_surface(path)
    omega, directions = rad["omega"].values, dif["wave_direction"].values
    names = [b.hdb_body_name for b in run.scene.bodies if b.wet]
    built = [str(b) for b in rad["body"].values]
    rows = np.array([run.bodies.index(b.name) for b in run.scene.bodies if b.wet])
    radiated = rad.values[:, [built.index(n) for n in names]]            # (n_w, B, 6, y, x)
    radiated = radiated.reshape(*radiated.shape[:3], -1)
    diffracted = dif.values.reshape(*dif.shape[:2], -1)                 # (n_w, n_dir, P)
    grid = Grid(rad["x"].values, rad["y"].values)
    if not wanted:
        return None, grid, ""
    why = _not_drawn(run, comps, omega, directions)
    if why:
        return None, None, "radiated/diffracted waves: " + why
    if comps.kind == "regular":
        iw = np.flatnonzero(np.isclose(omega, comps.omega[0], rtol=1e-9, atol=0))
        if iw.size:
            ib = int(np.flatnonzero(same_direction(directions, comps.direction))[0])
            return DisturbedField(float(comps.omega[0]), complex(comps.amplitude[0] * np.exp(1j * comps.phase[0])),
                                  comps.ramp, rows, radiated[iw[0]], diffracted[iw[0], ib]), grid, ""
    q = kernel_step(omega, float(run.time[1] - run.time[0]))
    kernel = radiation_kernel(omega, radiated, q * float(run.time[1] - run.time[0]), run.scene.hydro.irf_duration)
    phasor, outside = diffraction_phasor(comps, omega, directions, diffracted)
    note = (f"radiated/diffracted waves: {100 * outside:.3g} % of the sea's variance lies outside the build's "
            f"[free_surface] omega {omega[0]:.4g}-{omega[-1]:.4g} rad/s: its diffracted wave is left out; "
            f"widen [free_surface] omega") if outside > 0 else ""
    return ConvolvedField(rows, kernel, q, PhasorField(comps, phasor)), grid, note


def _not_drawn(run: RunFile, comps: WaveComponents, omega: np.ndarray, directions: np.ndarray) -> str:
    """Why the stored solution cannot give this run's disturbed field ("" if it can)."""
    if comps.intrinsic is not None:
        return "not drawn in a current (waves.current: the stored solution is for still water)"
    regular_stored = comps.kind == "regular" and np.isclose(omega, comps.omega[0], rtol=1e-9, atol=0).any()
    if not regular_stored and (run.steady or omega.size < 2):
        held = f"omega {omega.tolist()}" if omega.size < 4 else f"{omega.size} frequencies"
        wave = f"{comps.omega[0]:.6g} rad/s" if comps.kind == "regular" else comps.kind
        return (f"the build's [free_surface] {held} do not hold this run's wave ({wave}): "
                + ("add its frequency to [free_surface] omega" if run.steady else
                   "give [free_surface] omega as a grid over the sea's frequencies (at least two)"))
    missing = sorted({round(float(np.degrees(h)) % 360, 6) for h in comps.heading_of()
                      if not same_direction(directions, h).any()})
    if missing:
        shown = ", ".join(f"{d:g}" for d in missing[:8]) + (" ..." if len(missing) > 8 else "")
        return f"the build spec's [waves] directions lack the run's heading(s) {shown} deg: add them to the build spec"
    if not regular_stored and run.time.size < 2:
        return "the results hold one row: no velocity history to convolve"
    if not regular_stored:
        steps = np.diff(run.time)
        if np.abs(steps - steps[0]).max() > 1e-9 * max(1.0, abs(float(run.time[-1]))):
            return "the results' rows are not evenly spaced in time: the radiated wave's convolution needs them so"
    return ""
