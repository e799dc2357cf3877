"""What is drawn beside the bodies: PTO and joint points moved with their bodies, the controllers'
wave gauges riding the incident wave, and MoorDyn's lines from the results' ``line_node_position``."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from hydrolink.clients.view.placement import rigid_points
from hydrolink.clients.view.results import RunFile, read_rows

VTK_VERTEX, VTK_POLY_LINE = 1, 4
KINDS = ("pto", "joint", "wave_gauge")


@dataclass(frozen=True)
class Marker:
    """A point of kind ``kind`` (one of KINDS): ``point`` (3,) at equilibrium on the results'
    body row ``row`` (None: fixed, ground or a wave gauge)."""
    name: str
    kind: str
    point: np.ndarray
    row: int | None


def scene_markers(run: RunFile) -> tuple[list[Marker], list[str]]:
    """The markers of the scene, and a note for each one left out (on a body the results do not
    hold: a dry body's motion is not in the file)."""
    scene, out, left = run.scene, [], []

    def on(body: str, point, name: str, kind: str) -> None:
        if body == "ground":
            out.append(Marker(name, kind, np.asarray(point, float), None))
        elif body in run.bodies:
            out.append(Marker(name, kind, np.asarray(point, float), run.bodies.index(body)))
        else:
            left.append(f"{kind} {name}: on body {body!r}, whose motion the results file does not hold")
    for pto in scene.ptos:
        name = pto.name
        if pto.type == "linear":
            on(pto.body1, pto.point1, f"{name}.point1", "pto")
            if pto.point2 is not None:
                on(pto.body2, pto.point2, f"{name}.point2", "pto")
        else:
            on(pto.body1, pto.point, name, "pto")
    for i, joint in enumerate(scene.joints):
        on(joint.body1, joint.point, joint.name or f"joint{i}", "joint")
    for c in scene.controllers:
        if "wave_elevation" in c.measurements:
            out += [Marker(f"{c.name}.gauge{j}", "wave_gauge", np.array([x, y, 0.0]), None)
                    for j, (x, y) in enumerate(c.wave_points)]
    return out, left


def marker_points(markers: list[Marker], run: RunFile, position: np.ndarray,
                  gauge_eta: np.ndarray | None) -> np.ndarray:
    """The markers' points (M, 3) at one frame: ``position`` (B, 6) that frame's row,
    ``gauge_eta`` the incident elevation at the wave gauges (in their order)."""
    pts = np.array([m.point for m in markers], float).reshape(-1, 3)
    g = 0
    for k, m in enumerate(markers):
        if m.row is not None:
            pts[k] = rigid_points(m.point[None], run.equilibrium[m.row, :3], position[m.row])[0]
        elif m.kind == "wave_gauge" and gauge_eta is not None:
            pts[k, 2] = gauge_eta[g]
            g += 1
    return pts


@dataclass(frozen=True)
class MooringLines:
    """MoorDyn lines as poly-lines over the nodes each line has (``line_node_position`` is NaN
    past a line's last node): ``index`` the (line, node) pairs drawn, in order."""
    index: tuple[np.ndarray, np.ndarray]
    connectivity: np.ndarray
    offsets: np.ndarray
    types: np.ndarray

    @property
    def n_points(self) -> int:
        return int(self.index[0].size)


def mooring_lines(run: RunFile) -> MooringLines | None:
    """The lines of the file's ``line_node_position`` (None when it has none)."""
    if "line_node_position" not in run.variables:
        return None
    first = read_rows(run.path, ["line_node_position"], np.array([0]))["line_node_position"][0]
    valid = np.all(np.isfinite(first), axis=-1)                  # (line, node)
    valid &= (valid.sum(axis=1) > 1)[:, None]                    # a line needs two nodes
    lines, nodes = np.nonzero(valid)
    counts = valid.sum(axis=1)
    counts = counts[counts > 0]
    if counts.size == 0:
        return None
    offsets = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
    return MooringLines((lines, nodes), np.arange(offsets[-1], dtype=np.int64), offsets,
                        np.full(counts.size, VTK_POLY_LINE, np.uint8))
