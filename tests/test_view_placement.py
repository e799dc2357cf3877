"""hydrolink view's bodies (clients/view/placement.py, written by series.py through vtkhdf.py):
read back with VTK's own VTKHDF reader, every vertex at every written time is the rigid transform of
the mesh by the results' position row, written here independently (Exudyn's NodeRigidBodyRxyz:
R = Rx(roll) Ry(pitch) Rz(yaw), the angles the clients write), within 1e-9 m; the markers move
with their bodies; bad input is refused naming the file and key."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from conftest import body, linear_pto, regular_waves, scene_toml, write_gdf

vtk = pytest.importorskip("vtk")
from vtk.util.numpy_support import vtk_to_numpy  # noqa: E402

from hydrolink.clients.lockstep.results import ResultWriter  # noqa: E402
from hydrolink.clients.view.frames import ViewOptions  # noqa: E402
from hydrolink.clients.view.results import ViewError  # noqa: E402
from hydrolink.clients.view.series import view_results  # noqa: E402

EQ = np.array([[0.0, 0.0, -0.5, 0, 0, 0], [4.0, 1.0, -1.0, 0, 0, 0]])
#: a unit cube (8 vertices, 6 quads) about (0, 0, -0.5) and a box about (4, 1, -1)
CUBE_V = np.array([[x, y, z] for x in (-0.5, 0.5) for y in (-0.5, 0.5) for z in (-1.0, 0.0)])
CUBE_F = np.array([[0, 1, 3, 2], [4, 6, 7, 5], [0, 4, 5, 1], [2, 3, 7, 6], [0, 2, 6, 4], [1, 5, 7, 3]])


def rot(roll: float, pitch: float, yaw: float) -> np.ndarray:
    """Rx(roll) @ Ry(pitch) @ Rz(yaw), written out."""
    cr, sr, cp, sp, cy, sy = np.cos(roll), np.sin(roll), np.cos(pitch), np.sin(pitch), np.cos(yaw), np.sin(yaw)
    rx = np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]])
    ry = np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]])
    rz = np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1]])
    return rx @ ry @ rz


def poses(t: np.ndarray) -> np.ndarray:
    """(T, 2, 6) positions with large, distinct angles (a convention error shows at once)."""
    pos = np.repeat(EQ[None], t.size, axis=0).copy()
    for b in range(2):
        pos[:, b, :3] += np.column_stack([0.3 * np.sin(t + b), 0.2 * np.cos(2 * t), 0.5 * np.sin(0.7 * t)])
        pos[:, b, 3:] = np.column_stack([0.4 * np.sin(1.3 * t), -0.6 * np.cos(0.9 * t + b), 0.8 * np.sin(0.5 * t)])
    return pos


def results_file(folder: Path, t: np.ndarray, *, scene_bodies=("a", "b"), file_bodies=("a", "b")) -> Path:
    """A results file written by the run's own ResultWriter, for a scene whose bodies name mesh files."""
    write_gdf(folder / "a.gdf", CUBE_V, CUBE_F)               # centred on its reference point (0, 0, -0.5)
    write_gdf(folder / "b.gdf", CUBE_V * [2, 1, 1] + EQ[1, :3] + [0, 0, 0.5], CUBE_F)
    bodies = [body(n, hdb="none.nc", mass=1.0, center_of_mass=list(EQ[i, :3]), inertia=[1, 1, 1], mesh=f"{n}.gdf")
              for i, n in enumerate(scene_bodies)]
    text = scene_toml(dt=float(t[1] - t[0]), duration=float(t[-1]), bodies=bodies, waves=regular_waves(0.0, 5.0),
                      ptos=[linear_pto("pto", "a", [0.0, 0.0, -0.5], "b", [4.0, 1.0, -1.0], damping=1.0)])
    path = folder / "run.nc"
    pos, zero = poses(t), np.zeros((len(file_bodies), 6))
    with ResultWriter(path, scene_text=text, bodies=list(file_bodies), equilibrium_position=EQ[:len(file_bodies)],
                      dt=float(t[1] - t[0])) as w:
        for k, tk in enumerate(t):
            w.append(float(tk), pos[k, :len(file_bodies)], zero, zero, zero, zero, 0.0)
    return path


def read_series(path: Path) -> list[tuple[float, np.ndarray]]:
    """(time, points) of every step of a VTKHDF file, read by VTK."""
    reader = vtk.vtkHDFReader()
    reader.SetFileName(str(path))
    reader.UpdateInformation()
    out = []
    for t in reader.GetOutputInformation(0).Get(vtk.vtkStreamingDemandDrivenPipeline.TIME_STEPS()):
        reader.UpdateTimeStep(t)
        out.append((t, vtk_to_numpy(reader.GetOutput().GetPoints().GetData()).copy()))
    return out


def test_vertices_are_the_rigid_transform_at_every_time(tmp_path):
    t = np.arange(0.0, 3.0, 0.1)
    run = results_file(tmp_path, t)
    summary, _, rows = view_results(run, tmp_path / "view", ViewOptions(stride=3, parts=("bodies", "markers")),
                                    progress=False)
    assert summary.frames == rows.size == 10
    pos = poses(t)
    rest = {"a": CUBE_V, "b": CUBE_V * [2, 1, 1] + EQ[1, :3] + [0, 0, 0.5]}
    for b, name in enumerate("ab"):
        series = read_series(tmp_path / "view" / f"{name}.vtkhdf")
        assert [s[0] for s in series] == pytest.approx(t[::3], abs=1e-12)
        for (tk, pts), k in zip(series, range(0, t.size, 3)):
            want = pos[k, b, :3] + (rest[name] - EQ[b, :3]) @ rot(*pos[k, b, 3:]).T
            np.testing.assert_allclose(pts, want, rtol=0, atol=1e-9)
    markers = read_series(tmp_path / "view" / "markers.vtkhdf")
    for (tk, pts), k in zip(markers, range(0, t.size, 3)):
        np.testing.assert_allclose(pts[0], pos[k, 0, :3], atol=1e-9)    # pto.point1: body a's reference point
        np.testing.assert_allclose(pts[1], pos[k, 1, :3], atol=1e-9)    # pto.point2: body b's


def test_vertex_velocity_is_the_rigid_velocity(tmp_path):
    """The written point velocity against a central difference of the moved vertices."""
    from hydrolink.clients.view.placement import rigid_points, rigid_velocity
    p0, ref, h = CUBE_V, np.zeros(3), 1e-6
    pos = lambda s: poses(np.array([s]))[0, 0]     # noqa: E731
    vel = (pos(1.0 + h) - pos(1.0 - h)) / (2 * h)
    moved = rigid_points(p0, ref, pos(1.0))
    fd = (rigid_points(p0, ref, pos(1.0 + h)) - rigid_points(p0, ref, pos(1.0 - h))) / (2 * h)
    np.testing.assert_allclose(rigid_velocity(moved, pos(1.0), vel), fd, atol=1e-7)


def test_a_mesh_whose_body_is_not_in_the_results(tmp_path):
    run = results_file(tmp_path, np.arange(0.0, 1.0, 0.1), file_bodies=("a",))
    with pytest.raises(ViewError, match=r"bodies\[1\]\.mesh: the scene's body 'b' is not in the results file"):
        view_results(run, tmp_path / "view", ViewOptions(parts=("bodies",)), progress=False)


def test_results_without_positions(tmp_path):
    import xarray as xr
    path = tmp_path / "sweep.nc"
    xr.Dataset({"mean_power": ("case", [1.0, 2.0])}, attrs={"sweep_file": "x"}).to_netcdf(path)
    with pytest.raises(ViewError, match=r"sweep.nc: position: the file has no body positions over time.*cases/"):
        view_results(path, tmp_path / "view", progress=False)
