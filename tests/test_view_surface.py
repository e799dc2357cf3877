"""hydrolink view's free surface (clients/view/surface.py): read back with VTK's reader, the incident
elevation at every grid point and written time equals the wave elevation computed here from the
run's components (the force server's own ``wave_components``: a spread irregular sea, every
component with its own heading; deep-water dispersion written here) within 1e-9 m; a grid too
large to allocate is refused naming --grid-cells and the limit; a steady file's wave has no ramp."""

from __future__ import annotations

import numpy as np
import pytest

from conftest import irregular_waves
from test_view_placement import read_series, results_file

vtk = pytest.importorskip("vtk")

from hydrolink.clients.view.frames import ViewOptions  # noqa: E402
from hydrolink.clients.view.results import ViewError, open_run  # noqa: E402
from hydrolink.clients.view.series import view_results  # noqa: E402
from hydrolink.server.errors import ModelError  # noqa: E402
from hydrolink.server.sea.waves import wave_components  # noqa: E402


def _with_waves(path, waves_table: str) -> None:
    """Replace the results file's scene [waves] table and its wave_elevation with that sea's."""
    import netCDF4
    with netCDF4.Dataset(path, "a") as ds:
        text = ds.getncattr("scene")
        head, rest = text.split("[waves]\n", 1)
        tail = rest[rest.index("\n[") + 1:]
        ds.setncattr("scene", head + waves_table + tail)
    run = open_run(path)
    comps = wave_components(run.scene.waves, 0.0, np.inf)
    with netCDF4.Dataset(path, "a") as ds:
        t = ds["time"][:]
        ramp = np.where(t < comps.ramp, 0.5 * (1 - np.cos(np.pi * t / comps.ramp)), 1.0) if comps.ramp else 1.0
        ds["wave_elevation"][:] = ramp * (comps.amplitude[None] * np.cos(
            np.outer(t, comps.omega) - comps.phase[None])).sum(axis=1)


def test_incident_elevation_on_the_grid(tmp_path):
    from conftest import toml_document
    run = results_file(tmp_path, np.arange(0.0, 4.0, 0.25))
    sea = irregular_waves(1.5, 6.0, components=12, spreading="cos2s", s=4.0, directions=3, direction=20.0,
                          omega_range=[0.5, 2.0], ramp=2.0, seed=3)
    _with_waves(run, toml_document({"waves": sea}))
    summary, stage, rows = view_results(run, tmp_path / "view", ViewOptions(stride=2, extent=(-30, 40, -20, 25),
                                        cells=(14, 9), parts=("surface",)), progress=False)
    comps = wave_components(open_run(run).scene.waves, 0.0, np.inf)
    assert comps.size == 36 and len(set(comps.heading_of())) == 3
    series = read_series(tmp_path / "view" / "free_surface.vtkhdf")
    assert len(series) == rows.size == 8
    k = comps.omega ** 2 / 9.81                                          # deep water
    for t, pts in series:
        x, y = pts[:, 0], pts[:, 1]
        theta = (k[None] * (np.outer(x, np.cos(comps.heading_of())) + np.outer(y, np.sin(comps.heading_of())))
                 - comps.omega[None] * t + comps.phase[None])
        ramp = 0.5 * (1 - np.cos(np.pi * min(t, 2.0) / 2.0))
        eta = ramp * (comps.amplitude[None] * np.cos(theta)).sum(axis=1)
        np.testing.assert_allclose(pts[:, 2], eta, rtol=0, atol=1e-9)
    assert np.ptp(series[-1][1][:, 2]) > 0.5                          # a real sea, not zeros
    assert sorted(np.unique(series[0][1][:, 0]).round(9)) == pytest.approx(np.linspace(-30, 40, 15))


def test_a_scene_not_the_runs_is_refused(tmp_path):
    """Components that do not reproduce the file's wave_elevation (another scene folder's HDBs)."""
    import netCDF4
    run = results_file(tmp_path, np.arange(0.0, 2.0, 0.25))
    with netCDF4.Dataset(run, "a") as ds:
        text = ds.getncattr("scene").replace("height = 0.0", "height = 1.0")
        ds.setncattr("scene", text)
    with pytest.raises(ViewError, match=r"run.nc: wave_elevation: the waves rebuilt .* --scene-dir"):
        view_results(run, tmp_path / "view", ViewOptions(parts=("surface",)), progress=False)


def test_a_grid_of_a_billion_points(tmp_path):
    run = results_file(tmp_path, np.arange(0.0, 1.0, 0.25))
    with pytest.raises(ModelError, match=r"--grid-cells: the free-surface grid's .* over the .* a set-up array may take; "
                                         r"fewer --grid-cells"):
        view_results(run, tmp_path / "view", ViewOptions(cells=(40000, 25000), parts=("surface",)), progress=False)


def test_a_steady_file_has_the_wave_after_its_ramp(tmp_path):
    """``hydrolink steady`` writes one period of the steady state: its wave is the ramped-up one."""
    import netCDF4
    t = np.arange(0.0, 5.0, 0.25)
    run = results_file(tmp_path, t)
    with netCDF4.Dataset(run, "a") as ds:
        text = ds.getncattr("scene").replace("height = 0.0", "height = 1.0\nramp = 50.0")
        ds.setncattr("scene", text)
        ds.setncattr("steady_period", 5.0)
        ds["wave_elevation"][:] = 0.5 * np.cos(2 * np.pi / 5.0 * t)
    view_results(run, tmp_path / "view", ViewOptions(extent=(-10, 10, -5, 5), cells=(4, 2), parts=("surface",)),
                 progress=False)
    k = (2 * np.pi / 5.0) ** 2 / 9.81
    for tk, pts in read_series(tmp_path / "view" / "free_surface.vtkhdf"):
        np.testing.assert_allclose(pts[:, 2], 0.5 * np.cos(k * pts[:, 0] - 2 * np.pi / 5.0 * tk), atol=1e-9)


@pytest.mark.parametrize("extent", [(0, float("inf"), 0, 1), (0, 1e300, -1e300, 1), (0, float("nan"), 0, 1),
                                    (5, 5, 0, 1), (0, 1, 2, -2)])
def test_a_grid_extent_not_a_box_of_finite_metres_is_refused_naming_it(extent):
    """--grid-extent with an infinite, NaN, astronomical or empty side (inf and 1e300 were taken: the
    cylinder's view wrote its 6001 frames on such a grid) is an error naming the option, before any
    file is read."""
    with pytest.raises(ViewError, match=r"--grid-extent: .*x0 < x1 and y0 < y1"):
        ViewOptions(extent=extent)
