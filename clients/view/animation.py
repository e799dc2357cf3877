"""A picture without ParaView: the same frames drawn with matplotlib (Agg, headless) into a GIF
(Pillow) or an MP4 (ffmpeg), or one frame into a PNG. Bodies in orange, the free surface in blues by
its elevation (every few grid points), markers and mooring lines in black."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from mpl_toolkits.mplot3d import proj3d
from mpl_toolkits.mplot3d.art3d import Poly3DCollection

from hydrolink.clients.lockstep.driver import progress_bar
from hydrolink.clients.view.frames import Frame, Stage, frames
from hydrolink.clients.view.results import ViewError

BODY_COLOR = (0.93, 0.45, 0.10)
SURFACE_MAP = "Blues_r"                 # troughs dark, crests light
MAX_SURFACE_LINES = 40


def _faces(offsets: np.ndarray, connectivity: np.ndarray) -> list[np.ndarray]:
    return [connectivity[a:b] for a, b in zip(offsets[:-1], offsets[1:])]


class FrameFigure:
    """A 3D figure of a stage, redrawn frame by frame (fixed axes: the first frame's extent)."""

    def __init__(self, stage: Stage, first: Frame, size: tuple[float, float] = (6.4, 4.8), dpi: int = 100):
        self.stage = stage
        self.fig = Figure(figsize=size, dpi=dpi)
        self.canvas = FigureCanvasAgg(self.fig)
        # the artists' own order, not mplot3d's depth sort: the bodies over the (translucent) water
        self.ax = self.fig.add_subplot(projection="3d", computed_zorder=False)
        self._cells = [_faces(m.offsets, m.connectivity) for m in stage.meshes]
        self._bodies = [Poly3DCollection([], facecolor=BODY_COLOR, edgecolor=BODY_COLOR, linewidth=0.3,
                                         zorder=3)
                        for _ in stage.meshes]
        for coll in self._bodies:
            self.ax.add_collection3d(coll)
        self._surface = None
        self._extras: list = []
        self._limits(first)
        self.ax.view_init(elev=22, azim=-60)

    def _limits(self, first: Frame) -> None:
        pts = [p for p, _, _ in first.bodies] + [p for p in (first.markers, first.lines) if p is not None]
        g = self.stage.grid
        if g is not None:
            pts.append(np.array([[g.x[0], g.y[0], 0.0], [g.x[-1], g.y[-1], 0.0]]))
        xyz = np.concatenate(pts) if pts else np.zeros((1, 3))
        lo, hi = xyz.min(axis=0), xyz.max(axis=0)
        amp = float(self.stage.incident.comps.amplitude.sum()) if self.stage.incident else 0.0
        self._amp = max(1.5 * amp, 1e-6)
        lo[2], hi[2] = min(lo[2], -2 * amp), max(hi[2], 2 * amp)
        span = np.maximum(hi - lo, 1e-3)
        pad = 0.05 * span
        self.ax.set_xlim(lo[0] - pad[0], hi[0] + pad[0])
        self.ax.set_ylim(lo[1] - pad[1], hi[1] + pad[1])
        self.ax.set_zlim(lo[2] - pad[2], hi[2] + pad[2])
        self.ax.set_box_aspect((span[0], span[1], max(span[2], 0.25 * max(span[0], span[1]))))
        self.ax.set_xlabel("x (m)")
        self.ax.set_ylabel("y (m)")
        self.ax.set_zlabel("z (m)")

    def draw(self, frame: Frame) -> None:
        """Redraw the artists for ``frame``."""
        for coll, cells, (pts, _, _) in zip(self._bodies, self._cells, frame.bodies):
            coll.set_verts([pts[c] for c in cells])
        for artist in self._extras:
            artist.remove()
        self._extras = []
        g = self.stage.grid
        if frame.surface is not None and g is not None:
            z = frame.surface["elevation"].reshape(g.y.size, g.x.size)
            xx, yy = np.meshgrid(g.x, g.y)
            step = max(1, max(g.x.size, g.y.size) // MAX_SURFACE_LINES)
            self._extras.append(self.ax.plot_surface(xx[::step, ::step], yy[::step, ::step], z[::step, ::step],
                                                     cmap=SURFACE_MAP, vmin=-self._amp, vmax=self._amp, alpha=0.6,
                                                     linewidth=0, antialiased=False, zorder=1))
        if frame.markers is not None:
            m = frame.markers
            self._extras.append(self.ax.scatter(m[:, 0], m[:, 1], m[:, 2], color="k", s=12, depthshade=False))
        if frame.lines is not None and self.stage.lines is not None:
            ln = self.stage.lines
            for a, b in zip(ln.offsets[:-1], ln.offsets[1:]):
                (line,) = self.ax.plot(*frame.lines[a:b].T, color="k", linewidth=1.0)
                self._extras.append(line)
        self.ax.set_title(f"t = {frame.time:.2f} s")

    def pixel_of(self, point: np.ndarray) -> tuple[float, float]:
        """Where a 3D point lands in the saved image: (column, row from the top), pixels."""
        self.canvas.draw()
        x, y, _ = proj3d.proj_transform(*point, self.ax.get_proj())
        col, row_up = self.ax.transData.transform((x, y))
        return float(col), float(self.fig.bbox.height - row_up)

    def save_png(self, path: str | Path) -> Path:
        self.canvas.draw()
        self.fig.savefig(path)
        return Path(path)


def render_png(stage: Stage, rows: np.ndarray, path: str | Path) -> FrameFigure:
    """The first of ``rows`` drawn into a PNG; returns the figure (for :meth:`FrameFigure.pixel_of`)."""
    frame = next(frames(stage, rows[:1]))
    fig = FrameFigure(stage, frame)
    fig.draw(frame)
    fig.save_png(path)
    return fig


def animate(stage: Stage, rows: np.ndarray, path: str | Path, *, fps: int = 15, progress: bool = True) -> Path:
    """The frames at ``rows`` into a GIF (``.gif``, Pillow) or an MP4 (``.mp4``, ffmpeg)."""
    from matplotlib import animation

    path = Path(path)
    if path.suffix == ".mp4":
        if not animation.writers.is_available("ffmpeg"):
            raise ViewError("", "--mp4", "ffmpeg is not installed (matplotlib writes MP4 through it); use --gif")
        writer = animation.FFMpegWriter(fps=fps)
    elif path.suffix == ".gif":
        writer = animation.PillowWriter(fps=fps)
    else:
        raise ViewError("", str(path), "an animation is a .gif or an .mp4")
    stream = frames(stage, rows)
    first = next(stream)
    fig = FrameFigure(stage, first)
    with writer.saving(fig.fig, str(path), dpi=fig.fig.dpi), progress_bar(rows.size, progress, "hydrolink view: animation") as bar:
        for frame in _chain(first, stream):
            fig.draw(frame)
            writer.grab_frame()
            bar.update(1)
    return path


def _chain(first: Frame, rest):
    yield first
    yield from rest
