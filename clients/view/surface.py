"""The free surface on a grid: the grid (extent and resolution, its size checked before anything is
allocated) and the run's incident wave on it, from the same wave components the force server used
(rebuilt from the results' scene; checked against the file's ``wave_elevation`` at the origin).

eta(x, y, t) = r(t) Re sum_c a_c e^{i phi_c} e^{i k_c (x cos b_c + y sin b_c)} e^{-i w_c t}
(server/sea/waves.py's convention, its ramp r(t))."""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from hydrolink.clients.view.placement import VTK_QUAD
from hydrolink.clients.view.results import RunFile, ViewError, read_rows
from hydrolink.protocol.scene import ElevationWave, RegularWave, StillWater
from hydrolink.server.allocation import require_size
from hydrolink.server.sea.seastate import run_components
from hydrolink.server.sea.waves import WaveComponents, WaveError, elevation, ramp_factor


@dataclass(frozen=True)
class Grid:
    """A horizontal grid of nx x ny points at z = 0 (x fastest), quads between them."""
    x: np.ndarray
    y: np.ndarray

    @property
    def points(self) -> np.ndarray:
        """(ny nx, 3) points at still water, x varying fastest."""
        xx, yy = np.meshgrid(self.x, self.y)
        return np.column_stack([xx.ravel(), yy.ravel(), np.zeros(xx.size)])

    def cells(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """VTK quads: connectivity, offsets, types."""
        nx, ny = self.x.size, self.y.size
        i, j = np.meshgrid(np.arange(nx - 1), np.arange(ny - 1))
        p = (j * nx + i).ravel()
        conn = np.column_stack([p, p + 1, p + 1 + nx, p + nx]).ravel().astype(np.int64)
        n = p.size
        return conn, np.arange(0, 4 * n + 1, 4, dtype=np.int64), np.full(n, VTK_QUAD, np.uint8)


def make_grid(extent: tuple[float, float, float, float], cells: tuple[int, int], components: int) -> Grid:
    """The grid over ``extent`` (x0, x1, y0, y1) with ``cells`` (nx, ny) quads; its points and the
    point x component phasors it needs are checked for size first (``--grid-cells``)."""
    x0, x1, y0, y1 = extent
    nx, ny = cells
    if not (x1 > x0 and y1 > y0):
        raise ViewError("", "--grid-extent", f"must be x0 < x1 and y0 < y1, got {list(extent)}")
    if nx < 1 or ny < 1:
        raise ViewError("", "--grid-cells", f"must be at least 1 x 1, got {nx} x {ny}")
    points = (nx + 1.0) * (ny + 1.0)
    hint = f"fewer --grid-cells than {nx} x {ny}"
    require_size("--grid-cells", "the free-surface grid's points", (points, 3), hint=hint)
    require_size("--grid-cells", "the free-surface grid's wave phasors (points x components)",
                 (points, max(components, 1)), itemsize=16, hint=hint)
    return Grid(np.linspace(x0, x1, nx + 1), np.linspace(y0, y1, ny + 1))


def run_waves(run: RunFile) -> WaveComponents | None:
    """The run's wave components (None for ``[waves] type = "elevation"``: a series at the origin
    has no field to draw; a steady file's without the ramp), built as the force server built them
    (server/sea/seastate.py ``run_components``, over the wet bodies' common frequency range). The HDBs are loaded for their range (built ones from the cache)
    unless an irregular sea gives its ``omega_range``."""
    waves, scene = run.scene.waves, run.scene
    if isinstance(waves, ElevationWave):
        return None
    lo, hi = 1e-9, np.inf
    if not isinstance(waves, (StillWater, RegularWave)) and getattr(waves, "omega_range", None) is None:
        from hydrolink.clients.scene_inputs import load_scene_hdbs
        hdbs = load_scene_hdbs(scene, run.scene_path, progress=False)
        omegas = [hdbs[b.hdb]["omega"].values for b in scene.bodies if b.wet]
        lo, hi = max(float(w[0]) for w in omegas), min(float(w[-1]) for w in omegas)
    try:
        if scene.gauge_files():          # a sea from gauges: their records, read as the run read them
            from hydrolink.clients.scene_inputs import load_gauge_files
            waves = scene.with_gauges(load_gauge_files(scene, run.scene_path)).waves
        comps = run_components(waves, scene, lo, hi)
    except WaveError as exc:
        raise ViewError(run.path, exc.key, f"the run's waves cannot be rebuilt: {exc.why}") from None
    if run.steady:                       # the steady state is the wave after its ramp
        comps = replace(comps, ramp=0.0)
    _check_against_run(run, comps)
    return comps


def _check_against_run(run: RunFile, comps: WaveComponents) -> None:
    """The rebuilt components must give the file's ``wave_elevation`` at the origin (its first
    rows, up to 4096): else the scene's folder (HDB ranges) is not the run's."""
    if "wave_elevation" not in run.variables:
        return
    rows = np.arange(min(run.time.size, 4096))
    eta = read_rows(run.path, ["wave_elevation"], rows)["wave_elevation"]
    mine = elevation(comps, run.time[rows])
    scale = float(np.abs(comps.amplitude).sum()) if comps.size else 0.0
    err = float(np.abs(mine - eta).max())
    if err > 1e-9 + 1e-7 * scale:
        raise ViewError(run.path, "wave_elevation", f"the waves rebuilt from the file's scene differ from the run's by "
                        f"{err:.3g} m at the origin: the scene's HDBs (their frequency range) are not the run's; "
                        f"give the scene's folder with --scene-dir")


class PhasorField:
    """A linear wave field at fixed points from complex amplitudes per point and component
    (P, C): eta(t) = r(t) Re(phasor @ e^{-i w t}), one complex matrix-vector product a frame."""

    def __init__(self, comps: WaveComponents, phasor: np.ndarray):
        self.comps = comps
        self._phasor = phasor

    def __call__(self, t: float) -> np.ndarray:
        """eta (P,) at time t, ramp included."""
        if self.comps.size == 0:
            return np.zeros(self._phasor.shape[0])
        r = float(ramp_factor(np.array([t]), self.comps.ramp)[0])
        return r * np.real(self._phasor @ np.exp(-1j * self.comps.omega * t))


class IncidentField(PhasorField):
    """The incident elevation at fixed points (P, 2 or 3; z ignored): phasors per point and
    component a_c e^{i phi_c} e^{i k_c (x cos b_c + y sin b_c)}."""

    def __init__(self, comps: WaveComponents, points: np.ndarray, gravity: float, depth: float):
        k = comps.wave_numbers(gravity, depth) if comps.size else np.zeros(0)   # intrinsic in a current
        head = comps.heading_of()
        along = points[:, :1] * np.cos(head)[None] + points[:, 1:2] * np.sin(head)[None]
        super().__init__(comps, (comps.amplitude * np.exp(1j * comps.phase))[None] * np.exp(1j * k[None] * along))
