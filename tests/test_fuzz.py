"""Hostile input never reaches error 99 and never stops the server (SPEC §5.6): a bounded fuzz of
every field of every request type — hello (multibody and controller), step, measure, command,
ping, bye, upload, save, restore, release, and hello with an HDB file set (inline and by hash) — through the real codec and server (in process, frames as a socket carries them).
Each message takes one mutation of one field at any depth: a value of another type, a huge
string, extreme numbers, NaN, a value nested far deeper than any field allows (lists and maps), a
deleted or an extra field. Every reply must be a regular reply or a named error (code 1–13 with
its field for 4/5), and the server must answer a ping after each one."""

from __future__ import annotations

import copy
import math
import random
import typing

import msgpack
import numpy as np
import pytest
from pydantic import BaseModel

from analytic_hdb import make_body_hdb
from conftest import REPO, SCENE_SECTIONS, body, joint, linear_pto, regular_waves, rm3_float, rm3_spar, scene_toml, toml_document
from hydrolink.protocol import codec
from hydrolink.protocol.hdb.wire import HDBFiles, to_wire
from hydrolink.protocol.scene import Scene, parse_scene
from hydrolink.protocol.toml_model import models_in
from hydrolink.protocol.hdb.schema import to_netcdf
from hydrolink.server.hdb.io import load_hdb
from hydrolink.server.service.force_server import ForceServer

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
    token = welcome["control_token"]
    ctl = send(server, codec.pack(codec.message("hello", "c0", sid, role="controller", controller="ctl", token=token)))
    assert ctl["type"] == "welcome", ctl
    own = ctl["session"]   # the controller's own session id (SPEC §5.7.2)
    zeros = np.zeros((1, 6))
    plain = send(server, codec.pack(codec.message("hello", "h2", None, role="multibody", scene=scene_plain, hdbs=hdbs)))
    assert plain["type"] == "welcome", plain
    plain = plain["session"]   # no controllers: a session that can be rolled back (SPEC §5.9)
    wire = lambda m: codec.unpack(codec.pack(m))  # noqa: E731 - as the server receives it
    t = {"hello": wire(codec.message("hello", "h1", None, role="multibody", scene=scene, hdbs=hdbs,
                                     client={"name": "fuzz", "version": "1"})),
         "hello_controller": wire(codec.message("hello", "c1", sid, role="controller", controller="ctl",
                                                token=token)),
         "step": wire(codec.message("step", "s1", sid, seq=0, time=0.0, iteration=0, position=zeros,
                                    velocity=zeros)),
         "measure": wire(codec.message("measure", "m1", own, controller="ctl", epoch=ctl["epoch"], wait=0.0)),
         "command": wire(codec.message("command", "k1", own, controller="ctl", epoch=ctl["epoch"], step=0,
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


def _close_new_session(server: ForceServer, reply: dict) -> None:
    """Say bye to the session a fuzzed multibody hello opened: the fixture's sessions stay open,
    the others would fill the server's session bound (max_sessions; then error 14 busy)."""
    if reply["type"] == "welcome" and "epoch" not in reply:
        assert send(server, codec.pack(codec.message("bye", "bye-new", reply["session"])))["type"] == "goodbye"


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
        if reply["type"] == "welcome" and "epoch" in reply:   # a controller re-joined: later requests carry its
            for name in ("measure", "command"):                # epoch and its new session id (SPEC §5.7.2)
                t[name]["epoch"], t[name]["session"] = reply["epoch"], reply["session"]
        _close_new_session(server, reply)
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
    joined = send(server, codec.pack(t["hello_controller"]))
    t["measure"]["epoch"], t["measure"]["session"] = joined["epoch"], joined["session"]
    for name, field, code in (("step", "time", 5), ("step", "seq", 5), ("measure", "wait", 5),
                              ("ping", "v", 2), ("ping", "type", 3)):
        for deep in (_deep_list(900), _deep_map(900)):
            msg = copy.deepcopy(t[name])
            msg[field] = deep
            reply = send(server, msgpack.packb(msg, default=codec._default))
            assert (reply["type"], reply["code"], reply["field"]) == ("error", code, field), reply


# ---------------------------------------------------------------- extreme values (issue 22)
#
# Every numeric scene key (found by walking the scene's pydantic models) and every numeric message
# field gets each extreme value in turn. A scene value out of its bounds is error 8 naming its key;
# a value in bounds builds a session (welcome); nothing is error 99, and the server serves on: a
# valid session runs steps afterwards.

EXTREMES = [1e300, -1e300, 1e-308, 5e-324, float("nan"), float("inf"), -float("inf"), 2 ** 70, -2 ** 70]
IN_RANGE_POSSIBLE = (1e-308, 5e-324)   # tiny: within some keys' bounds (a tolerance, an angle)
FREE_KEYS = ("client.parameters.", "controllers[0].parameters.")   # values handed on as they are (finite)
HEADINGS = np.deg2rad(np.arange(-180.0, 181.0, 30.0))


def _numeric(annotation) -> bool:
    """Whether an annotation holds a float or an int (bool is no number here)."""
    return annotation in (int, float) or any(_numeric(a) for a in typing.get_args(annotation))


def numeric_fields(model: type[BaseModel] = Scene, seen: set | None = None) -> set[tuple[str, str]]:
    """(model name, field) of every numeric field of the scene's models, found by walking them."""
    seen = set() if seen is None else seen
    out: set[tuple[str, str]] = set()
    if model in seen:
        return out
    seen.add(model)
    for name, f in model.model_fields.items():
        if _numeric(f.annotation):
            out.add((model.__name__, name))
        for sub in models_in(f.annotation):
            out |= numeric_fields(sub, seen)
    return out


def set_fields(obj) -> set[tuple[str, str]]:
    """(model name, field) of the numeric fields a parsed scene sets explicitly."""
    out: set[tuple[str, str]] = set()
    if isinstance(obj, BaseModel):
        for name in obj.model_fields_set:
            if _numeric(type(obj).model_fields[name].annotation):
                out.add((type(obj).__name__, name))
            out |= set_fields(getattr(obj, name))
    elif isinstance(obj, (list, tuple)):
        for v in obj:
            out |= set_fields(v)
    elif isinstance(obj, dict):
        for v in obj.values():
            out |= set_fields(v)
    return out


def _rich_body(**keys):
    return body("float", hdb="wide.nc", mass=3.0e5, center_of_mass=[0.0, 0.0, -1.0], inertia=[1e7, 1e7, 2e7],
                initial_displacement=[0.0] * 6, initial_velocity=[0.0] * 6, linear_damping=[1e3] * 6,
                quadratic_damping=[[1e2 if i == j else 0.0 for j in range(6)] for i in range(6)],
                drag={"cd": [1.0] * 6, "area": [1.0] * 6}, **keys)


def _templates() -> dict[str, dict]:
    """Scenes (as sections) that together set every numeric scene key; each is valid as it is."""
    sim = {"dt": 0.05, "duration": 10.0, "flush_seconds": 1.0, "spectral_radius": 0.9}
    hydro = {"irf_duration": 2.0, "irf_taper": 0.1, "irf_domega": 0.1, "irf_tail": "asymptotic",
             "irf_tail_cutoff": 8.0, "ss_tolerance": 0.01, "ss_order": 4, "ss_max_order": 24, "coupling_tolerance": 0.0}
    mechanism = {
        "steady": {"order": 10, "tolerance": 1e-10, "max_iterations": 50},
        "coupling": {"scheme": "mass-matrix", "exchange_every": 1, "tolerance": 1e-8, "max_iterations": 50,
                     "explicit_limit": 0.9},
        "bodies": [_rich_body(), body("arm", mass=1e3, center_of_mass=[5.0, 0.0, 2.0], inertia=[1e3, 1e3, 1e3],
                                      reference_point=[5.0, 0.0, 2.0], buoyancy_volume=0.5,
                                      center_of_buoyancy=[5.0, 0.0, 1.0])],
        "point_masses": [{"name": "buoy", "mass": 10.0, "position": [0.0, 5.0, -1.0], "initial_velocity": [0.0] * 3,
                          "buoyancy_volume": 0.001}],
        "joints": [joint("revolute", "float", "arm", [2.0, 0.0, 0.0], axis=[0.0, 1.0, 0.0],
                         friction={"force": 10.0, "velocity": 1e-3}),
                   joint("universal", "arm", "ground", [5.0, 0.0, 2.0], axis=[1.0, 0.0, 0.0], axis2=[0.0, 1.0, 0.0])],
        "constraints": [{"body": "float", "dof": "yaw", "value": 0.0}],
        "ptos": [linear_pto("pto", "float", [0.0, 0.0, -1.0], "ground", [0.0, 0.0, -20.0], stiffness=0.0,
                            damping=1e5, rest_length=19.0, force_limit=1e6),
                 {"name": "rot", "type": "rotary", "body1": "float", "body2": "arm", "point": [2.0, 0.0, 0.0],
                  "axes": ["pitch"], "frame": [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
                  "stiffness": [1.0], "damping": 1.0, "torque_limit": 1e5}],
        "moorings": [{"type": "linear", "body": "float", "point": [0.0, 0.0, 0.0], "stiffness": [1e3] * 6,
                      "damping": [[0.0] * 6 for _ in range(6)], "pretension": [0.0] * 6},
                     {"type": "rope", "anchor": [0.0, 10.0, -50.0], "attach_to": "buoy", "length": 50.0,
                      "axial_stiffness": 1e8, "mass_per_length": 10.0, "diameter": 0.05, "elements": 5,
                      "bending_stiffness": 0.0},
                     {"type": "rope", "anchor": [0.0, -10.0, -50.0], "attach_to": "float", "point": [0.0, 0.0, -1.0],
                      "length": 50.0, "axial_stiffness": 1e8, "mass_per_length": 10.0}],
        "morison": [{"body": "float", "point_a": [0.0, 0.0, -1.0], "point_b": [0.0, 0.0, -5.0], "diameter": 0.5,
                     "cd": 1.0, "ca": 1.0, "segments": 4}],
        "controllers": [{"name": "ctl", "ptos": ["pto"], "period": 0.1, "preview": 1.0, "preview_step": 0.1,
                         "latency": 1, "timeout": 0.01, "join_timeout": 0.01, "fallback": "passive",
                         "fallback_damping": 1e5, "max_force": 1e6, "damping_range": [0.0, 1e12],
                         "stiffness_range": [-1e12, 1e12], "wave_points": [[0.0, 0.0]],
                         "parameters": {"gain": 1.5, "n": 3, "v": [1.0, 2.0]}}]}
    water = {"density": 1025.0, "gravity": 9.81, "depth": 50.0}
    return {
        "regular": {"simulation": sim, "water": water, "hydro": hydro, **mechanism,
                    "optimize": {"order": 5, "oversampling": 8, "efficiency": 0.8,
                                 "limits": [{"pto": "pto", "force": 1e6, "stroke": 2.0, "velocity": 3.0},
                                            {"body": "float", "dof": "heave", "displacement": 2.0}]},
                    "waves": regular_waves(1.0, 6.0, direction=0.0, phase=10.0, ramp=2.0,
                                           excitation_irf_duration=5.0),
                    "current": {"speed": 0.5, "direction": 10.0, "profile": "power", "depth": 20.0}},
        "irregular": {"simulation": sim, "water": water, "hydro": {"irf_duration": 2.0, "froude_krylov_energy": 0.99},
                      "waves": {"type": "irregular", "spectrum": "jonswap", "hs": 1.0, "tp": 6.0, "gamma": 3.3,
                                "seed": 1, "direction": 0.0, "components": 40, "ramp": 1.0, "spreading": "cos2s",
                                "s": 10.0, "directions": 3, "omega_range": [0.3, 3.5],
                                "excitation_irf_duration": 5.0},
                      "bodies": [_rich_body()],
                      "ptos": [linear_pto("heave", "float", [0.0, 0.0, -1.0], "ground", None, direction=[0.0, 0.0, -1.0],
                                          damping=1e5)],
                      # (the file is the client's to read: the server's scene names it only)
                      "moorings": [{"name": "lines", "type": "moordyn", "file": "lines.dat", "bodies": ["float"],
                                    "workers": 2}]},
        # several systems: a spread JONSWAP (cos-2s), a Mitsuyasu swell, a directional table S(w, theta)
        "sea": {"simulation": sim, "water": water, "hydro": {"irf_duration": 2.0},
                "waves": {"type": "sea", "components": 40, "seed": 1, "omega_range": [0.3, 3.5], "ramp": 1.0,
                          "excitation_irf_duration": 5.0,
                          "systems": [{"spectrum": "jonswap", "hs": 1.0, "tp": 6.0, "gamma": 3.3, "direction": 30.0,
                                       "spreading": "cos2s", "s": 10.0, "directions": 3},
                                      {"spectrum": "pierson-moskowitz", "hs": 0.5, "tp": 10.0, "direction": -60.0,
                                       "spreading": "mitsuyasu", "s_max": 25.0, "directions": 3},
                                      {"spectrum": "table", "direction": 0.0, "omega": [0.3, 1.0, 2.0, 3.5],
                                       "theta": [-10.0, 0.0, 10.0],
                                       "density": [[0.0, 0.0, 0.0], [0.01, 0.02, 0.01], [0.005, 0.01, 0.005],
                                                   [0.0, 0.0, 0.0]]}]},
                "bodies": [_rich_body()]},
        "components": {"simulation": sim, "water": water, "hydro": {"irf_duration": 2.0},
                       "waves": {"type": "components", "omega": [0.5, 1.0], "direction": [0.0, 30.0],
                                 "amplitude": [0.5, 0.2], "phase": [0.0, 90.0], "ramp": 1.0,
                                 "excitation_irf_duration": 5.0},
                       "bodies": [_rich_body(passive_yaw=True, passive_yaw_filter=5.0,
                                             passive_yaw_coefficients="initial-heading")]},
        "elevation": {"simulation": sim, "water": water, "hydro": {"irf_duration": 2.0},
                      "waves": {"type": "elevation", "file": "eta.csv", "direction": 0.0, "start": 10.0, "ramp": 1.0,
                                "excitation_irf_duration": 5.0},
                      "bodies": [_rich_body()]},
        # a sea fitted to three gauges' records (hello.gauges: extreme_server's extra)
        "gauges": {"simulation": sim, "water": water, "hydro": {"irf_duration": 2.0},
                   "waves": {"type": "gauges", "directions": [0.0, 60.0], "omega_range": [0.5, 3.5], "start": 10.0,
                             "max_condition": 1e4, "ramp": 1.0, "excitation_irf_duration": 5.0,
                             "gauges": [{"x": 0.0, "y": 0.0, "file": "g0.csv"}, {"x": 30.0, "y": 0.0, "file": "g1.csv"},
                                        {"x": 0.0, "y": 30.0, "file": "g2.csv", "quantity": "elevation"}]},
                   "bodies": [_rich_body()]},
        # a body switching between two states (the same HDB) by a time rule and a band
        "switching": {"simulation": sim, "water": water, "hydro": {"irf_duration": 2.0}, "waves": regular_waves(1.0, 6.0),
                      "bodies": [body("float", hdb="wide.nc", mass=3.0e5, center_of_mass=None, inertia=None,
                                      dofs=["heave"], hydro_state="a", hydro_states=[{"name": "b", "hdb": "wide.nc"}])],
                      "hydro_switches": [{"body": "float", "state": "b", "time": 5.0},
                                         {"body": "float", "state": "a", "dof": "heave", "below": -1.0},
                                         {"body": "float", "state": "b", "dof": "heave", "above": 1.0}]},
        # a flexible body: the barge's three generalized modes, their structure and a PTO on one of them
        "modes": {"simulation": sim, "water": {"density": 1025.0}, "hydro": {"irf_duration": 2.0},
                  "waves": regular_waves(1.0, 8.0),
                  "bodies": [body("barge", hdb="barge.nc", mass=656000.0, center_of_mass=[0.0, 0.0, 0.0],
                                  inertia=[3990666.7, 87466666.7, 87466666.7],
                                  modes={"names": ["bend_z1", "bend_z2", "twist1"],
                                         "mass": [164000.0, 164000.0, 1995333.0],
                                         "stiffness": [39106.55, 297151.3, 6168503.0],
                                         "damping": [3203.4, 8830.2, 140332.3],
                                         "initial_displacement": [0.01, 0.0, 0.0],
                                         "pto_stiffness": [1.0e3, 0.0, 0.0], "pto_damping": [1.0e4, 0.0, 0.0]})]},
        # the loads along a body and its panel pressures (outputs of the run; the server takes the keys as they are)
        "sections": {"simulation": sim, "water": water, "hydro": {"irf_duration": 2.0}, "waves": regular_waves(1.0, 6.0),
                     "bodies": [body("float", hdb="wide.nc", mass=3.0e5, center_of_mass=[0.0, 0.0, 0.0],
                                     inertia=[1.0e6] * 3, pressure_output=True,
                                     sections={"axis": "x", "stations": [0.0], "mass_stations": [-5.0, 5.0],
                                               "mass_per_length": [3.0e4], "section_inertia": [[1.0, 1.0, 1.0]],
                                               "point_masses": [[0.0, 1.0]]})]},
        # a WAMIT run sent as its .1, .3 and .hst alone: the facts its files do not state, from the scene
        "wamit": {"simulation": sim, "water": {"density": 1000.0, "gravity": 9.81, "depth": 200.0},
                  "hydro": {"irf_duration": 2.0}, "waves": regular_waves(1.0, 8.0),
                  "bodies": [rm3_float("rm3.1", hdb_body="body1", dofs=["heave"],
                                       wamit={"ulen": 1.0, "gravity": 9.81, "depth": 200.0,
                                              "xbody": [[0.0, 0.0, -0.72], [0.0, 0.0, -21.29]], "vcg": [0.0, 0.0],
                                              "volume": [725.833, 886.687], "iperout": 1}),
                             rm3_spar("rm3.1", hdb_body="body2", dofs=["heave"])]},
        "fmu": {"simulation": sim, "water": water, "hydro": {"irf_duration": 2.0},
                "bodies": [body("float", hdb="wide.nc", mass=3.0e5, center_of_mass=None, inertia=None, dofs=["heave"])],
                "client": {"type": "fmu", "fmu": "x.fmu", "communication_step": 0.05, "parameters": {"k": 1.5, "n": 2},
                           "coupling": {"mode": "auto", "tolerance": 1e-6, "max_iterations": 50, "explicit_limit": 0.5},
                           "bodies": {"float": {"position": {"heave": "z"}, "velocity": {"heave": "v"},
                                                "force": {"heave": "f"}}}}},
    }


def _numeric_leaves(value, path=""):
    """(key path, value) of every number in a scene section tree; of a list only its first item."""
    if isinstance(value, dict):
        for k, v in value.items():
            yield from _numeric_leaves(v, f"{path}.{k}" if path else k)
    elif isinstance(value, list) and value:
        yield from _numeric_leaves(value[0], f"{path}[0]")
    elif isinstance(value, (int, float)) and not isinstance(value, bool):
        yield path, value


def _with(sections: dict, path: str, value) -> dict:
    """A deep copy of ``sections`` with the number at ``path`` replaced."""
    out = copy.deepcopy(sections)
    parts = [p for p in path.replace("[0]", ".0").split(".")]
    parent = out
    for p in parts[:-1]:
        parent = parent[int(p)] if p.isdigit() else parent[p]
    last = parts[-1]
    parent[int(last) if last.isdigit() else last] = value
    return out


@pytest.fixture(scope="module")
def extreme_server():
    hdb = make_body_hdb(omega=np.linspace(0.2, 4.0, 12), directions=HEADINGS, depth=50.0, rho=1025.0)
    server = ForceServer("tcp://127.0.0.1:*", session_timeout=600.0)   # bound (controllers need one), not served
    t = np.arange(0.0, 40.0, 0.05)
    rm3 = REPO / "examples" / "data" / "rm3_wamit"
    wamit = HDBFiles("wamit", (rm3 / "rm3.1", rm3 / "rm3.3", rm3 / "rm3.hst")).entry(inline=True)
    extra = {"elevation": {"wave_elevation": {"time": t, "eta": 0.5 * np.sin(1.1 * t)}},
             "wamit": {"own_hdbs": {"rm3.1": wamit}},
             "modes": {"own_hdbs": {"barge.nc": to_wire(load_hdb(REPO / "examples" / "data" / "flexible_barge" /
                                                                 "flexible_barge.nc"))}},
             "gauges": {"gauges": {f"waves.gauges[{i}].file": {"time": t, "eta": 0.5 * np.sin(1.1 * t - i)}
                                   for i in range(3)}}}
    yield server, {"wide.nc": to_wire(hdb)}, extra
    server.close()


def _setup_numbers(value, path):
    """(path, value) of every number and numeric array in a decoded setup map."""
    if isinstance(value, dict):
        for k, v in value.items():
            yield from _setup_numbers(v, f"{path}.{k}")
    elif isinstance(value, list):
        for i, v in enumerate(value):
            yield from _setup_numbers(v, f"{path}[{i}]")
    elif isinstance(value, np.ndarray) and value.dtype.kind in "fc" or \
            isinstance(value, float):
        yield path, value


def _hello(server, hdbs, sections: dict, **fields) -> dict:
    hdbs = fields.pop("own_hdbs", hdbs)   # a template's own HDBs (extreme_server's extra)
    text = toml_document({k: sections[k] for k in SCENE_SECTIONS if k in sections})
    reply = send(server, codec.pack(codec.message("hello", "x", None, role="multibody", scene=text, hdbs=hdbs,
                                                  **fields)))
    if reply["type"] == "welcome":   # every number it sends is finite; then closed: hundreds of sessions are built here
        bad = [path for path, v in _setup_numbers(codec.decode_tree(reply["setup"]), "setup") if not np.all(np.isfinite(v))]
        assert not bad, f"a welcome with non-finite values in {bad}"
        send(server, codec.pack(codec.message("bye", "b", reply["session"])))
    return reply


def test_the_templates_set_every_numeric_scene_key(extreme_server):
    """The walk of the scene's models finds the numeric keys; the templates set each of them (a new
    numeric key fails here until a template sets it), and each template builds a session."""
    server, hdbs, extra = extreme_server
    every = numeric_fields()
    covered: set[tuple[str, str]] = set()
    for name, sections in _templates().items():
        reply = _hello(server, hdbs, sections, **extra.get(name, {}))
        assert reply["type"] == "welcome", (name, reply)
        covered |= set_fields(parse_scene(toml_document(sections)))
    assert len(every) > 100 and every - covered == set(), sorted(every - covered)


@pytest.mark.parametrize("template", ["regular", "irregular", "sea", "elevation", "fmu"])
def test_extreme_values_in_every_numeric_scene_key(extreme_server, template):
    server, hdbs, extra = extreme_server
    sections = _templates()[template]
    ping = codec.pack(codec.message("ping", "alive", None))
    tried = 0
    for path, _ in _numeric_leaves(sections):
        for value in EXTREMES:
            reply = _hello(server, hdbs, _with(sections, path, value), **extra.get(template, {}))
            tried += 1
            where = (path, value, reply.get("field"), reply.get("message"))
            if reply["type"] == "welcome":
                free = path.startswith(FREE_KEYS) and math.isfinite(value)
                assert value in IN_RANGE_POSSIBLE or free, where
                continue
            assert reply["type"] == "error" and reply["code"] == codec.Code.BAD_SCENE, where
            if value not in IN_RANGE_POSSIBLE:   # out of bounds: the key itself is named (or its list entry)
                assert path.startswith(reply["field"].removeprefix("scene.")), where
                assert f"{path}: " in reply["message"], where
            else:                                # in bounds but not runnable: the key to change is named
                assert reply["field"].startswith("scene."), where
            assert send(server, ping)["type"] == "pong"
    assert tried > 8 * 10


MESSAGE_EXTREMES = [1e300, -1e300, 1e-308, 5e-324, float("nan"), float("inf"), -float("inf"), 2 ** 64 - 1, -2 ** 63,
                    2 ** 70, -2 ** 70]


def _field_name(path: tuple) -> str:
    out = ""
    for part in path:
        out = f"{out}[{part}]" if isinstance(part, int) else codec.key_path(out, part) if out else str(part)
    return out


def test_extreme_values_in_every_numeric_message_field(templates):
    """Each number of each request type (envelope, seq, time, iteration, epoch, wait, step, state,
    commands, array shapes) takes every extreme value: a regular reply or a named error, never
    99; an int msgpack cannot carry (2^70) is refused by the codec naming the field. Then a new
    session runs as ever."""
    server, t = templates
    ping = codec.pack(codec.message("ping", "alive", None))
    sent = 0
    for name, msg in t.items():
        for path in _paths(msg):
            parent = msg
            for part in path[:-1]:
                parent = parent[part]
            if not path or isinstance(parent, dict) and path[-1] == "data" or \
                    not isinstance(parent[path[-1]], (int, float)) or isinstance(parent[path[-1]], bool):
                continue
            for value in MESSAGE_EXTREMES:
                bad = copy.deepcopy(msg)
                target = bad
                for part in path[:-1]:
                    target = target[part]
                target[path[-1]] = value
                try:
                    frame = codec.pack(bad)
                except codec.EncodeError as exc:
                    assert abs(value) >= 2 ** 64 - 1 and exc.field == _field_name(path), (name, path, exc)
                    continue
                reply = send(server, frame)
                sent += 1
                if reply["type"] == "welcome" and "epoch" in reply:
                    for other in ("measure", "command"):
                        t[other]["epoch"] = reply["epoch"]
                _close_new_session(server, reply)
                where = (name, path, value, reply)
                if reply["type"] == "error":
                    assert reply["code"] != codec.Code.INTERNAL, where
                    if reply["code"] in (codec.Code.MISSING_FIELD, codec.Code.BAD_VALUE):
                        assert reply["field"], where
                assert send(server, ping)["type"] == "pong"
    assert sent > 100
    scene = parse_scene(t["hello"]["scene"])
    plain = scene_toml(dt=DT, duration=1.0, hydro={"irf_duration": 2.0}, bodies=[
        body("float", hdb="float.nc", mass=3.0e5, center_of_mass=[0, 0, -1], inertia=[1e7, 1e7, 2e7])])
    welcome = send(server, codec.pack(codec.message("hello", "n0", None, role="multibody", scene=plain,
                                                    hdbs=t["hello"]["hdbs"])))
    assert welcome["type"] == "welcome" and scene.bodies[0].name == "float", welcome
    zeros = np.zeros((1, 6))
    for seq in range(3):
        reply = send(server, codec.pack(codec.message("step", f"n{seq + 1}", welcome["session"], seq=seq,
                                                      time=seq * DT, position=zeros, velocity=zeros)))
        assert reply["type"] == "forces" and reply["seq"] == seq, reply


def test_a_controller_session_step_with_a_non_integer_iteration_is_error_5(templates):
    """Issue 22: a step with iteration = "x" in a session with controllers was a TypeError (99)."""
    server, t = templates
    for value in ("x", 1.5, [1], -1):
        msg = copy.deepcopy(t["step"])
        msg["iteration"] = value
        reply = send(server, codec.pack(msg))
        assert (reply["type"], reply["code"], reply["field"]) == ("error", codec.Code.BAD_VALUE, "iteration"), reply


def test_extreme_state_values_in_a_step_are_error_5_naming_the_array(templates):
    """A step's position and velocity hold numbers too: each extreme float in one element is error 5
    naming the array (beyond 1e5 m / 1e4 m/s the forces overflowed to inf and NaN: a reply hydrolink
    cannot vouch for); 1e-308 and 5e-324 are states like any other."""
    server, t = templates
    for field in ("position", "velocity"):
        for value in MESSAGE_EXTREMES[:7]:
            msg = copy.deepcopy(t["step"])
            state = np.zeros((1, 6))
            state[0, 2] = value
            msg[field] = state
            reply = send(server, codec.pack(msg))
            if value in IN_RANGE_POSSIBLE:
                assert reply["type"] != "error" or reply["field"] != field, reply
                continue
            assert (reply["type"], reply["code"], reply["field"]) == ("error", codec.Code.BAD_VALUE, field), reply
            assert "NaN or inf" in reply["message"] or "|value| must be <= 10000" in reply["message"], reply
