"""A joined controller's binary frames (protocol/codec.py, SPEC §5.7.6): the layout's
frames carry the values bit for bit; a command frame gets the same checks, errors, decisions and
counts as the same command as a msgpack map (two ControlHubs of one scene fed the same sequence,
one by maps, one by frames); over a server, a controller that asks gets them when the server does
not sign, and a frame from one that did not ask is refused. A whole run over frames equals one
over ZeroMQ maps bit for bit: tests/test_controllers.py (test_run_polls_its_own_server...)."""

from __future__ import annotations

import math
import struct

import numpy as np
import pytest
from conftest import rm3_example_text

from hydrolink.clients.control import _Link, _command_map
from hydrolink.protocol import codec
from hydrolink.protocol.codec import Code, ProtocolError
from hydrolink.protocol.codec import COMMAND_FRAME_HEAD, FRAME_MAGIC, ControlLayout, is_control_frame
from hydrolink.protocol.scene import parse_scene
from hydrolink.server.service.controllers import ControlHub

TOKEN = "t" * 40


def controlled_scene(command: str, **keys) -> tuple:
    """RM3 (its two bodies, its one linear PTO) with one controller ``ctl`` of ``command``."""
    extra = "".join(f"{k} = {v!r}\n".replace("'", '"') for k, v in keys.items())
    text = rm3_example_text("rm3.toml") + (
        f'\n[[controllers]]\nname = "ctl"\nptos = ["pto"]\ncommand = "{command}"\ntimeout = 5.0\n'
        f'measurements = ["pto_velocity", "body_position", "wave_elevation"]\nwave_points = [[0.0, 0.0], [5.0, 0.0]]\n'
        f'preview = 0.3\n{extra}')
    return parse_scene(text), text


def test_layout_frames_carry_values_bit_for_bit_and_refuse_what_they_cannot_carry():
    layout = ControlLayout((("pto_velocity", (2,)), ("body_position", (2, 6)), ("wave_preview", (1, 3))),
                           (("a", "damping"), ("a", "stiffness"), ("b", "damping"), ("b", "stiffness")))
    assert ControlLayout.from_wire(codec.unpack(codec.pack({"x": layout.to_wire()}))["x"]) == layout
    values = [math.pi, -0.0, 1e-300, 7]
    frame = layout.command_frame(5, 3, 17, 0.5, {"a": {"damping": values[0], "stiffness": values[1]},
                                                 "b": {"stiffness": np.int64(7), "damping": np.float32(1e-30)}})
    cmd = layout.read_command(frame)
    assert is_control_frame(frame) and (cmd.request, cmd.epoch, cmd.step, cmd.wait) == (5, 3, 17, 0.5)
    assert struct.pack("<4d", *cmd.values) == struct.pack("<4d", values[0], values[1], float(np.float32(1e-30)), 7.0)
    assert math.copysign(1.0, cmd.values[1]) == -1.0   # -0.0 kept
    nan = layout.command_frame(1, 1, 0, 1.0, {"a": {"damping": math.nan, "stiffness": 0}, "b": {"damping": 1,
                                                                                             "stiffness": 2}})
    assert math.isnan(layout.read_command(nan).values[0])   # carried: the server refuses it as a map's
    for unfit in ({"a": {"damping": 1.0}, "b": {"damping": 1, "stiffness": 2}},               # a setpoint omitted
                  {"a": 1.0, "b": 2.0},                                                        # forces, not impedance
                  {"a": {"damping": 1, "stiffness": True}, "b": {"damping": 1, "stiffness": 2}},   # a bool
                  {"a": {"damping": 1, "stiffness": "2"}, "b": {"damping": 1, "stiffness": 2}},    # a string
                  {"a": {"damping": 1, "stiffness": 2}, "b": {"damping": 1, "stiffness": 2}, "c": 1},
                  [1.0, 2.0], None):
        assert layout.command_frame(1, 1, 0, 1.0, unfit) is None, unfit
    rng = np.random.default_rng(1)
    sample = {"step": 40, "seq": 20, "time": 0.4, "pto_velocity": rng.standard_normal(2),
              "body_position": rng.standard_normal((2, 6)), "wave_preview": rng.standard_normal((1, 3))}
    request, got = layout.read_measurements(layout.measurements_frame(9, sample))
    assert request == 9 and (got["step"], got["seq"], got["time"]) == (40, 20, 0.4)
    for name, _ in layout.measurements:
        assert got[name].dtype == np.float64 and got[name].tobytes() == sample[name].tobytes()
    assert layout.measurements_frame(9, {k: v for k, v in sample.items() if k != "wave_preview"}) is None
    assert layout.measurements_frame("k-1", sample) is None and layout.measurements_frame(1 << 32, sample) is None
    for bad in (frame[:-8], frame[:1], b"\xc1M" + frame[2:]):   # too short, no kind byte, another kind
        with pytest.raises(ProtocolError) as err:
            layout.read_command(bad)
        assert err.value.code == Code.MALFORMED
    with pytest.raises(ValueError):
        layout.read_measurements(b"\xc1")


def hub_pair(command: str, **keys) -> tuple[list, list]:
    """Two hubs of one scene, each with its sent replies."""
    scene, text = controlled_scene(command, **keys)
    out = []
    for _ in range(2):
        sent: list = []
        hub = ControlHub(scene, text, 1, "s", lambda route, mtype, parent, fields, own=None, sent=sent:
                         sent.append((mtype, parent, fields)), TOKEN)
        out.append((hub, sent))
    return out


def outcome(call):
    try:
        return "reply", call()
    except ProtocolError as exc:
        return "error", (exc.code, exc.field, exc.message)


@pytest.mark.parametrize("command,keys,good,bad", [
    ("force", {"max_force": 5e5}, [{"pto": 1.5e5}, {"pto": {"force": -2e5}}],
     [{"pto": math.nan}, {"pto": 6e5}, {"pto": -math.inf}]),
    ("impedance", {"damping_range": [0.0, 1e6], "stiffness_range": [-1e5, 1e5]},
     [{"pto": {"damping": 3e5, "stiffness": -2e4}}], [{"pto": {"damping": -1.0, "stiffness": 0.0}},
                                                      {"pto": {"damping": 1.0, "stiffness": math.nan}},
                                                      {"pto": {"damping": 1.0, "stiffness": 2e5}}]),
])
def test_a_command_frame_gets_the_same_checks_errors_and_decisions_as_its_map(command, keys, good, bad):
    """The same controller sequence to two hubs of one scene, as maps and as frames: each step's
    measurements relayed, the controller's reply and error (code, field, message) equal, then the
    decisions of every step equal (status, the commands' values bit for bit) and the counts."""
    (maps, sent_maps), (frames, sent_frames) = hub_pair(command, **keys)
    layout = frames.layout(frames.slots["ctl"])
    assert layout.measurements == (("pto_velocity", (1,)), ("body_position", (2, 6)), ("wave_elevation", (2,)),
                                   ("wave_preview", (2, 3)))
    rng = np.random.default_rng(0)
    shapes = dict(maps.mb_shapes)
    script = [("ok", c) for c in good] + [("bad", c) for c in bad] + [("late", good[0]), ("epoch", good[0]),
                                                                     ("wait", good[0]), ("ok", good[-1])]
    for hub, _ in ((maps, sent_maps), (frames, sent_frames)):
        hub.join("ctl")
    for k, (kind, commands) in enumerate(script):
        meas = {"step": k, **{n: rng.standard_normal(s) for n, s in shapes.items()}}
        waves = {"ctl": rng.standard_normal((2, 4))}
        results = []
        for hub, sent in ((maps, sent_maps), (frames, sent_frames)):
            hub.relay(meas, waves)
            parked = [(m, f) for m, _, f in sent if m == "measurements" and f["step"] == k]
            forces = hub.after_step(k + 1, 0, True, None, {"seq": k + 1}, ["mb"], f"m{k}")
            if forces is not None:   # decided at once (else sent when decided)
                sent.append(("forces", None, forces))
            ident = {"controller": "ctl", "epoch": 1, "wait": 1.0}
            if parked:   # to the command parked since the step before
                delivered = parked[0]
            else:
                delivered = hub.measure(ident, ["ctl"], f"q{k}", "own")
            assert delivered[0] == "measurements" and delivered[1]["step"] == k
            if hub is frames:   # what the server writes: the measurements frame, read back
                _, got = layout.read_measurements(layout.measurements_frame(7, delivered[1]))
                for name, _ in layout.measurements:
                    assert got[name].tobytes() == delivered[1][name].tobytes()
            step = k - 1 if kind == "late" else k
            epoch = 0 if kind == "epoch" else 1
            wait = -1.0 if kind == "wait" else 1.0
            if hub is maps:
                call = lambda: hub.command({**ident, "epoch": epoch, "wait": wait, "step": step,
                                            "commands": _command_map(commands)}, ["ctl"], f"c{k}", "own")
            else:
                cmd = layout.read_command(layout.command_frame(k, epoch, step, wait, commands))
                call = lambda: hub.command_frame("ctl", cmd, ["ctl"], "own")
            results.append(outcome(call))
            if kind != "ok" or results[-1][0] == "error":
                hub.poll(math.inf)   # the deadline passes: the step decided on the fallback
        assert results[0] == results[1], (kind, commands, results)
        if k < len(good) + len(bad):   # later: a late, stale or wrong request, then absent (decided at once)
            assert (results[0][0] == "error") == (kind == "bad"), results[0]
    decisions = [[{n: {**d, "latency": d["latency"] is not None} for n, d in f["control"].items()}   # (wall time)
                  for mtype, _, f in sent if mtype == "forces"] for sent in (sent_maps, sent_frames)]
    assert len(decisions[0]) == len(script)
    assert codec.pack({"d": decisions[0]}) == codec.pack({"d": decisions[1]})   # every value bit for bit
    assert [d["ctl"]["status"] for d in decisions[0]].count("invalid") == len(bad)
    assert maps.summary() == frames.summary()


@pytest.mark.parametrize("key,ask,offered", [(None, True, True), (None, False, False), (b"k" * 32, True, False)])
def test_frames_offered_only_when_asked_and_unsigned_and_refused_from_who_did_not_ask(reference_data, tmp_path, key,
                                                                                     ask, offered):
    """A server's controller welcome offers frames (direct.frames: the layout) when the hello asks
    and the server does not sign (SPEC §5.7.6: a signed session keeps its signed maps); a command
    frame is answered as its map would be (here out of order: no measurements delivered yet), and
    on a connection whose welcome offered none it is error 1, the connection kept."""
    from hydrolink.clients.lockstep.connection import ServerConnection
    from hydrolink.clients.scene_inputs import load_scene_hdbs
    from hydrolink.server.service.force_server import serve_in_thread

    scene, text = controlled_scene("force")
    text = text.replace('"../data/rm3_wamit/rm3.1"', f'"{(reference_data / "rm3_wamit" / "rm3.1").as_posix()}"')
    (tmp_path / "s.toml").write_text(text)
    hdbs = load_scene_hdbs(parse_scene(text), tmp_path / "s.toml")
    srv, thread = serve_in_thread("tcp://127.0.0.1:*", key=key)
    link = _Link(srv.address, key, 10.0)
    try:
        with ServerConnection(srv.address, timeout=30.0, key=key) as conn:
            conn.hello(text, hdbs)
            reply = link.request("hello", role="controller", token=conn.control_token, **({"frames": True} if ask else {}))
            assert reply["type"] == "welcome", reply
            assert ("frames" in reply["direct"]) == offered
            if offered:
                layout = ControlLayout.from_wire(reply["direct"]["frames"])
                assert layout.measurements == (("pto_velocity", (1,)), ("body_position", (2, 6)),
                                               ("wave_elevation", (2,)), ("wave_preview", (2, 3)))
                assert layout.commands == (("pto", "force"),)
            link.session = reply["session"]
            link.go_direct(reply["direct"])
            assert link.direct is not None and (link.frames is not None) == offered
            frame = COMMAND_FRAME_HEAD.pack(FRAME_MAGIC, ord("C"), 0, 3, 1, 0, 0, 1.0) + struct.pack("<d", 1.0)
            got = link.direct.request(frame, 3, 10.0, key, link.frames)
            if offered:
                assert (got["type"], got["code"], got["field"]) == ("error", Code.OUT_OF_ORDER, "step")
            else:
                assert (got["type"], got["code"]) == ("error", Code.MALFORMED) and "0xC1" in got["message"]
            got = link.direct.request(b"\xc1", 4, 10.0, key, link.frames)   # one byte: unread, error 1 (never 99)
            assert (got["type"], got["code"], got["parent"]) == ("error", Code.MALFORMED, None)
            assert link.request("ping")["type"] == "pong"   # on the same connection: kept
            assert link.direct is not None
    finally:
        link.close()
        srv.stop()
        thread.join(5)
