"""What a run reports: the typed summary of a lockstep run (``hydrolink run`` prints it; sweeps,
benches and scripts read it).

The lockstep driver (:func:`hydrolink.clients.lockstep.driver.run`) returns a :class:`RunSummary`
with the loop's counts and costs; each adapter adds what only it knows (MoorDyn reports, the
mechanism's notes, the FMU's version and costs) and ``hydrolink run`` adds the server's side
(:func:`hydrolink.clients.run.run_scene_file`), each with :func:`dataclasses.replace`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Protocol, Sequence

import numpy as np

from hydrolink.protocol.pacing import RealtimeReport


class LimitMetrics(Protocol):
    """What a summary shows of a run's limits (clients/analysis/optimal/metrics.py RunMetrics)."""
    mean_power: float
    peak_to_average: float
    limits: Sequence


@dataclass(frozen=True)
class CouplingReport:
    """How the run was coupled (scene ``[coupling]``) and what it cost in iterations."""
    scheme: str                   # "mass-matrix" | "implicit" | "explicit-predictor" | "explicit"
    added_mass_ratio: float       # largest A∞/m the coupling feeds back (0 for "mass-matrix")
    exchange_every: int = 1       # client steps per server exchange
    between_exchanges: str = "hold"   # forces between exchanges (Exudyn client)
    reason: str = ""              # why this scheme (FMU master: what the FMU takes as parameters)
    iterations_mean: float = 1.0  # server samples per exchange
    iterations_max: int = 1
    initial_iterations: int = 0   # iterations of the consistent start (feedback schemes)
    iterations: np.ndarray | None = None   # (n_exchanges,) per exchange, "implicit" only


@dataclass(frozen=True)
class RunSummary:
    """One run's outcome and costs. Times in s, costs in µs per (client) step."""
    steps: int                    # client steps taken
    time: float                   # simulated time reached
    wall_time: float
    rows: int                     # rows in the results file
    status: str                   # "complete" (a run that stops raises instead)
    coupling: CouplingReport
    client_us_per_step: float     # the client's own work (everything but the server round trips)
    round_trip_us_per_step: float
    warnings: list[str] = field(default_factory=list)   # what hydrolink cannot vouch for, naming keys
    client: str = "exudyn"        # "exudyn" | "fmu"
    mechanism_notes: list[str] = field(default_factory=list)   # Exudyn: the mechanism's notes and reductions
    controllers: dict | None = None       # external controllers' events (SPEC §5.7)
    moordyn: list[dict] | None = None     # per MoorDyn system: file, lines, substeps
    fmi_version: str | None = None        # FMU master
    fmu_us_per_step: float | None = None
    recorded: dict[str, np.ndarray] = field(default_factory=dict)   # FMU outputs asked for by name
    output: str | None = None             # the results file
    server: str | None = None             # the force server's address (None: no server was needed)
    metrics: LimitMetrics | None = None                   # WECCCOMP metrics of a scene with limits (clients/analysis/optimal/metrics.py)
    hdb_uploads: int = 0                  # HDB contents the server lacked (--hdb-files)
    server_compute_us_per_step: float | None = None
    radiation: str | None = None          # setup's radiation option and its pruning
    radiation_pairs: int | None = None
    dropped_pair_fraction: float | None = None
    dropped_block_fraction: float | None = None
    state_space_fitted_pairs: int | None = None   # fitted in this setup (the rest from the fit cache)
    realtime: RealtimeReport | None = None   # --realtime: overruns and step latencies (None: not paced)
