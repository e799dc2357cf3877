"""A controller's round trip as msgpack maps and as binary frames (SPEC §5.7.6), message by message
in one process: the CPU each side spends on one control step's messages, without the sockets and
the wake-ups (those are bench_realtime.py's).

    python bench/bench_control_frames.py [--steps 20000] [--measurements pto_displacement pto_velocity ...]
                                         [--paths maps frames]

RM3's scene (examples/rm3/rm3.toml) with one force controller (latency 1, every step) on its PTO, a
ControlHub as the run's own server keeps it (server/service/controllers.py). Each step, timed apart
(median of per-call perf_counter_ns over the steps, robust to a loaded host; the load average is
printed beside):

- **relay**: the run's measurements relayed to the controller's parked request and its reply
  encoded (``codec.pack`` of the ``measurements`` message, or the measurements frame);
- **controller**: the reply decoded, the reactive law (F = c v + k x), the command encoded
  (``codec.pack`` of the ``command`` map, or the command frame);
- **command in**: the command decoded and checked (``codec.unpack``, the envelope, ``without_nil``,
  ``ControlHub.command``; or ``read_command``, ``ControlHub.command_frame``) and the decision taken.

The server's dispatch around the hub (the same for both) and the direct channel's reads and writes
are left out. Both paths' decisions are checked equal, bit for bit. ``--paths frames`` (or maps)
runs one path once: under ``valgrind --tool=callgrind``, two step counts' instruction totals give
its instructions a step, repeatable on a loaded host.
"""

from __future__ import annotations

import argparse
import os
import statistics
import time
from pathlib import Path

import numpy as np

from hydrolink.clients.control import _command_map, decode_measurements
from hydrolink.protocol import codec
from hydrolink.protocol.scene import parse_scene
from hydrolink.server.service.controllers import ControlHub

REPO = Path(__file__).resolve().parents[1]
TOKEN = "t" * 43


def scene_text(measurements: list[str]) -> str:
    text = (REPO / "examples" / "rm3" / "rm3.toml").read_text()
    return text + ('\n[[controllers]]\nname = "ctl"\nptos = ["pto"]\ncommand = "force"\ntimeout = 5.0\n'
                   f'measurements = {measurements!r}\n'.replace("'", '"'))


def run(path: str, text: str, steps: int) -> tuple[dict[str, float], list]:
    """One path ("maps" or "frames") over ``steps`` control steps: median µs of each part, the decisions."""
    scene = parse_scene(text)
    out: list = []   # what the hub sends: (type, parent, bytes or fields)
    hub = ControlHub(scene, text, 1, "s", lambda route, mtype, parent, fields, own=None: out.append(
        (mtype, parent, encode(mtype, parent, fields))), TOKEN)
    slot, _ = hub.join("ctl")
    layout = hub.layout(slot)
    ids = codec.id_source("s")

    def encode(mtype: str, parent, fields):
        if mtype != "measurements":
            return fields
        if path == "frames":
            return layout.measurements_frame(parent, fields)
        return codec.pack(codec.message(mtype, next(ids), "own", parent, **fields))

    c, k_ = 3.9e5, 1.36e6
    ident = {"controller": "ctl", "epoch": 1, "wait": 1.0}
    assert hub.measure(ident, ["ctl"], 0 if path == "frames" else "k-0", "own") is None   # parked
    rng = np.random.default_rng(0)
    shapes = dict(hub.mb_shapes)
    times: dict[str, list[int]] = {"relay": [], "controller": [], "command in": []}
    decisions = []
    for k in range(steps):
        meas = {"step": k, **{n: rng.standard_normal(s) for n, s in shapes.items()}}
        t0 = time.perf_counter_ns()
        hub.relay(meas, {})
        t1 = time.perf_counter_ns()
        hub.after_step(k + 1, 0, True, None, {"seq": k + 1}, ["mb"], f"m{k}")
        _, parent, data = out.pop()
        t2 = time.perf_counter_ns()
        if path == "frames":
            _, m = layout.read_measurements(data)
        else:
            reply = codec.unpack(data)
            m = decode_measurements(reply)
        v, x = m["pto_velocity"].tolist(), m["pto_displacement"].tolist()
        commands = {"pto": c * v[0] + k_ * x[0]}
        if path == "frames":
            frame = layout.command_frame(k + 1, 1, m["step"], 1.0, commands)
        else:
            frame = codec.pack(codec.message("command", f"k-{k + 1}", "own", step=reply["step"],
                                             commands=_command_map(commands), **ident))
        t3 = time.perf_counter_ns()
        if path == "frames":
            cmd = layout.read_command(frame)
            got = hub.command_frame("ctl", cmd, ["ctl"], "own")
        else:
            msg = codec.unpack(frame)
            codec.check_envelope(msg)
            got = hub.command(codec.without_nil(msg), ["ctl"], msg["msg_id"], "own")
        t4 = time.perf_counter_ns()
        assert got is None   # parked for the next measurements
        times["relay"].append(t1 - t0)
        times["controller"].append(t3 - t2)
        times["command in"].append(t4 - t3)
        forces = out.pop()
        assert forces[0] == "forces"
        decisions.append(forces[2]["control"]["ctl"]["commands"])
    return {part: statistics.median(ns) / 1e3 for part, ns in times.items()}, decisions


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--steps", type=int, default=20000)
    ap.add_argument("--measurements", nargs="+", default=["pto_displacement", "pto_velocity"])
    ap.add_argument("--paths", nargs="+", default=["maps", "frames"], choices=["maps", "frames"])
    args = ap.parse_args()
    text = scene_text(args.measurements)
    if len(args.paths) == 1:
        parts, _ = run(args.paths[0], text, args.steps)
        print(f"{args.paths[0]}, {args.steps} steps: " + ", ".join(f"{p} {us:.1f} µs" for p, us in parts.items()))
        return
    load0 = os.getloadavg()[0]
    results = {}
    for path in ("maps", "frames", "maps", "frames"):   # interleaved: the better of two runs each
        parts, decisions = run(path, text, args.steps)
        results[path] = {p: min(v, results.get(path, {}).get(p, v)) for p, v in parts.items()}
        results.setdefault("decisions " + path, decisions)
    assert codec.pack({"d": results["decisions maps"]}) == codec.pack({"d": results["decisions frames"]})
    print(f"load average {load0:.2f} before, {os.getloadavg()[0]:.2f} after; {args.steps} steps, measurements "
          f"{args.measurements}; median µs per step (the better of two interleaved runs)\n")
    print("| part | maps (µs) | frames (µs) | ratio |")
    print("|---|---|---|---|")
    for part in ("relay", "controller", "command in"):
        a, b = results["maps"][part], results["frames"][part]
        print(f"| {part} | {a:.1f} | {b:.1f} | {a / b:.1f}x |")


if __name__ == "__main__":
    main()
