"""The multibody side of external controllers (SPEC §5.7): measurements out, decisions in.

Every control step k (a multiple of a controller's period) the Exudyn client sends the
measurements of the state at t_k with its next ``step`` request; a reply may carry the server's
``control`` decisions, applied before the integration step they are due for:

- ``force`` command F: the linear PTO's connector gets the added tension F (its ``force``
  parameter), its scene stiffness and damping;
- ``impedance`` command: the connector's ``damping``/``stiffness`` parameters (an omitted one keeps
  its value), added force 0;
- fallback ``hold``: nothing changes (the last command stays in force); ``passive``: added force 0,
  damping ``fallback_damping``, scene stiffness.

Results (dims ``pto`` and ``controller``): ``pto_command_force``, ``pto_damping``,
``pto_stiffness`` — what was in force over the step ending at the row (NaN for PTOs no controller
drives); ``controller_status`` — the decision taken for the step ending at the row (0 ok,
1 timeout, 2 absent, 3 invalid; NaN: no decision due); ``controller_fallbacks`` — cumulative count
of fallback decisions; ``controller_latency`` — s from relay to command (NaN if none). The global
attribute ``controller_events`` sums them up per controller.
"""

from __future__ import annotations

import json
import logging

import numpy as np

from hydrolink.clients.exudyn.ptos import PTOSample, PTOSet
from hydrolink.protocol.scene import LinearPTO, Scene

log = logging.getLogger(__name__)

STATUS_CODES = {"ok": 0, "timeout": 1, "absent": 2, "invalid": 3}


class PTOControl:
    """Measurements, decisions and their results for one run."""

    def __init__(self, scene: Scene, ptos: PTOSet, mbs, writer, modal_ptos: int = 0):
        """``modal_ptos``: the PTOs on modes after ``ptos`` in the results' ``pto`` dim (no control)."""
        self.scene, self.ptos, self.mbs, self.writer = scene, ptos, mbs, writer
        dt = scene.simulation.dt
        self.linear = [p for p in scene.ptos if isinstance(p, LinearPTO)]
        self.lin_index = {p.name: i for i, p in enumerate(self.linear)}
        self.entry = {p.name: ptos.linear[i].entry for i, p in enumerate(self.linear)}
        self.periods = [c.steps_per_period(dt) for c in scene.controllers]
        self.join_timeout = max(c.join_timeout for c in scene.controllers)
        self.by_name = {c.name: c for c in scene.controllers}
        n = len(ptos.names) + modal_ptos
        self.force = np.full(n, np.nan)
        self.damping = np.full(n, np.nan)
        self.stiffness = np.full(n, np.nan)
        for c in scene.controllers:
            for name in c.ptos:
                p = self.linear[self.lin_index[name]]
                e = self.entry[name]
                self.force[e], self.damping[e], self.stiffness[e] = 0.0, float(p.damping), float(p.stiffness)
        m = len(scene.controllers)
        self.names = [c.name for c in scene.controllers]
        self.status = np.full(m, np.nan)
        self.latency = np.full(m, np.nan)
        self.fallbacks = np.zeros(m)
        self.events = {c.name: {"ok": 0, "timeout": 0, "absent": 0, "invalid": 0, "latency_sum": 0.0,
                                "latency_max": 0.0} for c in scene.controllers}
        coords = {"pto": list(ptos.names), "controller": self.names}
        writer.add_variable("pto_command_force", ("pto",), coords, "N",
                            "controller-commanded tension added to the PTO, in force over the step ending here")
        writer.add_variable("pto_damping", ("pto",), coords, "N s/m", "controlled PTO damping in force")
        writer.add_variable("pto_stiffness", ("pto",), coords, "N/m", "controlled PTO stiffness in force")
        writer.add_variable("controller_status", ("controller",), coords, "1",
                            "decision for the step ending here: 0 ok, 1 timeout, 2 absent, 3 invalid; NaN none due")
        writer.add_variable("controller_fallbacks", ("controller",), coords, "1",
                            "cumulative number of fallback decisions (timeout, absent, invalid)")
        writer.add_variable("controller_latency", ("controller",), coords, "s",
                            "wall time from relaying the measurements to receiving the command")
        # the compiled exchange's linear PTO table (clients/exudyn/compiled_exchange.py, PTOSet.linear_table:
        # a row per linear PTO, its stiffness, damping and added force in columns 1-3), kept as the commands change
        self.table: np.ndarray | None = None
        # what stage() hands the writer each row: the arrays above, changed in place (made once)
        self._row = {"pto_command_force": self.force, "pto_damping": self.damping, "pto_stiffness": self.stiffness,
                     "controller_status": self.status, "controller_fallbacks": self.fallbacks,
                     "controller_latency": self.latency}

    def is_sample(self, k: int) -> bool:
        return any(k % p == 0 for p in self.periods)

    def measurements(self, k: int, q_bodies: np.ndarray, v_bodies: np.ndarray, sample: PTOSample) -> dict:
        """The ``measurements`` map of step k (SPEC §5.7.3): every linear PTO, every body."""
        rows = [self.entry[p.name] for p in self.linear]
        return {"step": int(k), "pto_displacement": np.ascontiguousarray(sample.extension),
                "pto_velocity": np.ascontiguousarray(sample.velocity[rows]),
                "pto_force": np.ascontiguousarray(sample.force[rows]),
                "body_position": np.ascontiguousarray(q_bodies), "body_velocity": np.ascontiguousarray(v_bodies)}

    def apply(self, decisions: dict | None) -> None:
        """Apply the server's decisions due at this step (before the integration step)."""
        self.status.fill(np.nan)
        self.latency.fill(np.nan)
        if not decisions:
            return
        for j, name in enumerate(self.names):
            d = decisions.get(name)
            if d is None:
                continue
            c = self.by_name[name]
            status = d.get("status", "invalid")
            ev = self.events[name]
            ev[status] = ev.get(status, 0) + 1
            self.status[j] = STATUS_CODES.get(status, 3)
            commands = d.get("commands")
            if status == "ok" and commands is not None:
                lat = float(d.get("latency") or 0.0)
                self.latency[j] = lat
                ev["latency_sum"] += lat
                ev["latency_max"] = max(ev["latency_max"], lat)
                for pto, cmd in commands.items():
                    self._set(pto, c.command, cmd)
            else:
                self.fallbacks[j] += 1
                if c.fallback == "passive":
                    for i, pto in enumerate(c.ptos):
                        p = self.linear[self.lin_index[pto]]
                        fb = c.fallback_damping if c.fallback_damping is not None else p.damping
                        self._put(pto, force=0.0, damping=float(fb), stiffness=float(p.stiffness))

    def _set(self, pto: str, kind: str, cmd: dict) -> None:
        p = self.linear[self.lin_index[pto]]
        if kind == "force":
            self._put(pto, force=float(cmd["force"]), damping=float(p.damping), stiffness=float(p.stiffness))
        else:
            self._put(pto, force=0.0, damping=cmd.get("damping"), stiffness=cmd.get("stiffness"))

    def _put(self, pto: str, *, force=None, damping=None, stiffness=None) -> None:
        i = self.lin_index[pto]
        self.ptos.set_linear(self.mbs, i, force=force, damping=damping, stiffness=stiffness)
        e, table = self.entry[pto], self.table
        for column, values, value in ((1, self.stiffness, stiffness), (2, self.damping, damping), (3, self.force, force)):
            if value is not None:
                values[e] = value
                if table is not None:   # (as set_linear keeps the PTO's current value)
                    table[i, column] = value

    def stage(self) -> None:
        self.writer.stage_extra(self._row)

    def summary(self) -> dict:
        out = {}
        for name, ev in self.events.items():
            ok = ev["ok"]
            out[name] = {k: ev[k] for k in ("ok", "timeout", "absent", "invalid")}
            out[name]["mean_latency_s"] = ev["latency_sum"] / ok if ok else None
            out[name]["max_latency_s"] = ev["latency_max"] if ok else None
        return out

    def finish(self) -> dict:
        s = self.summary()
        self.writer.set_attribute("controller_events", json.dumps(s))
        for i, (name, ev) in enumerate(s.items()):
            bad = ev["timeout"] + ev["absent"] + ev["invalid"]
            if bad:
                log.warning("controller %r: %d fallback decision(s) (timeout %d, absent %d, invalid %d)%s",
                            name, bad, ev["timeout"], ev["absent"], ev["invalid"], "" if ev["ok"] else
                            f": it decided no step. Did it join? The run waits for it at t = 0 for the scene's "
                            f"controllers[{i}].join_timeout; `hydrolink control --join-wait` must outlast the run's "
                            "set-up")
        return s
