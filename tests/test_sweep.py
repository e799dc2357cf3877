"""``hydrolink sweep``: cases on a real Dask LocalCluster (2 worker processes) and on a real
``dask scheduler`` + ``dask worker`` pair on loopback; per-case powers against the frequency-domain
P = 1/2 c w^2 |X|^2 of a heaving sphere with a damper PTO (from its HDB, in the test); steady
cases; resume after a killed sweep; a worker killed mid-case; failing cases; the power matrix and
AEP of an irregular sweep against MHKiT; bad sweep files."""

from __future__ import annotations

import json
import math
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from contextlib import ExitStack
from pathlib import Path

import numpy as np
import pytest
import xarray as xr
from click.testing import CliRunner

from conftest import EXIT_S
from conftest import SPHERE_WATER, irregular_waves, linear_pto, regular_waves, scene_toml, sphere_body, sweep_toml, write_scene
from hydrolink.clients.cli import cli
from hydrolink.clients.studies.sweep import open_cluster, run_sweep

# One pytest-xdist worker runs this whole module (pyproject: --dist loadgroup): its module fixtures (a Dask
# LocalCluster, the regular sweep run) cost ~11 s, paid once per worker otherwise.
pytestmark = pytest.mark.xdist_group("sweep")

MASS, HEIGHT, DT = 261.724e3, 1.0, 0.04
OMEGA_INDEX = (19, 27)                    # HDB grid frequencies 1.0 and 1.4 rad/s (no interpolation)
DAMPING = (1.0e5, 4.0e5)


@pytest.fixture(scope="module")
def sphere_hdb(sphere_path):
    from hydrolink.server.hdb.io import load_hdb
    return load_hdb(sphere_path)


@pytest.fixture(scope="module")
def periods(sphere_hdb) -> list[float]:
    w = sphere_hdb["omega"].values
    return [float(2 * math.pi / w[i]) for i in OMEGA_INDEX]


@pytest.fixture(scope="module")
def sphere_dir(tmp_path_factory, sphere_path) -> Path:
    """A sphere in heave with a damper to ground, regular waves (swept by the tests)."""
    folder = tmp_path_factory.mktemp("sphere_sweep")
    write_scene(folder, scene_toml(
        dt=DT, duration=130.0, water={**SPHERE_WATER, "gravity": 9.81},
        waves=regular_waves(HEIGHT, 6.0, ramp=10.0),
        bodies=[sphere_body(str(sphere_path), mass=MASS, dofs=["heave"])],
        ptos=[linear_pto("damper", "sphere", [0, 0, 0], "ground", [0, 0, -50], damping=2e5)]), "sphere.toml")
    return folder


def frequency_domain(hdb, i: int, c: float) -> tuple[complex, float]:
    """Heave amplitude X = F a / (-w^2 (m + A) - i w (B + c) + C) and P = 1/2 c w^2 |X|^2."""
    w = float(hdb["omega"].values[i])
    a = hdb["added_mass"].values[i, 2, 2]
    b = hdb["radiation_damping"].values[i, 2, 2]
    f = hdb["excitation_force"].values[i, 0, 2]
    k = hdb["hydrostatic_stiffness"].values[2, 2]
    x = f * HEIGHT / 2 / (-w ** 2 * (MASS + a) - 1j * w * (b + c) + k)
    return x, 0.5 * c * w ** 2 * abs(x) ** 2


@pytest.fixture(scope="module")
def local_client():
    """A LocalCluster of 2 worker processes as hydrolink sweep opens it (one thread each)."""
    with ExitStack() as stack:
        yield open_cluster(stack, 2, None)


@pytest.fixture(scope="module")
def regular_sweep(sphere_dir, periods, local_client, tmp_path_factory):
    """The CLI on a 2 x 2 regular sweep plus a case outside the HDB's range, on the module's LocalCluster
    of 2 by its address (``--scheduler``: a second cluster would cost the suite its start-up again)."""
    sweep = sphere_dir / "regular.toml"
    sweep.write_text(sweep_toml("sphere.toml", window=[60.0, 130.0], characteristic_width=10.0,
                                 grid={"waves.period": periods, "ptos.damper.damping": list(DAMPING)},
                                 cases=[{"label": "too long", "waves.period": 200.0}]))
    out = tmp_path_factory.mktemp("regular_out")
    r = CliRunner().invoke(cli, ["sweep", str(sweep), "-o", str(out), "--scheduler", local_client.scheduler.address,
                                 "--no-progress"],
                           catch_exceptions=False)
    return sweep, out, r


def test_regular_sweep_powers_against_frequency_domain(regular_sweep, sphere_hdb, periods):
    sweep, out, r = regular_sweep
    assert r.exit_code == 0, r.output
    assert "5 cases (0 finished before, 5 run, 1 failed: ['too long'])" in r.output
    ds = xr.load_dataset(out / "sweep.nc")
    assert set(ds["mean_total_pto_power"].dims) == {"waves.period", "ptos.damper.damping"}
    assert list(ds["ptos.damper.damping"].values) == [1e5, 2e5, 4e5]     # the grid's and the scene's (2e5)
    for i, period in zip(OMEGA_INDEX, periods):
        for c in DAMPING:
            cell = ds.sel({"waves.period": period, "ptos.damper.damping": c})
            x, p = frequency_domain(sphere_hdb, i, c)
            w = 2 * math.pi / period
            print(f"T {period:.3f} s, c {c:.0e}: P {float(cell.mean_total_pto_power):.1f} W vs {p:.1f} W")
            assert str(cell.status.values) == "complete" and int(cell.attempts) == 1
            assert float(cell.mean_total_pto_power) == pytest.approx(p, rel=0.005)
            assert float(cell.mean_pto_power.sel(pto="damper")) == float(cell.mean_total_pto_power)
            assert float(cell.motion_std.sel(body="sphere", dof="heave")) == pytest.approx(abs(x) / math.sqrt(2), rel=0.01)
            # the maximum excursion from equilibrium: amplitude plus the mean offset (the sphere's weight
            # is not exactly its buoyancy), the offset read from the case's own file: its tail, the last
            # 5 wave periods of the run at the run's sampling
            name = str(cell.case_name.values)
            assert name == f"case-{int(name[5:8]):03d}_waves.period={period:g}_ptos.damper.damping={c:g}".replace(
                "e+0", "e")
            with xr.open_dataset(out / "cases" / f"{name}.nc") as res:
                z = res.position.sel(body="sphere", dof="heave") - res.equilibrium_position.sel(body="sphere", dof="heave")
                offset = float(z.mean())
                t = res.time.values
                assert res.attrs["case_series"] == "tail" and float(res.attrs["tail_seconds"]) == pytest.approx(5 * period)
                assert t[-1] == pytest.approx(130.0) and t[-1] - t[0] == pytest.approx(5 * period, abs=DT)
                assert np.diff(t) == pytest.approx(DT)
                assert float(res.summary_mean_total_pto_power) == float(cell.mean_total_pto_power)
            assert float(cell.motion_max.sel(body="sphere", dof="heave")) == pytest.approx(abs(x) + abs(offset), rel=0.01)
            assert float(cell.max_pto_force.sel(pto="damper")) == pytest.approx(c * w * abs(x), rel=0.01)
            j = 1000.0 * 9.81 ** 2 * HEIGHT ** 2 * period / (32 * math.pi)        # deep water (200 m)
            assert float(cell.energy_flux) == pytest.approx(j, rel=1e-3)
            assert float(cell.capture_width) == pytest.approx(float(cell.mean_total_pto_power) / float(cell.energy_flux))
            assert float(cell.capture_width_ratio) == pytest.approx(float(cell.capture_width) / 10.0)
            assert 60.0 <= float(cell.window_start) < 60.0 + period and float(cell.window_end) == 130.0
            # the case's own files
            for suffix in (".toml", ".nc", ".json"):
                assert (out / "cases" / f"{name}{suffix}").is_file()
            assert json.loads((out / "cases" / f"{name}.json").read_text())["case_id"] == str(cell.case_id.values)
    failed = ds.where(ds.status == "failed", drop=True)
    assert failed.status.size == 1 and "waves.period" in str(failed.error.values.ravel()[0])
    assert int((ds.status == "absent").sum()) == 4      # 3 periods x 3 dampings, 5 cases
    records = [json.loads(p.read_text()) for p in (out / "cases").glob("*.json")]
    assert len(records) == 5
    assert len({json.dumps(rec["caches"], sort_keys=True) for rec in records}) == 1   # one cache folder each kind
    assert len({rec["worker"] for rec in records}) == 2                               # both workers worked
    for png in ("power_matrix.png", "capture_width.png"):
        assert (out / png).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert "regular: H, T" in ds.attrs["sea_state"]
    rows = (out / "cases.csv").read_text().splitlines()
    assert len(rows) == 6 and rows[0].startswith("label,waves.period,ptos.damper.damping,status")


def test_steady_cases_equal_the_frequency_domain(sphere_dir, periods, sphere_hdb, local_client, tmp_path):
    """solver = "steady": hydrolink steady per case (linear: its harmonic balance is the
    frequency-domain solution), power over its one period."""
    sweep = sphere_dir / "steady.toml"
    sweep.write_text(sweep_toml("sphere.toml", solver="steady", grid={"waves.period": periods, "ptos.damper.damping": list(DAMPING)}))
    report = run_sweep(sweep, tmp_path, client=local_client, progress=False, log_line=lambda m: None)
    assert (report.cases, report.run, report.failed) == (4, 4, [])
    ds = xr.load_dataset(tmp_path / "sweep.nc")
    assert set(ds.solver.values.ravel()) == {"steady"}
    for i, period in zip(OMEGA_INDEX, periods):
        for c in DAMPING:
            _, p = frequency_domain(sphere_hdb, i, c)
            got = float(ds.mean_total_pto_power.sel({"waves.period": period, "ptos.damper.damping": c}))
            assert got == pytest.approx(p, rel=1e-6)


def test_remote_scheduler_and_workers_same_results(regular_sweep, sphere_dir, tmp_path):
    """A separately started ``dask scheduler`` and two ``dask worker`` processes on loopback: the
    same sweep gives the same numbers bit for bit; a state-space setup is fitted once (warm-up) and
    read from the shared on-disk fit cache by every case."""
    sweep, local_out, _ = regular_sweep
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    fits = tmp_path / "fits"
    env = {**os.environ, "HYDROLINK_STATE_SPACE_CACHE": str(fits), "OPENBLAS_NUM_THREADS": "1"}
    dask_cmd = [sys.executable, "-m", "dask"]
    procs = [subprocess.Popen(dask_cmd + ["scheduler", "--host", "127.0.0.1", "--port", str(port), "--no-dashboard"],
                              env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)]
    address = f"tcp://127.0.0.1:{port}"
    try:
        for _ in range(2):
            procs.append(subprocess.Popen(dask_cmd + ["worker", address, "--nthreads", "1", "--no-dashboard"],
                                          env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                                          start_new_session=True))
        from distributed import Client
        with Client(address, timeout="30s") as client:
            client.wait_for_workers(2, timeout=60)
        out = tmp_path / "remote"
        r = CliRunner().invoke(cli, ["sweep", str(sweep), "-o", str(out), "--scheduler", address, "--no-progress"],
                               catch_exceptions=False)
        assert r.exit_code == 0, r.output
        a, b = xr.load_dataset(local_out / "sweep.nc"), xr.load_dataset(out / "sweep.nc")
        for name in a.data_vars:
            if name not in ("wall_time",):
                np.testing.assert_array_equal(a[name].values, b[name].values, err_msg=name)
        for name in a.case_name.values.ravel():
            if name and (local_out / "cases" / f"{name}.nc").exists():
                x, y = xr.load_dataset(local_out / "cases" / f"{name}.nc"), xr.load_dataset(out / "cases" / f"{name}.nc")
                np.testing.assert_array_equal(x["position"].values, y["position"].values)
        # state-space: the warm-up fits, the cases read the fit
        ss = sphere_dir / "state_space.toml"
        ss.write_text(sweep_toml("sphere.toml", set={"hydro.radiation": "state-space", "simulation.duration": 20.0},
                                  grid={"ptos.damper.damping": list(DAMPING)}))
        report = run_sweep(ss, tmp_path / "ss", scheduler=address, progress=False, log_line=lambda m: None)
        assert (report.run, report.failed, report.notes) == (2, [], [])
        assert report.cache_folders["state_space"] == [str(fits.resolve())]
        records = [json.loads(p.read_text()) for p in (tmp_path / "ss" / "cases").glob("*.json")]
        assert [rec["fitted_pairs"] for rec in records] == [0, 0]
        assert len(list(fits.glob("fit-*.npz"))) == 1
    finally:
        for p in procs[::-1]:
            os.killpg(p.pid, signal.SIGTERM)
        for p in procs:
            try:
                p.wait(EXIT_S)
            except subprocess.TimeoutExpired:
                os.killpg(p.pid, signal.SIGKILL)


def test_resume_after_a_killed_sweep_runs_only_the_missing_cases(sphere_dir, local_client, tmp_path):
    sweep = sphere_dir / "resume.toml"
    dampings = [1e5, 2e5, 3e5, 4e5, 5e5, 6e5]
    sweep.write_text(sweep_toml("sphere.toml", set={"simulation.duration": 40.0}, grid={"ptos.damper.damping": dampings}))
    out = tmp_path / "out"
    proc = subprocess.Popen([sys.executable, "-m", "hydrolink.clients.cli", "sweep", str(sweep), "-o", str(out),
                             "--workers", "1", "--no-progress"], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                            start_new_session=True, env={**os.environ, "OPENBLAS_NUM_THREADS": "1"})
    try:
        deadline = time.monotonic() + 120
        while len(list((out / "cases").glob("*.json"))) < 2:
            assert proc.poll() is None, proc.stderr.read().decode()
            assert time.monotonic() < deadline
            time.sleep(0.05)
    finally:
        os.killpg(proc.pid, signal.SIGKILL)      # the client, its cluster and its worker, at once
        proc.wait()
    done = {p.name: p.read_bytes() for p in (out / "cases").glob("*.json")}
    assert 2 <= len(done) < len(dampings)
    assert not (out / "sweep.nc").exists()
    lines = []
    report = run_sweep(sweep, out, client=local_client, progress=False, log_line=lines.append)
    assert (report.cases, report.skipped, report.run) == (6, len(done), 6 - len(done))
    assert f"{len(done)} finished before, {6 - len(done)} to run" in lines[0]
    for name, data in done.items():            # finished work untouched
        assert (out / "cases" / name).read_bytes() == data
    ds = xr.load_dataset(out / "sweep.nc")
    assert set(ds.status.values) == {"complete"} and np.isfinite(ds.mean_total_pto_power.values).all()
    again = run_sweep(sweep, out, client=local_client, progress=False, log_line=lambda m: None)
    assert (again.skipped, again.run) == (6, 0)


def test_a_case_whose_name_changes_is_found_by_its_key_and_renamed(sphere_dir, local_client, tmp_path):
    """Files are named by the case's index, keys and values; a value inserted before finished cases
    shifts their index: they are found by their key (in their record), not run again, and their
    files are renamed (bytes unchanged); only the new case runs."""
    sweep = sphere_dir / "rename.toml"
    fixed = {"simulation.duration": 30.0}
    sweep.write_text(sweep_toml("sphere.toml", set=fixed, grid={"ptos.damper.damping": [2e5, 3e5]}))
    first = run_sweep(sweep, tmp_path, client=local_client, progress=False, log_line=lambda m: None)
    assert (first.run, first.failed) == (2, [])
    cases = tmp_path / "cases"
    before = {p.name: p.read_bytes() for p in cases.glob("*.nc")}
    assert sorted(before) == ["case-000_ptos.damper.damping=200000.nc", "case-001_ptos.damper.damping=300000.nc"]
    sweep.write_text(sweep_toml("sphere.toml", set=fixed, grid={"ptos.damper.damping": [1e5, 2e5, 3e5]}))
    again = run_sweep(sweep, tmp_path, client=local_client, progress=False, log_line=lambda m: None)
    assert (again.skipped, again.run, again.failed) == (2, 1, [])
    stems = [f"case-00{i}_ptos.damper.damping={c}" for i, c in enumerate((100000, 200000, 300000))]
    assert sorted(p.name for p in cases.iterdir()) == sorted(f"{s}{x}" for s in stems for x in (".json", ".nc", ".toml"))
    assert (cases / f"{stems[1]}.nc").read_bytes() == before["case-000_ptos.damper.damping=200000.nc"]
    assert (cases / f"{stems[2]}.nc").read_bytes() == before["case-001_ptos.damper.damping=300000.nc"]
    assert [json.loads((cases / f"{s}.json").read_text())["name"] for s in stems] == stems
    ds = xr.load_dataset(tmp_path / "sweep.nc")
    assert list(ds.case_name.values) == stems and set(ds.status.values) == {"complete"}


def test_a_worker_killed_mid_case_has_its_case_run_once_more(sphere_dir, local_client, tmp_path):
    sweep = sphere_dir / "kill.toml"
    # 240 s: 6000 steps. The worker is killed as soon as the scheduler lists a case on it: a task listed on a
    # worker that dies is that worker's (KilledWorker) whether it has started or not, so the kill needs only
    # the case not to end in the few ms between the listing and the kill. A case takes far longer: 3 s on a
    # fresh worker, 0.3-0.4 s on one warmed by the module's earlier sweeps (2026-12-08; a fixed 0.5 s wait
    # before the kill let both warmed cases finish first, and nothing was retried)
    sweep.write_text(sweep_toml("sphere.toml", set={"simulation.duration": 240.0}, grid={"ptos.damper.damping": [1e5, 2e5]}))
    pids = local_client.run(os.getpid)
    killed: list[int] = []

    def kill_a_busy_worker() -> None:
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline and not killed:
            busy = [w for w, keys in local_client.processing().items() if any("hydrolink-case" in k for k in keys)]
            if busy:
                os.kill(pids[busy[0]], signal.SIGKILL)
                killed.append(pids[busy[0]])
            time.sleep(0.02)
    killer = threading.Thread(target=kill_a_busy_worker)
    killer.start()
    report = run_sweep(sweep, tmp_path, client=local_client, progress=False, log_line=lambda m: None)
    killer.join()
    assert killed and report.retried >= 1 and report.failed == []
    records = [json.loads(p.read_text()) for p in (tmp_path / "cases").glob("*.json")]
    assert sorted(rec["attempt"] for rec in records)[-1] == 2
    assert all(rec["status"] == "complete" for rec in records)
    local_client.wait_for_workers(2, timeout=60)     # the nanny restarted it


@pytest.mark.filterwarnings("ignore:.*IEC TS 62600-100 limit:UserWarning")
def test_irregular_sweep_power_matrix_and_aep_equal_mhkit(sphere_dir, sphere_path, local_client, tmp_path):
    """waves.hs x waves.te (the derived energy-period key) with a site scatter diagram: sweep.nc's
    power matrix and AEP against MHKiT's from the same cases, bins and occurrences."""
    perf = pytest.importorskip("mhkit.wave.performance", reason="mhkit (test dependency) not installed")
    scatter = sphere_dir / "scatter.csv"
    scatter.write_text("# illustrative occurrences (hours), test data\nhm0\\te,5.5,6.5,7.5\n"
                       "0.75,100,300,200\n1.25,50,400,350\n1.75,0,150,250\n")
    write_scene(sphere_dir, scene_toml(
        dt=0.05, duration=60.0, water={**SPHERE_WATER, "gravity": 9.81},
        waves=irregular_waves(1.0, 8.0, ramp=10.0, components=200),
        bodies=[sphere_body(str(sphere_path), mass=MASS, dofs=["heave"])],
        ptos=[linear_pto("damper", "sphere", [0, 0, 0], "ground", [0, 0, -50], damping=2e5)]), "irregular_scene.toml")
    sweep = sphere_dir / "irregular.toml"
    # the checks compare sweep.nc's post-processing with MHKiT's of the same cases' powers: any run length
    # does (60 s; was 120 s)
    sweep.write_text(sweep_toml("irregular_scene.toml", window=[20.0, 60.0],
                                 grid={"waves.hs": [0.75, 1.25], "waves.te": [6.5, 7.5]},
                                 site={"scatter": "scatter.csv"}))
    report = run_sweep(sweep, tmp_path, client=local_client, progress=False, log_line=lambda m: None)
    assert (report.run, report.failed) == (4, [])
    ds = xr.load_dataset(tmp_path / "sweep.nc")
    assert "JONSWAP (gamma 3.3)" in ds.attrs["sea_state"] and "0.9033 Tp" in ds.attrs["sea_state"]
    np.testing.assert_allclose(ds.sea_state_period.values, np.broadcast_to(ds["waves.te"].values, (2, 2)), rtol=1e-7)
    np.testing.assert_allclose(ds.sea_state_height.values.T, np.broadcast_to(ds["waves.hs"].values, (2, 2)), rtol=1e-7)
    h, t = ds.sea_state_height.values.ravel(), ds.sea_state_period.values.ravel()
    p, j = ds.mean_total_pto_power.values.ravel(), ds.energy_flux.values.ravel()
    hc, tc = ds["hm0"].values, ds["te"].values
    cwm = perf.capture_width_matrix(h, t, p / j, "mean", hc, tc, to_pandas=False)
    jm = perf.wave_energy_flux_matrix(h, t, j, "mean", hc, tc, to_pandas=False)
    np.testing.assert_allclose(ds.power_matrix.values, perf.power_matrix(cwm, jm).values, rtol=1e-12)
    occ = ds.occurrence.values
    freq = xr.DataArray(occ, dims=cwm.dims, coords=cwm.coords)
    aep = perf.mean_annual_energy_production_matrix(cwm, jm, freq)
    assert float(ds.annual_energy) == pytest.approx(float(aep), rel=1e-12)
    assert float(ds.uncovered_occurrence) == pytest.approx(1 - (300 + 200 + 400 + 350) / 1800)
    assert (tmp_path / "power_matrix.png").is_file() and (tmp_path / "capture_width.png").is_file()


class _Stream:
    """A stderr that is, or is not, a terminal, keeping what is written to it."""

    def __init__(self, tty: bool):
        self.tty, self.text = tty, ""

    def isatty(self) -> bool:
        return self.tty

    def write(self, s: str) -> int:
        self.text += s
        return len(s)

    def flush(self) -> None:
        pass


@pytest.mark.parametrize("tty", [False, True])
def test_progress_bars_draw_only_on_a_terminal(tty, monkeypatch):
    """The run's and the sweep's tqdm bars write nothing to a stderr that is not a terminal (a CI
    log, a pipe: no carriage-return redraws), and draw on one that is; off when not asked for."""
    from hydrolink.clients.lockstep.driver import progress_bar
    from hydrolink.clients.studies.sweep import _Progress
    for enabled in (True, False):
        stream = _Stream(tty)
        monkeypatch.setattr(sys, "stderr", stream)
        bar = progress_bar(50, enabled)
        for _ in range(50):
            bar.update(1)
        bar.close()
        sweep = _Progress(4, enabled)
        for _ in range(4):
            sweep.update(done=1, running=0)
        sweep.close()
        monkeypatch.undo()
        drawn = tty and enabled
        assert ("\r" in stream.text) == drawn, repr(stream.text)
        assert ("50/50" in stream.text and "4/4" in stream.text) == drawn, repr(stream.text)
