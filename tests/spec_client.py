"""A multibody client written from protocol/SPEC.md alone, as a third party would write one.

KEEP IT SO: this module must not import hydrolink (only numpy, msgpack and pyzmq). It is the guard
that the SPEC by itself gives a correct co-simulation: if a change to the server breaks a client
that follows the document, tests/test_spec_client.py fails. Every rule used here cites its section.

The body model is the linear one of SPEC §5.2 "Force contract": the client's mass matrix holds
M + setup.added_mass, its stiffness matrix setup.hydrostatic_stiffness, it applies
setup.net_buoyancy as a constant heave force and, from each `forces` reply, excitation + radiation
(the reply's `hydrostatic` field is then not applied: it is the same stiffness). Time stepping is
Newmark's average-acceleration rule; the two lockstep recipes of SPEC §8.3 are implemented:

- ``"predictor"``: step seq k+1 is sent once, at the state predicted from t_k;
- ``"iterated"``: the same first pass, then the step is re-sent with ``iteration`` 1 at the state
  the client actually reached, solved with the published ``setup.radiation_feedthrough`` in its
  damping matrix (one Newton correction is exact: the force is linear in the velocity sent).
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, field

import msgpack
import numpy as np
import zmq

DOFS = ("surge", "sway", "heave", "roll", "pitch", "yaw")


# ------------------------------------------------------------------------------ SPEC §2.1 arrays

def pack_array(a: np.ndarray) -> dict:
    """The binary array map (§2.1): little-endian float64/complex128/bool, C order."""
    a = np.asarray(a)
    dtype = {"f": "<f8", "c": "<c16", "b": "|b1", "i": "<i8"}[a.dtype.kind]
    return {"dtype": dtype, "shape": list(a.shape), "data": np.ascontiguousarray(a, dtype).tobytes()}


def unpack(value):
    """Replace every array map in a decoded message by a numpy array (§2.1)."""
    if isinstance(value, dict):
        if set(value) == {"dtype", "shape", "data"} and isinstance(value["data"], bytes):
            return np.frombuffer(value["data"], np.dtype(value["dtype"])).reshape(value["shape"])
        return {k: unpack(v) for k, v in value.items()}
    if isinstance(value, list):
        return [unpack(v) for v in value]
    return value


class ServerError(Exception):
    """An `error` reply (§5.6)."""

    def __init__(self, reply: dict):
        self.code, self.name, self.field = reply["code"], reply["name"], reply.get("field")
        super().__init__(f"error {self.code} {self.name} [{self.field}]: {reply['message']}")


# ------------------------------------------------------------------------------ §1, §3 transport

class Connection:
    """One DEALER socket, the envelope of §3, one request in flight."""

    def __init__(self, address: str, timeout_s: float = 120.0):   # a loaded 2-core CI: hellos over 30 s
        self.ctx = zmq.Context()
        self.sock = self.ctx.socket(zmq.DEALER)
        self.sock.setsockopt(zmq.RCVTIMEO, int(timeout_s * 1000))
        self.sock.setsockopt(zmq.LINGER, 0)
        self.sock.connect(address)
        self.session: str | None = None
        self._ids = itertools.count(1)

    def request(self, kind: str, **fields) -> dict:
        msg_id = f"c-{next(self._ids)}"
        self.sock.send(msgpack.packb({"v": 1, "type": kind, "msg_id": msg_id, "session": self.session, **fields},
                                     use_bin_type=True))
        while True:
            reply = msgpack.unpackb(self.sock.recv(), raw=False)
            if reply.get("parent") == msg_id:       # a late reply to an earlier request is dropped (§6)
                break
        if reply["type"] == "error":
            raise ServerError(reply)
        return unpack(reply)

    def close(self) -> None:
        self.sock.close(0)
        self.ctx.term()


# ------------------------------------------------------------------------------ the body model

@dataclass
class Record:
    """What the client keeps per step: time, active-DOF displacement from equilibrium, elevation."""
    time: list[float] = field(default_factory=list)
    displacement: list[np.ndarray] = field(default_factory=list)
    elevation: list[float] = field(default_factory=list)
    corrections: list[float] = field(default_factory=list)   # |F(iteration 1) - predicted by the feedthrough|


def run(address: str, scene: str, hdbs: dict[str, dict], mass: np.ndarray, recipe: str) -> Record:
    """Co-simulate ``scene`` to its end with the server at ``address``. ``mass``: the bodies' own
    (6N, 6N) rigid-body mass matrix about their reference points (the client's business, not the
    server's). ``recipe``: "predictor" or "iterated" (SPEC §8.3)."""
    if recipe not in ("predictor", "iterated"):
        raise ValueError(recipe)
    conn = Connection(address)
    try:
        welcome = conn.request("hello", role="multibody", scene=scene, hdbs=hdbs,
                               client={"name": "spec-client", "version": "1"})
        conn.session = welcome["session"]
        setup = welcome["setup"]
        return _lockstep(conn, setup, mass, recipe)
    finally:
        if conn.session is not None:
            try:
                conn.request("bye")
            finally:
                conn.close()
        else:
            conn.close()


def _lockstep(conn: Connection, setup: dict, mass: np.ndarray, recipe: str) -> Record:
    n = len(setup["bodies"])
    act = np.flatnonzero(np.asarray(setup["active"], bool).reshape(-1))       # §5.1 active
    ix = np.ix_(act, act)
    m = (np.asarray(mass) + setup["added_mass"])[ix]                          # §5.2 force contract
    k = np.asarray(setup["hydrostatic_stiffness"])[ix]
    d = np.asarray(setup["radiation_feedthrough"])[ix]
    x_eq = np.asarray(setup["equilibrium_position"], float).reshape(-1)
    f_const = np.zeros(6 * n)
    f_const[2::6] = setup["net_buoyancy"]                                     # on heave, constant
    f_const = f_const[act]
    h, last = float(setup["dt"]), int(setup["last_seq"])                     # §2.2 clock, §5.3

    def send(seq: int, u: np.ndarray, v: np.ndarray, iteration: int = 0) -> tuple[np.ndarray, float]:
        pos, vel = x_eq.copy(), np.zeros(6 * n)
        pos[act] += u
        vel[act] = v
        r = conn.request("step", seq=seq, time=seq * h, iteration=iteration,
                         position=pack_array(pos.reshape(n, 6)), velocity=pack_array(vel.reshape(n, 6)))
        load = (np.asarray(r["excitation"]) + np.asarray(r["radiation"])).reshape(-1)[act] + f_const
        return load, float(r["wave_elevation"])

    rec = Record()
    u, v = np.zeros(act.size), np.zeros(act.size)
    f, eta = send(0, u, v)
    a = np.linalg.solve(m, f - k @ u)
    rec.time.append(0.0), rec.displacement.append(u.copy()), rec.elevation.append(eta)
    newmark = m + 0.25 * h * h * k
    with_feedthrough = newmark - 0.5 * h * d          # the radiation's direct term moved to the left
    for seq in range(1, last + 1):
        up, vp = u + h * v + 0.5 * h * h * a, v + h * a                      # the predicted state
        f, eta = send(seq, up, vp)
        base = k @ (u + h * v + 0.25 * h * h * a)
        if recipe == "predictor":
            a_new = np.linalg.solve(newmark, f - base)
        else:
            f_hist = f - d @ vp                                              # the part that does not move with v
            a_new = np.linalg.solve(with_feedthrough, f_hist - base + d @ (v + 0.5 * h * a))
        u, v = u + h * v + 0.25 * h * h * (a + a_new), v + 0.5 * h * (a + a_new)
        a = a_new
        if recipe == "iterated":                                             # §5.3 rule 2: replace
            f1, _ = send(seq, u, v, iteration=1)
            rec.corrections.append(float(np.abs(f1 - (f_hist + d @ v)).max()))
        rec.time.append(seq * h), rec.displacement.append(u.copy()), rec.elevation.append(eta)
    return rec
