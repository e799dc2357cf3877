"""Radiation options ([hydro] radiation): one builder per option, picked by :func:`radiation_option`.

Every option shares the IRF stage, per interaction group over its active DOFs: B(w) resampled
(hydro.irf_domega) and extended by an asymptotic tail (hydro.irf_tail), K(t) on the step grid over
irf_duration (over OGILVIE_DEFAULT_DURATION when irf_duration = 0: Ogilvie's A_inf needs an IRF),
the cosine taper (hydro.irf_taper), A_inf from the HDB or else by Ogilvie; and, when irf_duration >
0, how well K reproduces B(w) and A(w) and the aliasing check. The options differ in the force
object of each group (``push(v, replace_last) -> F``) and in the added mass the client puts in its
mass matrix:

  "convolution"  RadiationMemory of K(t) over the DOF pairs kept (hydro.coupling_tolerance)   A_inf
  "state-space"  StateSpaceRadiation fitted to the same IRF's transfer function, kept pairs   A_inf
  "constant"     ConstantDamping -B(w0) v at the regular-wave frequency w0                   A(w0)
  "off"          no radiation force                                                          A_inf
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import ClassVar, Protocol

import numpy as np

from hydrolink.protocol.scene import Hydro, Waves
from hydrolink.server.allocation import require_size
from hydrolink.server.errors import ModelError
from hydrolink.server.fused.step import FusedRadiation
from hydrolink.server.radiation.irf import (COS_TABLE_ROWS, added_mass_transform, aliasing_time, asymptotic_tail,
                                          irf_report, irf_samples, irf_transfer, ogilvie_added_mass_inf, ogilvie_report,
                                          radiation_irf, resample_damping, taper_window)
from hydrolink.server.radiation.memory_cut import (CUT_EFFECT_WARN, cut_effect, judged_frequencies, longer_memory,
                                                 natural_frequencies)
from hydrolink.server.radiation.convolution import RadiationMemory
from hydrolink.server.radiation.state_space import Realization, StateSpaceError, StateSpaceRadiation
from hydrolink.server.radiation.state_space_cache import FitCache, FitSettings, default_cache_dir

OGILVIE_DEFAULT_DURATION = 40.0  # s of IRF used for Ogilvie's A_inf when hydro.irf_duration = 0
SS_FIT_POINTS = 120              # frequencies on [0, w_max] the state-space fit is made (and checked) on
TAIL_CUTOFF_FACTOR = 10.0        # default hydro.irf_tail_cutoff: 10 w_max
ALIAS_REFUSE = 0.25              # refuse an IRF whose part past pi/d_omega exceeds this share of max |K|
MAX_IRF_PRODUCTS = 2.0e9         # IRF samples x frequencies of one transform: the set-up work one hello may
                                 # ask (three transforms; about 10 s of CPU at 8e8 on this project's machine)


class RadiationForce(Protocol):
    """What a group's radiation force object offers the step (RadiationMemory and the others)."""

    def push(self, v: np.ndarray, replace_last: bool = False) -> np.ndarray: ...

    def feedthrough(self) -> np.ndarray:
        """dF/dv (n, n) of the newest sample: how push()'s force moves with the velocity it is given."""
        ...

    def state(self) -> tuple:
        """What push() changes, copied (for a session rolled back, SPEC §5.9)."""
        ...

    def set_state(self, state: tuple) -> None:
        """Back to a :meth:`state`."""
        ...


class ConstantDamping:
    """radiation = "constant": F = -B(w0) v (the push() interface of RadiationMemory)."""

    def __init__(self, damping: np.ndarray):
        self.b = np.ascontiguousarray(damping, float)
        self.n = self.b.shape[0]

    def push(self, v: np.ndarray, replace_last: bool = False) -> np.ndarray:
        return -(self.b @ v)

    def feedthrough(self) -> np.ndarray:
        return -self.b.copy()

    def fused(self) -> FusedRadiation:
        """This force as the fused step takes it (server/fused/step.py): a one-sample convolution."""
        return FusedRadiation("dense", 1, k=-self.b)

    def realization(self) -> Realization:
        """F = -B(w0) v: no state, all feedthrough."""
        e = np.zeros(0, int)
        return Realization(np.zeros((0, 0)), np.zeros((0, self.n)), np.zeros((self.n, 0)), -self.b.copy(), e, e)

    def state(self) -> tuple:
        return ()

    def set_state(self, state: tuple) -> None:
        pass


@dataclass(frozen=True)
class RadiationGroup:
    """One interaction group's radiation data over its active DOFs, in the scene's density."""
    source: str                         # the HDB's source (key of the per-HDB reports)
    bodies: tuple[str, ...]             # the group's wet bodies
    act: np.ndarray                     # (n,) rows of the active DOFs in the 6N vectors
    pos: np.ndarray                     # (n,) their positions in the reduced (active) vectors
    labels: tuple[str, ...]             # "body.dof" of each active DOF (messages)
    omega: np.ndarray                   # (n_w,) the HDB's frequencies
    added_mass: np.ndarray              # (n_w, n, n)
    damping: np.ndarray                 # (n_w, n, n)
    added_mass_inf: np.ndarray | None   # (n, n) from the HDB; None: Ogilvie's from the IRF
    inertia: np.ndarray | None = None   # (n,) the scene's rigid-body mass diagonal about the reference point
    stiffness: np.ndarray | None = None  # (n,) the restoring stiffness diagonal (hydrostatics, gravity)


@dataclass(frozen=True)
class GroupIrf:
    """The IRF stage's result for one group."""
    omega: np.ndarray           # the grid K(t) is integrated over (resampled, tail appended)
    damping: np.ndarray         # B on that grid
    kernel: np.ndarray          # (M + 1, n, n) K(j dt), tapered
    added_mass_inf: np.ndarray  # (n, n)
    tail_exponent: float | None  # median fitted n of B ~ w^-n (hydro.irf_tail = "asymptotic")
    # int K sin(w t) dt over the HDB's own grid where Ogilvie's A_inf took it (its report reuses it), else None
    added_mass_transform: np.ndarray | None = None


@dataclass
class PairCount:
    """DOF pairs and body-pair blocks of the radiation memories, kept and in all (coupling pruning)."""
    kept: int = 0
    total: int = 0
    blocks_total: int = 0
    blocks_dropped: int = 0

    @property
    def dropped_pair_fraction(self) -> float:
        return (1.0 - self.kept / self.total) if self.total else 0.0

    @property
    def dropped_block_fraction(self) -> float:
        return (self.blocks_dropped / self.blocks_total) if self.blocks_total else 0.0


@dataclass
class StateSpaceStats:
    """Totals of the state-space fits over the groups (setup ``state_space``)."""
    states: int = 0
    pairs: int = 0
    fitted_pairs: int = 0           # distinct pair fits computed (0: all from the fit cache)
    max_order: int = 0
    max_fit_error: float = 0.0
    unmet: int = 0
    worst_pair: str | None = None   # "(row, col)" labels of the worst fit; None until a fit errs

    def as_dict(self) -> dict:
        out = {"states": self.states, "pairs": self.pairs, "fitted_pairs": self.fitted_pairs,
               "max_order": self.max_order,
               "max_fit_error": self.max_fit_error, "unmet": self.unmet}
        if self.worst_pair is not None:
            out["worst_pair"] = self.worst_pair
        return out


@dataclass
class _Log:
    """What the groups' builds add up to: pair counts, fit totals and warnings."""
    pairs: PairCount = field(default_factory=PairCount)
    fits: StateSpaceStats = field(default_factory=StateSpaceStats)
    warnings: list[str] = field(default_factory=list)


@dataclass(frozen=True)
class RadiationReport:
    """The setup fields the radiation option answers for (HydroModel.setup_info)."""
    radiation: str
    irf_samples: int
    irf_duration: float
    added_mass_inf_source: dict[str, str]     # body -> "hdb" | "ogilvie"
    irf_fit_error: dict[str, float]           # HDB source -> worst relative B(w) error of K
    irf_added_mass_error: dict[str, float]    # HDB source -> worst relative A(w) error of K (Ogilvie)
    irf_domega: float | None
    irf_taper: float
    irf_tail: str
    tail_exponent: dict[str, float]           # HDB source -> fitted tail exponent
    coupling_tolerance: float
    pairs: PairCount
    state_space: dict | None                  # StateSpaceStats.as_dict() for "state-space"
    radiation_frequency: float | None         # w0 for "constant"


@dataclass(frozen=True)
class Radiation:
    """What a radiation option builds: the force objects, the added-mass matrices and the report."""
    forces: list[tuple[np.ndarray, RadiationForce]]  # (positions in the reduced vectors, force) per group
    added_mass_inf: np.ndarray   # (6N, 6N)
    added_mass: np.ndarray       # (6N, 6N) what the client puts in its mass matrix
    report: RadiationReport
    warnings: list[str]


def interp_matrix(omega: np.ndarray, values: np.ndarray, w: float) -> np.ndarray:
    """Linear interpolation of (n_w, n, n) in omega at w."""
    i = int(np.clip(np.searchsorted(omega, w) - 1, 0, omega.size - 2))
    f = (w - omega[i]) / (omega[i + 1] - omega[i])
    return (1 - f) * values[i] + f * values[i + 1]


def prune_pairs(norms: np.ndarray, body_of: np.ndarray, tolerance: float) -> tuple[np.ndarray, np.ndarray]:
    """Which DOF pairs of one group's radiation memory to keep (hydro.coupling_tolerance).

    ``norms`` (n, n): N_ij = int_0^T |K_ij(t)| dt, the largest force per unit velocity amplitude
    the pair can give; ``body_of`` (n,) the (group) body of each DOF. A body-to-body block (a, b),
    a != b, is dropped when max_{i in a, j in b} N_ij < tol sqrt(d_a d_b), d_a = max_{i in a} N_ii;
    inside kept blocks a pair i != j is dropped when N_ij < tol sqrt(N_ii N_jj). Diagonal pairs
    are always kept. Returns (keep (n, n) bool, dropped_blocks (n_b, n_b) bool over the group's
    bodies present)."""
    n = norms.shape[0]
    bodies = np.unique(body_of)
    d = np.diag(norms)
    dmax = np.array([d[body_of == b].max() for b in bodies])
    keep = np.ones((n, n), bool)
    dropped = np.zeros((bodies.size, bodies.size), bool)
    if tolerance <= 0:
        return keep, dropped
    for ia, a in enumerate(bodies):
        for ib, b in enumerate(bodies):
            if a == b:
                continue
            ra, rb = body_of == a, body_of == b
            if norms[np.ix_(ra, rb)].max() < tolerance * np.sqrt(dmax[ia] * dmax[ib]):
                dropped[ia, ib] = True
                keep[np.ix_(ra, rb)] = False
    keep &= ~(norms < tolerance * np.sqrt(np.outer(d, d)))
    np.fill_diagonal(keep, True)
    return keep, dropped


class RadiationOption:
    """Base of the option builders: the IRF stage shared by all options and the loop over groups.

    A subclass gives one group's force object and, if it differs from A_inf, the client's added
    mass (:meth:`_force`); its constructor refuses scene settings the option cannot run."""
    name: ClassVar[str]
    radiation_frequency: float | None = None
    memory: ClassVar[bool] = False    # the force convolves (or fits) the kept K(t): its cut matters
    irf_settings: ClassVar[bool] = True   # hydro.irf_duration (taper, aliasing) apply: not for "constant"

    def __init__(self, hydro: Hydro, waves: Waves, dt: float):
        self.hydro, self.dt = hydro, float(dt)
        self.duration = float(hydro.irf_duration) if self.irf_settings else 0.0
        self.samples = irf_samples(self.duration, self.dt)
        self._key = "hydro.irf_duration" if self.samples > 0 else "simulation.dt"
        m = self.samples if self.samples > 0 else irf_samples(OGILVIE_DEFAULT_DURATION, self.dt)
        require_size(self._key, "the IRF's time grid", (m + 1,), hint=self._hint)
        self.t = np.arange(m + 1) * self.dt
        self.taper = float(hydro.irf_taper) if self.samples > 0 else 0.0
        self._window = taper_window(self.t, self.duration, self.taper)[:, None, None] if self.taper > 0 else None

    def build(self, groups: list[RadiationGroup], n: int, waves: np.ndarray | None = None) -> Radiation:
        """Force objects and added mass of every group (6N = ``n`` rows), with the report; ``waves``:
        the scene's wave frequencies [rad/s] the memory's cut is judged at (memory_cut.py)."""
        a_inf, a_client = np.zeros((n, n)), np.zeros((n, n))
        log = _Log()
        sources: dict[str, str] = {}
        fit_b: dict[str, float] = {}
        fit_a: dict[str, float] = {}
        tails: dict[str, float] = {}
        forces: list[tuple[np.ndarray, RadiationForce]] = []
        for g in groups:
            sources.update(dict.fromkeys(g.bodies, "ogilvie" if g.added_mass_inf is None else "hdb"))
            if not g.act.size:
                continue
            irf = self._irf(g)
            ix = np.ix_(g.act, g.act)
            a_inf[ix] = irf.added_mass_inf
            if irf.tail_exponent is not None:
                tails[g.source] = irf.tail_exponent
            force, a_own = self._force(g, irf, log)
            a_client[ix] = irf.added_mass_inf if a_own is None else a_own
            if force is not None:
                forces.append((g.pos, force))
            if self.samples > 0:
                fit_b[g.source] = max(irf_report(g.omega, g.damping, self.t, irf.kernel)["worst"],
                                      fit_b.get(g.source, 0.0))
                fit_a[g.source] = max(ogilvie_report(g.omega, g.added_mass, irf.added_mass_inf, self.t, irf.kernel,
                                                     irf.added_mass_transform)["worst"], fit_a.get(g.source, 0.0))
                self._check_aliasing(irf, g.source, log.warnings)
                self._check_cut(irf, g, np.zeros(0) if waves is None else np.asarray(waves, float), log.warnings)
        hyd = self.hydro
        report = RadiationReport(
            radiation=self.name, irf_samples=self.samples, irf_duration=self.samples * self.dt,
            added_mass_inf_source=sources, irf_fit_error=fit_b, irf_added_mass_error=fit_a,
            irf_domega=hyd.irf_domega, irf_taper=hyd.irf_taper, irf_tail=hyd.irf_tail, tail_exponent=tails,
            coupling_tolerance=float(hyd.coupling_tolerance), pairs=log.pairs,
            state_space=self._fit_report(log.fits), radiation_frequency=self.radiation_frequency)
        return Radiation(forces, a_inf, a_client, report, log.warnings)

    def _force(self, g: RadiationGroup, irf: GroupIrf, log: _Log) -> tuple[RadiationForce | None, np.ndarray | None]:
        """One group's force object (None: no force) and the client's added mass (None: A_inf)."""
        raise NotImplementedError

    def _fit_report(self, fits: StateSpaceStats) -> dict | None:
        """Setup ``state_space``: None except for "state-space"."""
        return None

    @property
    def _hint(self) -> str:
        return (f"at dt = {self.dt:g} s the IRF has one sample per step: a shorter hydro.irf_duration "
                f"({self.duration:g} s) or a longer dt")

    def irf(self, g: RadiationGroup) -> GroupIrf:
        """The IRF stage of :meth:`build` for one group: what other forces made from the same HDB's
        coefficients (the loads along a body, server/loads/sections.py) take so that their memory is
        processed as the model's is; ``g``'s damping may have more rows than columns."""
        return self._irf(g)

    def _irf(self, g: RadiationGroup) -> GroupIrf:
        """B(w) resampled and tailed as the scene asks, K(t) on the step grid (tapered), A_inf."""
        hyd = self.hydro
        omega, damping, tail = g.omega, g.damping, None
        pairs = damping.shape[1] * damping.shape[2]
        if hyd.irf_domega is not None:
            require_size("hydro.irf_domega", "B(w) resampled", (float(omega[-1]) / hyd.irf_domega + 2, pairs),
                         hint=f"a coarser step than {hyd.irf_domega:g} rad/s up to w_max = {omega[-1]:.4g} rad/s")
            omega, damping = resample_damping(omega, damping, float(hyd.irf_domega))
        if hyd.irf_tail == "asymptotic":
            cutoff = hyd.irf_tail_cutoff or TAIL_CUTOFF_FACTOR * omega[-1]
            step = float(omega[-1] - omega[-2])
            require_size("hydro.irf_tail_cutoff", "B(w)'s asymptotic tail", ((cutoff - omega[-1]) / step + 1, pairs),
                         hint=f"a lower cutoff than {cutoff:g} rad/s (the tail continues the HDB's spacing "
                              f"{step:.3g} rad/s)")
            omega, damping, n_tail = asymptotic_tail(omega, damping, float(cutoff))
            tail = float(np.median(np.diagonal(n_tail)))
        require_size(self._key, "the radiation IRF K(t)", (self.t.size, pairs), hint=self._hint)
        require_size("hydro.irf_domega" if hyd.irf_domega is not None else "hydro.irf_tail_cutoff",
                     "the IRF's cosine table", (min(self.t.size, COS_TABLE_ROWS), omega.size + 1),
                     hint="fewer frequencies in B(w)")
        self._check_work(omega.size)
        k = radiation_irf(omega, damping, self.t)
        if self._window is not None:
            k = k * self._window
        if g.added_mass_inf is not None:
            return GroupIrf(omega, damping, k, g.added_mass_inf, tail)
        transform = added_mass_transform(g.omega, self.t, k)
        a_inf = ogilvie_added_mass_inf(g.omega, g.added_mass, self.t, k, transform=transform)
        return GroupIrf(omega, damping, k, a_inf, tail, transform)

    def _check_work(self, n_omega: int) -> None:
        """Refuse an IRF whose transforms cost more than MAX_IRF_PRODUCTS (before computing it)."""
        products = self.t.size * (n_omega + 1)
        if products > MAX_IRF_PRODUCTS:
            raise ModelError(self._key, f"the IRF of {self.t.size} samples (irf_duration / dt) over {n_omega} "
                                        f"frequencies is {products:.3g} sample-frequency products per transform, over "
                                        f"the set-up bound of {MAX_IRF_PRODUCTS:.3g}: {self._hint}, or resample "
                                        "coarser with hydro.irf_domega")

    def _check_aliasing(self, irf: GroupIrf, source: str, warnings: list[str]) -> None:
        """A badly sampled HDB: the transform of B on a grid of spacing dw repeats with period
        2 pi/dw, so K(t) beyond pi/dw mirrors its start. Warn when irf_duration reaches past pi/dw;
        refuse when the mirrored part is large (ALIAS_REFUSE of max |K|) — docs/stability.md."""
        t_alias = aliasing_time(irf.omega)
        k, duration = irf.kernel, self.duration
        if duration <= t_alias or not k.size:
            return
        past = self.t > t_alias
        share = float(np.abs(k[past]).max(initial=0.0)) / max(float(np.abs(k).max()), 1e-300)
        grid = f"the {'resampled grid (hydro.irf_domega)' if self.hydro.irf_domega is not None else 'HDB grid'} " \
               f"of {source!r}"
        why = (f"{duration:g} s reaches past the aliasing time pi/d_omega = {t_alias:.3g} s of {grid}: K(t) "
               f"beyond it is a mirror image of its start (there {100 * share:.2g} % of max |K|); set "
               f"hydro.irf_duration <= {t_alias:.3g} s, or resample with hydro.irf_domega <= "
               f"{np.pi / duration:.3g} rad/s, or compute the HDB on a finer frequency grid")
        if share > ALIAS_REFUSE:
            raise ModelError("hydro.irf_duration", why)
        warning = f"hydro.irf_duration: {why}"
        if warning not in warnings:
            warnings.append(warning)


    def _check_cut(self, irf: GroupIrf, g: RadiationGroup, waves: np.ndarray, warnings: list[str]) -> None:
        """A memory cut that changes B(w) near the scene's frequencies (memory_cut.py) by more than
        CUT_EFFECT_WARN: warned with the irf_duration (and irf_domega) that would not, unless the
        scene states ``irf_taper`` (the cut chosen, e.g. checked against the effective coefficients
        it realises) or the option uses no memory ("constant", "off")."""
        if not self.memory or "irf_taper" in self.hydro.model_fields_set or not irf.kernel.size:
            return
        diag = np.arange(g.act.size)   # each DOF's own damping (diagonals: a many-body group stays small)
        a, b = g.added_mass[:, diag, diag], g.damping[:, diag, diag]
        natural = (natural_frequencies(g.omega, a, g.inertia, g.stiffness)
                   if g.inertia is not None and g.stiffness is not None else np.zeros(0))
        judged = judged_frequencies(g.omega, waves, natural)
        effect = cut_effect(irf.omega, irf.damping[:, diag, diag], self.duration, self.taper, g.omega, b, a,
                            g.inertia, judged)
        if effect is None or effect.change <= CUT_EFFECT_WARN:
            return
        longer, step, left = longer_memory(g.omega, b, self.duration, self.taper, a, g.inertia, judged)
        grid = "" if step is None else f" with hydro.irf_domega = {step:.3g} rad/s (alias-free to it)"
        advice = (f"set hydro.irf_duration = {longer:.3g} s{grid} (changes it by {100 * left:.2g} %)"
                  if left <= CUT_EFFECT_WARN else
                  f"even {longer:.3g} s{grid} leaves {100 * left:.2g} %: consider hydro.radiation = \"state-space\"")
        warnings.append(
            f"hydro.irf_duration: cutting the radiation memory of {g.source!r} at {self.duration:g} s changes the "
            f"damping of {g.labels[effect.dof]} by {100 * effect.change:.3g} % {effect.why} (the damping the kept "
            f"kernel realises against the HDB's B(w); warned above {100 * CUT_EFFECT_WARN:g} %); {advice}, or "
            "state hydro.irf_taper to keep this cut")


class OffOption(RadiationOption):
    """radiation = "off": no radiation force; the client still uses A_inf."""
    name = "off"

    def _force(self, g: RadiationGroup, irf: GroupIrf, log: _Log) -> tuple[RadiationForce | None, np.ndarray | None]:
        return None, None


class _MemoryOption(RadiationOption):
    """Radiation memory over irf_duration (none when it is 0) on the DOF pairs kept by pruning."""
    memory = True

    def _force(self, g: RadiationGroup, irf: GroupIrf, log: _Log) -> tuple[RadiationForce | None, np.ndarray | None]:
        if self.samples == 0:
            return None, None
        return self._memory(g, irf, self._keep(g, irf.kernel, log.pairs), log), None

    def _memory(self, g: RadiationGroup, irf: GroupIrf, keep: np.ndarray, log: _Log) -> RadiationForce:
        raise NotImplementedError

    def _keep(self, g: RadiationGroup, k: np.ndarray, pairs: PairCount) -> np.ndarray:
        """The DOF pairs kept by hydro.coupling_tolerance (trapezoid L1 norms of K), counted in ``pairs``."""
        body_of = g.act // 6
        wt = np.full(k.shape[0], self.dt)
        wt[[0, -1]] *= 0.5
        norms = np.tensordot(wt, np.abs(k), axes=(0, 0))
        keep, dropped = prune_pairs(norms, body_of, float(self.hydro.coupling_tolerance))
        nb_g = np.unique(body_of).size
        pairs.kept += int(keep.sum())
        pairs.total += keep.size
        pairs.blocks_total += nb_g * (nb_g - 1)
        pairs.blocks_dropped += int(dropped.sum())
        return keep


class ConvolutionOption(_MemoryOption):
    """radiation = "convolution": direct convolution of K(t) with the velocity history."""
    name = "convolution"

    def _memory(self, g: RadiationGroup, irf: GroupIrf, keep: np.ndarray, log: _Log) -> RadiationForce:
        return RadiationMemory(irf.kernel, self.dt, None if keep.all() else keep)


class StateSpaceOption(_MemoryOption):
    """radiation = "state-space": rational fits of the IRF's transfer function per kept DOF pair."""
    name = "state-space"

    def __init__(self, hydro: Hydro, waves: Waves, dt: float):
        super().__init__(hydro, waves, dt)
        if self.samples < 2:
            raise ModelError("hydro.irf_duration", f"{self.duration} s: the state-space fit reproduces the IRF "
                                                   "over irf_duration, which must span at least two time steps")
        self.cache = FitCache(default_cache_dir())  # one per setup: identical groups are fitted once
        self.settings = FitSettings(float(hydro.ss_tolerance), hydro.ss_order, int(hydro.ss_max_order),
                                    bool(hydro.ss_enforce_stability))

    def _fit_report(self, fits: StateSpaceStats) -> dict | None:
        return fits.as_dict()

    def _memory(self, g: RadiationGroup, irf: GroupIrf, keep: np.ndarray, log: _Log) -> RadiationForce:
        """Fit every kept, non-zero DOF pair of one group (server/radiation/state_space.py) to the transfer
        function of the same IRF the convolution would use, over [0, w_max] of the HDB."""
        hyd, labels = self.hydro, g.labels
        n = keep.shape[0]
        wf = np.linspace(0.0, float(g.omega[-1]), SS_FIT_POINTS)
        h = irf_transfer(irf.omega, irf.damping, self.duration, self.taper, wf).reshape(wf.size, n * n).T  # (pairs, K)
        peak = np.abs(h).max(axis=1)
        d = peak.reshape(n, n).diagonal()
        scale = np.sqrt(np.outer(d, d)).reshape(-1)
        rows, cols = np.divmod(np.arange(n * n), n)
        use = keep.reshape(-1) & (peak > 1e-12 * max(float(d.max(initial=0.0)), 1e-300))
        fits = self.cache.fit_pairs(wf, h[use], rows[use], cols[use], np.maximum(scale[use], 1e-300), self.settings)
        log.warnings.extend(self.cache.take_warnings())
        try:
            ss = StateSpaceRadiation(n, fits, self.dt, list(labels))
        except StateSpaceError as exc:
            raise ModelError("hydro.radiation", str(exc)) from None
        st = log.fits
        st.states += ss.states
        st.pairs += int(use.sum())
        st.fitted_pairs += fits.fitted
        if use.any():
            st.max_order = max(st.max_order, int(fits.orders.max()))
            worst = int(np.argmax(fits.error))
            if fits.error[worst] > st.max_fit_error:
                st.max_fit_error = float(fits.error[worst])
                st.worst_pair = f"({labels[fits.rows[worst]]}, {labels[fits.cols[worst]]})"
            unmet = int(np.sum(fits.error > hyd.ss_tolerance))
            st.unmet += unmet
            if unmet and hyd.ss_order is None:
                log.warnings.append(
                    f"hydro.ss_tolerance: {unmet} of {int(use.sum())} DOF pairs stay above {hyd.ss_tolerance:g} at "
                    f"ss_max_order = {hyd.ss_max_order} (worst {fits.error[worst]:.3g} for "
                    f"{st.worst_pair}); raise ss_max_order, add irf_taper or irf_tail, or use \"convolution\"")
        return ss


class ConstantOption(RadiationOption):
    """radiation = "constant": -B(w0) v and A(w0) in the client's mass matrix, w0 the regular wave's.
    No memory: hydro.irf_duration is not used (an HDB's wide period grid, e.g. 0.15-150 s, whose
    aliasing time is a fraction of a second, is taken as it is); the IRF serves only Ogilvie's A_inf
    for the setup's report when the HDB has none (issue 38 item 5)."""
    name = "constant"
    irf_settings = False

    def __init__(self, hydro: Hydro, waves: Waves, dt: float):
        super().__init__(hydro, waves, dt)
        if waves.type != "regular":
            raise ModelError("hydro.radiation", "\"constant\" takes A(w0) and B(w0) at the regular-wave "
                             f"frequency: it needs [waves] type = \"regular\" (got {waves.type!r}); use "
                             "\"convolution\" or \"state-space\"")
        self.radiation_frequency = 2 * np.pi / float(waves.period)

    def _force(self, g: RadiationGroup, irf: GroupIrf, log: _Log) -> tuple[RadiationForce | None, np.ndarray | None]:
        w0, omega = self.radiation_frequency, g.omega
        if not omega[0] <= w0 <= omega[-1]:
            raise ModelError("waves.period", f"w0 = {w0:.4g} rad/s lies outside the HDB's range "
                                             f"{omega[0]:.4g}..{omega[-1]:.4g} rad/s")
        return ConstantDamping(interp_matrix(omega, g.damping, w0)), interp_matrix(omega, g.added_mass, w0)


OPTIONS: dict[str, type[RadiationOption]] = {
    o.name: o for o in (ConvolutionOption, StateSpaceOption, ConstantOption, OffOption)}


def radiation_option(hydro: Hydro, waves: Waves, dt: float) -> RadiationOption:
    """The builder of ``hydro.radiation`` for a server step ``dt``; refuses settings it cannot run."""
    option = OPTIONS.get(hydro.radiation)
    if option is None:
        raise ModelError("hydro.radiation", f"unknown option {hydro.radiation!r}: one of {sorted(OPTIONS)}")
    return option(hydro, waves, dt)
