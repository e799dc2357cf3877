"""hydrolink view's MoorDyn lines and wave gauges (clients/view/markers.py): read back with VTK's
reader, the moorings file holds at every written time the results' ``line_node_position`` nodes of
each line (NaN past a line's last node left out), one poly-line per line; a controller's wave gauges
ride the incident wave at their points."""

from __future__ import annotations

import numpy as np
import pytest

from conftest import body, linear_pto, regular_waves, scene_toml

vtk = pytest.importorskip("vtk")

from hydrolink.clients.lockstep.results import ResultWriter  # noqa: E402
from hydrolink.clients.view.frames import ViewOptions  # noqa: E402
from hydrolink.clients.view.series import view_results  # noqa: E402
from vtk.util.numpy_support import vtk_to_numpy  # noqa: E402


def vtk_steps(path):
    """(time, the grid at that time) of every step of a VTKHDF file, read by VTK's reader (the grid
    is the reader's output: read it before the next step)."""
    reader = vtk.vtkHDFReader()
    reader.SetFileName(str(path))
    reader.UpdateInformation()
    for tk in reader.GetOutputInformation(0).Get(vtk.vtkStreamingDemandDrivenPipeline.TIME_STEPS()):
        reader.UpdateTimeStep(tk)
        yield tk, reader.GetOutput()


def nodes(t: float) -> np.ndarray:
    """(2 lines, 5 nodes, xyz): line 0 has 5 nodes, line 1 three (then NaN)."""
    out = np.full((2, 5, 3), np.nan)
    s = np.linspace(0, 1, 5)
    out[0] = np.column_stack([100 * s, 5 * np.sin(t) * s, -50 + 50 * s ** 2])
    s3 = np.linspace(0, 1, 3)
    out[1, :3] = np.column_stack([-80 * s3, 2 * np.cos(t) * s3, -50 + 45 * s3])
    return out


def test_lines_are_the_recorded_nodes(tmp_path):
    t = np.arange(0.0, 2.0, 0.2)
    text = scene_toml(dt=0.2, duration=2.0, waves=regular_waves(0.0, 5.0),
                      bodies=[body("a", hdb="none.nc", mass=1.0, center_of_mass=[0, 0, 0], inertia=[1, 1, 1])])
    zero = np.zeros((1, 6))
    with ResultWriter(tmp_path / "run.nc", scene_text=text, bodies=["a"], equilibrium_position=zero, dt=0.2) as w:
        w.add_variable("line_node_position", ("line", "node", "xyz"),
                       {"line": ["spread:1", "spread:2"], "node": [str(i) for i in range(5)], "xyz": ["x", "y", "z"]}, "m")
        for tk in t:
            w.stage_extra({"line_node_position": nodes(tk)})
            w.append(float(tk), zero, zero, zero, zero, zero, 0.0)
    summary, stage, rows = view_results(tmp_path / "run.nc", tmp_path / "view", ViewOptions(parts=("moorings",)),
                                        progress=False)
    seen = 0
    for tk, out in vtk_steps(tmp_path / "view" / "moorings.vtkhdf"):
        seen += 1
        assert out.GetNumberOfCells() == 2 and out.GetCellType(0) == vtk.VTK_POLY_LINE
        want = nodes(tk)
        pts = vtk_to_numpy(out.GetPoints().GetData())
        np.testing.assert_allclose(pts, np.concatenate([want[0], want[1, :3]]), atol=1e-12)
        assert [out.GetCell(c).GetNumberOfPoints() for c in range(2)] == [5, 3]
    assert seen == t.size


def test_wave_gauges_ride_the_incident_wave(tmp_path):
    """Gauges at a controller's ``wave_points``: z = a cos(k (x cos b + y sin b) - w t + phi), deep
    water k = w^2 / g, written here, within 1e-9 m at every frame."""
    height, period, phase, direction = 1.2, 6.0, 25.0, 30.0
    gauges = [[3.0, -2.0], [-5.0, 1.0]]
    t = np.arange(0.0, 3.0, 0.25)
    text = scene_toml(dt=0.25, duration=float(t[-1]), water={"density": 1025.0, "gravity": 9.81, "depth": "inf"},
                      waves=regular_waves(height, period, phase=phase, direction=direction),
                      bodies=[body("a", hdb="none.nc", mass=1.0, center_of_mass=[0, 0, 0], inertia=[1, 1, 1])],
                      ptos=[linear_pto("pto", "a", [0.0, 0.0, 0.0], "ground", [0.0, 0.0, -10.0], damping=1.0)],
                      controllers=[{"name": "ctl", "ptos": ["pto"], "measurements": ["wave_elevation"],
                                    "wave_points": gauges}])
    w_, a, phi, b = 2 * np.pi / period, height / 2, np.radians(phase), np.radians(direction)
    k = w_ ** 2 / 9.81
    zero = np.zeros((1, 6))
    with ResultWriter(tmp_path / "run.nc", scene_text=text, bodies=["a"], equilibrium_position=zero, dt=0.25) as w:
        for tk in t:
            w.append(float(tk), zero, zero, zero, zero, zero, float(a * np.cos(-w_ * tk + phi)))
    summary, stage, rows = view_results(tmp_path / "run.nc", tmp_path / "view", ViewOptions(parts=("markers",)),
                                        progress=False)
    seen = 0
    for tk, out in vtk_steps(tmp_path / "view" / "markers.vtkhdf"):
        seen += 1
        kind = vtk_to_numpy(out.GetPointData().GetArray("kind"))
        pts = vtk_to_numpy(out.GetPoints().GetData())[kind == 2]
        want = [a * np.cos(k * (x * np.cos(b) + y * np.sin(b)) - w_ * tk + phi) for x, y in gauges]
        np.testing.assert_allclose(pts[:, :2], gauges, atol=1e-12)
        np.testing.assert_allclose(pts[:, 2], want, atol=1e-9)
    assert seen == t.size
