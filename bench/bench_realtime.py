"""Paced lockstep (docs/realtime.md): RM3 with an external controller over loopback TCP, run at wall
clock (``hydrolink run --realtime``) at 100 Hz, 200 Hz and 1 kHz: overruns and step-latency
percentiles, beside the unpaced cost of a step of the same run.

    python bench/bench_realtime.py [--rates 100 200 1000] [--seconds 60] [--unpaced-seconds 10] [--radiation state-space]
                                   [--relays polled thread] [--channels direct zeromq] [--rt-priority N]
    python bench/bench_realtime.py --probe SECONDS [--probe-work MS] [--probe-peer MS] [--rates 1000] [--rt-priority N]

Each rate: the scene's dt = 1/rate, the run's own force server listening on a loopback port, the
example controller examples/controllers/reactive.py in its own process (force command every step,
latency 1 step). The unpaced run is the same setup without --realtime: its wall time per step is
what a step costs here; a paced run can keep its rate only if that cost stays below 1/rate.
``--channels``: the controller on the polled server's direct channel (SPEC §5.7.5, what ``hydrolink
control`` takes when offered) and/or on ZeroMQ (``--no-direct``), alternated in one run.
``--rt-priority N``: the run's loop (this process's thread, for each run) and the controller's under
SCHED_FIFO at N (``hydrolink run/control --rt-priority``, clients/lockstep/rt_priority.py).
Prints a markdown table (the load average before and after: the figures are the host's as much as
the code's; the CPU time per step of each side, the run's process and the controller's, from the
unpaced run's loop: valid under load), then per paced run where the step time went (protocol/pacing.py PARTS: mean per step,
and the overruns by cause) and the overruns counted in the results file beside the summary's.
``--probe SECONDS``: instead, what the host does by itself to a paced thread (probe(): the pacing around a busy
loop and nothing else; its overruns are the floor under any run's on this host).
"""

from __future__ import annotations

import argparse
import os
import re
import secrets
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

TOKEN = secrets.token_urlsafe(32)   # the runs' join token, handed to their controllers (SPEC §5.7.2)

REPO = Path(__file__).resolve().parents[1]
DATA = REPO / "examples" / "data"
UNPACED = 1e9   # pace factor of the unpaced runs: every release is already past
CONTROLLER = ('\n[[controllers]]\nname = "ctl"\nptos = ["pto"]\ncommand = "force"\ntimeout = 1.0\njoin_timeout = 30.0\n'
              'measurements = ["pto_displacement", "pto_velocity"]\nparameters = { damping = 3.9e5, stiffness = 1.36e6 }\n')


def scene(dt: float, duration: float, radiation: str = "convolution") -> str:
    """examples/rm3/rm3.toml at ``dt``, ``duration`` s, passive damping 0, the reactive controller."""
    text = (REPO / "examples" / "rm3" / "rm3.toml").read_text().replace(
        'interaction = "full"', f'interaction = "full"\nradiation = "{radiation}"')
    for a, b in (('"../data/', f'"{DATA.as_posix()}/'),   # the HDB and the meshes
                 ("duration = 400.0", f"duration = {duration}"), ("dt = 0.08", f"dt = {dt}"),
                 ("ramp = 40.0", "ramp = 10.0"), ("damping = 1.2e6          # N s/m", "damping = 0.0")):
        assert a in text
        text = text.replace(a, b)
    return text + CONTROLLER


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def run(tmp: Path, rate: float, seconds: float, realtime: float | None, radiation: str, relay: str = "polled",
        channel: str = "direct", rt_priority: int | None = None):
    """One run with the controller process; returns the RunSummary (its results file: ``output``)
    and the CPU µs per step of the run's process and of the controller's (LoopCost)."""
    path = tmp / f"rm3_{int(rate)}_{'paced' if realtime else 'free'}_{relay}_{channel}.toml"
    path.write_text(scene(1.0 / rate, seconds, radiation))
    cost = LoopCost()
    summary = run_controlled(path, REPO / "examples" / "controllers" / "reactive.py", realtime, relay, channel, cost,
                             rt_priority)
    return summary, cost


class LoopCost:
    """CPU µs per step of a controlled run: the run's process over its lockstep loop
    (``time.process_time`` around clients/lockstep/driver.run: every thread, ZeroMQ's I/O thread
    and the results writer's included; the set-up left out) and the controller process's from its
    own report (``hydrolink control``: its loop, every thread)."""

    def __init__(self) -> None:
        self.run_cpu_s = 0.0
        self.controller_us: float = float("nan")

    def timed(self, run):
        def wrapped(*args, **kwargs):
            c0 = time.process_time()
            try:
                return run(*args, **kwargs)
            finally:
                self.run_cpu_s += time.process_time() - c0
        return wrapped


def run_controlled(path: Path, controller: Path, realtime: float | None, relay: str = "polled",
                   channel: str = "direct", cost: LoopCost | None = None, rt_priority: int | None = None):
    """Run the scene file ``path`` (results beside it) with the Python controller file
    ``controller`` in its own process (``hydrolink control``) over loopback TCP; the RunSummary.
    ``relay``: "polled", the run's own server polled from its thread (what ``hydrolink run`` does);
    "thread", what it did before: a force server in a thread of this process, the run its client
    over loopback TCP (two Python hops a step, two threads sharing the GIL). ``channel``:
    "direct", the controller on the polled server's direct channel (SPEC §5.7.5); "zeromq", on
    ZeroMQ only (``--no-direct``: what it did before). ``cost``: filled with the CPU per step.
    ``rt_priority``: the run's loop and the controller's under SCHED_FIFO at that priority."""
    from hydrolink.clients.lockstep import driver
    from hydrolink.clients.run import run_scene_file
    from hydrolink.server.service.force_server import serve_in_thread

    address = f"tcp://127.0.0.1:{free_port()}"
    ctl = subprocess.Popen([sys.executable, "-m", "hydrolink.clients.cli", "control", str(controller), "--server",
                            address, "--token", TOKEN, "--join-wait", "60", *(["--no-direct"] if channel == "zeromq" else []),
                            *(["--rt-priority", str(rt_priority)] if rt_priority is not None else [])],
                           stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    srv = thread = None
    plain_run, err = driver.run, ""
    if cost is not None:
        driver.run = cost.timed(plain_run)
    try:
        if relay == "thread":
            from hydrolink.clients.analysis.plant import build_plant
            srv, thread = serve_in_thread(address, plant_builder=build_plant)
        summary = run_scene_file(path, path.with_suffix(".nc"), progress=False, listen=address,
                                 control_token=TOKEN, realtime=realtime, server=address if srv is not None else None,
                                 rt_priority=rt_priority)
    finally:
        driver.run = plain_run
        if srv is not None:
            srv.stop()
            thread.join(5.0)
        try:
            _, err = ctl.communicate(timeout=30)
        except subprocess.TimeoutExpired:
            ctl.kill()
            ctl.communicate()
    said = re.search(r"(\d+) µs CPU a step", err or "")
    if cost is not None:
        cost.run_cpu_s /= max(summary.steps, 1)
        cost.controller_us = float(said.group(1)) if said else float("nan")
    if channel == "direct" and relay == "polled" and "direct channel" not in (err or ""):
        print(f"warning: the controller did not take the direct channel: {err.strip()[-300:]}", file=sys.stderr)
    return summary


def _peer(sock, work: float, rt_priority: int | None) -> None:
    """The probe's peer process (``--probe-peer``): each request answered after ``work`` s of a busy
    loop (bench_controller_wait.serve), as a controller answers a measurement; ends when the socket
    closes."""
    from bench_controller_wait import serve

    from hydrolink.clients.lockstep.rt_priority import rt_priority as held
    with held(rt_priority):
        serve(sock, work)


def probe(seconds: float, work: float, rate: float = 1000.0, rt_priority: int | None = None,
          peer: float | None = None) -> dict:
    """The host's own floor for a paced run: the run's pacing (protocol/pacing.py: the same release,
    sleep and spin) around ``work`` seconds of a busy loop a step and nothing else (no hydrolink, no
    other thread, no file), ``seconds`` at ``rate``. Every gap over 50 µs between two clock reads
    of the busy loop is a time the thread did not run (the VM's vCPU descheduled: steal; an
    interrupt's work on its core); ``late`` is the release's lateness (the sleep's wake-up). Returns
    the steps, the overruns (counted as a run counts them: StepRecord), the lateness and gap
    percentiles and the host's steal time over the probe (/proc/stat).

    ``peer``: half the work, then one round trip over a Unix socket pair to a second process (the
    same policy) that busy-works ``peer`` s before it answers, then the other half — the floor of a
    paced run whose controller is another process on this host, with no hydrolink in either."""
    import numpy as np

    from hydrolink.protocol.pacing import PARTS

    n = int(seconds * rate)
    gaps = []
    clock = time.perf_counter
    link, child = None, 0
    if peer is not None:
        link, theirs = socket.socketpair(socket.AF_UNIX, socket.SOCK_STREAM)
        child = os.fork()
        if child == 0:   # the peer: answer until the probe closes its end, then leave at once
            link.close()
            try:
                _peer(theirs, peer, rt_priority)
            finally:
                os._exit(0)
        theirs.close()
    half = work / 2 if peer is not None else work
    try:
        record, s0, s1 = _probe_steps(n, rate, rt_priority, half, link, gaps, clock)
    finally:
        if link is not None:
            link.close()
            os.waitpid(child, 0)
    rt = record.report()
    late = record.parts[:n, PARTS.index("wake")]     # each release's own lateness (not carried)
    g = np.asarray(gaps) if gaps else np.zeros(1)
    return {"steps": n, "overruns": rt.overruns, "latency_ms": [1e3 * rt.latency_p50, 1e3 * rt.latency_p99,
                                                                  1e3 * rt.latency_max],
            "late_wakeup_ms": [float(1e3 * x) for x in np.percentile(late, [50, 99, 100])],
            "overrun_causes": {k: v for k, v in rt.overrun_causes.items() if v},
            "gaps_over_50us": len(gaps), "gaps_over_500us": int((g > 5e-4).sum()), "gap_max_ms": float(1e3 * g.max()),
            "gap_total_ms": float(1e3 * g.sum()) if gaps else 0.0,
            "steal_percent": 100.0 * (s1[0] - s0[0]) / max(s1[1] - s0[1], 1)}


def _probe_steps(n: int, rate: float, rt_priority: int | None, work: float, link, gaps: list, clock):
    """The probe's paced loop (:func:`probe`): returns its StepRecord and the /proc/stat steal
    ticks before and after."""
    from hydrolink.clients.lockstep.rt_priority import rt_priority as held
    from hydrolink.protocol.pacing import Pacer, StepRecord

    def steal() -> tuple[int, int]:
        with open("/proc/stat") as f:
            ticks = [int(x) for x in f.readline().split()[1:]]
        return ticks[7], sum(ticks)

    def busy(start: float) -> None:
        prev, end = start, start + work
        while prev < end:
            now = clock()
            if now - prev > 5e-5:
                gaps.append(now - prev)
            prev = now

    with held(rt_priority):
        pacer = Pacer(1.0 / rate)
        record = StepRecord(pacer, n)
        s0 = steal()
        for e in range(n):
            pacer.release(e)
            busy(pacer.released)
            if link is not None:
                link.sendall(b"measured")
                if len(link.recv(8)) != 8:
                    raise RuntimeError("the probe's peer process ended")
                busy(clock())
            record.step(e, clock(), 0.0, 0.0, 0.0)
        s1 = steal()
    return record, s0, s1


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rates", type=float, nargs="+", default=[100.0, 200.0, 1000.0])
    ap.add_argument("--seconds", type=float, default=60.0, help="simulated (= wall) seconds of each paced run")
    ap.add_argument("--unpaced-seconds", type=float, default=10.0, help="simulated seconds of each unpaced run")
    ap.add_argument("--radiation", default="convolution", choices=["convolution", "state-space"],
                    help="[hydro] radiation: the convolution's cost grows with irf_duration/dt (40 000 samples "
                         "at 1 kHz), the state-space fit's does not")
    ap.add_argument("--relays", nargs="+", default=["polled"], choices=["polled", "thread"],
                    help="polled: hydrolink run's own server polled from the run's thread; thread: the relay "
                         "before (a server thread, the run over loopback TCP), for a comparison in one run")
    ap.add_argument("--channels", nargs="+", default=["direct"], choices=["direct", "zeromq"],
                    help="direct: the controller on the polled server's direct channel (SPEC §5.7.5); zeromq: "
                         "on ZeroMQ (hydrolink control --no-direct, before revision 1.12), for a comparison")
    ap.add_argument("--rt-priority", type=int, default=None, metavar="N",
                    help="the run and the controller under SCHED_FIFO at N (1-98; needs CAP_SYS_NICE or ulimit -r)")
    ap.add_argument("--probe", type=float, default=None, metavar="SECONDS",
                    help="only the host's floor: the pacing around a busy loop of --probe-work ms a step and "
                         "nothing else, SECONDS at each rate (probe())")
    ap.add_argument("--probe-work", type=float, default=0.3, metavar="MS", help="the probe's busy work a step")
    ap.add_argument("--probe-peer", type=float, default=None, metavar="MS",
                    help="the probe also makes a round trip a step to a second process that works MS before it "
                         "answers (a controller's floor: no hydrolink in either)")
    args = ap.parse_args()
    if args.probe is not None:
        for rate in args.rates:
            load0 = os.getloadavg()[0]
            peer = None if args.probe_peer is None else 1e-3 * args.probe_peer
            out = probe(args.probe, 1e-3 * args.probe_work, rate, args.rt_priority, peer)
            print(f"{rate:g} Hz, {args.probe_work:g} ms of work a step"
                  + ("" if peer is None else f" and a round trip to a peer process working {args.probe_peer:g} ms")
                  + f", load {load0:.2f} -> {os.getloadavg()[0]:.2f}"
                  + (f", SCHED_FIFO {args.rt_priority}" if args.rt_priority is not None else "") + f": {out}")
        return
    rows, notes = [], []
    load0 = os.getloadavg()
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        for rate in args.rates:
            for relay, channel in [(r, c) for r in args.relays for c in args.channels
                                   if r == "polled" or c == args.channels[0]]:   # a thread relay has no direct channel
                label = relay if relay == "thread" else f"{relay}, {channel}"
                # unpaced: released at once (a factor no step can keep up with); the step costs are its
                # steps' times from their actual start (latency less "behind" and "wake"; the controller's join left out)
                unpaced, cost = run(tmp, rate, args.unpaced_seconds, UNPACED, args.radiation, relay, channel,
                                    args.rt_priority)
                free = unpaced.realtime
                paced, _ = run(tmp, rate, args.seconds, 1.0, args.radiation, relay, channel, args.rt_priority)
                rt = paced.realtime
                notes.append(breakdown(rate, paced) + f" ({label}); unpaced: the server's model "
                             f"{unpaced.server_compute_us_per_step:.1f} µs per step, ms per step: "
                             + ", ".join(f"{k} {1e3 * v:.3f}" for k, v in free.parts_mean.items() if k not in ("behind", "wake")))
                c50, c99 = step_cost(unpaced)
                rows.append((rate, label, 1e3 / rate, 1e3 * c50, 1e3 * c99, 1e6 * cost.run_cpu_s, cost.controller_us,
                             rt.steps, rt.overruns, 1e3 * rt.worst_lateness, 1e3 * rt.latency_p50,
                             1e3 * rt.latency_p99, 1e3 * rt.latency_max, paced.wall_time, os.getloadavg()[0]))
                print(f"{rate:g} Hz {label}: unpaced {free}; paced {rt}", file=sys.stderr, flush=True)
    load1 = os.getloadavg()
    print(f"load average {load0[0]:.2f} before, {load1[0]:.2f} after ({os.cpu_count()} CPUs)"
          + (f"; run and controller under SCHED_FIFO {args.rt_priority}" if args.rt_priority is not None else "") + "\n")
    print("| rate | relay | budget (ms) | unpaced step p50 (ms) | unpaced p99 (ms) | CPU µs/step: run | controller | "
          "paced steps | overruns | worst lateness (ms) | paced latency p50 (ms) | p99 (ms) | max (ms) | loop wall (s) "
          "| load after |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r[0]:g} Hz | {r[1]} | {r[2]:.3g} | {r[3]:.3f} | {r[4]:.3f} | {r[5]:.0f} | {r[6]:.0f} | {r[7]} | "
              f"{r[8]} ({100 * r[8] / max(r[7], 1):.2g} %) | {r[9]:.2f} | {r[10]:.3f} | {r[11]:.3f} | {r[12]:.2f} | "
              f"{r[13]:.1f} | {r[14]:.2f} |")
    print()
    for line in notes:
        print(line)


def step_cost(summary) -> tuple[float, float]:
    """p50 and p99 of a run's step times from each exchange's actual start (its results file's
    step_time without "behind" and "wake"): what a step costs when nothing waits for a release."""
    import netCDF4
    import numpy as np

    with netCDF4.Dataset(summary.output) as ds:
        parts = np.asarray(ds["step_time"][1:].filled(np.nan))
        labels = list(ds["step_part"][:])
    cost = parts[:, [i for i, k in enumerate(labels) if k not in ("behind", "wake")]].sum(axis=1)
    return float(np.percentile(cost, 50)), float(np.percentile(cost, 99))


def breakdown(rate: float, summary) -> str:
    """Where a paced run's step time went (mean ms per step by part), its overruns by cause, and the
    overrun flags in its results file (they must equal the summary's count)."""
    import netCDF4

    rt = summary.realtime
    with netCDF4.Dataset(summary.output) as ds:
        in_file = int(ds["overrun"][:].sum())
    parts = ", ".join(f"{k} {1e3 * v:.3f}" for k, v in rt.parts_mean.items())
    causes = ", ".join(f"{k} {n}" for k, n in rt.overrun_causes.items() if n)
    return (f"- {rate:g} Hz: ms per step: {parts}; overruns {rt.overruns} (in the file: {in_file})"
            + (f", by cause: {causes}" if causes else "") + f"; GC between steps: {rt.gc_collections} "
            f"collection(s), {1e3 * rt.gc_seconds:.2f} ms")


if __name__ == "__main__":
    main()
