"""Shared test fixtures (the reference HDBs live in examples/data, with their sources and licences in
its README) and the scene builder every test uses to write scene TOML."""

from __future__ import annotations

import contextlib
import fcntl
import json
import numbers
import os
import re
import shutil
import signal
import subprocess
import sys
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[1]
REFERENCE_DATA = REPO / "examples" / "data"
# How long a test waits for a reply or an exit it expects (s). Generous on purpose: on a loaded 2-core
# CI a hello's set-up (an isolated HDB parse, IRFs) has taken over 30 s, and a passing test never waits
# it out. A test whose subject is a timeout states its own short one.
REPLY_S = 120.0
# How long a test waits for a process it expects to end by itself (a run, a plot script, a controller
# after its run, a server after SIGTERM): a hang guard, never a timing check.
EXIT_S = 600.0
# How long a test's own server keeps an idle session (s): at least the longest wait above, so a session a
# test has opened is never ended for idleness while the test waits on something else under load.
IDLE_S = EXIT_S


WARMUPS = pytest.StashKey[list]()            # the controller's numba warm-up processes (tests/numba_warmup.py)
WARMUP_FOLDER = "HYDROLINK_TEST_NUMBA_WARMUP"   # environment: their locks' folder, for the workers


def pytest_sessionstart(session: pytest.Session) -> None:
    """Under pytest-xdist, before any worker starts, the controller

    - starts the compiles of hydrolink's numba kernels, one process a group, into numba's cache
      (tests/numba_warmup.py): on a fresh clone each worker would otherwise compile them again;
      a worker's first import of a group's compiled module waits for its compile (pytest_configure);
    - makes (or loads) Capytaine's one-off Green-function tabulation: Capytaine writes it into its
      cache folder in place, not atomically, so on a fresh machine two workers making it at once
      could read each other's half-written file;
    - gives the workers (and the processes they start) one BLAS/OpenMP thread each, as `hydrolink`
      itself defaults to (clients/cli.py main): one worker a core, with every pool sized to the
      machine the threads only contend (tests/test_hdb_build_multibody.py alone: 25.9 s of CPU
      with the default pools, 17.7 s with one thread). Variables already set are kept.

    Serial runs (``-n 0``) and the workers themselves skip this."""
    config = session.config
    if getattr(config, "workerinput", None) is None and getattr(config.option, "numprocesses", None):
        import tempfile

        import numba_warmup
        folder = tempfile.mkdtemp(prefix="hydrolink-numba-warmup-")
        config.stash[WARMUPS] = numba_warmup.start(Path(folder))
        os.environ[WARMUP_FOLDER] = folder
        import capytaine
        capytaine.BEMSolver()
        for var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
            os.environ.setdefault(var, "1")


# Dask's self-monitoring, off or slowed for the tests' clusters (by the environment, so the sweeps' LocalCluster
# workers and the `dask scheduler`/`dask worker` processes a test starts have it too): a worker's statistical
# profiler samples every thread's stack every 10 ms, each process's event loop wakes every 20 ms to time itself
# and its system monitor every 0.5 s. No test looks at any of them; an idle LocalCluster of 2 workers spent
# 2.15-2.30 s of CPU in 20 s with them, 0.56-0.75 s without (4 pairs, load 3-11). Values already set are kept.
DASK_QUIET = {"DASK_DISTRIBUTED__WORKER__PROFILE__ENABLED": "False",
              "DASK_DISTRIBUTED__ADMIN__TICK__INTERVAL": "1s",
              "DASK_DISTRIBUTED__ADMIN__SYSTEM_MONITOR__INTERVAL": "2s"}


def pytest_configure(config: pytest.Config) -> None:
    """Every `hydrolink run` a test starts waits REPLY_S for a reply (its ``--reply-timeout``, by
    $HYDROLINK_REPLY_TIMEOUT; a set value is kept); Dask's self-monitoring is quiet (DASK_QUIET,
    before any test module imports dask); and a pytest-xdist worker imports each group of
    compiled kernels once the controller's compile of it is done (tests/numba_warmup.py)."""
    os.environ.setdefault("HYDROLINK_REPLY_TIMEOUT", str(REPLY_S))
    for var, value in DASK_QUIET.items():
        os.environ.setdefault(var, value)
    folder = os.environ.get(WARMUP_FOLDER)
    if folder and hasattr(config, "workerinput"):
        import numba_warmup
        numba_warmup.gate_imports(Path(folder))


def pytest_sessionfinish(session: pytest.Session) -> None:
    """The controller's numba warm-up processes reaped (and their folder removed); one that failed
    is said (the tests then compiled the kernels themselves)."""
    warmups = session.config.stash.get(WARMUPS, None)
    if warmups is None:
        return
    import numba_warmup
    reporter = session.config.pluginmanager.get_plugin("terminalreporter")
    for line in numba_warmup.finish(warmups):
        reporter.write_line(f"\nwarning: {line}", yellow=True)     # (after xdist's progress line)
    shutil.rmtree(os.environ.pop(WARMUP_FOLDER), ignore_errors=True)


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_protocol(item: pytest.Item, nextitem: pytest.Item | None):
    """Under pytest-xdist a test marked ``timing`` (it asserts wall-clock bounds) runs while no other
    test of the suite runs, nor any fixture set-up or teardown: every test's whole protocol holds a
    shared lock on a file the run's workers share, a timing test's the exclusive lock, taken through
    a turnstile lock that keeps the other workers from queueing new shared holds meanwhile (flock
    favours none). Serial runs have nothing to share."""
    if not hasattr(item.config, "workerinput"):
        yield
        return
    folder = Path(item.config.option.basetemp).parent          # one per run: the workers' base folders' parent
    turnstile = os.open(folder / "timing-turnstile.lock", os.O_RDWR | os.O_CREAT, 0o600)
    tests = os.open(folder / "timing-tests.lock", os.O_RDWR | os.O_CREAT, 0o600)
    alone = item.get_closest_marker("timing") is not None
    try:
        fcntl.flock(turnstile, fcntl.LOCK_EX)
        fcntl.flock(tests, fcntl.LOCK_EX if alone else fcntl.LOCK_SH)
        if not alone:
            fcntl.flock(turnstile, fcntl.LOCK_UN)
        yield
    finally:
        os.close(tests)                                          # closing releases the locks
        os.close(turnstile)


@pytest.fixture(scope="session")
def reference_data() -> Path:
    """Folder with the reference HDBs in the repository (rm3_wamit/, rm3_capytaine/, sphere_task10/)."""
    return REFERENCE_DATA


@pytest.fixture(scope="session")
def sphere_path(reference_data: Path) -> Path:
    """The IEA Task-10 floating sphere (BEMIO .h5; depth 200 m, rho 1000)."""
    return reference_data / "sphere_task10" / "sphere.h5"


@pytest.fixture(scope="module")
def server() -> str:
    """The address of a force server in a thread of this process, one per test module."""
    from hydrolink.server.service.force_server import serve_in_thread
    srv, thread = serve_in_thread("tcp://127.0.0.1:*")
    yield srv.address
    srv.stop()
    thread.join(5.0)


@pytest.fixture
def served():
    """Start force servers in threads of this process (``served(**kw)``: serve_in_thread's keywords,
    session timeout 600 s unless given); each is stopped and its thread joined at the test's end."""
    from hydrolink.server.service.force_server import serve_in_thread
    started = []

    def start(**kw):
        srv, thread = serve_in_thread(**{"session_timeout": 600.0, **kw})
        started.append((srv, thread))
        return srv

    yield start
    for srv, thread in started:
        srv.stop()
        thread.join(timeout=30)
        assert not thread.is_alive()


def build_zmq_msgpack_program(source: Path, exe: Path, *flags: str) -> Path:
    """Compile a C program against libzmq and msgpack-c into ``exe`` (gcc ``flags``); the test is
    skipped, naming the Debian packages, when gcc or the headers are not on this machine."""
    if shutil.which("gcc") is None:
        pytest.skip("needs gcc (Debian package gcc)")
    missing = [h for h in ("zmq.h", "msgpack.h") if not Path("/usr/include", h).is_file()]
    if missing:
        pytest.skip(f"needs {', '.join(missing)} (Debian packages libzmq3-dev libmsgpack-dev; .ci/run installs them)")
    out = subprocess.run(["gcc", *flags, "-o", str(exe), str(source), "-lzmq", "-lmsgpackc", "-lm"],
                         capture_output=True, text=True)
    assert out.returncode == 0, f"building {source.name} failed (apt-get install libzmq3-dev libmsgpack-dev):\n{out.stderr}"
    return exe


def dealer(address: str):
    """A DEALER socket (linger 0) connected to ``address``, on the process's shared context: the raw
    client of the tests that send frames by hand."""
    import zmq
    sock = zmq.Context.instance().socket(zmq.DEALER)
    sock.setsockopt(zmq.LINGER, 0)
    sock.connect(address)
    return sock


def finished(proc: subprocess.Popen, timeout: float = EXIT_S) -> tuple:
    """(stdout, stderr) of a child a test started that ends by itself: waited for ``timeout`` s,
    then killed; always reaped."""
    try:
        return proc.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        proc.kill()
        return proc.communicate()


def stopped(proc: subprocess.Popen) -> None:
    """End a child a test started (a server) whatever state the test is in: SIGTERM, EXIT_S s to
    exit, then SIGKILL; always reaped."""
    if proc.poll() is None:
        proc.terminate()
    try:
        proc.wait(EXIT_S)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()


@dataclass
class ControllerExit:
    """How a controller process of :func:`controller_process` ended (set when its block exits)."""
    returncode: int | None = None
    stderr: str = ""


@contextlib.contextmanager
def controller_process(file: Path, server: str, token: str, *extra: str):
    """A `hydrolink control FILE` process joining ``server`` with the session's join ``token``;
    yields a :class:`ControllerExit`, filled when the block ends (the process waited for 30 s,
    then killed: always reaped)."""
    proc = subprocess.Popen([sys.executable, "-m", "hydrolink.clients.cli", "control", str(file), "--server", server,
                             "--token", token, "--join-wait", str(REPLY_S), *extra],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    ended = ControllerExit()
    try:
        yield ended
    finally:
        _, ended.stderr = finished(proc)
        ended.returncode = proc.returncode


@contextlib.contextmanager
def serve_process(*args: str, cwd: Path | None = None):
    """A `hydrolink serve` process on a free loopback port (``args``: more options, e.g. --store
    DIR); yields its address and stops it on exit."""
    proc = subprocess.Popen([sys.executable, "-m", "hydrolink.clients.cli", "serve", "--bind", "tcp://127.0.0.1:*",
                             *args], cwd=cwd, stderr=subprocess.PIPE, text=True)
    try:
        line = proc.stderr.readline()
        match = re.search(r"listening on (tcp://\S+)", line)
        assert match, f"hydrolink serve printed {line!r}"
        yield match.group(1)
    finally:
        stopped(proc)


def cli_here(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    """`hydrolink ARGS` run in this process (click's runner, in ``cwd``), for the commands that end
    before a run's own work (errors, ``hdb info``, ``keys``): a subprocess would spend 0.3-2.5 s of
    CPU importing what this process has loaded. Runs stay in subprocesses: once under load a suite
    worker hung in a ZeroMQ ``Context.term`` run by the garbage collector on a context some earlier
    test of that worker left (not identified; in-process runs were the change that worker had).
    Unexpected exceptions propagate."""
    from click.testing import CliRunner

    from hydrolink.clients.cli import cli

    here = os.getcwd()
    os.chdir(cwd)
    try:
        r = CliRunner().invoke(cli, list(args), prog_name="hydrolink", catch_exceptions=False)
    finally:
        os.chdir(here)
    return subprocess.CompletedProcess(["hydrolink", *args], r.exit_code, r.stdout, r.stderr)


@pytest.fixture(scope="session")
def sphere(sphere_path: Path):
    """The sphere's HDB, loaded once."""
    from hydrolink.server.hdb.io import load_hdb
    return load_hdb(sphere_path)


@pytest.fixture(scope="session", autouse=True)
def _state_space_fit_cache(tmp_path_factory):
    """State-space fits are cached in a temporary folder for the session, never in the user's cache
    (tests that look at the cache point $HYDROLINK_STATE_SPACE_CACHE at their own folder)."""
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("HYDROLINK_STATE_SPACE_CACHE", str(tmp_path_factory.mktemp("state_space_cache")))
        yield


@pytest.fixture(scope="session", autouse=True)
def _hdb_store(tmp_path_factory):
    """Servers keep HDB file contents sent by hash (SPEC §5.8) in a temporary folder for the
    session, never in the user's cache (servers started by tests inherit the variable)."""
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("HYDROLINK_HDB_STORE", str(tmp_path_factory.mktemp("hdb_store")))
        yield


# ------------------------------------------------------------------------------ scene builder
#
# Tests describe scenes as keyword arguments and get TOML text back, so the real parser
# (protocol/scene.py) validates exactly what a user's file would hold:
#
#     text = scene_toml(dt=0.05, duration=10.0, waves=regular_waves(1.0, 6.0),
#                       bodies=[body("float", hdb="float.nc", mass=3e5, center_of_mass=[0, 0, -1],
#                                    inertia=[1e7, 1e7, 2e7])])
#     path = write_scene(tmp_path, text)
#
# A section is a dict (``[water]``), or a list of dicts for the arrays of tables (``[[bodies]]``);
# dicts inside a section become inline tables (``friction = { force = 4.0 }``).

Section = Mapping[str, Any]
SCENE_SECTIONS: tuple[str, ...] = ("simulation", "water", "waves", "current", "hydro", "steady", "optimize", "coupling", "bodies",
                                   "point_masses", "joints", "constraints", "ptos", "moorings", "morison", "client",
                                   "controllers", "hydro_switches")
_BARE_KEY = re.compile(r"^[A-Za-z0-9_-]+$")


def toml_key(key: str) -> str:
    """A TOML key: bare when it can be, else a quoted string ("surge,pitch")."""
    return key if _BARE_KEY.match(key) else json.dumps(key)


def toml_value(value: Any) -> str:
    """One TOML value: bool, int, float (repr, so it round-trips exactly; inf and nan as TOML
    spells them), str, list (an array) or mapping (an inline table)."""
    if isinstance(value, (bool, np.bool_)):
        return "true" if value else "false"
    if isinstance(value, numbers.Integral):
        return str(int(value))
    if isinstance(value, numbers.Real):
        return repr(float(value))
    if isinstance(value, str):
        return json.dumps(value)
    if isinstance(value, Mapping):
        return "{ " + ", ".join(f"{toml_key(k)} = {toml_value(v)}" for k, v in value.items()) + " }"
    if isinstance(value, (list, tuple, np.ndarray)):
        return "[" + ", ".join(toml_value(v) for v in value) + "]"
    raise TypeError(f"no TOML value for {value!r}")


def toml_document(sections: Mapping[str, Section | Sequence[Section]]) -> str:
    """TOML text of named sections: a mapping becomes ``[name]``, a list of mappings ``[[name]]``."""
    lines: list[str] = []
    for name, section in sections.items():
        tables = [(f"[{name}]", section)] if isinstance(section, Mapping) else [(f"[[{name}]]", s) for s in section]
        for header, table in tables:
            lines.append(header)
            lines.extend(f"{toml_key(k)} = {toml_value(v)}" for k, v in table.items())
    return "\n".join(lines) + "\n"


def scene_toml(*, dt: float, duration: float, bodies: Sequence[Section], progress: bool | None = None,
               simulation: Section | None = None, **sections: Section | Sequence[Section] | None) -> str:
    """Scene TOML text: [simulation] from dt, duration, progress (written only when given) and any
    further ``simulation`` keys; then the other sections by their scene names (water, waves, hydro,
    steady, coupling, bodies, point_masses, joints, constraints, ptos, moorings, client,
    controllers). A section given as None or empty is left out (the scene's default)."""
    unknown = set(sections) - set(SCENE_SECTIONS)
    if unknown:
        raise TypeError(f"scene_toml: unknown section(s) {sorted(unknown)}")
    sim: dict[str, Any] = {"dt": dt, "duration": duration}
    if progress is not None:
        sim["progress"] = progress
    sim.update(simulation or {})
    given = {**sections, "simulation": sim, "bodies": bodies}
    return toml_document({k: given[k] for k in SCENE_SECTIONS if given.get(k)})


def body(name: str, *, mass: float, center_of_mass: Sequence[float] | None, inertia: Sequence[Any] | None,
         hdb: str | None = None, **keys: Any) -> dict[str, Any]:
    """One ``[[bodies]]`` entry: wet with ``hdb``, dry without; ``center_of_mass`` or ``inertia``
    None leaves the key out (a wet body that only translates); further keys as the scene names them
    (dofs, initial_displacement, hdb_body, ...)."""
    wet = {"hdb": hdb} if hdb is not None else {}
    given = {k: list(v) for k, v in (("center_of_mass", center_of_mass), ("inertia", inertia)) if v is not None}
    return {"name": name, **wet, "mass": mass, **given, **keys}


def joint(kind: str, body1: str, body2: str, point: Sequence[float], **keys: Any) -> dict[str, Any]:
    """One ``[[joints]]`` entry of type ``kind`` at ``point`` (name, axis, axis2, friction as keys)."""
    return {"type": kind, "body1": body1, "body2": body2, "point": list(point), **keys}


def linear_pto(name: str, body1: str, point1: Sequence[float], body2: str, point2: Sequence[float] | None,
               **keys: Any) -> dict[str, Any]:
    """One ``[[ptos]]`` entry of type "linear" from point1 on body1 to point2 on body2, or, with
    point2 None, along ``direction`` to ground (damping, stiffness, force_limit, ... as keys)."""
    to = {} if point2 is None else {"point2": list(point2)}
    return {"name": name, "type": "linear", "body1": body1, "point1": list(point1), "body2": body2, **to, **keys}


def regular_waves(height: float, period: float, **keys: Any) -> dict[str, Any]:
    """A ``[waves]`` section of regular waves (ramp, phase, excitation, ... as keys)."""
    return {"type": "regular", "height": height, "period": period, **keys}


def irregular_waves(hs: float, tp: float, spectrum: str = "jonswap", **keys: Any) -> dict[str, Any]:
    """A ``[waves]`` section of irregular waves (seed, components, ramp, spreading, ... as keys)."""
    return {"type": "irregular", "spectrum": spectrum, "hs": hs, "tp": tp, **keys}


SPHERE_WATER: dict[str, Any] = {"density": 1000.0, "depth": 200.0}   # as in the Task-10 sphere HDB


def sphere_body(hdb: str, *, mass: float, **keys: Any) -> dict[str, Any]:
    """The IEA Task-10 sphere as body "sphere": centre of mass 2 m below its reference point and
    inertia 2.6e6 kg m^2 about each axis unless ``keys`` say otherwise."""
    return body("sphere", hdb=hdb, mass=mass, **{"center_of_mass": [0.0, 0.0, -2.0], "inertia": [2.6e6] * 3, **keys})


def rm3_float(hdb: str, **keys: Any) -> dict[str, Any]:
    """RM3's float (rho V at rho = 1000; WEC-Sim's mass properties) as body "float"."""
    return body("float", hdb=hdb, mass=725833.0, center_of_mass=[0, 0, -0.72],
                inertia=[20907301, 21306090.66, 37085481.11], **keys)


def rm3_spar(hdb: str, **keys: Any) -> dict[str, Any]:
    """RM3's spar/plate (rho V at rho = 1000; WEC-Sim's mass properties) as body "spar"."""
    return body("spar", hdb=hdb, mass=886687.0, center_of_mass=[0, 0, -21.29],
                inertia=[94419614.57, 94407091.24, 28542224.82], **keys)


def rm3_pto(damping: float = 1.2e6) -> dict[str, Any]:
    """RM3's linear damper "pto" between the float's and the spar's centres of mass."""
    return linear_pto("pto", "float", [0.0, 0.0, -0.72], "spar", [0.0, 0.0, -21.29], damping=damping)


def sweep_toml(scene: str | Path, *, set: Section | None = None, grid: Section | None = None,
               site: Section | None = None, cases: Sequence[Section] = (), **top: Any) -> str:
    """Sweep TOML text (``hydrolink sweep``): ``scene`` and the other top-level keys (mode, solver,
    window, ...), then [set], [grid], [site] and the [[cases]]."""
    head = [f"scene = {toml_value(str(scene))}"] + [f"{toml_key(k)} = {toml_value(v)}" for k, v in top.items()]
    tables = {k: v for k, v in (("set", set), ("grid", grid), ("site", site), ("cases", list(cases))) if v}
    return "\n".join(head) + "\n" + (toml_document(tables) if tables else "")


def write_gdf(path: Path, vertices: np.ndarray, faces: np.ndarray) -> Path:
    """A panel mesh as a WAMIT GDF file (ULEN 1, g 9.81, no symmetry; one quadrilateral a panel,
    a triangle's last corner repeated), for scenes that name a body's ``mesh``."""
    quads = np.asarray(faces) if np.shape(faces)[1] == 4 else np.column_stack([faces, np.asarray(faces)[:, 2]])
    corners = np.asarray(vertices, float)[quads].reshape(-1, 3)
    lines = ["hydrolink test mesh", "1.0 9.81", "0 0", str(len(quads))]
    lines += [" ".join(repr(float(c)) for c in p) for p in corners]
    path.write_text("\n".join(lines) + "\n")
    return path


def rm3_example_text(name: str = "rm3.toml") -> str:
    """An RM3 example scene's text (examples/rm3/NAME) with its mesh files' paths made absolute, so
    the text runs from any folder a test writes it to (its HDB path the tests replace themselves)."""
    folder = Path(__file__).resolve().parents[1] / "examples"
    text = (folder / "rm3" / name).read_text()
    return text.replace('mesh = "../data/', f'mesh = "{(folder / "data").as_posix()}/')


def rm3_short_text(reference_data: Path, *, duration: float = 16.0, ramp: float = 4.0) -> str:
    """examples/rm3/rm3.toml's text for a short run: the repository's HDB by its absolute path,
    ``duration`` and the waves' ``ramp`` as given (dt 0.08 s as the example's)."""
    text = rm3_example_text("rm3.toml")
    for a, b in (('"../data/rm3_wamit/rm3.1"', f'"{(reference_data / "rm3_wamit" / "rm3.1").as_posix()}"'),
                 ("duration = 400.0", f"duration = {duration!r}"), ("ramp = 40.0", f"ramp = {ramp!r}")):
        assert a in text, a
        text = text.replace(a, b)
    return text


def write_scene(folder: Path, text: str, name: str = "scene.toml") -> Path:
    """Write scene text into ``folder`` (beside its HDBs, so relative paths resolve) and return the path."""
    path = folder / name
    path.write_text(text)
    return path


def needs_python_sigint() -> None:
    """Skip where SIGINT is not Python's KeyboardInterrupt: a process started in the background by a
    non-interactive shell inherits SIGINT ignored, and Python then leaves it ignored."""
    if signal.getsignal(signal.SIGINT) is not signal.default_int_handler:
        pytest.skip("SIGINT is ignored in this process (started in the background by a non-interactive shell)")


def box_build_spec(*, name: str, length: float, width: float, draft: float, panel_size: float, frequencies: str,
                   density: float, directions: str = "[0.0, 30.0]") -> str:
    """An ``hdb build`` spec of a box (freeboard 1 m) that keeps its panel pressures (panel_pressures =
    true); ``frequencies`` the [frequencies] table's lines."""
    return (f"panel_pressures = true\n[body]\nname = \"{name}\"\nshape = \"box\"\nlength = {length}\nwidth = {width}\n"
            f"draft = {draft}\nfreeboard = 1.0\npanel_size = {panel_size}\n[frequencies]\n{frequencies}\n"
            f"[waves]\ndirections = {directions}\n[water]\ndensity = {density}\n")


def unit_rigid_motions(points: np.ndarray) -> np.ndarray:
    """(6, P, 3) the displacement at ``points`` of a unit surge, sway, heave, roll, pitch, yaw about the origin."""
    x, y, z = np.asarray(points, float).T
    zero, one = np.zeros_like(x), np.ones_like(x)
    return np.stack([np.c_[one, zero, zero], np.c_[zero, one, zero], np.c_[zero, zero, one],
                     np.c_[zero, -z, y], np.c_[z, zero, -x], np.c_[-y, x, zero]])
