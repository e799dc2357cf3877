"""hydrolink's benchmark suite, case for case like SEA-Stack's, with the machine named and each
case's bare-Exudyn floor measured in the same run.

    python bench/bench_suite.py [-o suite.json] [--cases sphere_decay_conv,...] [--scale 1.0]

Cases (SEA-Stack's v1.0.0-beta suite, /work/shared/notes/field-research.md §2, in kind):

- ``sphere_decay_conv`` / ``_ss``: the IEA Task-10 sphere (examples/data/sphere_task10) in heave,
  released 1 m above equilibrium in still water, dt 0.015 s, 100 s, radiation by convolution
  (10 s of memory) / state space;
- ``sphere_irreg_conv`` / ``_ss``: the same sphere in a JONSWAP sea (Hs 2 m, Tp 8 s, 300
  components), dt 0.015 s, 600 s;
- ``oswec_reg_batch``: an OSWEC-like flap (F3OF's base, held, and its up-wave flap on a hinge:
  examples/f3of/f3of_hdb.toml, built by ``hydrolink hdb build`` and cached) in 16 regular waves
  (T 6-16 s, H 1 m), 62.5 s each (1000 s in all), dt 0.03 s;
- ``rm3_mooring_irreg_conv`` / ``_ss``: RM3 (examples/rm3_moordyn) on SEA-Stack's own MoorDyn file
  (bench/suite/rm3_lines.txt: its data/demos/run_seastack/rm3/assets/mooring/lines_rm3.txt, MIT,
  read by its tests/benchmark/rm3/test_bench_rm3_mooring_irreg.cpp: three chains from anchors 267 m
  out to clump weights, 40 m up to the fairleads, six lines, 60 segments, dtM 0.0005 s, so 20
  MoorDyn substeps a step, its line and body outputs written; only the fairleads' z is made
  relative to the spar's reference point) in a JONSWAP sea (Hs 2.5 m, Tp 8 s), dt 0.01 s, 300 s.
  SEA-Stack's sea is WEC-Sim's recorded elevation (an eta file, excitation by IRF convolution
  truncated at 20 s); hydrolink's 300 components cost about as much a step and leave MoorDyn's
  share, the case's dominant cost, the same;
- ``f3of_decay_conv`` / ``_ss``: examples/f3of/f3of_decay.toml at dt 0.02 s, 200 s;
- ``five_body_spreading``: five cylinders in a row (bench/suite/five_body.toml: one HDB, full
  interaction, cos-2s spreading over 5 directions, two MoorDyn chains each), dt 0.02 s, 200 s.
  **Not SEA-Stack's case**: its 5sa_spreading (tests/benchmark/5sa/test_bench_5sa_spreading.cpp,
  demos/5sa/five_sa_model_setup.h) is the 5SA attenuator: five 36 m segments on universal joints
  with 16 spring-dampers, linear damping, JONSWAP Hs 3 m Tp 10 s cos-2s s = 12 over 64 x 21
  components, an HDB (5sa_directional.h5) its repository snapshot does not hold, and MoorDyn's
  lines_5sa.txt on two of the segments (five lines, 165 segments, a clump, dtM 0.0005 s: 40
  substeps a step). Its bare MoorDyn step costs 2.5x this case's ten chains (2,745 against 1,113
  CPU µs at load 5, same machine), so this case's RTF against the goal flatters hydrolink: read
  it as the array's cost, not as the comparison;

Per case: the loop's wall time (``hydrolink run``'s, set-up excluded: HDBs, IRFs and fits come
from their caches after a first run), RTF = simulated / wall seconds, µs per step, where the step's
time goes (hydro: the force server's round trips, in-process; client: the rest, Exudyn and the
loop), and the **bare-Exudyn floor** of the same case in the same run: its wet bodies' active DOFs
as one ``ObjectGenericODE2`` (rigid-body mass + A∞, hydrostatic stiffness), stepped one
``SolveSteps`` at a time, a Python PreStep calling the case's own ``HydroModel.step`` (the
compiled linear step) and setting the force vector: what a step costs with nothing but Exudyn and
the hydrodynamics (no joints, PTOs or MoorDyn; their cost is the case's own). SEA-Stack's RTFs
were measured on a Ryzen 9 9950X (~1.4x this VM's per-core speed); the goal is 1.5 x its RTF / 1.4.

Beside the wall-clock figures, the loop's CPU time on its thread (``rtf_cpu``,
``cpu_us_per_step``; the floor's likewise): on a loaded machine a thread waiting for a core spends
none, so these are the figures load distorts least (cache and core sharing still inflate them).
MoorDyn steps in a worker process by default (``[[moorings]] workers``, README): its CPU is not the
loop's; ``children_cpu_us_per_step`` is the run's child processes' (the MoorDyn workers, and
MoorDyn's layout probe at set-up).

The JSON names the machine (CPU model, cores, load averages before and after, versions). On a
shared machine only ratios taken in the same run compare: state the load with every figure.
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import platform
import re
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from importlib import metadata
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
SUITE = REPO / "bench" / "suite"
SPHERE = REPO / "examples" / "data" / "sphere_task10" / "sphere.h5"
#: SEA-Stack's RM3 MoorDyn file (its fairleads' z made relative to the spar's reference point)
RM3_LINES = SUITE / "rm3_lines.txt"
#: the spar's moored equilibrium on RM3_LINES from its reference position (the run's moordyn report)
RM3_SPAR_OFFSET = "[0.0, 0.0, -0.0464, 0.0, 0.0, 0.0]"
SEA_STACK_SPEEDUP = 1.4    # SEA-Stack's machine per core over this VM's (issue 36)
GOAL_FACTOR = 1.5          # goal: this times SEA-Stack's RTF / SEA_STACK_SPEEDUP


@dataclass(frozen=True)
class Case:
    """One benchmark case: scene texts (one per run; absolute paths), SEA-Stack's published RTF."""
    name: str
    scenes: tuple[str, ...]
    sea_stack_rtf: float
    note: str


def _sphere(dt: float, duration: float, waves: str, radiation: str, dofs: str, extra: str = "") -> str:
    return f"""[simulation]
dt = {dt}
duration = {duration}
progress = false
[water]
density = 1000.0
depth = 200.0
{waves}
[hydro]
irf_duration = 10.0
radiation = "{radiation}"
[[bodies]]
name = "sphere"
hdb = "{SPHERE}"
mass = 261800.0
center_of_mass = [0.0, 0.0, -2.0]
inertia = [2.6e6, 2.6e6, 2.6e6]
dofs = {dofs}
{extra}"""


def _absolute(path: Path, **replace: str) -> str:
    """A scene file's text with its relative file paths made absolute and ``key = value`` lines
    replaced (a key not in the file is added to [simulation])."""
    text = path.read_text()
    for key in ("hdb", "file", "mesh"):
        text = re.sub(rf'(?m)^{key} = "([^"/][^"]*)"', lambda m: f'{key} = "{(path.parent / m.group(1)).resolve()}"',
                      text)
    for key, value in replace.items():
        if re.search(rf"(?m)^{key} = ", text):
            text = re.sub(rf"(?m)^{key} = .*$", f"{key} = {value}", text, count=1)
        else:
            text = text.replace("[simulation]", f"[simulation]\n{key} = {value}", 1)
    return text


def _section(text: str, name: str, body: str) -> str:
    """``text`` with its [name] section's body replaced by ``body``."""
    return re.sub(rf"(?ms)^\[{name}\]\n.*?(?=^\[)", f"[{name}]\n{body}\n", text, count=1)


def _oswec(period: float, duration: float) -> str:
    hdb = (REPO / "examples" / "f3of" / "f3of_hdb.toml").resolve()
    return f"""[simulation]
dt = 0.03
duration = {duration}
progress = false
[water]
density = 1025.0
depth = "inf"
[waves]
type = "regular"
height = 1.0
period = {period:.6g}
ramp = 10.0
[hydro]
irf_duration = 30.0
irf_taper = 0.3
[[bodies]]
name = "base"
hdb = "{hdb}"
mass = 1089825.0
center_of_mass = [0.0, 0.0, -9.0]
inertia = [7.63e7, 7.63e7, 2.0e7]
[[bodies]]
name = "flap1"
hdb = "{hdb}"
mass = 179250.0
center_of_mass = [-12.5, 0.0, -5.5]
inertia = [5.85e6, 1.3e6, 4.58e6]
[[joints]]
name = "hinge"
type = "revolute"
body1 = "base"
body2 = "flap1"
point = [-12.5, 0.0, 0.0]
axis = [0.0, 1.0, 0.0]
[[joints]]
name = "hold"
type = "fixed"
body1 = "ground"
body2 = "base"
point = [0.0, 0.0, -9.0]
"""


def cases(scale: float) -> list[Case]:
    """The suite (module docstring); ``scale`` shortens every duration (a quick check)."""
    def d(seconds: float) -> float:
        return round(seconds * scale, 6)
    still = '[waves]\ntype = "still"'
    jonswap = '[waves]\ntype = "irregular"\nspectrum = "jonswap"\nhs = 2.0\ntp = 8.0\nseed = 1\ncomponents = 300\nramp = 20.0'
    decay = "initial_displacement = [0.0, 0.0, 1.0, 0.0, 0.0, 0.0]"
    out = []
    for rad, tag, sea in (("convolution", "conv", (659, 74)), ("state-space", "ss", (513, 97))):
        out.append(Case(f"sphere_decay_{tag}", (_sphere(0.015, d(100), still, rad, '["heave"]', decay),), sea[0],
                        "Task-10 sphere, heave, 1 m decay, dt 0.015 s, 100 s"))
        out.append(Case(f"sphere_irreg_{tag}", (_sphere(0.015, d(600), jonswap, rad, '["surge", "heave", "pitch"]'),),
                        sea[1], "Task-10 sphere, surge/heave/pitch, JONSWAP Hs 2 m Tp 8 s, 300 components, 600 s"))
    out.append(Case("oswec_reg_batch", tuple(_oswec(p, d(62.5)) for p in np.linspace(6.0, 16.0, 16)), 269,
                    "F3OF base held + flap on a hinge, 16 regular waves T 6-16 s, 62.5 s each, dt 0.03 s"))
    rm3 = REPO / "examples" / "rm3_moordyn" / "rm3_moordyn.toml"
    f3of = REPO / "examples" / "f3of" / "f3of_decay.toml"
    for rad, tag in (("convolution", "conv"), ("state-space", "ss")):
        text = _absolute(rm3, dt="0.01", duration=str(d(300)), progress="false")
        text = _section(text, "waves", 'type = "irregular"\nspectrum = "jonswap"\nhs = 2.5\ntp = 8.0\nseed = 1\n'
                                       'components = 300\nramp = 20.0')
        text = text.replace("[hydro]", f'[hydro]\nradiation = "{rad}"', 1)
        text = re.sub(r'(?m)^file = ".*"', f'file = "{RM3_LINES}"', text, count=1)
        text = re.sub(r"(?m)^initial_displacement = .*$", f"initial_displacement = {RM3_SPAR_OFFSET}", text, count=1)
        out.append(Case(f"rm3_mooring_irreg_{tag}", (text,), 15,
                        "RM3 on SEA-Stack's MoorDyn spread (three chains with clump weights: six lines, 60 "
                        "segments, dtM 0.0005 s), JONSWAP Hs 2.5 m Tp 8 s, dt 0.01 s, 300 s"))
        text = _absolute(f3of, dt="0.02", duration=str(d(200)), progress="false")
        out.append(Case(f"f3of_decay_{tag}", (text.replace("[hydro]", f'[hydro]\nradiation = "{rad}"', 1),), 21,
                        "F3OF, flap 1 released from 10 deg, base held, dt 0.02 s, 200 s"))
    five = _absolute(SUITE / "five_body.toml", duration=str(d(200)), progress="false")
    out.append(Case("five_body_spreading", (five,), 8.2,
                    "five cylinders, one HDB, cos-2s over 5 directions, 10 MoorDyn chains, dt 0.02 s, 200 s"))
    return out


# ------------------------------------------------------------------------------ the floor

def bare_exudyn(scene_path: Path, hdbs: dict) -> dict:
    """µs per step of the case's wet bodies' active DOFs in bare Exudyn with the case's own
    HydroModel in a PreStep (module docstring); with the PreStep's share."""
    from bench_lockstep import generic_ode2_us

    from hydrolink.protocol.scene import load_scene
    from hydrolink.server.model import HydroModel
    from hydrolink.server.rigid_body import rigid_body_mass_matrix

    scene, _ = load_scene(scene_path)
    model = HydroModel(scene, {b.name: hdbs[b.hdb] for b in scene.bodies if b.hdb})
    setup = model.setup_info()
    idx = np.flatnonzero(setup.active.reshape(-1))
    n6 = setup.active.size
    rigid = np.zeros((n6, n6))
    by_name = {b.name: b for b in scene.bodies}
    for k, name in enumerate(setup.bodies):
        b = by_name[name]
        ref = setup.equilibrium_position[k, :3]
        rigid[6 * k:6 * k + 6, 6 * k:6 * k + 6] = rigid_body_mass_matrix(
            b.mass, b.inertia_matrix, np.asarray(b.com_or(ref), float) - ref)
    dt = float(model.dt)
    eq = setup.equilibrium_position.reshape(-1).copy()
    x6, v6, hydro = eq.copy(), np.zeros(n6), [0.0]

    def force(k, q, v):
        t0 = time.perf_counter()
        x6[idx] = eq[idx] + q
        v6[idx] = v
        r = model.step(k * dt, x6.reshape(-1, 6), v6.reshape(-1, 6))
        f = (r["excitation"] + r["radiation"]).reshape(-1)[idx]
        hydro[0] += time.perf_counter() - t0
        return f

    steps = scene.n_exchanges
    wall, cpu = generic_ode2_us((rigid + setup.added_mass)[np.ix_(idx, idx)],
                                setup.hydrostatic_stiffness[np.ix_(idx, idx)], None, force, steps, dt)
    model_us = hydro[0] / steps * 1e6
    return {"us_per_step": wall, "hydro_us": model_us, "exudyn_us": wall - model_us, "cpu_us_per_step": cpu}


# ------------------------------------------------------------------------------ the runs

class LoopClock:
    """The lockstep loop's CPU time on its thread (``time.thread_time``): the loop with the
    in-process server's steps, not the set-up nor the results writer's thread. On a loaded machine
    the figure it distorts least (a thread waiting for a core spends none), so it is reported
    beside the wall time."""

    def __init__(self) -> None:
        from hydrolink.clients.lockstep import driver
        self.seconds, self._run = 0.0, driver.run

        def timed(*args, **kwargs):
            c0 = time.thread_time()
            try:
                return self._run(*args, **kwargs)
            finally:
                self.seconds += time.thread_time() - c0
        driver.run = timed


def _input_copies(text: str, folder: Path) -> str:
    """``text`` with each ``file = "..."`` it names (the MoorDyn files) copied into ``folder`` and
    named there: MoorDyn writes its outputs and log beside its input file, in the run's temporary
    folder rather than the repository."""
    folder.mkdir(parents=True, exist_ok=True)

    def copy(m: re.Match) -> str:
        source = Path(m.group(1))
        target = folder / source.name
        shutil.copyfile(source, target)
        return f'file = "{target}"'
    return re.sub(r'(?m)^file = "([^"]+)"', copy, text)


def run_case(case: Case, work: Path, clock: LoopClock) -> dict:
    """Every run of ``case`` (a first short run of two exchanges warms the caches, numba and the
    imports) and its floor on the first scene."""
    from hydrolink.clients.run import run_scene_file
    from hydrolink.clients.scene_inputs import load_scene_hdbs
    from hydrolink.protocol.scene import load_scene

    wall = sim = steps = hydro = cpu = children = 0.0
    floor = None
    for i, text in enumerate(case.scenes):
        text = _input_copies(text, work / case.name)
        path, short = work / f"{case.name}_{i}.toml", work / f"{case.name}_{i}_short.toml"
        path.write_text(text)
        scene, _ = load_scene(path)
        hdbs = load_scene_hdbs(scene, path, progress=False)
        if i == 0:
            short.write_text(re.sub(r"(?m)^duration = .*$", f"duration = {2 * scene.exchange_dt!r}", text, count=1))
            run_scene_file(short, work / "warm.nc", progress=False, hdbs=hdbs)
            floor = bare_exudyn(path, hdbs)
        c0, ch0 = clock.seconds, resource.getrusage(resource.RUSAGE_CHILDREN)
        s = run_scene_file(path, work / "out.nc", progress=False, hdbs=hdbs)
        if s.status != "complete":
            raise RuntimeError(f"{case.name}: {s.status}")
        cpu += clock.seconds - c0
        ch1 = resource.getrusage(resource.RUSAGE_CHILDREN)
        children += ch1.ru_utime + ch1.ru_stime - ch0.ru_utime - ch0.ru_stime
        wall += s.wall_time
        sim += s.time
        steps += s.steps
        hydro += s.round_trip_us_per_step * s.steps
    us = wall / steps * 1e6
    goal = GOAL_FACTOR * case.sea_stack_rtf / SEA_STACK_SPEEDUP
    return {"case": case.name, "note": case.note, "runs": len(case.scenes), "steps": int(steps), "simulated_s": sim,
            "wall_s": wall, "rtf": sim / wall, "us_per_step": us, "hydro_us": hydro / steps,
            "client_us": us - hydro / steps, "cpu_s": cpu, "rtf_cpu": sim / cpu, "cpu_us_per_step": cpu / steps * 1e6,
            "children_cpu_us_per_step": children / steps * 1e6,
            "floor": floor, "ratio_to_floor": us / floor["us_per_step"],
            "cpu_ratio_to_floor": cpu / steps * 1e6 / floor["cpu_us_per_step"],
            "sea_stack_rtf": case.sea_stack_rtf, "goal_rtf": goal, "meets_goal": sim / wall >= goal,
            "meets_goal_cpu": sim / cpu >= goal}


def machine() -> dict:
    """The machine and software the figures come from."""
    cpu = "unknown"
    try:
        cpu = next(line.split(":", 1)[1].strip() for line in Path("/proc/cpuinfo").read_text().splitlines()
                   if line.startswith("model name"))
    except (OSError, StopIteration):
        pass
    versions = {"python": platform.python_version()}
    for pkg in ("hydrolink", "numpy", "scipy", "numba", "exudyn", "moordyn", "threadpoolctl"):
        try:
            versions[pkg] = metadata.version(pkg)
        except metadata.PackageNotFoundError:
            versions[pkg] = None
    commit = subprocess.run(["git", "-C", str(REPO), "rev-parse", "--short", "HEAD"], capture_output=True,
                            text=True).stdout.strip()
    return {"cpu": cpu, "cores": os.cpu_count(), "platform": platform.platform(), "versions": versions,
            "commit": commit or None, "load_before": list(os.getloadavg())}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("-o", "--output", type=Path, help="JSON file to write (default: print it)")
    parser.add_argument("--cases", help="comma-separated case names (default: all)")
    parser.add_argument("--scale", type=float, default=1.0, help="scale every duration (a quick check: 0.1)")
    args = parser.parse_args()
    logging.disable(logging.WARNING)   # the scenes' setup warnings are not what is measured
    chosen = cases(args.scale)
    if args.cases:
        names = set(args.cases.split(","))
        unknown = names - {c.name for c in chosen}
        if unknown:
            parser.error(f"unknown case(s) {sorted(unknown)}; the suite's: {[c.name for c in chosen]}")
        chosen = [c for c in chosen if c.name in names]
    report = {"machine": machine(), "started": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
              "sea_stack_speedup": SEA_STACK_SPEEDUP, "goal_factor": GOAL_FACTOR, "cases": []}
    clock = LoopClock()
    with tempfile.TemporaryDirectory() as tmp:
        for case in chosen:
            load = os.getloadavg()[0]
            try:
                result = run_case(case, Path(tmp), clock)
            except Exception as exc:   # noqa: BLE001 - one case's failure is its row, not the suite's end
                report["cases"].append({"case": case.name, "note": case.note, "load": load,
                                        "error": f"{type(exc).__name__}: {exc}"})
                print(f"{case.name}: failed: {type(exc).__name__}: {exc}", file=sys.stderr, flush=True)
                continue
            result["load"] = load
            report["cases"].append(result)
            f = result["floor"]
            print(f"{case.name}: RTF {result['rtf']:.0f} (by CPU time {result['rtf_cpu']:.0f}; goal "
                  f"{result['goal_rtf']:.0f}), {result['us_per_step']:.0f} µs/step (hydro {result['hydro_us']:.0f}, client "
                  f"{result['client_us']:.0f}; CPU {result['cpu_us_per_step']:.0f}); floor {f['us_per_step']:.0f} "
                  f"(Exudyn {f['exudyn_us']:.0f}, model {f['hydro_us']:.0f}; CPU {f['cpu_us_per_step']:.0f}); "
                  f"load {load:.1f}", file=sys.stderr, flush=True)
    report["machine"]["load_after"] = list(os.getloadavg())
    text = json.dumps(report, indent=1)
    if args.output:
        args.output.write_text(text + "\n")
    else:
        print(text)


if __name__ == "__main__":
    main()
