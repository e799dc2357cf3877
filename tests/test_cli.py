"""The `hydrolink` command end to end: run embedded vs against a separately started `hydrolink serve`,
`hdb info`, and one-line errors for bad input."""

from __future__ import annotations

import hashlib
import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import xarray as xr

from conftest import EXIT_S, SPHERE_WATER, cli_here, irregular_waves, scene_toml, serve_process, sphere_body, stopped, write_scene

from hydrolink.clients.run import run_scene_file

HYDROLINK = [sys.executable, "-m", "hydrolink.clients.cli"]

def sphere_scene(*, hdb: str = "sphere.h5", mass: float = 261800.0, **body_keys) -> str:
    """The CLI's scene: the Task-10 sphere in irregular waves; ``body_keys`` add to the body's keys."""
    return scene_toml(dt=0.05, duration=12.0, progress=False, water=SPHERE_WATER,
                      waves=irregular_waves(1.0, 5.0, seed=7, components=80, ramp=3.0), hydro={"irf_duration": 10.0},
                      bodies=[sphere_body(hdb, mass=mass, center_of_mass=[0, 0, -2],
                                          dofs=["surge", "heave", "pitch"],
                                          initial_displacement=[0, 0, 0.3, 0, 0, 0], **body_keys)])


@pytest.fixture()
def scene_dir(tmp_path: Path, reference_data: Path) -> Path:
    shutil.copy(reference_data / "sphere_task10" / "sphere.h5", tmp_path / "sphere.h5")
    write_scene(tmp_path, sphere_scene())
    return tmp_path


def _cli(*args: str, cwd: Path, timeout: float = 120) -> subprocess.CompletedProcess:
    env = dict(os.environ, MPLBACKEND="Agg")
    return subprocess.run([*HYDROLINK, *args], cwd=cwd, capture_output=True, text=True, timeout=timeout, env=env)


def test_remote_server_run_equals_embedded_run(scene_dir: Path):
    """Deterministic lockstep: the same scene against `hydrolink serve` over TCP equals the embedded run."""
    embedded = run_scene_file(scene_dir / "scene.toml", scene_dir / "embedded.nc", progress=False)
    assert embedded.status == "complete"

    server = subprocess.Popen([*HYDROLINK, "serve", "--bind", "tcp://127.0.0.1:*"], cwd=scene_dir,
                              stderr=subprocess.PIPE, text=True)
    try:
        line = server.stderr.readline()
        match = re.search(r"listening on (tcp://\S+)", line)
        assert match, f"serve printed {line!r}"
        result = _cli("run", "scene.toml", "-o", "remote.nc", "--server", match.group(1), "--no-progress",
                      cwd=scene_dir)
        assert result.returncode == 0, result.stderr
    finally:
        stopped(server)
    a, b = xr.load_dataset(scene_dir / "embedded.nc"), xr.load_dataset(scene_dir / "remote.nc")
    assert a.sizes["time"] == b.sizes["time"] == 241
    for name in ("position", "velocity", "excitation_force", "radiation_force", "hydrostatic_force",
                 "wave_elevation"):
        scale = max(float(np.abs(a[name]).max()), 1e-30)
        diff = float(np.abs(a[name] - b[name]).max())
        assert diff <= 1e-9 * scale, f"{name}: max difference {diff:g} (scale {scale:g})"
    assert float(np.abs(a["position"].sel(dof="surge") - a["equilibrium_position"].sel(dof="surge")).max()) > 1e-4


def test_run_with_hdb_files_uploads_once_and_equals_the_map_run(scene_dir: Path, tmp_path_factory):
    """`hydrolink run --server ... --hdb-files` against `hydrolink serve --store DIR`: the first run
    uploads the sphere's file, the next, after the server restarts on the same store, nothing; both
    equal a run that sent the converted HDB, bit for bit."""
    store = tmp_path_factory.mktemp("cli_store")

    outputs = {}
    for restart in (False, True):
        with serve_process("--store", str(store), cwd=scene_dir) as address:
            runs = (("files again", ["--hdb-files"]),) if restart else (("map", []), ("files", ["--hdb-files"]))
            for name, flag in runs:
                out = f"{name.replace(' ', '_')}{int(restart)}.nc"
                result = _cli("run", "scene.toml", "-o", out, "--server", address, "--no-progress", *flag, cwd=scene_dir)
                assert result.returncode == 0, result.stderr
                outputs[name, restart] = xr.load_dataset(scene_dir / out)
                if flag:
                    uploaded = 0 if restart else 1
                    assert f"{uploaded} content(s) uploaded" in result.stdout, result.stdout
    assert [p.name for p in store.iterdir()] == [hashlib.sha256(
        (scene_dir / "sphere.h5").read_bytes()).hexdigest()]
    ref = outputs["map", False]
    for key, ds in outputs.items():
        for name in ("position", "velocity", "excitation_force", "radiation_force", "hydrostatic_force"):
            assert np.array_equal(ref[name].values, ds[name].values), (key, name)
    assert cli_here("run", "scene.toml", "--hdb-files", cwd=scene_dir).stderr.strip().endswith(
        "--hdb-files is for a remote server (the embedded one reads the files itself): give --server")


def test_serve_direct_port_is_offered_and_one_in_use_is_one_clear_line(tmp_path: Path):
    """`serve --direct-port P` offers P in the multibody welcome (a client steps over a TCP
    connection to it, on loopback too); a second serve given the same port says so in one line
    and exits 2, as a bad option."""
    import socket

    from analytic_hdb import make_body_hdb
    from conftest import body, regular_waves

    from hydrolink.clients.lockstep.connection import ServerConnection

    with socket.socket() as probe:   # a port free a moment ago
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    scene = scene_toml(dt=0.05, duration=10.0, waves=regular_waves(1.0, 6.0), hydro={"irf_duration": 4.0},
                       bodies=[body("float", hdb="float.nc", mass=3.0e5, center_of_mass=[0, 0, -1],
                                    inertia=[1e7, 1e7, 2e7])])
    with serve_process("--direct-port", str(port), cwd=tmp_path) as address:
        with ServerConnection(address, timeout=EXIT_S) as conn:   # a fresh serve's first set-up: seconds under load
            conn.hello(scene, {"float.nc": make_body_hdb()})
            assert conn._direct is not None and conn._direct.sock.getpeername()[1] == port
            conn.step(0, 0.0, np.zeros((1, 6)), np.zeros((1, 6)))
            assert conn._direct is not None   # the step went over it
        taken = cli_here("serve", "--bind", "tcp://127.0.0.1:*", "--direct-port", str(port), cwd=tmp_path)
        bound = cli_here("serve", "--bind", address, cwd=tmp_path)   # the ZeroMQ port in use: the same
    assert taken.returncode == 2
    assert taken.stderr == f"Error: --direct-port: no direct channel on port {port} of 127.0.0.1: Address already in use\n"
    assert bound.returncode == 2 and bound.stderr == f"Error: --bind: cannot listen on {address}: Address already in use\n"


def _children(pid: int) -> set[int]:
    """The live child processes of ``pid``."""
    return {int(c) for task in Path(f"/proc/{pid}/task").iterdir() for c in (task / "children").read_text().split()}


def test_serve_starts_its_parse_forkserver_after_its_start_up(scene_dir: Path):
    """`serve` does not start the forkserver of HDB parses and session workers with the server (its
    imports, ~2 s of CPU, competed with the server's start and first set-up, and were paid by every
    serve): none of its children exist once it listens; it starts WARM_CHILDREN_S later by itself
    (no file set sent), so a file set's parse does not wait for its imports; a hello holding a file
    set (asked for with error 13, uploaded, parsed in a child) sets up a session that steps."""
    import time

    from hydrolink.clients.lockstep.connection import ServerConnection
    from hydrolink.server.hdb.io import file_set
    from hydrolink.server.processes import WARM_CHILDREN_S

    store = scene_dir / "store"
    with serve_process("--store", str(store), cwd=scene_dir) as address:
        (pid,) = [c for c in _children(os.getpid()) if str(store).encode() in Path(f"/proc/{c}/cmdline").read_bytes()]
        assert _children(pid) == set()
        deadline = time.monotonic() + WARM_CHILDREN_S + EXIT_S
        while not _children(pid) and time.monotonic() < deadline:
            time.sleep(0.2)
        assert _children(pid)   # the forkserver (and multiprocessing's resource tracker)
        x = np.zeros((1, 6))
        with ServerConnection(address, timeout=EXIT_S) as conn:
            conn.hello(sphere_scene(), {"sphere.h5": file_set(scene_dir / "sphere.h5")})
            assert len(conn.uploads) == 1
            conn.step(0, 0.0, x, x)


def test_bad_scene_is_one_clear_line(scene_dir: Path):
    write_scene(scene_dir, sphere_scene(mass=-1.0), "bad.toml")
    result = cli_here("run", "bad.toml", cwd=scene_dir)
    assert result.returncode != 0
    assert "bad.toml: bodies[0].mass: Input should be greater than 0" in result.stderr
    assert "Traceback" not in result.stderr
    assert not (scene_dir / "bad.out.nc").exists()


@pytest.mark.parametrize("old,new,line", [
    ("duration = 12.0", "duration = 1e300", "huge.toml: simulation.duration: Input should be less than or equal to "
                                            "10000000 (got 1e+300): at most 1e7 s (116 days) of simulated time"),
    ("dt = 0.05", "dt = 1e-300", "huge.toml: simulation.dt: Input should be greater than or equal to 1e-06 (got "
                                 "1e-300): a time step from 1 µs to 1 h"),
    ("irf_duration = 10.0", "irf_duration = 1e300", "huge.toml: hydro.irf_duration: Input should be less than or "
                                                    "equal to 3600 (got 1e+300)"),
])
def test_out_of_bounds_scene_value_is_one_named_line(scene_dir: Path, old, new, line):
    """Issue 22: duration = 1e300 printed a 60-line traceback; every bound is the key's named error."""
    assert old in sphere_scene()
    write_scene(scene_dir, sphere_scene().replace(old, new), "huge.toml")
    result = cli_here("run", "huge.toml", cwd=scene_dir)
    assert result.returncode != 0 and "Traceback" not in result.stderr
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"Error: {line}"), lines


def test_misspelt_keys_are_each_listed_with_the_closest_valid_key(scene_dir: Path):
    text = sphere_scene().replace("duration = 12.0", "duraton = 12.0").replace("mass = 261800.0", "mas = 261800.0")
    write_scene(scene_dir, text, "typo.toml")
    result = cli_here("run", "typo.toml", cwd=scene_dir)
    assert result.returncode != 0 and "Traceback" not in result.stderr
    lines = result.stderr.strip().splitlines()
    assert lines == ["Error: typo.toml: simulation.duration: required key is missing",
                     "typo.toml: simulation.duraton: unknown key (did you mean 'duration'?)",
                     "typo.toml: bodies[0].mass: required key is missing",
                     "typo.toml: bodies[0].mas: unknown key (did you mean 'mass'?)"], lines


def test_water_that_differs_from_the_hdb_is_said_and_kept_with_the_results(scene_dir: Path):
    """The sphere's HDB is at rho = 1000: a scene at 1025 runs, rescaled, and says so on stderr and in
    the results' `warnings` attribute, naming both densities and the file."""
    text = sphere_scene().replace("density = 1000.0", "density = 1025.0")
    assert "density = 1025.0" in text
    write_scene(scene_dir, text, "salty.toml")
    result = _cli("run", "salty.toml", "-o", "salty.nc", "--no-progress", cwd=scene_dir)
    assert result.returncode == 0, result.stderr
    expect = "the scene's density 1025 kg/m^3 differs from the HDB"
    assert expect in result.stderr and "(1000 kg/m^3; gravity 9.81 m/s^2 in both)" in result.stderr
    with xr.open_dataset(scene_dir / "salty.nc") as ds:
        notes = json.loads(ds.attrs["warnings"])
    assert any(expect in n and "sphere.h5" in n for n in notes), notes


def test_run_says_what_it_wrote_and_its_headline_figures(scene_dir: Path):
    """`hydrolink run` ends with the file it wrote and the run's headline: over the second half of the
    run, the sphere's most varying translation and rotation (std and max of position - equilibrium),
    figures recomputed here from the file's own series."""
    result = _cli("run", "scene.toml", "-o", "said.nc", "--no-progress", cwd=scene_dir)
    assert result.returncode == 0, result.stderr
    lines = result.stdout.strip().splitlines()
    assert lines[0].startswith("wrote said.nc: 240 steps in "), lines
    with xr.open_dataset(scene_dir / "said.nc") as ds:
        t = ds["time"].values
        x = (ds["position"] - ds["equilibrium_position"]).sel(body="sphere").values[t > 6.0 - 1e-6]
    assert t[-1] == pytest.approx(12.0)
    head = re.fullmatch(r"t 6-12 s: sphere (\w+) std (\S+) m \(max \|x\| (\S+) m\), (\w+) std (\S+) deg "
                        r"\(max \|x\| (\S+) deg\)", lines[1])
    assert head, lines
    dofs = ["surge", "sway", "heave", "roll", "pitch", "yaw"]
    trans, rot = int(np.argmax(x[:, :3].std(axis=0))), 3 + int(np.argmax(x[:, 3:].std(axis=0)))
    assert head[1] == dofs[trans] and head[4] == dofs[rot] == "pitch"
    assert float(head[2]) == pytest.approx(x[:, trans].std(), rel=2e-3)
    assert float(head[3]) == pytest.approx(np.abs(x[:, trans]).max(), rel=2e-3)
    assert float(head[5]) == pytest.approx(np.degrees(x[:, rot].std()), rel=2e-3)
    assert float(head[6]) == pytest.approx(np.degrees(np.abs(x[:, rot]).max()), rel=2e-3)


def test_missing_files_come_with_the_schema_errors(scene_dir: Path):
    """A bad key and a missing HDB: both in the one error (before: the HDB only once the key was fixed)."""
    write_scene(scene_dir, sphere_scene(hdb="missing.h5", mass=-1.0), "both.toml")
    result = cli_here("run", "both.toml", cwd=scene_dir)
    assert result.returncode != 0 and "Traceback" not in result.stderr
    lines = result.stderr.strip().splitlines()
    assert lines[0].startswith("Error: both.toml: bodies[0].mass: Input should be greater than 0"), lines
    assert lines[1] == f"both.toml: bodies[0].hdb: file not found: {scene_dir / 'missing.h5'}", lines


def test_missing_hdb_names_the_key(scene_dir: Path):
    write_scene(scene_dir, sphere_scene(hdb="missing.h5"), "nohdb.toml")
    result = cli_here("run", "nohdb.toml", cwd=scene_dir)
    assert result.returncode != 0
    assert "nohdb.toml: bodies[0].hdb: file not found" in result.stderr
    assert "Traceback" not in result.stderr


def test_wrong_hdb_body_names_the_key(scene_dir: Path):
    write_scene(scene_dir, sphere_scene(hdb_body="float"), "wrong.toml")
    result = cli_here("run", "wrong.toml", cwd=scene_dir)
    assert result.returncode != 0
    assert "wrong.toml: bodies[0].hdb_body: the HDB sphere.h5 holds no body 'float'" in result.stderr


def test_hdb_info_on_wamit_files_with_plot(tmp_path: Path, reference_data: Path):
    for f in (reference_data / "rm3_wamit").iterdir():
        shutil.copy(f, tmp_path / f.name)
    result = cli_here("hdb", "info", "rm3.1", "--plot", "rm3.png", "--dofs", "heave", cwd=tmp_path)
    assert result.returncode == 0, result.stderr
    out = result.stdout
    assert "float" in out and "spar" in out
    # the float's heave A_inf from the WAMIT PER = 0 rows (rho = 1000): 1.2328e6 kg
    assert re.search(r"heave 1\.233e\+06", out), out
    # the IRF consistency report: the float's heave damping is reproduced by its 40 s IRF
    line = next(l for l in out.splitlines() if l.strip().startswith("float.heave: B(w) re-transformed"))
    assert float(re.search(r"re-transformed ([\d.e+-]+) %", line).group(1)) < 1.0, line
    assert (tmp_path / "rm3.png").stat().st_size > 10_000


def test_hdb_info_bad_file_is_one_clear_line(tmp_path: Path):
    (tmp_path / "junk.nc").write_text("not a netcdf file")
    result = cli_here("hdb", "info", "junk.nc", cwd=tmp_path)
    assert result.returncode != 0
    assert "junk.nc" in result.stderr and "Traceback" not in result.stderr


def write_ball_spec(folder: Path, panel_size: float, omegas: list[float], extra: str = "") -> None:
    """``sphere.toml``: an `hdb build` spec of a floating sphere "ball" of radius 1 m."""
    (folder / "sphere.toml").write_text(f'[body]\nname = "ball"\nshape = "sphere"\nradius = 1.0\n'
                                        f"panel_size = {panel_size}\n[frequencies]\nvalues = {omegas}\n{extra}")


def test_hdb_build_writes_a_loadable_hdb_and_caches(tmp_path: Path, monkeypatch):
    """`hdb build` in this process (its command's path is the same; a child spent ~3 s of CPU on imports)."""
    write_ball_spec(tmp_path, 0.35, [0.5, 1.5, 3.0], "[water]\ndensity = 1000.0\n")
    monkeypatch.setenv("HYDROLINK_CACHE", str(tmp_path / "cache"))
    first = cli_here("hdb", "build", "sphere.toml", "-o", "ball.nc", "--no-progress", cwd=tmp_path)
    assert first.returncode == 0, first.stderr
    assert list((tmp_path / "cache").glob("*.nc")), "the build was not cached"
    info = cli_here("hdb", "info", "ball.nc", cwd=tmp_path)
    assert info.returncode == 0, info.stderr
    assert "ball" in info.stdout and "3 frequencies" in info.stdout
    from hydrolink.server.hdb.io import load_hdb
    ds = load_hdb(tmp_path / "ball.nc")
    # a floating hemisphere: C33 = rho g pi R^2 (the builder's polyhedron keeps the exact volume/area
    # only approximately for the waterplane; 2 % covers the coarse mesh)
    assert float(ds["hydrostatic_stiffness"].sel(influenced_dof="ball.heave", radiating_dof="ball.heave")) == \
        pytest.approx(1000 * 9.81 * np.pi, rel=0.02)


def test_first_build_on_a_fresh_machine_says_what_happens_in_one_plain_line(tmp_path: Path):
    """A fresh Capytaine cache (its Green function not tabulated yet): `hdb build` prints one plain
    line of hydrolink's saying Capytaine tabulates once, never Capytaine's timestamped
    `WARNING capytaine...: Precomputing tabulation`; the tabulation is really made (its file in
    the fresh cache) and the next build, which loads it, says nothing of it."""
    write_ball_spec(tmp_path, 0.5, [1.0, 2.0])
    env = {**os.environ, "CAPYTAINE_CACHE_DIR": str(tmp_path / "capytaine")}
    runs = []
    for out in ("a.nc", "b.nc"):
        env["HYDROLINK_CACHE"] = str(tmp_path / f"cache-{out}")      # no HDB cache hit: Capytaine runs both times
        runs.append(subprocess.run([*HYDROLINK, "hdb", "build", "sphere.toml", "-o", out], cwd=tmp_path,
                                   capture_output=True, text=True, timeout=600, env=env))
        assert runs[-1].returncode == 0, runs[-1].stderr
    first, second = runs[0].stderr, runs[1].stderr
    assert "Precomputing tabulation" not in first + second and "WARNING" not in first + second, first
    line = ("hdb build: Capytaine is tabulating its Green function, once on this machine (about half a minute on 2 "
            "cores; kept in ")
    assert first.count(line) == 1 and line not in second
    assert list((tmp_path / "capytaine").rglob("tabulation_*.npz"))


def test_hdb_build_bad_spec_names_the_key(tmp_path: Path):
    (tmp_path / "bad.toml").write_text('[body]\nname = "b"\nshape = "sphere"\n[frequencies]\nvalues = [1.0, 2.0]\n')
    result = cli_here("hdb", "build", "bad.toml", "-o", "b.nc", cwd=tmp_path)
    assert result.returncode != 0
    assert "bad.toml: body.radius" in result.stderr and "Traceback" not in result.stderr


def test_reader_warnings_are_one_plain_line(tmp_path: Path):
    """A Capytaine file that records no rotation centre: the reader's warning reaches the user as
    one line 'warning: ...', without Python's source file, line number or category."""
    cpt = pytest.importorskip("capytaine")
    import logging

    logging.getLogger("capytaine").setLevel(logging.ERROR)
    mesh = cpt.mesh_sphere(radius=1.0, center=(0, 0, 0), resolution=(8, 8)).immersed_part()
    body = cpt.FloatingBody(mesh=mesh, dofs=cpt.rigid_body_dofs(rotation_center=(0, 0, 0)), name="buoy")
    ds = cpt.BEMSolver().fill_dataset(xr.Dataset(coords={"omega": [0.5, 1.0, 2.0], "wave_direction": [0.0],
                                                         "radiating_dof": ["Heave"]}), body)
    ds = ds.drop_vars([v for v in ("rotation_center", "center_of_mass") if v in ds.variables])
    ds["hydrostatic_stiffness"] = xr.DataArray(np.diag([0, 0, 1000 * 9.81 * np.pi, 0, 0, 0.0]),
                                               dims=("influenced_dof", "radiating_dof"),
                                               coords={"influenced_dof": list(body.dofs), "radiating_dof": list(body.dofs)})
    path = tmp_path / "buoy.nc"
    cpt.export_dataset(path, ds, format="netcdf")
    r = _cli("hdb", "info", "buoy.nc", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    lines = [line for line in r.stderr.splitlines() if "rotation_center" in line]
    assert len(lines) == 1 and lines[0].startswith("warning: ") and "no rotation_center" in lines[0], r.stderr
    assert "UserWarning" not in r.stderr and ".py:" not in r.stderr


def test_paced_run_prints_where_the_time_went_as_the_file_records_it(scene_dir: Path):
    """`hydrolink run --realtime` says where a step's time went (mean and max per part) and its
    overruns by cause: the figures the results file's `step_time` and `overrun` rows give, recomputed
    here (issue 36: the summary and the file agree)."""
    result = _cli("run", "scene.toml", "-o", "paced.nc", "--no-progress", "--realtime", "20", cwd=scene_dir)
    assert result.returncode == 0, result.stderr
    line = next(x for x in result.stdout.splitlines() if x.startswith("where a step's time went"))
    printed = dict(re.findall(r"(\w+) ([\d.]+) / [\d.]+", line.split(":", 1)[1].split(";")[0]))
    paced = next(x for x in result.stdout.splitlines() if x.startswith("paced at"))
    overruns = int(re.search(r"; (\d+) overrun\(s\) of (\d+) steps", paced)[1])
    with xr.open_dataset(scene_dir / "paced.nc") as ds:
        parts = ds["step_time"].values
        rows = np.isfinite(parts).all(axis=1)
        mean = dict(zip(ds["step_part"].values.tolist(), 1e3 * parts[rows].mean(axis=0)))
        assert int(ds["overrun"].values.sum()) == overruns
    assert set(printed) == set(mean), (printed, mean)
    for part, value in printed.items():
        assert float(value) == pytest.approx(mean[part], abs=1.5e-3), (part, value, mean[part])
    if overruns:
        causes = dict(re.findall(r"(\w+) (\d+)", line.split("overruns by cause:")[1]))
        assert sum(int(n) for n in causes.values()) == overruns


# What a `hydrolink` process imports only where it uses it: each costs every process that loads it
# its CPU (bench/bench_startup.py). The command module itself loads no science stack (a bad option,
# `--help` and `keys` need none); a run loads no HDB builder, plotting, study or spectral-wave package,
# and no xarray backend it does not read with (xarray loads every installed one where a file is
# opened without its engine named: wavespectra's, with scipy.interpolate and scipy.io).
NOT_IN_THE_CLI_MODULE = ("xarray", "pandas", "scipy", "dask", "numba", "pydantic", "exudyn", "h5py", "netCDF4",
                         "capytaine", "matplotlib", "mhkit", "wavespectra")
NOT_IN_A_RUN = ("capytaine", "matplotlib", "mhkit", "wavespectra", "distributed", "scipy.interpolate", "scipy.io",
                "hydrolink.clients.studies")


def _modules_after(tmp_path: Path, code: str) -> set[str]:
    """The modules a fresh Python process holds after ``code`` (run in ``tmp_path``)."""
    listing = tmp_path / "modules.json"
    program = f"{code}\nimport json, sys\njson.dump(sorted(sys.modules), open({str(listing)!r}, 'w'))"
    result = subprocess.run([sys.executable, "-c", program], cwd=tmp_path, capture_output=True, text=True,
                            timeout=EXIT_S)
    assert result.returncode == 0, result.stderr
    return set(json.loads(listing.read_text()))


def _loaded(modules: set[str], names: tuple[str, ...]) -> list[str]:
    return [name for name in names if any(m == name or m.startswith(name + ".") for m in modules)]


def test_the_command_module_imports_no_science_stack(tmp_path: Path):
    assert _loaded(_modules_after(tmp_path, "import hydrolink.clients.cli"), NOT_IN_THE_CLI_MODULE) == []


def test_a_run_imports_only_what_it_runs_with(scene_dir: Path):
    """`hydrolink run` of the module's scene (two steps), its results file written and read back for
    the headline, in one process: none of NOT_IN_A_RUN loaded."""
    write_scene(scene_dir, sphere_scene().replace("duration = 12.0", "duration = 0.1"), "short.toml")
    modules = _modules_after(scene_dir, "from hydrolink.clients.cli import cli\n"
                                        "cli.main(['run', 'short.toml', '-o', 'short.nc', '--no-progress'], "
                                        "prog_name='hydrolink', standalone_mode=False)")
    assert (scene_dir / "short.nc").is_file()
    assert _loaded(modules, NOT_IN_A_RUN) == []


@pytest.mark.parametrize("command,option", [
    (["serve"], "--session-timeout"), (["serve"], "--isolate-step-ms"),
    (["run", "scene.toml", "--server", "tcp://127.0.0.1:9"], "--link-timeout"),
    (["run", "scene.toml", "--server", "tcp://127.0.0.1:9"], "--reply-timeout"),
    (["control", "c.py", "--server", "tcp://127.0.0.1:9", "--token", "t" * 32], "--join-wait")])
@pytest.mark.parametrize("value", ["nan", "inf", "-inf", "1e300", "-1", "2e9"])
def test_a_duration_option_out_of_range_is_refused_naming_it(command, option, value):
    """NaN, infinities, negatives and durations past 1e6 s (a ZeroMQ timeout is an int of ms: 1e300 s
    and inf ended `run --link-timeout` and `control --join-wait` in a traceback) are refused by the
    option parser, naming the option, before anything starts."""
    from click.testing import CliRunner
    from hydrolink.clients.cli import cli

    r = CliRunner().invoke(cli, [*command, f"{option}={value}"])
    assert r.exit_code == 2 and f"Invalid value for '{option}'" in r.output, r.output
    assert r.exception is None or isinstance(r.exception, SystemExit)
