"""A flexible body's generalized modes on the mesh ``hydrolink view`` draws (issue 38): each
mode's shape at the hull's vertices, from the HDB build spec the body's modes were built with
(server/hdb/build/modes.py ``vertex_shapes``), and the vertices the run's modal coordinates
deform before the rigid motion moves them — x = p + R (v − r + Σ q_k φ_k(v)): linear modes,
displacements in the body's axes (docs/generalized-modes.md "Deformed mesh")."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import netCDF4
import numpy as np

from hydrolink.clients.scene_inputs import build_spec_of
from hydrolink.clients.view.results import ViewError
from hydrolink.protocol.scene import resolve_path
from hydrolink.server.allocation import require_size

if TYPE_CHECKING:
    from hydrolink.clients.view.results import RunFile


@dataclass(frozen=True)
class ModalShapes:
    """One body's modes on its drawn vertices: ``columns`` their positions in the results' ``mode``
    dimension, ``shapes`` (n, V, 3) each mode's displacement of the vertices per unit coordinate."""
    columns: np.ndarray
    shapes: np.ndarray

    def displacement(self, coordinates: np.ndarray) -> np.ndarray:
        """Σ_k q_k φ_k (V, 3), ``coordinates`` one row of the results' modal variable (every mode)."""
        return np.tensordot(coordinates[self.columns], self.shapes, axes=1)


def modal_shapes(run: "RunFile", i: int, vertices: np.ndarray) -> tuple[ModalShapes | None, str | None]:
    """The modes of ``run.scene.bodies[i]`` at its drawn ``vertices`` (its closed hull, global frame
    at rest), or None and a note saying why the body is drawn rigid (no modes: no note). ViewError
    naming ``bodies[i].modes.shapes`` when the spec's modes are not the body's; the shapes' size
    checked first (``require_size`` naming ``bodies[i].modes``)."""
    from hydrolink.server.hdb.build.modes import vertex_shapes
    from hydrolink.server.hdb.build.spec import SpecError, load_spec

    body = run.scene.bodies[i]
    if body.modes is None:
        return None, None
    spec_path = build_spec_of(run.scene, run.scene_path, i)
    if spec_path is None:
        return None, (f"bodies[{i}].modes.shapes: body {body.name!r} is drawn rigid: its HDB {body.hdb} is not a "
                      "build spec and no shapes name the one it was built from (its modes' shapes on the hull)")
    if "modal_position" not in run.variables:
        return None, f"bodies[{i}].modes: body {body.name!r} is drawn rigid: the results hold no modal_position"
    with netCDF4.Dataset(run.path, "r") as ds:
        labels = [str(v) for v in ds["mode"][:]]
    names = body.modes.names
    require_size(f"bodies[{i}].modes", "the deformed mesh's mode shapes (modes x vertices x 3)",
                 (len(names), len(vertices), 3), hint="draw fewer bodies (--parts) or a coarser mesh")
    spec = load_spec(spec_path)
    note = _shapes_source_note(run, i, spec, spec_path)
    index = next((k for k, b in enumerate(spec.all_bodies) if b.name == body.hdb_body_name), 0)
    try:     # a displacement table fits its mesh file's vertices only (not another bodies[i].mesh)
        fields = vertex_shapes(spec.all_bodies[index], spec.body_keys[index], vertices, spec_path)
    except SpecError as exc:
        raise ViewError(run.path, f"bodies[{i}].modes.shapes", f"the drawn hull's {len(vertices)} vertices: {exc}") from None
    unknown = [m for m in names if m not in fields or f"{body.name}.{m}" not in labels]
    if unknown:
        raise ViewError(run.path, f"bodies[{i}].modes.shapes", f"the modes {unknown} of body {body.name!r} are not "
                        f"among {spec_path.name}'s modes {list(fields)} and the results' {labels}")
    return ModalShapes(np.array([labels.index(f"{body.name}.{m}") for m in names]),
                       np.stack([fields[m] for m in names])), note


def _shapes_source_note(run: "RunFile", i: int, spec, spec_path: Path) -> str | None:
    """Whether ``bodies[i].modes.shapes`` is the spec the body's HDB file was built from: that
    HDB's ``build_spec_sha256`` (hydrolink's build records it) against the spec's build key; another
    spec is a ViewError naming the key (its shapes would be drawn on modal coordinates of other
    modes); an HDB that records none gets a note (the shapes drawn, not vouched for). None when the
    body's ``hdb`` is the spec itself or the HDB was built from ``shapes``."""
    from hydrolink.server.hdb.build.builder import cache_key

    body = run.scene.bodies[i]
    if body.hdb is None or body.hdb.endswith(".toml"):
        return None
    hdb_path = resolve_path(run.scene_path, body.hdb)
    recorded = None
    if hdb_path.suffix == ".nc" and hdb_path.is_file():
        with netCDF4.Dataset(hdb_path, "r") as ds:
            recorded = getattr(ds, "build_spec_sha256", None)
    if recorded is None:
        return (f"bodies[{i}].modes.shapes: body {body.name!r}'s HDB {body.hdb} records no build spec, so the "
                f"shapes of {spec_path.name} are drawn unchecked: they must be the modes it was built with")
    if str(recorded) != cache_key(spec, spec_path):
        raise ViewError(run.path, f"bodies[{i}].modes.shapes", f"{spec_path.name} is not the spec {body.hdb} was "
                        "built from (its build_spec_sha256 differs: another hull, modes or Capytaine version): name "
                        "the spec it was built from, or rebuild it (hydrolink hdb build)")
    return None
