"""What a run pays before its first step, measured.

    python bench/bench_setup.py examples [--repeat 3] [--warm-runs 10] [--only cylinder,rm3,...] [--tree DIR ...]
    python bench/bench_setup.py state-space [--bodies 9 27] [--prune 0.0] [--ss-tolerance 0.003] [--max-order 30]

``examples``: the set-up of ``hydrolink run`` for the README's cylinder (examples/cylinder/scene.toml),
RM3 (examples/rm3/rm3.toml), the OSWEC of bench_suite.py, WaveStar (examples/wavestar/wavestar_passive.toml,
bench_wavestar.py's scene without its controller process) and the hinged barges
(examples/hinged_barges/scene.toml), each cut to one exchange (duration = dt, no progress bar): a run
of one step is its set-up, that step and the results file closed. HDBs built from a spec come from
the build cache, state-space fits from theirs (a first run on a machine fills them). Per example:

- ``cold``: the CPU (user + system, every thread; ``os.wait4``) of a ``hydrolink run`` process,
  from its start: what a user's command pays; median of ``--repeat``;
- ``warm``: the CPU of one more run in a process that has run the scene before, its HDBs read once
  and passed in (``run_scene_file(hdbs=...)``): what each case of a sweep pays on a warm Dask worker;
  mean of ``--warm-runs``;
- where that time goes (``--breakdown``, once per example): a CPU-time sampler (SIGPROF every 0.5 ms
  of process CPU, each sample weighted by the CPU since the one before) puts each sample in the
  category of the innermost hydrolink frame by its module (:data:`CATEGORIES`; an import anywhere
  on the stack is ``imports``, a numba or llvmlite frame inside hydrolink's innermost is ``numba``).

BLAS pools get one thread (``OPENBLAS_NUM_THREADS=1``, as Dask's nanny gives its workers and
bench_startup.py its processes): with OpenBLAS's two threads on this loaded 2-core machine a set-up's
small products cost up to 30x their single-thread CPU (the OSWEC's IRF checks 33 against ~1 ms).
``--tree DIR`` (repeatable; DIR holds a ``hydrolink`` package first on PYTHONPATH, as
bench_startup.py's) measures each tree interleaved, example by example: an A/B under the same load.
State the load average printed with every figure.

``state-space``: HydroModel construction with state-space radiation, cold (empty fit cache) and from
the cache, for the scenes of ``bench_radiation.py cost``: 9 = the whole 9N9LA HDB (Capytaine, built
from examples/node_9n9la/node_9n9la_hdb.toml and cached), 27 = three 9N9LA arrays 200 m apart in one
HDB (cross blocks zero), every DOF active, full interaction, dt = 0.01 s, irf_duration = 10 s,
irf_taper = 0.2. Each case runs in a fresh temporary fit cache ($HYDROLINK_STATE_SPACE_CACHE): the
first model fits (cold), the second is built from the cache. Wall and CPU seconds are printed (on a
shared machine the wall time includes waiting for a core).
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import statistics
import subprocess
import sys
import tempfile
import time
from collections import defaultdict
from pathlib import Path

BENCH = Path(__file__).resolve().parent
REPO = BENCH.parent
EXAMPLES = ("cylinder", "rm3", "oswec", "wavestar", "hinged_barges")
TIMEOUT_S = 600.0

#: (category, module-name prefixes) of the innermost hydrolink frame; first match wins
CATEGORIES = (
    ("scene", ("hydrolink.protocol.scene", "hydrolink.protocol.toml_model", "hydrolink.protocol.current")),
    ("HDB load/convert/check", ("hydrolink.server.hdb.", "hydrolink.protocol.hdb.", "hydrolink.clients.scene_inputs")),
    ("state-space cache/fit", ("hydrolink.server.radiation.state_space",)),
    ("IRF and its checks", ("hydrolink.server.radiation.irf",)),
    ("radiation, other", ("hydrolink.server.radiation.",)),
    ("model, other", ("hydrolink.server.fused.", "hydrolink.server.sea.", "hydrolink.server.terms.",
                      "hydrolink.server.model", "hydrolink.server.allocation")),
    ("server's service", ("hydrolink.server.service.", "hydrolink.protocol.codec",
                          "hydrolink.clients.lockstep.connection")),
    ("results file", ("hydrolink.clients.lockstep.results",)),
    ("Exudyn build", ("hydrolink.clients.exudyn.",)),
    ("other hydrolink", ("hydrolink",)),
)


# ------------------------------------------------------------------------------ examples

def example_scenes() -> dict[str, str]:
    """Each example's scene text, one exchange long, its files by absolute path."""
    import tomllib

    from bench_suite import _absolute, _oswec

    files = {"cylinder": "cylinder/scene.toml", "rm3": "rm3/rm3.toml", "wavestar": "wavestar/wavestar_passive.toml",
             "hinged_barges": "hinged_barges/scene.toml"}
    out = {}
    for name, rel in files.items():
        path = REPO / "examples" / rel
        dt = tomllib.loads(path.read_text())["simulation"]["dt"]
        out[name] = _absolute(path, duration=repr(dt), progress="false")
    out["oswec"] = _oswec(8.0, 0.03)
    return {name: out[name] for name in EXAMPLES}


class CpuSampler:
    """Process CPU by category (module docstring): SIGPROF at ``interval`` s of process CPU."""

    def __init__(self, interval: float = 0.0005):
        self.interval = interval
        self.seconds: dict[str, float] = defaultdict(float)
        self._last = 0.0

    def _category(self, frame) -> str:
        numba = False
        while frame is not None:
            module = frame.f_globals.get("__name__", "")
            if frame.f_code.co_filename.startswith("<frozen importlib") or \
                    (frame.f_code.co_name == "<module>" and module != "__main__"):
                return "imports"   # a module's body: also hydrolink's own (pydantic's models, numba's decorators)
            if module.startswith("hydrolink"):
                return "numba compile/cache load" if numba else \
                    next(c for c, prefixes in CATEGORIES if module.startswith(prefixes))
            numba = numba or module.startswith(("numba", "llvmlite"))
            frame = frame.f_back
        return "numba compile/cache load" if numba else "outside hydrolink"

    def _sample(self, signum, frame) -> None:
        now = time.process_time()
        self.seconds[self._category(frame)] += now - self._last
        self._last = now

    def __enter__(self) -> CpuSampler:
        self._last = time.process_time()
        signal.signal(signal.SIGPROF, self._sample)
        signal.setitimer(signal.ITIMER_PROF, self.interval, self.interval)
        return self

    def __exit__(self, *exc) -> None:
        signal.setitimer(signal.ITIMER_PROF, 0.0, 0.0)
        self._sample(None, sys._getframe(1))


def sampled(scene: str, warm_runs: int) -> None:
    """In this process (PYTHONPATH picks the tree): one cold run of ``scene`` under the sampler, then
    ``warm_runs`` warm ones with its HDBs read once; prints the JSON of both."""
    cold = CpuSampler()
    with cold:
        from hydrolink.clients.run import run_scene_file
        run_scene_file(scene, Path(scene).with_suffix(".nc"), progress=False)
    cpu_cold = time.process_time()
    from hydrolink.clients.scene_inputs import load_scene_hdbs
    from hydrolink.protocol.scene import load_scene

    hdbs = load_scene_hdbs(load_scene(scene)[0], scene, progress=False)
    run_scene_file(scene, Path(scene).with_suffix(".nc"), progress=False, hdbs=hdbs)
    warm = CpuSampler()
    with warm:
        c0 = time.process_time()
        for _ in range(warm_runs):
            run_scene_file(scene, Path(scene).with_suffix(".nc"), progress=False, hdbs=hdbs)
        cpu_warm = (time.process_time() - c0) / warm_runs
    print(json.dumps({"cold": cpu_cold, "cold_by": cold.seconds, "warm": cpu_warm,
                      "warm_by": {k: v / warm_runs for k, v in warm.seconds.items()}}))


def _env(tree: Path | None) -> dict[str, str]:
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1"}
    if tree is not None:
        env["PYTHONPATH"] = str(tree)
    return env


def cold_cpu(scene: Path, tree: Path | None) -> float:
    """CPU seconds of one ``hydrolink run`` process of ``scene``."""
    proc = subprocess.Popen([sys.executable, "-m", "hydrolink.clients.cli", "run", str(scene), "-o",
                             str(scene.with_suffix(".nc"))], env=_env(tree), stdout=subprocess.DEVNULL)
    _, status, usage = os.wait4(proc.pid, 0)
    proc.returncode = os.waitstatus_to_exitcode(status)
    if proc.returncode:
        raise RuntimeError(f"hydrolink run {scene} ended with status {proc.returncode}")
    return usage.ru_utime + usage.ru_stime


def warm_cpu(scene: Path, tree: Path | None, warm_runs: int) -> dict:
    """The sampled child's JSON (:func:`sampled`)."""
    out = subprocess.run([sys.executable, __file__, "_sampled", str(scene), "--warm-runs", str(warm_runs)],
                         env=_env(tree), capture_output=True, text=True, timeout=TIMEOUT_S, check=True)
    return json.loads(out.stdout.splitlines()[-1])


def _breakdown(label: str, by: dict[str, float], unit: float) -> None:
    total = sum(by.values())
    parts = ", ".join(f"{k} {v * unit:.0f}" for k, v in sorted(by.items(), key=lambda kv: -kv[1]) if v * unit >= 0.5)
    print(f"    {label} (sampled {total * unit:.0f}): {parts}")


def examples(args) -> None:
    names = args.only.split(",") if args.only else list(EXAMPLES)
    trees = args.tree or [None]
    load_before = os.getloadavg()
    with tempfile.TemporaryDirectory(prefix="hydrolink-setup-") as tmp:
        scenes = {}
        for name, text in example_scenes().items():
            if name in names:
                scenes[name] = Path(tmp) / f"{name}.toml"
                scenes[name].write_text(text)
        for name, scene in scenes.items():   # fills the caches (HDB builds, fits, numba) before anything is timed
            for tree in trees:
                cold_cpu(scene, tree)
        cold: dict[tuple, list[float]] = defaultdict(list)
        warm: dict[tuple, dict] = {}
        for _ in range(args.repeat):        # interleaved: a change of load touches every tree alike
            for name, scene in scenes.items():
                for tree in trees:
                    cold[name, tree].append(cold_cpu(scene, tree))
        for name, scene in scenes.items():
            for tree in trees:
                warm[name, tree] = warm_cpu(scene, tree, args.warm_runs)
    print(f"load average before {load_before[0]:.1f} {load_before[1]:.1f}, after {os.getloadavg()[0]:.1f} "
          f"{os.getloadavg()[1]:.1f}; cold: median of {args.repeat} processes, warm: mean of {args.warm_runs} runs")
    print("| example | tree | cold CPU s (all) | warm CPU ms a run |")
    print("|---|---|---|---|")
    for (name, tree), values in cold.items():
        print(f"| {name} | {tree.name if tree else 'this'} | {statistics.median(values):.2f} "
              f"({' '.join(f'{v:.2f}' for v in values)}) | {1e3 * warm[name, tree]['warm']:.1f} |")
    if args.breakdown:
        print("CPU by category (cold: s x 1000 of the sampled process, warm: ms a run):")
        for (name, tree), w in warm.items():
            print(f"  {name} [{tree.name if tree else 'this'}]")
            _breakdown("cold", w["cold_by"], 1e3)
            _breakdown("warm", w["warm_by"], 1e3)


# ------------------------------------------------------------------------------ state space

def state_space(args) -> None:
    from bench_radiation import array_27, node_9n9la, scene_text

    from hydrolink.protocol.scene import parse_scene
    from hydrolink.server.model import HydroModel

    def build(ds, hydro: str):
        """Wall s, CPU s and the state-space report of one HydroModel over every body of ``ds``."""
        names = [str(b) for b in ds["body"].values]
        scene = parse_scene(scene_text(names, ds["reference_point"].values, hydro))
        t0, c0 = time.perf_counter(), time.process_time()
        m = HydroModel(scene, {nm: ds for nm in names})
        return time.perf_counter() - t0, time.process_time() - c0, m.setup_info().state_space

    ds9 = node_9n9la()
    hydro = (f'radiation = "state-space"\nirf_taper = 0.2\nss_tolerance = {args.ss_tolerance}\n'
             f'ss_max_order = {args.max_order}\ncoupling_tolerance = {args.prune}')
    print("| bodies | run | wall s | CPU s | pairs | pairs fitted | states | max order | max fit error |")
    print("|---|---|---|---|---|---|---|---|---|")
    for nb in args.bodies:
        ds = ds9 if nb == 9 else array_27(ds9)
        with tempfile.TemporaryDirectory() as tmp:
            os.environ["HYDROLINK_STATE_SPACE_CACHE"] = tmp
            for run in ("cold", "cached"):
                wall, cpu, ss = build(ds, hydro)
                print(f"| {nb} | {run} | {wall:.1f} | {cpu:.1f} | {ss.pairs} | {ss.fitted_pairs} | {ss.states} | "
                      f"{ss.max_order} | {ss.max_fit_error:.3g} |", flush=True)


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = p.add_subparsers(dest="what", required=True)
    ex = sub.add_parser("examples", help="each example's set-up CPU, cold and warm")
    ex.add_argument("--repeat", type=int, default=3)
    ex.add_argument("--warm-runs", type=int, default=10)
    ex.add_argument("--only", help=f"comma-separated examples of {','.join(EXAMPLES)}")
    ex.add_argument("--tree", type=Path, action="append", help="a folder holding a hydrolink package (repeatable)")
    ex.add_argument("--breakdown", action="store_true", help="also the CPU by category")
    ss = sub.add_parser("state-space", help="HydroModel construction with state-space radiation")
    ss.add_argument("--bodies", type=int, nargs="+", default=[9, 27], choices=[9, 27])
    ss.add_argument("--prune", type=float, default=0.0, help="hydro.coupling_tolerance")
    ss.add_argument("--ss-tolerance", type=float, default=0.003)
    ss.add_argument("--max-order", type=int, default=30)
    child = sub.add_parser("_sampled")   # the sampled child process of ``examples``
    child.add_argument("scene")
    child.add_argument("--warm-runs", type=int, default=10)
    args = p.parse_args(argv)
    if args.what == "_sampled":
        sampled(args.scene, args.warm_runs)
        return
    sys.path.insert(0, str(BENCH))
    if args.what == "examples":
        examples(args)
    else:
        state_space(args)


if __name__ == "__main__":
    sys.exit(main())
