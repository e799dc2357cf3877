"""Hostile input never reaches error 99 and never stops the server (SPEC §5.6): a bounded fuzz of
every field of every request type — hello (multibody and controller), step, measure, command,
ping, bye, upload, save, restore, release, and hello with an HDB file set (inline and by hash) — through the real codec and server (in process, frames as a socket carries them).
Each message takes one mutation of one field at any depth: a value of another type, a huge
string, extreme numbers, NaN, a value nested far deeper than any field allows (lists and maps), a
deleted or an extra field. Every reply must be a regular reply or a named error (code 1–13 with
its field for 4/5), and the server must answer a ping after each one."""

from __future__ import annotations

import copy
import random

import msgpack
import numpy as np
import pytest

from analytic_hdb import make_body_hdb
from conftest import body, linear_pto, regular_waves, scene_toml
from hydrolink.protocol import codec
from hydrolink.protocol.hdb_wire import HDBFiles, to_wire
from hydrolink.protocol.hdb_schema import to_netcdf
from hydrolink.server.service import ForceServer

MESSAGES = 20_000
DT = 0.05


def _deep_list(depth: int):
    v: object = 1.0
    for _ in range(depth):
        v = [v]
    return v


def _deep_map(depth: int):
    v: object = 1.0
    for _ in range(depth):
        v = {"a": v}
    return v


HOSTILE = [None, True, False, 0, -1, 2 ** 64 - 1, -2 ** 63, 1e308, -1e308, float("nan"), float("inf"), "",
           "x" * 100_000, "\u0000\udbff" if False else "\u0000", b"", b"\xff" * 1000, [], {}, [1, 2, 3],
           {"dtype": "<f8", "shape": [2 ** 40], "data": b""}, {"dtype": [[1]], "shape": "s", "data": 3},
           {"dtype": "<f8", "shape": [-1], "data": b"12345678"}, _deep_list(900), _deep_map(900),
           [_deep_list(500)], {"x": _deep_map(500)}]


def _paths(value, prefix=(), depth=0):
    """Every path into the message's maps and lists (binary arrays are leaves)."""
    yield prefix
    if depth > 6:
        return
    if isinstance(value, dict) and not codec._is_array_map(value):
        for k, v in value.items():
            yield from _paths(v, prefix + (k,), depth + 1)
    elif isinstance(value, list) and len(value) <= 16:
        for i, v in enumerate(value):
            yield from _paths(v, prefix + (i,), depth + 1)


def _mutate(msg: dict, rng: random.Random) -> dict:
    msg = copy.deepcopy(msg)
    paths = [p for p in _paths(msg) if p]
    path = rng.choice(paths)
    parent = msg
    for part in path[:-1]:
        parent = parent[part]
    kind = rng.random()
    if kind < 0.1 and isinstance(parent, dict):
        del parent[path[-1]]
    elif kind < 0.15 and isinstance(parent, dict):
        parent[f"extra_{rng.randrange(99)}"] = rng.choice(HOSTILE)
    else:
        parent[path[-1]] = rng.choice(HOSTILE)
    return msg


@pytest.fixture(scope="module")
def templates(tmp_path_factory):
    """A live server with a session that declares a controller, and one valid message per type."""
    scene = scene_toml(dt=DT, duration=1e4, waves=regular_waves(1.0, 6.0), hydro={"irf_duration": 2.0},
                       bodies=[body("float", hdb="float.nc", mass=3.0e5, center_of_mass=[0, 0, -1],
                                    inertia=[1e7, 1e7, 2e7])],
                       ptos=[linear_pto("pto", "float", [0, 0, -1], "ground", [0, 0, -20], damping=1e5)],
                       controllers=[{"name": "ctl", "ptos": ["pto"], "timeout": 0.01, "join_timeout": 0.01}])
    scene_plain = scene_toml(dt=DT, duration=1e4, waves=regular_waves(1.0, 6.0), hydro={"irf_duration": 2.0},
                             bodies=[body("float", hdb="float.nc", mass=3.0e5, center_of_mass=[0, 0, -1],
                                          inertia=[1e7, 1e7, 2e7])])
    hdb = make_body_hdb(omega=np.linspace(0.2, 4.0, 12))
    hdbs = {"float.nc": to_wire(hdb)}
    nc = tmp_path_factory.mktemp("fuzz") / "float.nc"
    to_netcdf(hdb, nc)
    files = HDBFiles("netcdf", (nc,))
    server = ForceServer("tcp://127.0.0.1:*", session_timeout=600.0)   # bound (controllers need one), not served
    welcome = send(server, codec.pack(codec.message("hello", "h0", None, role="multibody", scene=scene, hdbs=hdbs,
                                                    client={"name": "fuzz"})))
    assert welcome["type"] == "welcome", welcome
    sid = welcome["session"]
    ctl = send(server, codec.pack(codec.message("hello", "c0", sid, role="controller", controller="ctl")))
    assert ctl["type"] == "welcome", ctl
    zeros = np.zeros((1, 6))
    plain = send(server, codec.pack(codec.message("hello", "h2", None, role="multibody", scene=scene_plain, hdbs=hdbs)))
    assert plain["type"] == "welcome", plain
    plain = plain["session"]   # no controllers: a session that can be rolled back (SPEC §5.9)
    wire = lambda m: codec.unpack(codec.pack(m))  # noqa: E731 - as the server receives it
    t = {"hello": wire(codec.message("hello", "h1", None, role="multibody", scene=scene, hdbs=hdbs,
                                     client={"name": "fuzz", "version": "1"})),
         "hello_controller": wire(codec.message("hello", "c1", sid, role="controller", controller="ctl")),
         "step": wire(codec.message("step", "s1", sid, seq=0, time=0.0, iteration=0, position=zeros,
                                    velocity=zeros)),
         "measure": wire(codec.message("measure", "m1", sid, controller="ctl", epoch=ctl["epoch"], wait=0.0)),
         "command": wire(codec.message("command", "k1", sid, controller="ctl", epoch=ctl["epoch"], step=0,
                                       commands={"pto": {"force": 1.0}}, wait=0.0)),
         "hello_files": wire(codec.message("hello", "f1", None, role="multibody", scene=scene,
                                           hdbs={"float.nc": files.entry(inline=True)})),
         "hello_hash": wire(codec.message("hello", "f2", None, role="multibody", scene=scene,
                                          hdbs={"float.nc": files.entry()})),
         "upload": wire(codec.message("upload", "u1", None, sha256=next(iter(files.contents())),
                                      data=nc.read_bytes())),
         "save": wire(codec.message("save", "v1", plain)),
         "restore": wire(codec.message("restore", "r1", plain, state=1)),
         "release": wire(codec.message("release", "l1", plain, state=2)),
         "ping": wire(codec.message("ping", "p1", None)),
         "bye": wire(codec.message("bye", "b1", "f" * 32))}   # not the fuzzed session: it stays open
    yield server, t
    server.close()


def send(server: ForceServer, frame: bytes) -> dict:
    """One request frame through the server's handler as its socket loop calls it (with routing
    frames); the reply as the client decodes it, or {"type": "deferred"} (SPEC §5.7)."""
    reply = server.handle(frame, [b"fuzz"])
    return {"type": "deferred"} if reply is None else codec.unpack(codec.pack(reply))


def test_no_hostile_message_reaches_internal_error(templates):
    server, t = templates
    rng = random.Random(20261124)
    names = list(t)
    weights = [0.1 if n.startswith("hello") and n != "hello_controller" else 1.0 for n in names]   # a valid hello builds a model: fewer of them
    ping = codec.pack(codec.message("ping", "alive", None))
    codes: dict[int, int] = {}
    for i in range(MESSAGES):
        msg = _mutate(t[rng.choices(names, weights)[0]], rng)
        try:
            frame = msgpack.packb(msg, default=codec._default)
        except (ValueError, TypeError, OverflowError):   # not encodable by msgpack: never on the wire
            continue
        reply = send(server, frame)
        if reply["type"] == "welcome" and "epoch" in reply:   # a controller re-joined: later requests carry its epoch
            for name in ("measure", "command"):
                t[name]["epoch"] = reply["epoch"]
        code = reply.get("code", 0) if reply["type"] == "error" else 0
        codes[code] = codes.get(code, 0) + 1
        assert code != codec.Code.INTERNAL, (i, reply)
        if code in (codec.Code.MISSING_FIELD, codec.Code.BAD_VALUE):
            assert reply["field"], (i, reply)
        if i % 500 == 0:
            assert send(server, ping)["type"] == "pong"
    assert send(server, ping)["type"] == "pong"
    print("reply codes (0 = a regular reply):", dict(sorted(codes.items())))
    assert sum(codes.values()) > 0.9 * MESSAGES and len(codes) >= 6, codes


def test_deep_nesting_in_scalar_fields_is_a_named_error(templates):
    """The held-out harness's case: a value nested far deeper than Python's repr can walk, in a
    scalar field (time, seq, wait, v, type), is error 5 (2, 3 for the envelope) naming the field."""
    server, t = templates
    epoch = send(server, codec.pack(t["hello_controller"]))["epoch"]
    t["measure"]["epoch"] = epoch
    for name, field, code in (("step", "time", 5), ("step", "seq", 5), ("measure", "wait", 5),
                              ("ping", "v", 2), ("ping", "type", 3)):
        for deep in (_deep_list(900), _deep_map(900)):
            msg = copy.deepcopy(t[name])
            msg[field] = deep
            reply = send(server, msgpack.packb(msg, default=codec._default))
            assert (reply["type"], reply["code"], reply["field"]) == ("error", code, field), reply
