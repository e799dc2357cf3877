"""The bodies' meshes and their rigid motion: each mesh (global frame at equilibrium) moved by the
run's ``position`` row (reference point xyz, Tait-Bryan angles roll, pitch, yaw with
R = Rx(roll) Ry(pitch) Rz(yaw): Exudyn's ``NodeRigidBodyRxyz``, what the clients write), and each
vertex's velocity from the row's ``velocity`` (angle rates turned into the angular velocity)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from hydrolink.clients.scene_inputs import build_spec_of, load_body_hull
from hydrolink.clients.view.deformation import ModalShapes, modal_shapes
from hydrolink.clients.view.results import RunFile, ViewError
from hydrolink.server.terms.nonlinear.hull import rotation_xyz

VTK_TRIANGLE, VTK_QUAD = 5, 9


@dataclass(frozen=True)
class BodyMesh:
    """One body's mesh: ``row`` its index in the results' ``body`` dimension, ``vertices`` (V, 3)
    in the global frame at equilibrium, ``reference`` (3,) the reference point there, and the cells
    as VTK wants them (``connectivity``, ``offsets`` (F + 1,), ``types`` (F,))."""
    name: str
    row: int
    vertices: np.ndarray
    reference: np.ndarray
    connectivity: np.ndarray
    offsets: np.ndarray
    types: np.ndarray
    shapes: ModalShapes | None = None    # the body's modes' displacement of the vertices (None: rigid)

    @property
    def n_cells(self) -> int:
        return int(self.types.size)


def cells_of(faces: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Capytaine's (F, 4) faces (a triangle repeats its last vertex) as VTK cells: connectivity,
    offsets and types (triangles and quads)."""
    faces = np.asarray(faces, np.int64)
    tri = faces[:, 3] == faces[:, 2]
    sizes = np.where(tri, 3, 4)
    connectivity = np.concatenate([f[:n] for f, n in zip(faces, sizes)]) if faces.size else np.zeros(0, np.int64)
    offsets = np.concatenate([[0], np.cumsum(sizes)]).astype(np.int64)
    return connectivity, offsets, np.where(tri, VTK_TRIANGLE, VTK_QUAD).astype(np.uint8)


def body_meshes(run: RunFile) -> tuple[list[BodyMesh], list[str]]:
    """The mesh of every wet scene body (its ``mesh`` file or its HDB build spec's closed hull), and
    a note for each body without one (an HDB file and no ``mesh``: not drawn); ViewError naming
    ``bodies[i].mesh`` when the body is not in the results file. Dry bodies (no HDB, no mesh) are
    not drawn."""
    out, notes = [], []
    for i, body in enumerate(run.scene.bodies):
        if not body.wet:
            continue
        if body.name not in run.bodies:
            raise ViewError(run.path, f"bodies[{i}].mesh", f"the scene's body {body.name!r} is not in the "
                            f"results file (its bodies: {list(run.bodies)})")
        if body.mesh is None and build_spec_of(run.scene, run.scene_path, i) is None:
            notes.append(f"bodies[{i}].mesh: body {body.name!r} is not drawn: its HDB {body.hdb} is not a build spec "
                         "to take its hull from; name its closed hull's mesh file (global frame at equilibrium)")
            continue
        vertices, faces = load_body_hull(run.scene, run.scene_path, i, "to be drawn")
        vertices = np.asarray(vertices, float)
        row = run.bodies.index(body.name)
        shapes, note = modal_shapes(run, i, vertices)
        notes += [note] if note else []
        out.append(BodyMesh(body.name, row, vertices, run.equilibrium[row, :3].copy(), *cells_of(faces), shapes))
    return out, notes


def rigid_points(points: np.ndarray, reference: np.ndarray, position: np.ndarray) -> np.ndarray:
    """``points`` (P, 3), given at equilibrium with the body's reference point at ``reference``,
    moved to the pose ``position`` (6,): x = position[:3] + R(position[3:]) (p - reference)."""
    rot = rotation_xyz(position[3:])
    return position[:3] + (points - reference) @ rot.T


def angular_velocity(angles: np.ndarray, rates: np.ndarray) -> np.ndarray:
    """Angular velocity (global axes) of R = Rx(a) Ry(b) Rz(c) turning at the angle rates
    (a', b', c'): w = a' e_x + b' Rx(a) e_y + c' Rx(a) Ry(b) e_z."""
    a, b, _ = angles
    ey = np.array([0.0, np.cos(a), np.sin(a)])
    ez = np.array([np.sin(b), -np.sin(a) * np.cos(b), np.cos(a) * np.cos(b)])
    return rates[0] * np.array([1.0, 0.0, 0.0]) + rates[1] * ey + rates[2] * ez


def rigid_velocity(moved: np.ndarray, position: np.ndarray, velocity: np.ndarray) -> np.ndarray:
    """Velocity (P, 3) of the moved points: v + w x (x - x_ref)."""
    omega = angular_velocity(position[3:], velocity[3:])
    return velocity[:3] + np.cross(omega, moved - position[:3])
