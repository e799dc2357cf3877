"""The model class of an exported hydrolink FMU (copied into the FMU by ``hydrolink fmu export``).

FMI 2.0 co-simulation (pythonfmu). Per active DOF of each wet body ("sphere.heave"):

- inputs ``<body>.<dof>.displacement`` (from equilibrium, m or rad) and ``<body>.<dof>.velocity``;
- outputs ``<body>.<dof>.force`` (excitation + radiation memory + hydrostatic + net buoyancy) and
  its parts ``.excitation``, ``.radiation``, ``.hydrostatic``; ``wave_elevation``;
- constant outputs ``A_inf.<body>.<dof>.<body>.<dof>``: the infinite-frequency added mass, which
  the importer MUST add to its mass matrix (the force excludes −A∞·a);
- parameters ``server_address`` ("" = an embedded server in this process), ``timeout`` (s) and
  ``key_file`` (the shared HMAC key file of a signing server, SPEC §3.3; "" = none).

Outputs are the forces at the current communication point for the inputs set at that point
(direct feedthrough): set the state at t, read F(t). Setting the inputs again at the same point
(an iterating master) replaces the server's sample (SPEC §5.3 rule 2). The communication step
must equal the scene's dt (another is an error status, logged as an error). No rollback (the server keeps one sample per step).
The server's setup warnings (its HDB readers' among them, SPEC §5.1) are logged at the end of
initialisation with status warning, and written to stderr.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
from pythonfmu import Fmi2Causality, Fmi2Initial, Fmi2Slave, Fmi2Variability, Real, String
from pythonfmu.enums import Fmi2Status

CONFIG = "hydrolink_fmu.json"


class HydrolinkForces(Fmi2Slave):
    author = "hydrolink"
    description = "hydrolink linear potential-flow forces (excitation, radiation, hydrostatics) over ZeroMQ"

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        res = Path(self.resources)
        cfg = json.loads((res / CONFIG).read_text())
        self.modelName = cfg.get("model_name", "hydrolink_forces")
        self._cfg, self._res = cfg, res
        self._labels: list[str] = cfg["labels"]                    # "body.dof" per active DOF
        self._flat = np.asarray(cfg["flat"], int)                  # their indices in 6N
        self._n, self._dt = int(cfg["n_bodies"]), float(cfg["dt"])
        self._eq = np.asarray(cfg["equilibrium"], float).reshape(-1)
        self._net = np.asarray(cfg["net_buoyancy"], float)
        na = len(self._labels)
        self._x, self._v = np.zeros(na), np.zeros(na)
        self._out = {k: np.zeros(na) for k in ("force", "excitation", "radiation", "hydrostatic")}
        self._eta = 0.0
        self._seq, self._iteration, self._sent = 0, -1, None       # sample of the current step
        self._conn = self._server = None
        self.server_address, self.timeout, self.key_file = "", 30.0, ""
        self.register_variable(String("server_address", causality=Fmi2Causality.parameter,
                                      variability=Fmi2Variability.fixed))
        self.register_variable(String("key_file", causality=Fmi2Causality.parameter,
                                      variability=Fmi2Variability.fixed))
        self.register_variable(Real("timeout", causality=Fmi2Causality.parameter,
                                    variability=Fmi2Variability.fixed))
        a_inf = np.asarray(cfg["added_mass"], float)      # for the importer's mass matrix (SPEC §5.1)
        for i, a in enumerate(self._labels):
            for j, b in enumerate(self._labels):
                self.register_variable(Real(f"A_inf.{a}.{b}", causality=Fmi2Causality.output,
                                            variability=Fmi2Variability.constant, initial=Fmi2Initial.exact,
                                            getter=lambda v=float(a_inf[i, j]): v))
        for i, label in enumerate(self._labels):
            for arr, what in ((self._x, "displacement"), (self._v, "velocity")):
                self.register_variable(Real(f"{label}.{what}", causality=Fmi2Causality.input,
                                            getter=lambda a=arr, i=i: float(a[i]),
                                            setter=lambda value, a=arr, i=i: a.__setitem__(i, value)))
            for key in self._out:
                self.register_variable(Real(f"{label}.{key}", causality=Fmi2Causality.output,
                                            initial=Fmi2Initial.exact,
                                            getter=lambda k=key, i=i: self._output(k, i)))
        self.register_variable(Real("wave_elevation", causality=Fmi2Causality.output, initial=Fmi2Initial.exact,
                                    getter=lambda: self._output("eta", 0)))

    # -- the server ---------------------------------------------------------------------------
    def exit_initialization_mode(self):
        from hydrolink.clients.lockstep.connection import ServerConnection
        from hydrolink.protocol.reply import OPTIONAL_FORCES
        self._optional = OPTIONAL_FORCES
        from hydrolink.server.hdb.io import load_hdb

        address = self.server_address
        if not address:           # embedded: the server's request handler in this process
            from hydrolink.server.service.force_server import ForceServer
            self._server = address = ForceServer(None)
        key = None
        if self.key_file:         # a signing server (SPEC §3.3): the shared key file on this machine
            from hydrolink.protocol.security import read_hmac_key
            key = read_hmac_key(self.key_file)
        self._conn = ServerConnection(address, timeout=float(self.timeout), client_name="hydrolink-fmu", key=key)
        hdbs = {key: load_hdb(self._res / name) for key, name in self._cfg["hdbs"].items()}
        setup = self._conn.hello(self._cfg["scene"], hdbs)
        for note in setup.warnings:   # SPEC §5.1: shown to the user before the run (and on stderr:
            self.log(f"hydrolink: {note}", Fmi2Status.warning)   # pythonfmu's logger may be off)
            print(f"hydrolink FMU: warning: {note}", file=sys.stderr, flush=True)
        if abs(setup.dt - self._dt) > 1e-12 * self._dt:
            raise RuntimeError(f"the server's dt {setup.dt} differs from the exported {self._dt}")

    def _evaluate(self) -> None:
        """Make sure the server has this step's sample for the current inputs."""
        state = np.concatenate([self._x, self._v])
        if self._sent is not None and np.array_equal(state, self._sent):
            return
        pos, vel = self._eq.copy(), np.zeros(6 * self._n)
        pos[self._flat] += self._x
        vel[self._flat] = self._v
        self._iteration += 1
        reply = self._conn.step(self._seq, self._seq * self._dt, pos.reshape(self._n, 6),
                                vel.reshape(self._n, 6), iteration=self._iteration)
        for key in ("excitation", "radiation", "hydrostatic"):
            self._out[key][:] = np.asarray(reply[key], float).reshape(-1)[self._flat]
        self._out["hydrostatic"] += self._net
        self._out["force"][:] = self._out["excitation"] + self._out["radiation"] + self._out["hydrostatic"]
        for key in self._optional:           # scenes with those terms: part of the total force
            if reply.get(key) is not None:
                self._out["force"] += np.asarray(reply[key], float).reshape(-1)[self._flat]
        self._eta = float(np.asarray(reply["wave_elevation"], float).reshape(-1)[0])
        self._sent = state

    def _output(self, key: str, i: int) -> float:
        if self._conn is None:          # before initialisation (start values): zero
            return 0.0
        self._evaluate()
        return self._eta if key == "eta" else float(self._out[key][i])

    def do_step(self, current_time: float, step_size: float) -> bool:
        if abs(step_size - self._dt) > 1e-9 * self._dt:
            # raised: pythonfmu answers an exception with a status the master must see (Fatal);
            # returning False would answer Discard, which fmpy takes for a normal end at t = 0.
            # pythonfmu passes log messages on only with debug logging: the text also goes to stderr
            message = f"hydrolink FMU: communication step {step_size} s must equal the scene's dt {self._dt} s"
            self.log(message, Fmi2Status.error)
            print(message, file=sys.stderr, flush=True)
            raise ValueError(message)
        self._evaluate()                # every step gets its sample, even if no output was read
        self._seq += 1
        self._iteration, self._sent = -1, None
        return True

    def terminate(self):
        if self._conn is not None:
            try:
                self._conn.bye()
            except Exception:  # noqa: BLE001 - a server already gone: its session is gone too
                pass
            self._conn.close()
            self._conn = None
        if self._server is not None:
            self._server.close()
            self._server = None
