"""Lockstep cost per step beside its floors, all measured in the same run.

    python bench/bench_lockstep.py [--rm3-duration 400] [--cyl-duration 100] [--repeat 3] [--pin] [--no-tcp]

Cases (dt = 0.01 s):

- RM3 (examples/rm3/rm3.toml: float + spar, heave each, linear PTO, 40 s of radiation memory);
- the cylinder (examples/cylinder, 1 body, surge/heave/pitch, 20 s of radiation memory);

each run embedded (``hydrolink run`` with the in-process server) and against ``hydrolink serve``
over loopback TCP. Floors:

- bare Exudyn: the same linear system as RM3 (two heave masses m + A∞ with their coupling block,
  the hydrostatic springs, the PTO damper between them) as one ``ObjectGenericODE2`` on one
  2-coordinate node, stepped one ``SolveSteps`` at a time, with a Python PreStep doing the
  radiation convolution over the same (2, 2·4001) kernel (one np.dot over a ring buffer) plus a
  regular-wave force and setting the force vector: what a step costs with nothing but Exudyn and
  the physics;
- raw ZeroMQ: a DEALER/ROUTER round trip on loopback TCP to an echo process, msgpack frames the
  size of a step request and reply.

An embedded figure is compared with bare Exudyn (goal: RM3 ≤ 3×); a TCP figure with the embedded
figure + the raw round trip (goal ≤ 1.5×). Figures are medians over ``--repeat`` runs [min-max];
this 2-core machine is shared and noisy, so only ratios taken in the same run mean much.
"""

from __future__ import annotations

import argparse
import logging
import os
import re
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import msgpack
import numpy as np

from hydrolink.clients.scene_inputs import load_scene_hdbs
from hydrolink.clients.run import run_scene_file
from hydrolink.protocol.scene import load_scene

REPO = Path(__file__).resolve().parents[1]
CYLINDER_SPEC = REPO / "examples" / "cylinder" / "cylinder_hdb.toml"
RM3_SCENE = REPO / "examples" / "rm3" / "rm3.toml"
DT = 0.01


def cylinder_scene(duration: float, dofs: str = '["surge", "heave", "pitch"]') -> str:
    return f"""\
[simulation]
dt = {DT}
duration = {duration}
progress = false
[water]
density = 1025.0
[waves]
type = "regular"
height = 0.2
period = 3.0
ramp = 10.0
[hydro]
irf_duration = 20.0
[[bodies]]
name = "cylinder"
hdb = "{CYLINDER_SPEC}"
mass = 3220.1
center_of_mass = [0.0, 0.0, -0.5]
inertia = [1408.4, 1408.4, 1609.6]
dofs = {dofs}
"""


def rm3_scene(duration: float) -> str:
    """examples/rm3/rm3.toml at dt 0.01 s for ``duration`` s, its HDB and mesh paths made absolute."""
    text = RM3_SCENE.read_text()
    for path in set(re.findall(r'(?:hdb|mesh) = "([^"]+)"', text)):   # the HDB's and the meshes' files
        text = text.replace(f'"{path}"', f'"{(RM3_SCENE.parent / path).resolve().as_posix()}"')
    text = re.sub(r"(?m)^dt = .*$", f"dt = {DT}\nprogress = false", text)
    return re.sub(r"(?m)^duration = .*$", f"duration = {duration}", text)


# ------------------------------------------------------------------------------ floors

def generic_ode2_us(mass: np.ndarray, stiffness: np.ndarray, damping: np.ndarray | None, force, n_steps: int,
                    dt: float) -> tuple[float, float]:
    """(wall, thread CPU) µs per step of one ``ObjectGenericODE2`` of ``len(mass)`` coordinates on
    one node (at rest at the start), stepped one ``SolveSteps`` of ``dt`` at a time (generalized-α,
    spectral radius 1), a PreStep setting its force vector to ``force(k, q, v)`` at step k."""
    import exudyn as exu
    from exudyn.itemInterface import NodeGenericODE2, ObjectGenericODE2

    n = len(mass)
    sc = exu.SystemContainer()
    mbs = sc.AddSystem()
    node = mbs.AddNode(NodeGenericODE2(referenceCoordinates=[0.0] * n, initialCoordinates=[0.0] * n,
                                       initialCoordinates_t=[0.0] * n, numberOfODE2Coordinates=n))
    damped = {} if damping is None else {"dampingMatrix": damping}
    obj = mbs.AddObject(ObjectGenericODE2(nodeNumbers=[node], massMatrix=mass, stiffnessMatrix=stiffness,
                                          forceVector=[0.0] * n, **damped))
    sd = mbs.systemData
    step = [0]

    def pre_step(mbs, t):
        k = step[0]
        mbs.SetObjectParameter(obj, "forceVector", force(k, sd.GetODE2Coordinates(), sd.GetODE2Coordinates_t()))
        step[0] = k + 1
        return True

    mbs.SetPreStepUserFunction(pre_step)
    mbs.Assemble()
    ss = exu.SimulationSettings()
    ss.solution.file.write = False
    ss.solution.sensors.active = False
    ti = ss.timeIntegration
    ti.verboseMode, ti.adaptiveStep, ti.numberOfSteps, ti.endTime = 0, False, 1, dt
    ti.generalizedAlpha.spectralRadius = 1.0
    solver = exu.MainSolverImplicitSecondOrder()
    solver.InitializeSolver(mbs, ss)
    it = solver.it
    t0, c0 = time.perf_counter(), time.thread_time()
    for k in range(n_steps):
        it.startTime, it.endTime = k * dt, (k + 1) * dt
        solver.SolveSteps(mbs, ss)
    wall, cpu = time.perf_counter() - t0, time.thread_time() - c0
    solver.FinalizeSolver(mbs, ss)
    return wall / n_steps * 1e6, cpu / n_steps * 1e6


def bare_exudyn_us(scene_path: Path, n_steps: int) -> float:
    """µs per step of the RM3 linear system in bare Exudyn (module docstring), the force in a PreStep."""
    from hydrolink.server.model import HydroModel

    scene, _ = load_scene(scene_path)
    hdbs = load_scene_hdbs(scene, scene_path, progress=False)
    model = HydroModel(scene, {b.name: hdbs[b.hdb] for b in scene.bodies})
    setup = model.setup_info()
    idx = np.flatnonzero(setup.active.reshape(-1))                  # float heave, spar heave
    mass = np.diag([b.mass for b in scene.bodies]) + setup.added_mass[np.ix_(idx, idx)]
    stiff = setup.hydrostatic_stiffness[np.ix_(idx, idx)]
    c = scene.ptos[0].damping
    damp = c * np.array([[1.0, -1.0], [-1.0, 1.0]])
    n, L = idx.size, model.irf_samples + 1
    kernel = np.random.default_rng(0).standard_normal((n, L * n)) * 1e3   # the size is what costs
    amp, w = np.array([1e5, 2e4]), 2 * np.pi / 8.0
    buf, ring = np.zeros((2 * L, n)), [0]

    def force(k, q, v):
        p = ring[0] = (ring[0] - 1) % L
        buf[p] = v
        buf[p + L] = v
        return (kernel @ buf[p:p + L].reshape(-1) + amp * np.cos(w * k * DT)).tolist()

    return generic_ode2_us(mass, stiff, damp, force, n_steps, DT)[0]


ECHO = """\
import sys, msgpack, zmq
ctx = zmq.Context(); sock = ctx.socket(zmq.ROUTER); sock.setsockopt(zmq.LINGER, 0)
sock.bind("tcp://127.0.0.1:*"); print(sock.getsockopt_string(zmq.LAST_ENDPOINT), flush=True)
reply = sys.stdin.buffer.read()
while True:
    frames = sock.recv_multipart()
    if msgpack.unpackb(frames[-1]).get("type") == "bye":
        sock.send_multipart([*frames[:-1], b""]); break
    frames[-1] = reply
    sock.send_multipart(frames)
"""


def raw_zmq_us(n: int, n_bodies: int, pin: bool) -> np.ndarray:
    """Round trips (µs) of a step-sized msgpack request to an echo ROUTER process answering a
    forces-sized reply (unpacked on both sides: the transport plus the framing, nothing else)."""
    import zmq

    def arr(seed: int) -> dict:
        a = np.random.default_rng(seed).standard_normal((n_bodies, 6))
        return {"dtype": "<f8", "shape": [n_bodies, 6], "data": a.tobytes()}

    env = {"v": 1, "msg_id": "c-0123abcd-1", "session": "s" * 32}
    request = dict(env, type="step", seq=1, time=0.01, iteration=0, position=arr(0), velocity=arr(1))
    reply = dict(env, type="forces", parent="c-0123abcd-1", seq=1, iteration=0, time=0.01,
                 excitation=arr(2), radiation=arr(3), hydrostatic=arr(4), wave_elevation=0.1, compute_us=5.0)
    cmd = [sys.executable, "-c", ECHO]
    proc = subprocess.Popen(["taskset", "-c", "0", *cmd] if pin else cmd, stdin=subprocess.PIPE,
                            stdout=subprocess.PIPE)
    proc.stdin.write(msgpack.packb(reply))
    proc.stdin.close()
    address = proc.stdout.readline().decode().strip()
    ctx = zmq.Context()
    sock = ctx.socket(zmq.DEALER)
    sock.setsockopt(zmq.LINGER, 0)
    sock.connect(address)
    out = np.empty(n)
    try:
        for k in range(n + 200):
            t0 = time.perf_counter()
            sock.send(msgpack.packb(request))
            msgpack.unpackb(sock.recv())
            if k >= 200:   # warm-up
                out[k - 200] = (time.perf_counter() - t0) * 1e6
        sock.send(msgpack.packb({"type": "bye"}))
        sock.recv()
    finally:
        sock.close(0)
        ctx.term()
        proc.wait(10)
    return out


# ------------------------------------------------------------------------------ runs

def start_server(pin: bool) -> tuple[subprocess.Popen, str]:
    cmd = [sys.executable, "-m", "hydrolink.clients.cli", "serve", "--bind", "tcp://127.0.0.1:*"]
    if pin:
        cmd += ["--cpu", "0"]
    proc = subprocess.Popen(cmd, stderr=subprocess.PIPE, text=True)
    line = proc.stderr.readline()
    match = re.search(r"listening on (tcp://\S+)", line)
    if not match:
        proc.kill()
        raise RuntimeError(f"server did not start: {line!r}")
    return proc, match.group(1)


def run_us(scene_path: Path, out: Path, hdbs: dict, server: str | None = None) -> float:
    """µs per step of one whole run (client + server + transport + results file)."""
    summary = run_scene_file(scene_path, out, server=server, progress=False, hdbs=hdbs)
    assert summary.status == "complete", summary.status
    return summary.wall_time / summary.steps * 1e6


def med(xs: list[float]) -> str:
    return f"{statistics.median(xs):.0f} [{min(xs):.0f}-{max(xs):.0f}]"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rm3-duration", type=float, default=400.0, help="simulated seconds of RM3 per run")
    parser.add_argument("--cyl-duration", type=float, default=100.0, help="simulated seconds of the cylinder")
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--pin", action="store_true", help="pin client, server and echo process to CPU 0")
    parser.add_argument("--no-tcp", action="store_true", help="embedded runs only")
    args = parser.parse_args()
    logging.disable(logging.WARNING)   # the scenes' setup warnings are not what is measured
    if args.pin:
        os.sched_setaffinity(0, {0})

    cases = {"RM3 (2 bodies, heave, PTO)": (rm3_scene(args.rm3_duration), args.rm3_duration),
             "cylinder (surge, heave, pitch)": (cylinder_scene(args.cyl_duration), args.cyl_duration)}
    with tempfile.TemporaryDirectory() as tmp:
        paths, hdbs = {}, {}
        for i, (name, (text, _)) in enumerate(cases.items()):
            paths[name] = Path(tmp) / f"case{i}.toml"
            paths[name].write_text(text)
            hdbs[name] = load_scene_hdbs(load_scene(paths[name])[0], paths[name])  # build / warm the cache
        rm3 = next(iter(cases))
        emb: dict[str, list[float]] = {name: [] for name in cases}
        tcp: dict[str, list[float]] = {name: [] for name in cases}
        bare: list[float] = []
        trips: list[np.ndarray] = []
        for _ in range(args.repeat):   # interleaved: each repeat sees the same machine load
            bare.append(bare_exudyn_us(paths[rm3], int(round(args.rm3_duration / DT))))
            trips.append(raw_zmq_us(5000, 2, args.pin))
            for name in cases:
                emb[name].append(run_us(paths[name], Path(tmp) / "embedded.nc", hdbs[name]))
                if args.no_tcp:
                    continue
                proc, address = start_server(args.pin)
                try:
                    tcp[name].append(run_us(paths[name], Path(tmp) / "tcp.nc", hdbs[name], address))
                finally:
                    proc.terminate()
                    proc.wait(10)

    floor, rt = statistics.median(bare), float(np.median(np.concatenate(trips)))
    p = np.percentile(np.concatenate(trips), [10, 90])
    print(f"dt {DT} s; RM3 {args.rm3_duration:g} s ({int(round(args.rm3_duration / DT))} steps), cylinder "
          f"{args.cyl_duration:g} s; medians of {args.repeat} [min-max]"
          f"{', pinned to CPU 0' if args.pin else ''}; load average {os.getloadavg()[0]:.1f} on "
          f"{os.cpu_count()} CPUs\n")
    print(f"floor: bare Exudyn (RM3 system, PreStep convolution) {med(bare)} µs/step")
    print(f"floor: raw ZeroMQ DEALER/ROUTER round trip (msgpack, loopback TCP) {rt:.0f} µs "
          f"[p10 {p[0]:.0f}, p90 {p[1]:.0f}]\n")
    print("| case | path | µs/step | steps/s | floor µs/step | ratio |")
    print("|---|---|---|---|---|---|")
    for name in cases:
        e = statistics.median(emb[name])
        print(f"| {name} | embedded | {med(emb[name])} | {1e6 / e:.0f} | {floor:.0f} (bare Exudyn) | "
              f"{e / floor:.2f} |")
        if tcp[name]:
            t = statistics.median(tcp[name])
            print(f"| {name} | loopback TCP | {med(tcp[name])} | {1e6 / t:.0f} | {e + rt:.0f} (embedded + "
                  f"raw ZeroMQ {rt:.0f}) | {t / (e + rt):.2f} |")


if __name__ == "__main__":
    main()
