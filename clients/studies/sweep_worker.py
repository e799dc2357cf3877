"""What a Dask worker runs for ``hydrolink sweep``: one case (``hydrolink run`` with an embedded
server, or ``hydrolink steady``) and the warm-up of a setup's on-disk caches.

A case's files live in ``OUTDIR/cases/``, named by the case (``case-012_waves.hs=2.5_ptos.pto.damping=1.2e6``,
clients/sweep_file.py ``case_name``): ``<name>.toml`` (the case's scene), ``<name>.nc`` (its summary
and the tail of its series, or every sample: clients/studies/sweep_case_file.py) and ``<name>.json`` (its
record: the case's key, status, error, wall time, attempts, ...), written in that order, each
atomically; a case whose record (with its key) exists is finished. A
worker that sees OUTDIR (same machine or a shared file system: it holds the sweep's token file)
writes them itself; a worker elsewhere returns the files' bytes and the client writes them.

The HDBs come from the client (loaded once, scattered to the workers), so no worker reads or builds
an HDB; state-space fits go through the on-disk fit cache (server/radiation/state_space_cache.py), whose
folder every worker reports so that the client can tell when they do not share one.
"""

from __future__ import annotations

import json
import os
import shutil
import socket
import tempfile
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

TOKEN_FILE = ".hydrolink-sweep"


@dataclass(frozen=True)
class CaseTask:
    """Everything a worker needs for one case (the HDBs travel separately)."""
    case_id: str
    name: str                    # stem of its files
    label: str
    scene_text: str
    solver: str                  # "run" | "steady"
    hdbs: tuple[str, ...]        # the HDB keys (bodies' hdb strings) of its scene
    outdir: str
    token: str
    window: tuple[float, float]  # s, its summary's averaging window
    tail: float | None           # s of series its file keeps (None: all)
    attempt: int = 1


@dataclass
class CaseOutcome:
    """What a worker hands back: the record, and the files when it could not write them itself."""
    case_id: str
    status: str                  # "complete" | "failed"
    error: str
    wall_time: float             # s, the whole case (setup, run, results file)
    solver: str
    worker: str                  # host:pid
    attempt: int
    caches: dict[str, str]       # kind -> folder the worker uses
    fitted_pairs: int | None = None
    stored: bool = False         # the worker wrote the case's files itself (it sees OUTDIR)
    files: dict[str, bytes] = field(default_factory=dict)   # name -> bytes (remote workers only)

    def record(self, name: str, label: str) -> "CaseRecord":
        return CaseRecord(self.case_id, label, self.status, self.error, self.wall_time, self.solver, self.worker,
                          self.attempt, dict(self.caches), self.fitted_pairs, name)


@dataclass
class CaseRecord:
    """A finished case (``<id>.json``): what the sweep keeps of it besides its results file."""
    case_id: str
    label: str
    status: str                  # "complete" | "failed"
    error: str
    wall_time: float             # s
    solver: str
    worker: str
    attempt: int
    caches: dict[str, str]
    fitted_pairs: int | None = None
    name: str = ""               # stem of its files

    def to_json(self) -> bytes:
        return json.dumps(asdict(self), indent=1).encode()

    @classmethod
    def read(cls, path: Path) -> "CaseRecord | None":
        """The record in ``path``; None when there is none or it is not a whole record (the case
        then runs again)."""
        try:
            return cls(**json.loads(path.read_text()))
        except (OSError, ValueError, TypeError):
            return None


CASE_FILES = {"scene": ".toml", "results": ".nc", "failed": ".failed.nc", "record": ".json"}


def case_paths(outdir: str | Path, name: str) -> dict[str, Path]:
    """A case's files by kind (:data:`CASE_FILES`), from the stem of their names."""
    base = Path(outdir) / "cases"
    return {kind: base / f"{name}{suffix}" for kind, suffix in CASE_FILES.items()}


def write_file_atomic(path: Path, data: bytes) -> None:
    from hydrolink.server.disk_cache import write_atomic
    write_atomic(path, lambda tmp: Path(tmp).write_bytes(data))


def store_outcome(task: CaseTask, outcome: CaseOutcome, case_file: Path | None, scene: bytes) -> None:
    """Write a case's scene, its file (copied from ``case_file``, or from ``outcome.files``) and its
    record; a complete case's file replaces a failed attempt's."""
    paths = case_paths(task.outdir, task.name)
    write_file_atomic(paths["scene"], scene)
    target = paths["results"] if outcome.status == "complete" else paths["failed"]
    if case_file is not None and case_file.exists():
        from hydrolink.server.disk_cache import write_atomic
        write_atomic(target, lambda tmp: shutil.copyfile(case_file, tmp))
    elif "results" in outcome.files:
        write_file_atomic(target, outcome.files["results"])
    if outcome.status == "complete":
        paths["failed"].unlink(missing_ok=True)
    write_file_atomic(paths["record"], outcome.record(task.name, task.label).to_json())


def sees_outdir(task: CaseTask) -> bool:
    """True when this process sees the client's OUTDIR (its token file holds the sweep's token)."""
    try:
        return (Path(task.outdir) / TOKEN_FILE).read_text().strip() == task.token
    except OSError:
        return False


def cache_folders() -> dict[str, str]:
    """The HDB build cache and state-space fit cache folders of this process."""
    from hydrolink.server.hdb.build.builder import default_cache_dir as hdb_dir
    from hydrolink.server.radiation.state_space_cache import default_cache_dir as fit_dir
    return {"hdb": str(hdb_dir().resolve()), "state_space": str(fit_dir().resolve())}


def _first_line(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()
    return f"{type(exc).__name__}: {text[0][:400]}" if text else type(exc).__name__


def run_case(task: CaseTask, hdbs: dict, *after) -> CaseOutcome:
    """Run one case into a full results file, summarise it over the case's window and write the
    case's file (clients/studies/sweep_case_file.py); never raises for the case's own failure (recorded in
    the outcome, with the partial results as its file). ``after``: futures this case waits for (the
    warm-up of its setup's caches), unused."""
    from hydrolink.clients.studies.sweep_case_file import summarise, write_case_file
    work = Path(tempfile.mkdtemp(prefix=f"hydrolink-case-{task.case_id[:8]}-"))
    scene_path = work / "scene.toml"
    scene_path.write_text(task.scene_text)
    results, case_file = work / "results.nc", work / "case.nc"
    t0 = time.perf_counter()
    status, error, fitted = "complete", "", None
    try:
        if task.solver == "steady":
            import math

            from hydrolink.clients.analysis.steady import steady_scene_file
            from hydrolink.protocol.scene import parse_scene
            scene = parse_scene(task.scene_text, "scene")
            period, dt = scene.waves.period, scene.simulation.dt
            # a whole number of samples per period: the period means (power) are then exact
            steady_scene_file(scene_path, results, progress=False, hdbs=hdbs,
                              dt=period / math.ceil(period / dt - 1e-9))
        else:
            from hydrolink.clients.run import run_scene_file
            summary = run_scene_file(scene_path, results, progress=False, hdbs=hdbs)
            fitted = summary.state_space_fitted_pairs
    except Exception as exc:  # noqa: BLE001 - a failing case is a result; the sweep goes on
        status, error = "failed", _first_line(exc)
    if status == "complete":
        try:
            steady = task.solver == "steady"
            write_case_file(results, case_file, summarise(results, task.window, steady), None if steady else task.tail)
        except (OSError, ValueError) as exc:
            status, error = "failed", f"summary: {_first_line(exc)}"
    wall = time.perf_counter() - t0
    outcome = CaseOutcome(task.case_id, status, error, wall, task.solver, f"{socket.gethostname()}:{os.getpid()}",
                          task.attempt, cache_folders(), fitted)
    kept = case_file if status == "complete" else results
    try:
        if sees_outdir(task):
            store_outcome(task, outcome, kept, task.scene_text.encode())
            outcome.stored = True
        elif kept.exists():
            outcome.files["results"] = kept.read_bytes()
    finally:
        shutil.rmtree(work, ignore_errors=True)
    return outcome


def warm_setup(scene_text: str, hdbs: dict) -> None:
    """Build the server model of a scene once, so that its state-space fits land in the on-disk
    cache the cases of this setup then read. A failure is left to the cases, which report it."""
    from hydrolink.clients.scene_inputs import load_scene_hulls, load_wave_elevation
    from hydrolink.protocol.scene import parse_scene
    from hydrolink.server.model import HydroModel
    from hydrolink.server.terms.hulls import closed_hull
    try:
        scene = parse_scene(scene_text, "scene")   # its file paths are absolute
        HydroModel(scene, {b.name: hdbs[b.hdb] for b in scene.bodies if b.wet}, load_wave_elevation(scene, "scene.toml"),
                   hulls={n: closed_hull(v, f) for n, (v, f) in load_scene_hulls(scene, "scene.toml").items()})
    except Exception:  # noqa: BLE001 - the cases will say what is wrong
        pass
