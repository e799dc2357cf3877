"""Controllers inside a session (SPEC §5.7): the relay of measurements and commands, deadlines
and fallback decisions (the wave probes of the measurements: server/sea/probes.py).

The server mediates: the multibody client and each controller talk only to the server. A
:class:`ControlHub` per session keeps one :class:`Slot` per declared controller. Deferred replies
(a controller waiting for measurements, a multibody step waiting for a command) are parked with
their routing frames and sent through the ``send(route, type, parent, fields)`` callback of the
service when their condition is met or their deadline passes (:meth:`ControlHub.poll`). Requests
pipelined behind a deferred step wait in :attr:`ControlHub.held` and are handled, in order, once
it is answered (SPEC §1: a client's requests are answered in order).
"""

from __future__ import annotations

import hmac
import logging
import math
import re
import secrets
import time as _time
from collections import deque
from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np

from hydrolink.protocol import codec
from hydrolink.protocol.codec import Code, CommandFrame, ControlLayout, ProtocolError
from hydrolink.protocol.scene import Controller, LinearPTO, Scene
from hydrolink.server.allocation import require_size
from hydrolink.server.sea.probes import PreviewGrid

log = logging.getLogger("hydrolink.server.service.controllers")

MAX_WAIT = 30.0
STATUSES = ("ok", "timeout", "absent", "invalid")
MB_FIELDS = ("pto_displacement", "pto_velocity", "pto_force", "body_position", "body_velocity")
_F8 = np.dtype(np.float64)
SEQUENCED = ("step", "bye", "save", "restore", "release")   # requests that act on the step sequence


# ---------------------------------------------------------------- one controller

@dataclass
class Slot:
    cfg: Controller
    pto_rows: np.ndarray           # rows of its PTOs among the scene's linear PTOs
    body_rows: np.ndarray          # rows of its bodies among the scene bodies
    period: int                    # P
    latency: int                   # L
    grid: PreviewGrid              # where and when its wave probes look (computed where the model steps)
    fallback_damping: list[float] | None
    state: str = "waiting"         # waiting | active | absent
    epoch: int = 0
    parked: tuple | None = None    # (route, msg_id, idle deadline, the controller's session id)
    newest: int = -1               # newest step relayed to this slot
    delivered: int = -1            # newest step delivered to the controller
    sample: dict | None = None     # the newest measurements (reply fields)
    sample_whole: bool = True      # False: the newest has no wave fields (relayed before the first join)
    relay_time: dict[int, float] = field(default_factory=dict)
    received: dict[int, tuple] = field(default_factory=dict)   # step -> ("ok", commands, latency) | ("invalid", msg)
    decided: int = -1              # newest step decided: every step up to it is (in step order: no rollback)
    counts: dict[str, int] = field(default_factory=lambda: {s: 0 for s in (*STATUSES, "late", "joins")})

    @property
    def name(self) -> str:
        return self.cfg.name


def setpoints(c: Controller) -> tuple[str, ...]:
    """The setpoints of each PTO's command of controller ``c`` (SPEC §5.7.4)."""
    return ("force",) if c.command == "force" else ("damping", "stiffness")


TOKEN = re.compile(r"[A-Za-z0-9_-]{32,128}")   # a join token: at least 32 characters (SPEC §5.7.2)


def join_token(msg: dict) -> str:
    """The multibody hello's ``control_token`` (checked), or a new one of 256 random bits."""
    token = msg.get("control_token")
    if token is None:
        return secrets.token_urlsafe(32)
    if not isinstance(token, str) or not TOKEN.fullmatch(token):
        raise ProtocolError(Code.BAD_VALUE, "control_token", "must be 32 to 128 characters of A-Z, a-z, 0-9, "
                            f"'-' and '_' (a secret the controllers show to join), got {codec.describe(token)}")
    return token


def token_matches(hub: "ControlHub", token: str) -> bool:
    """Whether ``token`` is ``hub``'s join token (compared in constant time)."""
    return hmac.compare_digest(hub.token.encode(), token.encode())


class ControlHub:
    """The controllers of one session (see module docstring)."""

    def __init__(self, scene: Scene, scene_text: str, n_waves: int, session_id: str, send: Callable[..., None],
                 token: str):
        """``n_waves``: the model's wave components. ``token``: the secret a controller's hello must
        carry to join (SPEC §5.7.2): the owner's (its hello's ``control_token``) or one drawn by the
        server; the owner's welcome returns it."""
        self.scene, self.scene_text, self.session_id, self.send = scene, scene_text, session_id, send
        self.token = token
        self.dt = float(scene.simulation.dt)
        self.n_steps = scene.simulation.n_steps
        linear = [p for p in scene.ptos if isinstance(p, LinearPTO)]
        self.pto_names = [p.name for p in linear]
        self.pto_damping = {p.name: float(p.damping) for p in linear}
        self.body_names = [b.name for b in scene.bodies]
        # the measurements' arrays (SPEC §5.7.3): (field, shape) in MB_FIELDS order
        self.mb_shapes = tuple((name, (len(self.pto_names),) if name.startswith("pto") else (len(self.body_names), 6))
                               for name in MB_FIELDS)
        self.slots: dict[str, Slot] = {}
        for i, c in enumerate(scene.controllers):
            P = c.steps_per_period(self.dt)
            hstep = int(round((c.preview_step or P * self.dt) / self.dt))
            n_h = int(math.floor(c.preview / (hstep * self.dt) + 1e-9)) if c.preview > 0 else 0
            require_size(f"controllers[{i}].preview_step", "the wave probes' phasors and preview window "
                         "(components + samples, x probes)", (max(n_waves, 1) + n_h + 1, len(c.wave_points)),
                         16, hint="fewer preview samples: a longer preview_step or a shorter preview "
                         f"({c.preview:g} s)")
            grid = PreviewGrid(tuple((float(x), float(y)) for x, y in c.wave_points), self.dt, hstep, n_h)
            fb = None
            if c.fallback == "passive":
                fb = [float(c.fallback_damping) if c.fallback_damping is not None else self.pto_damping[p]
                      for p in c.ptos]
            self.slots[c.name] = Slot(c, np.array([self.pto_names.index(p) for p in c.ptos], int),
                                      np.array([self.body_names.index(b) for b in (c.bodies or self.body_names)], int),
                                      P, int(c.latency), grid, fb)
        self.pending: dict | None = None   # the multibody step reply waiting for commands
        self.held: deque[tuple[dict, list[bytes]]] = deque()   # (request, route) behind the pending step
        self.pending_deadline = math.inf
        self.last_control: tuple[int, dict] | None = None
        self.ended: str | None = None

    # ------------------------------------------------------------ controller side

    def info(self, slot: Slot) -> dict:
        c = slot.cfg
        return {
            "name": c.name, "ptos": list(c.ptos), "bodies": [self.body_names[i] for i in slot.body_rows],
            "command": c.command, "dt": self.dt, "period": slot.period * self.dt,
            "steps_per_period": slot.period, "latency": slot.latency,
            "duration": self.n_steps * self.dt, "steps": self.n_steps,
            "measurements": list(c.measurements), "wave_points": np.array(c.wave_points, float).reshape(-1, 2),
            "preview_times": slot.grid.offsets[1:], "timeout": c.timeout, "fallback": c.fallback,
            "fallback_damping": slot.fallback_damping,
            "limits": {"max_force": c.max_force, "damping": list(c.damping_range),
                       "stiffness": list(c.stiffness_range)},
            "parameters": dict(c.parameters), "scene": self.scene_text,
        }

    def join(self, name: str | None) -> tuple[Slot, bool]:
        """The slot a controller hello names (ProtocolError 5 if none); (slot, rejoined)."""
        if name is None:
            if len(self.slots) != 1:
                raise ProtocolError(Code.MISSING_FIELD, "controller", "this session declares controllers "
                                    f"{sorted(self.slots)}: name one in 'controller'")
            name = next(iter(self.slots))
        slot = self.slots.get(name)
        if slot is None:
            raise ProtocolError(Code.BAD_VALUE, "controller", f"this session declares no controller "
                                f"{name!r} (it declares {sorted(self.slots)})")
        rejoined = slot.counts["joins"] > 0
        slot.counts["joins"] += 1
        slot.epoch += 1
        if slot.parked is not None:   # the replaced connection's request: answered, not left hanging
            route, msg_id, _, own = slot.parked
            slot.parked = None
            self.send(route, "idle", msg_id, {}, own)
        self._activate(slot)
        if slot.newest > slot.decided and slot.sample_whole:
            slot.delivered = min(slot.delivered, slot.newest - 1)   # the newest goes to the new connection
        log.info("session %s: controller %r %s (epoch %d)", self.session_id, name,
                 "rejoined" if rejoined else "joined", slot.epoch)
        self._maybe_finish_pending()
        return slot, rejoined

    def slot_for(self, msg: dict) -> Slot:
        name = codec.require_str(msg, "controller")
        slot = self.slots.get(name)
        if slot is None:
            raise ProtocolError(Code.BAD_VALUE, "controller", f"this session declares no controller "
                                f"{name!r} (it declares {sorted(self.slots)})")
        epoch = codec.require_int(msg, "epoch", minimum=1)
        if epoch != slot.epoch:
            raise ProtocolError(Code.WRONG_STATE, "epoch", f"controller {name!r} epoch {epoch} was replaced by a "
                                f"newer connection (epoch {slot.epoch}); send hello again to take over")
        return slot

    def _activate(self, slot: Slot) -> None:
        if slot.state != "active":
            if slot.state == "absent":
                log.warning("session %s: controller %r is back", self.session_id, slot.name)
            slot.state = "active"

    def _wait(self, msg: dict) -> float:
        w = msg.get("wait", 1.0)
        if type(w) not in (int, float) or not math.isfinite(w) or w < 0:
            raise ProtocolError(Code.BAD_VALUE, "wait", f"must be a number of seconds >= 0, got {codec.describe(w)}")
        return min(float(w), MAX_WAIT)

    def measure(self, msg: dict, route, msg_id, own: str) -> tuple[str, dict] | None:
        """Reply to ``measure``: the next measurements now, or None (parked). ``own``: the
        controller's session id (SPEC §5.7.2), which its deferred replies carry."""
        slot = self.slot_for(msg)
        wait = self._wait(msg)
        self._activate(slot)
        return self._next_for(slot, route, msg_id, wait, own)

    def layout(self, slot: Slot) -> ControlLayout:
        """The binary frames of ``slot``'s controller (SPEC §5.7.6): its measurements in the order of
        its ``measurements`` replies, its command's setpoints per PTO."""
        c = slot.cfg
        meas = [(n, (len(slot.pto_rows),) if n.startswith("pto") else (len(slot.body_rows), 6))
                for n in c.measurements if n != "wave_elevation"]
        if "wave_elevation" in c.measurements:
            meas.append(("wave_elevation", (len(c.wave_points),)))
        if slot.grid.samples > 0:
            meas.append(("wave_preview", (len(c.wave_points), slot.grid.samples)))
        return ControlLayout(tuple(meas), tuple((p, k) for p in c.ptos for k in setpoints(c)))

    def command(self, msg: dict, route, msg_id, own: str) -> tuple[str, dict] | None:
        """Reply to ``command`` (a msgpack map): its ``commands`` and ``hydro_state`` checked."""
        return self._command(msg, route, msg_id, own, lambda slot: (self._validate(slot, msg.get("commands")),
                                                                     self._hydro_state(slot, msg.get("hydro_state"))))

    def command_frame(self, name: str, cmd: CommandFrame, route, own: str) -> tuple[str, dict] | None:
        """Reply to a command frame (SPEC §5.7.6) of controller ``name``: the same checks, errors,
        decisions and counts as :meth:`command`'s, its values checked in the layout's slot order."""
        slot = self.slots[name]
        msg = {"controller": name, "epoch": cmd.epoch, "wait": cmd.wait, "step": cmd.step}
        keys = setpoints(slot.cfg)

        def values(slot: Slot) -> tuple[dict, None]:
            it = iter(cmd.values)
            return {p: {k: self._setpoint(slot.cfg, p, k, next(it)) for k in keys} for p in slot.cfg.ptos}, None
        return self._command(msg, route, cmd.request, own, values)

    def _command(self, msg: dict, route, msg_id, own: str, checked: Callable[[Slot], tuple]) -> tuple[str, dict] | None:
        """A command of either form: the step's order checked, then ``checked(slot)`` ((commands,
        hydro_state), ProtocolError for an invalid one), the decision taken when it can be."""
        slot = self.slot_for(msg)
        wait = self._wait(msg)
        self._activate(slot)
        step = codec.require_int(msg, "step", minimum=0)
        if step != slot.delivered:
            raise ProtocolError(Code.OUT_OF_ORDER, "step", f"command for step {step}, but the newest measurements "
                                f"delivered to {slot.name!r} are of step {slot.delivered}; continue with measure")
        if step <= slot.decided or step in slot.received:
            if step <= slot.decided and step not in slot.received:
                slot.counts["late"] += 1
                log.warning("session %s: controller %r late for step %d (fallback used)", self.session_id,
                            slot.name, step)
            raise ProtocolError(Code.OUT_OF_ORDER, "step", f"the decision for step {step} was already taken "
                                "(late: its deadline passed and the fallback was used, or a second command); "
                                "continue with measure")
        try:
            commands, hydro = checked(slot)
        except ProtocolError:
            slot.received[step] = ("invalid",)
            self._maybe_finish_pending()
            raise
        latency = _time.monotonic() - slot.relay_time.get(step, _time.monotonic())
        slot.received[step] = ("ok", commands, latency, hydro)
        self._maybe_finish_pending()
        return self._next_for(slot, route, msg_id, wait, own)

    def _hydro_state(self, slot: Slot, value: Any) -> dict[str, str] | None:
        """A command's optional ``hydro_state`` {body: state} (SPEC §5.7.4), checked against the
        controller's ``hydro_states`` bodies and their states; ProtocolError 5 naming ``hydro_state.<body>``."""
        if value is None:
            return None
        if not isinstance(value, dict):
            raise ProtocolError(Code.BAD_VALUE, "hydro_state", f"must be a map {{body: state}}, got "
                                f"{codec.describe(value)}")
        allowed = {b.name: b.state_names() for b in self.scene.bodies if b.name in slot.cfg.hydro_states}
        for body, state in value.items():
            if body not in allowed:
                raise ProtocolError(Code.BAD_VALUE, f"hydro_state.{body}", f"controller {slot.cfg.name!r} may "
                                    f"command the hydro state of {sorted(allowed)} only (controllers[i].hydro_states)")
            if state not in allowed[body]:
                raise ProtocolError(Code.BAD_VALUE, f"hydro_state.{body}", f"body {body!r} has no state "
                                    f"{codec.describe(state)} (its states: {allowed[body]})")
        return {str(b): str(v) for b, v in value.items()} or None

    def hydro_command(self, seq: int) -> dict[str, str] | None:
        """The hydro states commanded by the decisions taken at step seq − 1 (they act from step seq)."""
        if self.last_control is None or self.last_control[0] != seq - 1:
            return None
        out: dict[str, str] = {}
        for d in self.last_control[1].values():
            out.update(d.get("hydro_state") or {})
        return out or None

    def _validate(self, slot: Slot, commands: Any) -> dict:
        c = slot.cfg
        if not isinstance(commands, dict):
            raise ProtocolError(Code.BAD_VALUE if commands is not None else Code.MISSING_FIELD, "commands",
                                f"must be a map {{pto name: {{setpoint: value}}}}, got {type(commands).__name__}")
        for name in commands:
            if name not in c.ptos:
                raise ProtocolError(Code.BAD_VALUE, f"commands.{name}", f"controller {c.name!r} drives no PTO "
                                    f"{name!r} (it drives {list(c.ptos)})")
        keys = setpoints(c)
        out = {}
        for name in c.ptos:
            if name not in commands:
                raise ProtocolError(Code.MISSING_FIELD, f"commands.{name}", f"no command for PTO {name!r}")
            entry = commands[name]
            if not isinstance(entry, dict):
                raise ProtocolError(Code.BAD_VALUE, f"commands.{name}",
                                    f"must be a map with {' and/or '.join(map(repr, keys))}, got {codec.describe(entry)}")
            for key in entry:
                if key not in keys:
                    raise ProtocolError(Code.BAD_VALUE, f"commands.{name}.{key}", f"not a {c.command} setpoint "
                                        f"(expected {list(keys)})")
            if not entry or (c.command == "force" and "force" not in entry):
                raise ProtocolError(Code.MISSING_FIELD, f"commands.{name}", f"needs {' and/or '.join(keys)}")
            vals = {}
            for key, value in entry.items():
                if type(value) not in (int, float):
                    raise ProtocolError(Code.BAD_VALUE, f"commands.{name}.{key}",
                                        f"must be a number, got {type(value).__name__}")
                vals[key] = self._setpoint(c, name, key, float(value))
            out[name] = vals
        return out

    @staticmethod
    def _setpoint(c: Controller, name: str, key: str, value: float) -> float:
        """``value``, a setpoint ``key`` of PTO ``name``, checked: finite and within ``c``'s limits
        (ProtocolError 5 naming ``commands.<name>.<key>``)."""
        if not math.isfinite(value):
            raise ProtocolError(Code.BAD_VALUE, f"commands.{name}.{key}", f"must be finite, got {value}")
        if key == "force":
            if c.max_force is not None and abs(value) > c.max_force:
                raise ProtocolError(Code.BAD_VALUE, f"commands.{name}.{key}",
                                    f"|{value:g}| exceeds max_force {c.max_force:g}")
        else:
            lo, hi = c.damping_range if key == "damping" else c.stiffness_range
            if not lo <= value <= hi:
                raise ProtocolError(Code.BAD_VALUE, f"commands.{name}.{key}",
                                    f"{value:g} outside the {key}_range [{lo:g}, {hi:g}]")
        return value

    def _next_for(self, slot: Slot, route, msg_id, wait: float, own: str) -> tuple[str, dict] | None:
        if slot.newest > slot.delivered:
            return self._deliver(slot)
        if self.ended is not None:
            return "stop", {"reason": self.ended}
        if slot.parked is not None:   # an older request of the same controller: do not leave it hanging
            self.send(slot.parked[0], "idle", slot.parked[1], {}, slot.parked[3])
        slot.parked = (route, msg_id, _time.monotonic() + wait, own)
        return None

    def _deliver(self, slot: Slot) -> tuple[str, dict]:
        slot.delivered = slot.newest
        return "measurements", slot.sample

    def undelivered(self, name: str, step: int) -> None:
        """The measurements of ``step`` sent to controller ``name`` did not leave (its direct
        channel was gone, SPEC §5.7.5): its next request gets them again while their decision is open."""
        slot = self.slots.get(name)
        if slot is not None and slot.delivered == step and step > slot.decided:
            slot.delivered = step - 1

    # ------------------------------------------------------------ multibody side

    def holds(self, mtype: str, msg: dict, route: list[bytes]) -> bool:
        """Whether a request waits for the deferred step (then kept in :attr:`held`): the later
        requests of the same client (its routing frames) and any step, bye, save, restore or
        release of the session. A retry of the deferred step itself (a client on a new
        connection) is not held: it takes over the deferred reply (:meth:`after_step`)."""
        p = self.pending
        if p is None:
            return False
        if mtype == "step" and type(msg.get("seq")) is int and msg["seq"] == p["seq"] \
                and msg.get("iteration", 0) == 0:
            return False
        if route != p["route"] and mtype not in SEQUENCED:
            return False
        self.held.append((msg, route))
        return True

    def step_request(self, msg: dict, seq: int, iteration: int, new: bool) -> dict | None:
        """Parse (and check) a step's ``measurements`` before the step is computed; None if absent."""
        if not new or iteration > 0 or not self.measured_at(seq):
            return None
        k = seq - 1
        raw = msg.get("measurements")
        if raw is None:
            raise ProtocolError(Code.MISSING_FIELD, "measurements", f"step {seq} must carry the measurements of "
                                f"step {k} (a control step of this session's controllers)")
        if not isinstance(raw, dict):
            raise ProtocolError(Code.BAD_VALUE, "measurements", f"must be a map, got {type(raw).__name__}")
        got = codec.require_int(raw, "step", path="measurements.step")
        if got != k:
            raise ProtocolError(Code.BAD_VALUE, "measurements.step", f"must be {k} (seq - 1), got {got}")
        out = {"step": k}
        for name, shape in self.mb_shapes:
            out[name] = codec.require_array(raw, name, shape, path=f"measurements.{name}")
        return out

    def own_measurements(self, seq: int, raw: Any) -> dict:
        """The measurements of a new step ``seq`` (iteration 0, :meth:`measured_at`) made by this
        process's own run (server/service/controlled_step.py): :meth:`step_request`'s result, with
        only what its maker cannot vouch for checked — the step, each array's type, dtype and
        shape, every value finite (one sum over their few values); anything else gets
        step_request's own error."""
        k = seq - 1
        if type(raw) is dict and type(raw.get("step")) is int and raw["step"] == k:
            out: dict[str, Any] = {"step": k}
            total = 0.0
            for name, shape in self.mb_shapes:
                v = raw.get(name)
                if type(v) is not np.ndarray or v.dtype is not _F8 or v.shape != shape:
                    break
                out[name] = v
                total += sum(v.ravel().tolist())   # (a few values: cheaper than a numpy reduction)
            else:
                if math.isfinite(total):   # every value finite (else step_request says which one)
                    return out
        return self.step_request({} if raw is None else {"measurements": raw}, seq, 0, True)

    def measured_at(self, seq: int) -> bool:
        """Whether a new step ``seq`` carries measurements: step seq − 1 is a control step of a
        controller of this session."""
        k = seq - 1
        return k >= 0 and any(k % s.period == 0 for s in self.slots.values())

    def previews_due(self, meas: dict | None) -> dict[str, PreviewGrid]:
        """The wave probes the measurements ``meas`` (of :meth:`step_request`) are relayed with: of
        the controllers whose control step it is, that joined (a controller that never joined costs
        no wave evaluation) and measure waves. Computed where the session's model steps
        (Session.previews), handed back to :meth:`after_step`."""
        if meas is None:
            return {}
        k = meas["step"]
        return {s.name: s.grid for s in self.slots.values()
                if k % s.period == 0 and s.counts["joins"] > 0
                and ("wave_elevation" in s.cfg.measurements or s.grid.samples > 0)}

    def relay(self, meas: dict, waves: dict[str, np.ndarray]) -> None:
        """Relay the measurements ``meas`` (of :meth:`step_request`, with ``waves``, the elevations
        of :meth:`previews_due`) before the step is computed: a controller waiting for them gets
        them at once, its deadline counted from now; :meth:`after_step` then gets ``meas=None``."""
        self._relay(meas, _time.monotonic(), waves)

    def relay_with(self, meas: dict, previews: Callable[[dict[str, PreviewGrid], int], dict[str, np.ndarray]]) -> None:
        """:meth:`relay` the measurements ``meas`` with the wave probes due with them
        (:meth:`previews_due`), evaluated by ``previews`` (the session's ``Session.previews``:
        grids, step → elevations), where the model steps."""
        self.relay(meas, previews(self.previews_due(meas), meas["step"]))

    def after_step(self, seq: int, iteration: int, new: bool, meas: dict | None, fields: dict,
                   route, msg_id, waves: dict[str, np.ndarray] | None = None) -> dict | None:
        """Relay measurements (with ``waves``, the elevations of :meth:`previews_due`; None when
        :meth:`relay` sent them before the step), take the decisions due at ``seq``; the reply
        fields, or None (deferred)."""
        now = _time.monotonic()
        if not new or iteration > 0:
            if self.last_control and self.last_control[0] == seq:
                fields["control"] = self.last_control[1]
            if self.pending is not None and self.pending["seq"] == seq:   # a retry of the deferred step
                self.pending.update(route=route, msg_id=msg_id)
                return None
            return fields
        if meas is not None:
            self._relay(meas, now, waves or {})
        due = [s for s in self.slots.values()
               if seq - s.latency >= 0 and (seq - s.latency) % s.period == 0]
        self.pending = {"seq": seq, "fields": fields, "route": route, "msg_id": msg_id,
                        "due": due, "decisions": {}}
        if seq == 0 and any(s.state == "waiting" for s in self.slots.values()):
            self.pending["join"] = now + max(s.cfg.join_timeout for s in self.slots.values() if s.state == "waiting")
        for s in due:
            k = seq - s.latency
            if s.state in ("absent", "waiting") and k not in s.received:
                self._decide(s, k, "absent")
        return self._maybe_finish_pending(send=False)

    def _relay(self, meas: dict, now: float, waves: dict[str, np.ndarray]) -> None:
        k = meas["step"]
        t = k * self.dt
        for s in self.slots.values():
            if k % s.period:
                continue
            sample = {"step": k, "time": t, "seq": k // s.period}
            for name in s.cfg.measurements:
                if name == "wave_elevation":
                    continue
                v = meas[name]
                sample[name] = np.ascontiguousarray(v[s.pto_rows] if name.startswith("pto") else v[s.body_rows])
            eta = waves.get(s.name)
            if eta is not None:
                if "wave_elevation" in s.cfg.measurements:
                    sample["wave_elevation"] = np.ascontiguousarray(eta[:, 0])
                if eta.shape[1] > 1:
                    sample["wave_preview"] = np.ascontiguousarray(eta[:, 1:])
            s.sample, s.newest = sample, k
            s.sample_whole = eta is not None or not ("wave_elevation" in s.cfg.measurements or s.grid.samples > 0)
            s.relay_time[k] = now
            if s.parked is not None and s.state == "active":
                route, msg_id, _, own = s.parked
                s.parked = None
                mtype, fields = self._deliver(s)
                self.send(route, mtype, msg_id, fields, own)

    def _decide(self, s: Slot, k: int, status: str) -> None:
        p = self.pending
        if p is None or k <= s.decided:
            return
        s.decided = k
        s.counts[status] += 1
        d = {"step": k, "status": status, "commands": None, "latency": None,
             "fallback": None if status == "ok" else s.cfg.fallback}
        if status == "ok":
            _, d["commands"], d["latency"], hydro = s.received[k]
            if hydro:
                d["hydro_state"] = hydro
        elif status != "absent":
            log.warning("session %s: controller %r %s at step %d: fallback %r", self.session_id, s.name,
                        status, k, s.cfg.fallback)
        p["decisions"][s.name] = d

    def _maybe_finish_pending(self, send: bool = True, now: float | None = None) -> dict | None:
        """Take every decision that can be taken; when all are in, the reply (sent, or returned)."""
        p = self.pending
        if p is None:
            return None
        now = _time.monotonic() if now is None else now
        if "join" in p:
            if any(s.state == "waiting" for s in self.slots.values()) and now < p["join"]:
                return None
            for i, s in enumerate(self.slots.values()):
                if s.state == "waiting":
                    s.state = "absent"
                    log.warning("session %s: controller %r did not join within its join_timeout (%g s, the scene's "
                                "controllers[%d].join_timeout; a longer one waits longer at t = 0): it starts absent, "
                                "its fallback %r deciding until it joins", self.session_id, s.name,
                                s.cfg.join_timeout, i, s.cfg.fallback)
            del p["join"]
        seq = p["seq"]
        waiting = False
        for s in p["due"]:
            k = seq - s.latency
            if s.name in p["decisions"]:
                continue
            got = s.received.get(k)
            if got is not None:
                self._decide(s, k, "ok" if got[0] == "ok" else "invalid")
            elif s.state != "active":
                self._decide(s, k, "absent")
            elif now >= s.relay_time.get(k, now) + s.cfg.timeout:
                self._decide(s, k, "timeout")
                if s.parked is None:   # a controller waiting for measurements is alive: not absent
                    s.state = "absent"
            else:
                waiting = True
        if waiting:
            return None
        self.pending = None
        fields = p["fields"]
        if p["decisions"]:
            fields["control"] = p["decisions"]
            self.last_control = (seq, p["decisions"])
        for s in p["due"]:   # keep only what a later decision can still refer to
            s.received = {k: v for k, v in s.received.items() if k > seq - s.latency}
            s.relay_time = {k: v for k, v in s.relay_time.items() if k > seq - s.latency}
        if send:
            self.send(p["route"], "forces", p["msg_id"], fields)
            return None
        return fields

    # ------------------------------------------------------------ time

    def next_deadline(self) -> float:
        t = math.inf
        p = self.pending
        if p is not None:
            if "join" in p:
                t = p["join"]
            for s in p["due"]:
                k = p["seq"] - s.latency
                if s.name not in p["decisions"] and s.state == "active":
                    t = min(t, s.relay_time.get(k, 0.0) + s.cfg.timeout)
        for s in self.slots.values():
            if s.parked is not None:
                t = min(t, s.parked[2])
        return t

    def poll(self, now: float) -> None:
        """Send what is due at ``now``: idle replies, timed-out step replies."""
        for s in self.slots.values():
            if s.parked is not None and now >= s.parked[2]:
                route, msg_id, _, own = s.parked
                s.parked = None
                self.send(route, "idle", msg_id, {}, own)
        self._maybe_finish_pending(now=now)

    def end(self, reason: str) -> None:
        """The session is closing: parked controller requests get ``stop``; a deferred step's reply
        is dropped (its client is gone: the session closed by expiry or server shutdown)."""
        self.ended = reason
        self.pending = None
        for s in self.slots.values():
            if s.parked is not None:
                route, msg_id, _, own = s.parked
                s.parked = None
                self.send(route, "stop", msg_id, {"reason": reason}, own)

    def summary(self) -> dict:
        return {name: dict(s.counts) for name, s in self.slots.items()}
