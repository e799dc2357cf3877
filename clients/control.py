"""Python controllers (SPEC §5.7): subclass :class:`Controller`, run it with ``hydrolink control``.

::

    from hydrolink.clients.control import Controller

    class Damper(Controller):
        def on_start(self, info):                 # info: the welcome's "control" map
            self.c = info["parameters"].get("damping", 1e6)
        def on_step(self, t, m):                  # m: the measurements of the state at t
            return {p: self.c * v for p, v in zip(self.ptos, m["pto_velocity"])}

    $ hydrolink control damper.py --server tcp://HOST:PORT --token TOKEN [--name NAME]

``TOKEN`` is the session's join token (SPEC §5.7.2), which its owner hands over: ``hydrolink run``
prints it, or takes it from ``--control-token`` / ``$HYDROLINK_CONTROL_TOKEN``.

``on_step`` returns ``{pto: value}``: a number is a force command; a map gives the setpoints
(``{"force": F}``, or ``{"damping": c, "stiffness": k}`` for ``command = "impedance"``).
Measurements: ``step``, ``seq``, ``time`` and numpy arrays per name of ``info["measurements"]``
(``pto_*`` in ``info["ptos"]`` order, ``body_*`` (n, 6) in ``info["bodies"]`` order,
``wave_elevation`` per probe, ``wave_preview`` (probe, time) at t + ``info["preview_times"]``).
The arrays are read-only (views of the received message): copy one to change it. On the server's
direct channel the commands and the measurements answering them travel as binary frames (SPEC
§5.7.6) when the server offers them; a command the frames cannot carry (a ``hydro_state``, an
impedance setpoint left out) goes as a map, with the same result.

A file that defines WAPPAC's ``my_controller(x, v, t, eta10)`` and no Controller subclass runs
unchanged through :class:`WappacController` (below).

This module imports only numpy, pyzmq and the codec, so a controller process starts fast.
"""

from __future__ import annotations

import contextlib
import gc
import importlib.util
import itertools
import math
import inspect
import logging
import sys
import time
from pathlib import Path
from typing import Any, Callable

import numpy as np
import zmq

from hydrolink.clients.lockstep.direct_channel import DirectChannel
from hydrolink.clients.lockstep.rt_priority import rt_priority as held_priority
from hydrolink.protocol import codec
from hydrolink.protocol.codec import FRAME_REQUESTS, ControlLayout

log = logging.getLogger("hydrolink.control")



class Controller:
    """Base class of a Python controller; override :meth:`on_step` (and optionally the others)."""

    #: the scene's ``controllers[i].name`` this class serves (``--name`` overrides; None: the
    #: session's only controller)
    name: str | None = None
    #: ask for the device as a linear plant at join (SPEC §5.7.2): None: no; "continuous"; or a
    #: sampling time in s (zero-order hold). ``on_start``'s ``info["plant"]`` is then a
    #: :class:`hydrolink.clients.analysis.plant.Plant`
    plant: str | float | None = None

    def on_start(self, info: dict) -> None:
        """Called once with the welcome's ``control`` map (ptos, bodies, dt, period, parameters...)."""

    def on_step(self, t: float, measurements: dict) -> dict:
        """Commands from the measurements of the state at ``t``."""
        raise NotImplementedError

    def on_stop(self) -> None:
        """Called when the run ends (or the session closes)."""

    def switch_hydro_state(self, body: str, state: str) -> None:
        """From :meth:`on_step`: command ``body`` into its hydrodynamic ``state`` with this step's
        commands (the scene's ``controllers[i].hydro_states`` lists the body; SPEC §5.7.4)."""
        self._hydro_state = {**(getattr(self, "_hydro_state", None) or {}), body: state}

    def take_hydro_state(self) -> dict[str, str] | None:
        """The hydro states commanded since the last call (the runner sends them), then forgotten."""
        out, self._hydro_state = getattr(self, "_hydro_state", None), None
        return out

    def on_error(self, error: dict) -> None:
        """A command was refused (``code``, ``name``, ``field``, ``message``; SPEC §5.7.4): that step
        ran on the fallback. Default: nothing (the runner logs it)."""


class ControllerError(RuntimeError):
    """The server refused the controller (wrong session, version, name), or went silent."""

    def __init__(self, message: str, code: int | None = None, field: str | None = None):
        super().__init__(message)
        self.code, self.field = code, field


def _command_map(commands: Any) -> Any:
    """Plain numbers become ``{"force": F}``; values are sent as Python floats (NaN stays NaN:
    the server rejects it, SPEC §5.7.4)."""
    if not isinstance(commands, dict):
        return commands
    out = {}
    for pto, value in commands.items():
        if isinstance(value, dict):
            out[str(pto)] = {str(k): float(v) if isinstance(v, (int, float, np.number)) else v
                             for k, v in value.items()}
        elif isinstance(value, (int, float, np.number)) and not isinstance(value, bool):
            out[str(pto)] = {"force": float(value)}
        else:
            out[str(pto)] = value
    return out


def decode_measurements(reply: dict) -> dict:
    out = {k: reply[k] for k in ("step", "seq", "time") if k in reply}
    for k, v in reply.items():
        if isinstance(v, dict) and "dtype" in v:
            out[k] = codec.decode_array(v, k, "f")
    return out


class _Link:
    """One DEALER socket to the server; requests matched by ``parent``; every receive times out.
    After the welcome, :meth:`go_direct` moves the requests to the server's direct channel when it
    offers one (SPEC §5.7.5): a plain stream socket, no ZeroMQ I/O thread on either side."""

    def __init__(self, address: str, key: bytes | None, timeout: float, curve=None):
        self.address, self.key, self.timeout = address, key, timeout
        self.ctx = zmq.Context()
        self.sock = self.ctx.socket(zmq.DEALER)
        self.sock.setsockopt(zmq.LINGER, 0)
        if curve is not None:  # hydrolink.protocol.security.ClientKeys
            curve.apply(self.sock)
        self.sock.connect(address)
        self.ids = codec.id_source("k")
        self.numbers = itertools.count(1)   # the command frames' request numbers
        self.session: str | None = None
        self.direct: DirectChannel | None = None
        self.frames: ControlLayout | None = None   # the binary frames the welcome offered (SPEC §5.7.6)

    def request(self, mtype: str, hold: float = 0.0, **fields: Any) -> dict:
        """``hold``: how long the server may hold the request (SPEC §5.7.4 ``wait``)."""
        msg_id = next(self.ids)
        frame = codec.pack(codec.message(mtype, msg_id, self.session, **fields), self.key)
        if self.direct is not None:
            try:
                return self.direct.request(frame, msg_id, hold + self.timeout, self.key)
            except OSError as exc:   # the channel broke: the request again over ZeroMQ
                self._lost(exc)
        self.sock.send(frame)
        deadline = time.monotonic() + hold + self.timeout
        while True:
            left = deadline - time.monotonic()
            if left <= 0 or not self.sock.poll(int(left * 1000) + 1):
                raise ControllerError(f"no reply to {mtype!r} from the hydrolink server at {self.address} within "
                                      f"{hold + self.timeout:g} s")
            reply = codec.unpack(self.sock.recv(), self.key)
            if reply.get("parent") == msg_id:
                return reply

    def command(self, step: int, commands: Any, wait: float, ident: dict, hydro: dict | None) -> dict:
        """Send the commands of ``step`` (what ``on_step`` returned): as a command frame when the
        welcome offered frames and they fit its layout (SPEC §5.7.6), else as a ``command`` map."""
        if self.frames is not None and self.direct is not None and not hydro:
            number = next(self.numbers) % FRAME_REQUESTS
            frame = self.frames.command_frame(number, ident["epoch"], step, wait, commands)
            if frame is not None:
                try:
                    return self.direct.request(frame, number, wait + self.timeout, self.key, self.frames)
                except OSError as exc:   # the channel broke: the command again, as a map over ZeroMQ
                    self._lost(exc)
        return self.request("command", wait, step=step, commands=_command_map(commands), **ident,
                            **({"hydro_state": hydro} if hydro else {}))

    def _lost(self, exc: OSError) -> None:
        log.warning("direct channel to %s lost (%s): continuing over ZeroMQ", self.address, exc)
        self.direct.close()
        self.direct = None

    def go_direct(self, offer: Any) -> None:
        """Open the direct channel the welcome offers (``welcome.direct``), with its binary frames
        when it offers them (``direct.frames``); without one, or when it cannot be opened within
        CONNECT_S (clients/lockstep/direct_channel.py), the requests stay on ZeroMQ."""
        if not isinstance(offer, dict) or not isinstance(offer.get("ticket"), str):
            return
        try:
            self.direct = DirectChannel.open(self.address, offer)
        except (OSError, ValueError) as exc:
            log.info("direct channel to %s not opened (%s): requests stay on ZeroMQ", self.address, exc)
            return
        if "frames" in offer:
            try:
                self.frames = ControlLayout.from_wire(offer["frames"])
            except ValueError as exc:
                log.warning("direct channel to %s: its frames not taken (%s): commands go as maps", self.address, exc)

    def close(self) -> None:
        if self.direct is not None:
            self.direct.close()
        self.sock.close(0)
        self.ctx.term()


def _join(link: _Link, controller: Controller, name: str | None, token: str, join_wait: float, direct: bool,
          any_session: bool) -> dict:
    """The ``welcome`` to the controller's ``hello``, retried for ``join_wait`` s while no session
    declares it (``any_session``: no session was named); ControllerError otherwise."""
    t_end = time.monotonic() + join_wait
    while True:
        ask = {} if controller.plant is None else {
            "plant": {"dt": None if controller.plant == "continuous" else float(controller.plant)}}
        try:
            reply = link.request("hello", max(0.0, t_end - time.monotonic()), role="controller", controller=name,
                                 token=token, client={"name": f"hydrolink-python-controller "
                                                      f"{type(controller).__name__}", "version": _version()},
                                 **ask, **({"frames": True} if direct else {}))
        except ControllerError as exc:
            raise ControllerError(f"{exc}: no session to join within the join wait ({join_wait:g} s; a run's "
                                  "set-up on a loaded host may need more: --join-wait)") from None
        if reply["type"] == "welcome":
            return reply
        if reply.get("code") == codec.Code.UNKNOWN_SESSION and any_session and time.monotonic() < t_end:
            time.sleep(0.1)
            continue
        raise ControllerError(f"server refused the controller: error {reply.get('code')} {reply.get('name')} "
                              f"[{reply.get('field')}]: {reply.get('message')}", reply.get("code"), reply.get("field"))


def run_controller(controller: Controller, server: str, *, token: str, session: str | None = None,
                   name: str | None = None, key: bytes | None = None, join_wait: float = 30.0, wait: float = 1.0,
                   timeout: float = 30.0, curve=None, direct: bool = True, rt_priority: int | None = None) -> dict:
    """Join a session and serve it until the run ends; returns counts (steps, errors, idles),
    ``direct``: whether the requests ended on the server's direct channel, and ``cpu_s``: this
    process's CPU time (every thread's, ZeroMQ's I/O thread included) from ``on_start`` to ``stop``.

    ``token``: the session's join token (SPEC §5.7.2), which its owner has (``hydrolink run`` prints
    it, or takes it from ``--control-token``): without it the server refuses the join.

    Retries ``hello`` for ``join_wait`` s while no session declares the controller (the multibody
    run may start later), and waits as long for the reply to a ``hello`` (plus ``timeout``): a
    server not yet bound, or the run's own server, which answers its socket only once the run's
    set-up is done (SPEC §5.7.1: minutes of model building and compilation on a loaded host), is a
    session not open yet, not a server gone; after the welcome, as long for the first measurements
    (that server does not turn either while the run's first step compiles). ``wait``: how long the
    server holds a ``measure`` before ``idle``; ``timeout``: extra time for any reply before the
    server is declared gone; ``curve``: a :class:`hydrolink.protocol.security.ClientKeys` for a
    server that requires CURVE; ``direct``: take the server's direct channel when its welcome offers one (SPEC §5.7.5; False: ZeroMQ only);
    ``rt_priority``: the loop, from the first ``measure`` (after the join and ``on_start``) to
    ``stop``, under ``SCHED_FIFO`` at that priority (clients/lockstep/rt_priority.py; the caller
    checks it may be had before the join)."""
    name = name if name is not None else getattr(controller, "name", None)
    link = _Link(server, key, timeout, curve)
    link.session = session
    stats = {"steps": 0, "errors": 0, "idle": 0, "late": 0, "invalid": 0, "cpu_s": math.nan}
    loop_priority = contextlib.ExitStack()   # the loop's real-time priority, given back in ``finally``
    try:
        reply = _join(link, controller, name, token, join_wait, direct, session is None)
        link.session = reply["session"]
        epoch = reply["epoch"]
        if direct:
            link.go_direct(reply.get("direct"))
        info = codec.decode_tree(reply["control"])
        if "plant" in info:
            from hydrolink.clients.analysis.plant import Plant
            info["plant"] = Plant.from_wire(info["plant"])
        name = info["name"]
        controller.ptos = list(info["ptos"])
        log.info("controller %r joined session %s (epoch %d)", name, link.session, epoch)
        controller.on_start(info)
        # what the process holds by now (imports, the controller's set-up) frozen: a collection in
        # the loop scans only what the steps make (the young generation), not the whole heap
        gc.collect()
        gc.freeze()
        cpu0 = time.process_time()
        ident = {"controller": name, "epoch": epoch, "wait": wait}
        loop_priority.enter_context(held_priority(rt_priority))
        # until the first measurements, a measure is waited for the join wait (plus the reply
        # timeout): the run's own server does not turn while the run's first step compiles
        first = time.monotonic() + join_wait
        reply = link.request("measure", max(wait, first - time.monotonic()), **ident)
        while True:
            kind = reply["type"]
            if kind == "measurements":
                first = -math.inf
                m = reply["frame"] if "frame" in reply else decode_measurements(reply)
                commands = controller.on_step(float(reply["time"]), m)
                stats["steps"] += 1
                reply = link.command(reply["step"], commands, wait, ident, controller.take_hydro_state())
            elif kind == "idle":
                stats["idle"] += 1
                reply = link.request("measure", max(wait, first - time.monotonic()), **ident)
            elif kind == "stop":
                log.info("controller %r: stop (%s)", name, reply.get("reason"))
                stats["cpu_s"] = time.process_time() - cpu0
                break
            elif kind == "error":
                code = reply.get("code")
                stats["errors"] += 1
                stats["late" if code == codec.Code.OUT_OF_ORDER else "invalid"] += 1
                log.warning("controller %r: server error %s %s [%s]: %s", name, code, reply.get("name"),
                            reply.get("field"), reply.get("message"))
                controller.on_error({k: reply.get(k) for k in ("code", "name", "field", "message")})
                if code in (codec.Code.UNKNOWN_SESSION, codec.Code.WRONG_STATE, codec.Code.VERSION_MISMATCH):
                    raise ControllerError(f"error {code} {reply.get('name')}: {reply.get('message')}", code,
                                          reply.get("field"))
                reply = link.request("measure", wait, **ident)
            else:
                raise ControllerError(f"unexpected reply type {kind!r}")
    finally:
        loop_priority.close()
        gc.unfreeze()
        stats["direct"] = link.direct is not None
        stats["frames"] = link.direct is not None and link.frames is not None
        link.close()
    controller.on_stop()
    return stats


# ---------------------------------------------------------------- WAPPAC's signature
# WAPPAC's controller signature as a hydrolink controller: a file that defines
# ``my_controller(x, v, t, eta10)`` (the WavePiston control competition's entry,
# https://emg-mu.github.io/WAPPAC_docs/) runs unchanged with ``hydrolink control FILE``.
#
# Each control period the function is called with the PTO's displacement ``x`` (m) and velocity
# ``v`` (m/s) of the measurements, the measurements' time ``t`` (s) and ``eta10``: the wave elevation
# (m) at the controller's first ``wave_points`` probe, which stands for WAPPAC's gauge 10 m up-wave
# (put it where the scene's device needs it). Its return value is the PTO force (N), WAPPAC's
# F_pto with absorbed power F_pto v: the same sign as hydrolink's force command (a damper returns
# c v). Like WAPPAC's ZOH, the force is held over the period (the scene's ``period``, ``latency``).
#
# The scene's controller must drive one PTO with ``command = "force"`` and measure
# ``pto_displacement``, ``pto_velocity`` and ``wave_elevation``; anything else is refused naming the
# key. A folder ``external_packages`` beside the file is importable, as in WAPPAC's distribution.

WAPPAC_MEASUREMENTS = ("pto_displacement", "pto_velocity", "wave_elevation")


class WappacController(Controller):
    """Calls ``function(x, v, t, eta10)`` every control period; its value is the force command."""

    def __init__(self, function: Callable[[float, float, float, float], float], source: str):
        self.function, self.source = function, source

    def on_start(self, info: dict) -> None:
        where = f"controllers[{info['name']!r}]"
        if len(info["ptos"]) != 1:
            raise ControllerError(f"{self.source}: my_controller drives one PTO; the scene's {where}.ptos "
                                  f"lists {info['ptos']}", field="ptos")
        if info["command"] != "force":
            raise ControllerError(f"{self.source}: my_controller returns a force; the scene's {where}.command is "
                                  f"{info['command']!r} (use \"force\")", field="command")
        missing = [m for m in WAPPAC_MEASUREMENTS if m not in info["measurements"]]
        if missing:
            raise ControllerError(f"{self.source}: my_controller needs {list(WAPPAC_MEASUREMENTS)}; add {missing} to the "
                                  f"scene's {where}.measurements", field="measurements")

    def on_step(self, t: float, m: dict) -> dict:
        force = self.function(float(m["pto_displacement"][0]), float(m["pto_velocity"][0]), t,
                              float(m["wave_elevation"][0]))
        try:
            value = float(force)
        except (TypeError, ValueError):
            raise ControllerError(f"{self.source}: my_controller returned {force!r} at t = {t:g} s, not a "
                                  "number (the PTO force in N)") from None
        if not math.isfinite(value):
            raise ControllerError(f"{self.source}: my_controller returned {value} at t = {t:g} s")
        return {self.ptos[0]: value}


def _version() -> str:
    from importlib import metadata
    try:
        return metadata.version("hydrolink")
    except metadata.PackageNotFoundError:  # pragma: no cover
        return "unknown"


def load_controller(path: str | Path, class_name: str | None = None) -> Controller:
    """Instantiate the Controller subclass defined in the Python file ``path`` (the only one, or
    ``class_name``); a file with none that defines WAPPAC's ``my_controller(x, v, t, eta10)`` runs
    it through :class:`WappacController`."""
    path = Path(path)
    spec = importlib.util.spec_from_file_location(f"hydrolink_controller_{path.stem}", path)
    if spec is None or spec.loader is None:
        raise ControllerError(f"{path}: not a Python file")
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    packages = path.resolve().parent / "external_packages"     # WAPPAC's folder for an entry's packages
    if packages.is_dir() and str(packages) not in sys.path:
        sys.path.insert(0, str(packages))
    spec.loader.exec_module(module)
    found = [obj for _, obj in inspect.getmembers(module, inspect.isclass)
             if issubclass(obj, Controller) and obj is not Controller and obj.__module__ == module.__name__]
    if not found and class_name is None and callable(getattr(module, "my_controller", None)):
        return WappacController(module.my_controller, str(path))
    if class_name is not None:
        found = [c for c in found if c.__name__ == class_name]
    if len(found) != 1:
        names = [c.__name__ for c in found]
        raise ControllerError(f"{path}: expected one Controller subclass{' named ' + class_name if class_name else ''}, "
                              f"found {names or 'none'} (use --class)")
    return found[0]()
