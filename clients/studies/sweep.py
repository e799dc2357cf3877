"""``hydrolink sweep SWEEP.toml``: every case of a sweep on Dask distributed, then sweep.nc and plots.

1. The sweep file and every case are validated (clients/studies/sweep_file.py) before anything runs.
2. The HDBs are loaded (HDB build specs built or taken from the on-disk cache) once, in this
   process; a case's key is the sha256 of its scene with every file replaced by its content's
   digest, its solver, the hydrolink version and what its file keeps
   (:func:`~hydrolink.clients.studies.sweep_file.case_identity`); its files are named by its index, keys and
   values (``cases/case-012_waves.hs=2.5_ptos.pto.damping=1.2e6.*``), its record holds its key.
3. Cases whose record (by key) exists in ``OUTDIR/cases`` are finished and skipped (failed ones too, unless
   ``retry_failed``); the others run on Dask: a ``LocalCluster`` of ``workers`` processes with one
   thread each (BLAS/OpenMP threads 1), or the scheduler at ``scheduler``. The HDBs are scattered
   to the workers once; a setup with state-space radiation is warmed first (its fits land in the
   on-disk cache that its cases then read). A case that fails is recorded with its error and the
   others go on; a case whose worker dies is run once more (the LocalCluster's scheduler is told
   to give up on a task after one death; a separate scheduler's ``allowed-failures`` applies
   before that); a progress bar shows cases done / failed / running and the ETA.
4. ``OUTDIR/sweep.nc`` (clients/studies/sweep_results.py), ``cases.csv``, ``power_matrix.png`` and
   ``capture_width.png`` (clients/studies/sweep_plots.py) are written from every finished case.
"""

from __future__ import annotations

import json
import logging
import math
import os
import secrets
import time
from contextlib import ExitStack
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from hydrolink.clients.studies.sweep_file import Sweep, SweepError, case_identity, dataset_digest, full_key, load_sweep
from hydrolink.clients.studies.sweep_worker import CASE_FILES, TOKEN_FILE, CaseOutcome, CaseRecord, CaseTask, case_paths, run_case, store_outcome, warm_setup, write_file_atomic

log = logging.getLogger(__name__)
PERIOD_KEYS = ("waves.te", "waves.tp", "waves.period")


@dataclass
class SweepReport:
    """What a sweep did: case counts, where the outputs are, the cache folders the workers used."""
    outdir: Path
    cases: int
    skipped: int                  # finished before this run (resumed)
    run: int                      # run by this run
    failed: list[str] = field(default_factory=list)       # labels of failed cases (all, this run or before)
    retried: int = 0              # cases run a second time after their worker died
    wall_time: float = 0.0
    workers: int = 0
    cache_folders: dict[str, list[str]] = field(default_factory=dict)
    outputs: list[str] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    annual_energy: list[str] = field(default_factory=list)   # "key = value ...: AEP" lines (with a site)


def load_hdbs(sweep: Sweep, progress: bool) -> tuple[dict, dict[str, str]]:
    """Every distinct HDB of the sweep's cases, loaded once (keyed by the absolute path the case
    scenes carry), and its content digest."""
    from hydrolink.clients.scene_inputs import load_scene_hdbs
    hdbs: dict = {}
    for case in sweep.cases:
        if any(b.hdb is not None and b.hdb not in hdbs for b in case.scene.bodies):
            hdbs.update(load_scene_hdbs(case.scene, sweep.scene_path, progress=progress))
    return hdbs, {k: dataset_digest(ds) for k, ds in hdbs.items()}


def finished_records(outdir: Path, cases: list) -> dict[str, CaseRecord | None]:
    """Per case key, its finished record (None: the case is to run). A record is found by the case's
    key whatever name its files have (a case whose name changed, e.g. another grid value before it,
    has its files renamed to its name now); a complete record whose file is gone does not count."""
    found: dict[str, CaseRecord] = {}
    for path in sorted((outdir / "cases").glob(f"*{CASE_FILES['record']}")):
        rec = CaseRecord.read(path)
        if rec is not None and rec.name == path.name[:-len(CASE_FILES["record"])]:
            found[rec.case_id] = rec
    out: dict[str, CaseRecord | None] = {}
    for case in cases:
        rec = found.get(case.case_id)
        if rec is not None and rec.name != case.name:
            rec = _rename_case_files(outdir, rec, case.name)
        if rec is not None and rec.status == "complete" and not case_paths(outdir, rec.name)["results"].exists():
            rec = None
        out[case.case_id] = rec
    return out


def _rename_case_files(outdir: Path, rec: CaseRecord, name: str) -> CaseRecord:
    """Move a finished case's files to its name now (the record last, rewritten with the name);
    files under that name belong to no case of this sweep (names are unique within it)."""
    old, new = case_paths(outdir, rec.name), case_paths(outdir, name)
    for kind in ("scene", "results", "failed"):
        if old[kind].exists():
            os.replace(old[kind], new[kind])
    moved = replace(rec, name=name)
    write_file_atomic(new["record"], moved.to_json())
    old["record"].unlink(missing_ok=True)
    return moved


def _setup_group(case, digests: dict[str, str]) -> str | None:
    """Cases sharing a state-space fit: same HDB content, water, [hydro] and wet bodies' DOFs."""
    scene = case.scene
    if scene.hydro.radiation != "state-space":
        return None
    key = {"water": scene.water.model_dump(), "hydro": scene.hydro.model_dump(),
           "bodies": [(digests[b.hdb], b.hdb_body_name, b.dofs) for b in scene.bodies if b.wet]}
    return json.dumps(key, sort_keys=True, default=str)


def open_cluster(stack: ExitStack, workers: int | None, scheduler: str | None):
    """A Dask client: on a new LocalCluster (processes, one thread each, BLAS threads 1, the
    hydrolink cache folders of this process) or on the scheduler at ``scheduler``."""
    import dask
    from distributed import Client, LocalCluster
    if scheduler:
        return stack.enter_context(Client(scheduler, timeout="30s"))
    n = workers or (len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1)
    env = {"OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
    for var in ("HYDROLINK_CACHE", "HYDROLINK_STATE_SPACE_CACHE", "XDG_CACHE_HOME"):
        if os.environ.get(var):
            env[var] = os.environ[var]
    # the in-process scheduler's and nanny's lifecycle messages are not the user's business
    for name in ("distributed", "distributed.scheduler", "distributed.nanny", "distributed.core"):
        logger = logging.getLogger(name)
        stack.callback(logger.setLevel, logger.level)
        logger.setLevel(logging.ERROR)
    with dask.config.set({"distributed.scheduler.allowed-failures": 0,
                          "distributed.nanny.pre-spawn-environ": {**dask.config.get(
                              "distributed.nanny.pre-spawn-environ", {}), **env}}):
        cluster = stack.enter_context(LocalCluster(n_workers=n, threads_per_worker=1, processes=True,
                                                   dashboard_address="127.0.0.1:0", silence_logs=logging.ERROR, env=env))
    return stack.enter_context(Client(cluster))


class _Progress:
    """tqdm bar of the cases to run: done / failed / running in its postfix, ETA from its rate."""

    def __init__(self, total: int, enabled: bool):
        from tqdm import tqdm
        # disable=None: tqdm leaves the bar out where stderr is not a terminal (no redraws in a log)
        self.bar = tqdm(total=total, unit="case", desc="sweep", disable=None if enabled else True, dynamic_ncols=True)
        self.failed = 0

    def update(self, done: int = 0, failed: int = 0, running: int | None = None) -> None:
        self.failed += failed
        self.bar.set_postfix_str(f"failed {self.failed}, running {running if running is not None else '?'}",
                                 refresh=False)
        self.bar.update(done)
        self.bar.refresh()

    def close(self) -> None:
        self.bar.close()


def _running(client, keys: set[str]) -> int | None:
    """Cases executing now: per worker, its tasks of ours up to its thread count (the scheduler
    hands a worker a little more than it can run at once)."""
    try:
        threads = client.nthreads()
        return sum(min(threads.get(w, 1), sum(1 for k in ks if k in keys)) for w, ks in client.processing().items())
    except Exception:  # noqa: BLE001 - only for the progress bar
        return None


def run_cases(client, tasks: list[CaseTask], hdbs: dict, digests: dict[str, str], groups: dict[str, list[CaseTask]],
              progress: bool, on_outcome) -> tuple[int, int]:
    """Submit the tasks (warm-ups first) and collect their outcomes; a task whose worker died is
    submitted once more. Returns (cases retried, workers seen)."""
    from distributed import KilledWorker, wait
    needed = sorted({k for t in tasks for k in t.hdbs})
    # one copy of each HDB per worker, keyed by its content
    futures = client.scatter({f"hydrolink-hdb-{digests[k]}": hdbs[k] for k in needed}, broadcast=True)
    scattered = {k: futures[f"hydrolink-hdb-{digests[k]}"] for k in needed}
    warm: dict[str, object] = {}
    for group, members in groups.items():
        first = members[0]
        warm[group] = client.submit(warm_setup, first.scene_text, {k: scattered[k] for k in first.hdbs},
                                    key=f"hydrolink-warm-{first.case_id}", pure=False)
    group_of = {t.case_id: g for g, members in groups.items() for t in members}

    def submit(task: CaseTask):
        after = [warm[group_of[task.case_id]]] if task.case_id in group_of else []
        return client.submit(run_case, task, {k: scattered[k] for k in task.hdbs}, *after,
                             key=f"hydrolink-case-{task.case_id}-{task.attempt}", pure=False)
    pending = {submit(t): t for t in tasks}
    bar = _Progress(len(tasks), progress)
    retried = 0
    workers = len(client.scheduler_info().get("workers", {}))
    try:
        while pending:
            try:
                done, _ = wait(list(pending), timeout=1.0, return_when="FIRST_COMPLETED")
            except TimeoutError:   # nothing finished this second: refresh the running count
                done = ()
            n_done = n_failed = 0
            for fut in done:
                task = pending.pop(fut)
                if fut.status == "finished":
                    outcome: CaseOutcome = fut.result()
                else:
                    try:
                        exc = fut.exception()
                    except BaseException as err:  # noqa: BLE001 - cancelled: its worker or scheduler is gone
                        exc = err
                    died = isinstance(exc, KilledWorker) or fut.status == "cancelled"
                    if died and task.attempt == 1:
                        again = replace(task, attempt=2)
                        pending[submit(again)] = again
                        retried += 1
                        log.warning("case %s: its worker died; running it once more", task.label)
                        continue
                    why = ("its worker died twice" if died
                           else f"{type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''}")
                    outcome = CaseOutcome(task.case_id, "failed", why, math.nan, task.solver, "", task.attempt, {})
                on_outcome(task, outcome)
                n_done += 1
                n_failed += outcome.status != "complete"
                fut.release()
            bar.update(n_done, n_failed, _running(client, {f.key for f in pending}) if pending else 0)
    finally:
        bar.close()
        for fut in pending:
            fut.cancel()
    return retried, workers


def run_sweep(sweep_path: str | Path, outdir: str | Path, *, workers: int | None = None, scheduler: str | None = None,
              client=None, retry_failed: bool = False, progress: bool = True, log_line=print) -> SweepReport:
    """Run a sweep file into ``outdir`` (module docstring); SweepError before anything runs when
    the file or a case is invalid. ``client``: a Dask client of the caller's to run on (instead of
    ``workers`` / ``scheduler``)."""
    t0 = time.perf_counter()
    sweep = load_sweep(sweep_path)
    outdir = Path(outdir).resolve()
    (outdir / "cases").mkdir(parents=True, exist_ok=True)
    hdbs, digests = load_hdbs(sweep, progress)
    for case in sweep.cases:
        case.case_id = case_identity(case, digests)
    records = finished_records(outdir, sweep.cases)
    todo = [c for c in sweep.cases if records[c.case_id] is None
            or (retry_failed and records[c.case_id].status != "complete")]
    report = SweepReport(outdir, len(sweep.cases), len(sweep.cases) - len(todo), len(todo))
    log_line(f"hydrolink sweep: {len(sweep.cases)} cases, {report.skipped} finished before, {len(todo)} to run")
    if todo:
        token = secrets.token_hex(16)
        (outdir / TOKEN_FILE).write_text(token)
        from hydrolink.clients.studies.sweep_results import averaging_window
        tasks = [CaseTask(c.case_id, c.name, c.label, c.text, c.solver,
                          tuple(sorted({b.hdb for b in c.scene.bodies if b.wet})), str(outdir), token,
                          averaging_window(c, sweep.spec.window, c.solver == "steady"), c.tail) for c in todo]
        groups: dict[str, list[CaseTask]] = {}
        for c, t in zip(todo, tasks):
            g = _setup_group(c, digests)
            if g is not None:
                groups.setdefault(g, []).append(t)
        folders: dict[str, set[str]] = {}

        def on_outcome(task: CaseTask, outcome: CaseOutcome) -> None:
            if not outcome.stored:   # a worker that does not see OUTDIR, or one that died
                store_outcome(task, outcome, None, task.scene_text.encode())
            records[task.case_id] = outcome.record(task.name, task.label)
            for kind, folder in outcome.caches.items():
                folders.setdefault(kind, set()).add(folder)
        with ExitStack() as stack:
            dask_client = client or open_cluster(stack, workers, scheduler)
            report.retried, report.workers = run_cases(dask_client, tasks, hdbs, digests, groups, progress,
                                                       on_outcome)
        report.cache_folders = {k: sorted(v) for k, v in folders.items()}
        for kind, fs in report.cache_folders.items():
            if len(fs) > 1:
                report.notes.append(f"the workers used {len(fs)} different {kind} cache folders ({fs}): set "
                                    "HYDROLINK_CACHE to one folder they all see to share it")
    report.failed = [c.label for c in sweep.cases
                     if records[c.case_id] is not None and records[c.case_id].status == "failed"]
    report.outputs, report.annual_energy = write_outputs(sweep, outdir, records)
    report.wall_time = time.perf_counter() - t0
    return report


def write_outputs(sweep: Sweep, outdir: Path, records: dict[str, CaseRecord | None]) -> tuple[list[str], list[str]]:
    """sweep.nc, cases.csv and the plots from every finished case; returns the files written and,
    with a site, one AEP line per combination of the other sweep keys."""
    from hydrolink.clients.studies.sweep_plots import plot_capture_width, plot_power_matrix
    from hydrolink.clients.studies.sweep_case_file import read_summary
    from hydrolink.clients.studies.sweep_results import build_dataset, case_sea_states, write_cases_csv
    summaries = {}
    done = {k: r for k, r in records.items() if r is not None}
    for case in sweep.cases:
        rec = done.get(case.case_id)
        if rec is None or rec.status != "complete":
            continue
        try:
            summaries[case.case_id] = read_summary(case_paths(outdir, rec.name)["results"])
        except (OSError, ValueError) as exc:
            rec.status, rec.error = "failed", f"summary: {exc}"
    ds = build_dataset(sweep, done, summaries, case_sea_states(sweep))
    paths = [outdir / "sweep.nc", outdir / "cases.csv"]
    from hydrolink.server.disk_cache import write_atomic
    write_atomic(paths[0], lambda tmp: ds.to_netcdf(tmp))
    write_cases_csv(ds, sweep, paths[1])
    title = f"{sweep.path.name} ({sweep.scene_path.name})"
    if plot_power_matrix(ds, outdir / "power_matrix.png", title):
        paths.append(outdir / "power_matrix.png")
    period_key = next((k for k in sweep.keys if full_key(k) in PERIOD_KEYS), None)
    if plot_capture_width(ds, sweep.keys, period_key, outdir / "capture_width.png", title):
        paths.append(outdir / "capture_width.png")
    aep = []
    if "annual_energy" in ds:
        others = list(ds["annual_energy"].dims)
        for idx in np.ndindex(*ds["annual_energy"].shape):
            sel = dict(zip(others, idx))
            where = ", ".join(f"{k} = {ds[k].values[i]:g}" if isinstance(ds[k].values[i], float)
                              else f"{k} = {ds[k].values[i]}" for k, i in sel.items())
            aep.append(f"{where + ': ' if where else ''}AEP {float(ds['annual_energy'][idx]) / 1e6:.4g} MWh "
                       f"({100 * float(ds['uncovered_occurrence'][idx]):.1f} % of the site's occurrence without a case)")
    return [str(p) for p in paths], aep


__all__ = ["SweepError", "SweepReport", "run_sweep", "write_outputs"]
