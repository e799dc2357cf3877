"""Remote lockstep under latency (docs/remote.md): steps/s versus one-way delay with the force server,
the multibody client and a controller each in its own network namespace (tests/netlab.py), the
results checked bit for bit against the same run on loopback; and the throughput option
``[coupling] exchange_every = k`` — its steps/s under latency and its accuracy cost against
lockstep (k = 1) on RM3.

    python bench/bench_remote_latency.py [--delays 0 1 10 50] [--steps 40] [--ks 1 2 5 10] [--mode auto]

Needs root and iproute2 (network namespaces); prints markdown tables.
"""

from __future__ import annotations

import argparse
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import xarray as xr

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "tests"))
import netlab  # noqa: E402  (tests/netlab.py)

DATA = REPO / "examples" / "data"
HYDROLINK = [sys.executable, "-m", "hydrolink.clients.cli"]
COMPARED = ("position", "velocity", "excitation_force", "radiation_force", "pto_force", "pto_power")
CONTROLLER = ('\n[[controllers]]\nname = "ctl"\nptos = ["pto"]\ncommand = "force"\ntimeout = 30.0\n'
              'measurements = ["pto_displacement", "pto_velocity"]\nparameters = { damping = 3.9e5, stiffness = 1.36e6 }\n')
TOKEN = "bench-remote-latency-join-token-0123456789"   # the run's join token (SPEC §5.7.2), given to both


def rm3(duration: float, *, period: float = 8.0, dt: float = 0.08, ramp: float = 40.0, controller: bool = False,
        coupling: str = "") -> str:
    text = (REPO / "examples" / "rm3" / "rm3.toml").read_text()
    for a, b in (('"../data/', f'"{DATA.as_posix()}/'),   # the HDB and the meshes
                 ("duration = 400.0", f"duration = {duration}"), ("period = 8.0", f"period = {period}"),
                 ("dt = 0.08", f"dt = {dt}"), ("ramp = 40.0", f"ramp = {ramp}")):
        text = text.replace(a, b)
    if controller:
        text = text.replace("damping = 1.2e6          # N s/m", "damping = 0.0") + CONTROLLER
    return text + coupling


def run_three(popen, scene: Path, out: Path, bind: str, connect: str | None, controller: bool) -> float:
    """Server (+ controller) + `hydrolink run`; the run's own steps/s (stepping loop only). The
    controller joins with the run's join token (SPEC §5.7.2) and must have served every control step
    (its own count, "controller done: N steps, 0 errors"): a controller that never joined would make
    the run wait its join timeout and step on the fallback (RuntimeError then, not a figure)."""
    server = popen("server", [*HYDROLINK, "serve", "--bind", bind])
    procs = [server]
    try:
        address = connect or server.stderr.readline().strip().rsplit(" ", 1)[-1]
        if controller:
            procs.append(popen("ctl", [*HYDROLINK, "control", str(REPO / "examples" / "controllers" / "reactive.py"),
                                       "--server", address, "--join-wait", "60", "--token", TOKEN]))
        client = popen("client", [*HYDROLINK, "run", str(scene), "-o", str(out), "--server", address, "--no-progress",
                                  *(["--control-token", TOKEN] if controller else [])])
        procs.append(client)
        stdout, stderr = client.communicate(timeout=900)
        if client.returncode:
            raise RuntimeError(stderr)
        if controller:
            served = controller_steps(procs[1])
            steps = int(re.search(r"wrote \S+: (\d+) steps", stdout).group(1))
            if served != steps:
                raise RuntimeError(f"the controller served {served} of {steps} steps")
        return float(re.search(r"\(([\d.]+) steps/s", stdout).group(1))
    finally:
        for p in reversed(procs):
            if p.poll() is None:
                p.terminate()
            try:
                p.communicate(timeout=30)
            except subprocess.TimeoutExpired:
                p.kill()


def controller_steps(ctl: subprocess.Popen) -> int:
    """The steps a `hydrolink control` process served, from its last line (it ends at the run's stop);
    RuntimeError with its output when it failed or reported errors."""
    try:
        _, err = ctl.communicate(timeout=60)
    except subprocess.TimeoutExpired:
        ctl.kill()
        _, err = ctl.communicate()
    done = re.search(r"controller done: (\d+) steps, (\d+) errors", err)
    if ctl.returncode or done is None or int(done.group(2)):
        raise RuntimeError(f"the controller failed (status {ctl.returncode}): {err.strip()[-500:]}")
    return int(done.group(1))


def local(who, argv):
    return subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def identical(a: Path, b: Path) -> bool:
    x, y = xr.load_dataset(a), xr.load_dataset(b)
    return all(np.array_equal(x[v].values, y[v].values, equal_nan=True) for v in COMPARED if v in x)


def latency_table(tmp: Path, delays: list[float], steps: int, mode: str, losses: list[float] = (0.0,)) -> list[str]:
    rows = ["| one-way delay | frames lost | round trip | participants | steps/s | per step | identical to loopback |",
            "|---|---|---|---|---|---|---|"]
    for controller in (False, True):
        scene = tmp / f"lat_{controller}.toml"
        scene.write_text(rm3(steps * 0.04, period=4.0, dt=0.04, ramp=1.0, controller=controller))
        ref = tmp / f"lat_{controller}_local.nc"
        sps = run_three(local, scene, ref, "tcp://127.0.0.1:*", None, controller)
        who = "server + client + controller" if controller else "server + client"
        rows.append(f"| loopback (no namespaces) | - | - | {who} | {sps:.0f} | {1e3 / sps:.2f} ms | (reference) |")
        for d in delays:
            for loss in losses:
                names = ["server", "client", "ctl"] if controller else ["server", "client"]
                with netlab.Lab(names, delay=d / 1e3, mode="switch" if loss else mode, loss=loss) as lab:
                    addr = f"tcp://{lab.address('server')}:5555"
                    out = tmp / f"lat_{controller}_{d}_{loss}.nc"
                    sps = run_three(lambda w, a: lab.popen(w, a), scene, out, addr, addr, controller)
                    rows.append(f"| {d:g} ms ({lab.mode}) | {100 * loss:g} % | {2 * d:g} ms | {who} | {sps:.1f} | "
                                f"{1e3 / sps:.1f} ms | {'yes' if identical(out, ref) else 'NO'} |")
            print(rows[-1], flush=True)
    return rows


def amplitude(path: Path, period: float) -> tuple[float, float]:
    """Float heave amplitude and mean PTO power over the last five periods."""
    ds = xr.load_dataset(path)
    t = ds["time"].values
    sel = t > t[-1] - 5 * period + 1e-9
    z = ds["position"].sel(body="float", dof="heave").values[sel]
    return 0.5 * float(z.max() - z.min()), float(ds["pto_power"].sel(pto="pto").values[sel].mean())


def accuracy_table(tmp: Path, ks: list[int], duration: float = 200.0) -> list[str]:
    from hydrolink.clients.run import run_scene_file
    rows = ["| exchange_every k | between exchanges | exchange interval | float heave amplitude | error | mean PTO power | error |",
            "|---|---|---|---|---|---|---|"]
    ref = None
    for k in ks:
        for between in (("hold",) if k == 1 else ("hold", "extrapolate")):
            scene = tmp / f"acc_{k}_{between}.toml"
            scene.write_text(rm3(duration, coupling=f'\n[coupling]\nexchange_every = {k}\nbetween_exchanges = "{between}"\n'))
            run_scene_file(scene, tmp / f"acc_{k}_{between}.nc", progress=False)
            a, p = amplitude(tmp / f"acc_{k}_{between}.nc", 8.0)
            ref = ref or (a, p)
            rows.append(f"| {k} | {between if k > 1 else '(lockstep)'} | {0.08 * k:g} s | {a:.4f} m | "
                        f"{100 * (a / ref[0] - 1):+.2f} % | {p / 1e3:.2f} kW | {100 * (p / ref[1] - 1):+.2f} % |")
            print(rows[-1], flush=True)
    return rows


def throughput_table(tmp: Path, ks: list[int], delays: list[float], steps: int, mode: str) -> list[str]:
    rows = ["| one-way delay | exchange_every k | steps/s | speed-up over lockstep |", "|---|---|---|---|"]
    for d in delays:
        base = None
        for k in ks:
            scene = tmp / f"thr_{k}.toml"
            scene.write_text(rm3(steps * 0.08, coupling=f'\n[coupling]\nexchange_every = {k}\nbetween_exchanges = "extrapolate"\n'))
            with netlab.Lab(["server", "client"], delay=d / 1e3, mode=mode) as lab:
                addr = f"tcp://{lab.address('server')}:5555"
                sps = run_three(lambda w, a: lab.popen(w, a), scene, tmp / f"thr_{k}_{d}.nc", addr, addr, False)
            base = base or sps
            rows.append(f"| {d:g} ms | {k} | {sps:.1f} | {sps / base:.1f}x |")
            print(rows[-1], flush=True)
    return rows


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--delays", type=float, nargs="+", default=[0, 1, 10, 50], help="one-way delays, ms")
    p.add_argument("--steps", type=int, default=40, help="steps per latency run")
    p.add_argument("--ks", type=int, nargs="+", default=[1, 2, 5, 10], help="exchange_every values")
    p.add_argument("--mode", default="auto", choices=["auto", "netem", "switch"])
    p.add_argument("--losses", type=float, nargs="+", default=[0.0],
                   help="fractions of frames dropped (the user-space switch), e.g. 0 0.05")
    p.add_argument("--skip-latency", action="store_true")
    p.add_argument("--latency-only", action="store_true", help="only the latency table")
    args = p.parse_args()
    reason = netlab.unsupported_reason()
    if reason:
        sys.exit(f"cannot build network namespaces here: {reason}")
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        tables = []
        if not args.skip_latency:
            tables.append(latency_table(tmp, args.delays, args.steps, args.mode, args.losses))
        if not args.latency_only:
            tables.append(accuracy_table(tmp, args.ks))
            tables.append(throughput_table(tmp, args.ks, [d for d in args.delays if d >= 10] or args.delays,
                                           max(args.ks) * 10, args.mode))
    for t in tables:
        print("\n" + "\n".join(t))
    print(f"\n(total {time.perf_counter() - t0:.0f} s)")


if __name__ == "__main__":
    main()
