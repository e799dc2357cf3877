"""The per-session force model: excitation, radiation memory and hydrostatics for a scene.

Only the scene's wet bodies (those with an ``hdb``) take part, in scene order: every (N, 6) array
and every 6N matrix here is over the wet bodies; dry bodies belong to the client alone. A scene
without any wet body is a ModelError (nothing to compute: SPEC §5.1).

Hydrodynamic interaction (``[hydro] interaction``): with "full" (default), bodies that share one
HDB dataset (the same object in ``hdbs``) keep all their body-to-body blocks of A∞, A(w), B(w),
K(t) and of the hydrostatic stiffness; bodies from different datasets never interact. With "none"
every body uses only its own 6x6 blocks, even when several bodies share one multi-body HDB.
Bodies that interact form a group; each group has its own radiation memory over its active DOFs
only, so no work is spent on blocks that are zero by construction. Every matrix is reduced to the
active DOFs once at setup, so a step is a few small matvecs and no Python loop over DOFs.
"""

from __future__ import annotations

import math

import numpy as np
import xarray as xr

from hydrolink.protocol.scene import Scene
from hydrolink.server.hdb.schema import DOF_NAMES, HDBError, select_bodies
from hydrolink.server.hydrostatics import total_stiffness
from hydrolink.server.irf import (aliasing_time, asymptotic_tail, irf_report, irf_transfer, ogilvie_added_mass_inf,
                                  ogilvie_report, radiation_irf, resample_damping, taper_window)
from hydrolink.server.radiation import RadiationMemory
from hydrolink.server.state_space import StateSpaceError, StateSpaceRadiation
from hydrolink.server.state_space_cache import FitCache, FitSettings
from hydrolink.server.state_space_cache import default_cache_dir as default_fit_cache_dir
from hydrolink.server.waves import (ConvolutionForcing, WaveError, WaveForcing, convolution_kernel, elevation_on_grid,
                                    interpolate_excitation, kernel_transfer, wave_components)

OGILVIE_DEFAULT_DURATION = 40.0  # s of IRF used for Ogilvie's A_inf when hydro.irf_duration = 0
SS_FIT_POINTS = 120              # frequencies on [0, w_max] the state-space fit is made (and checked) on
TAIL_CUTOFF_FACTOR = 10.0        # default hydro.irf_tail_cutoff: 10 w_max
BREAKING_STEEPNESS = 1.0 / 7.0   # H/lambda above which waves are refused (docs/stability.md)
ALIAS_REFUSE = 0.25              # refuse an IRF whose part past pi/d_omega exceeds this share of max |K|


class ConstantDamping:
    """radiation = "constant": F = -B(w0) v (the push() interface of RadiationMemory)."""

    def __init__(self, damping: np.ndarray):
        self.b = np.ascontiguousarray(damping, float)
        self.n = self.b.shape[0]

    def push(self, v: np.ndarray, replace_last: bool = False) -> np.ndarray:
        return -(self.b @ v)


def _interp_matrix(omega: np.ndarray, values: np.ndarray, w: float) -> np.ndarray:
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


class ModelError(ValueError):
    """A scene/HDB combination the model cannot run; the message names the scene key and why."""

    def __init__(self, key: str, why: str):
        self.key, self.why = key, why
        super().__init__(f"{key}: {why}")


def _groups(scene: Scene, wet: list[int], hdbs: dict[str, xr.Dataset]) -> list[tuple[xr.Dataset, list[int]]]:
    """Wet bodies (positions in ``wet``, a list of scene indices) grouped by interaction.

    "full": bodies sharing a dataset form one group (a repeated HDB body starts a new group);
    "none": one group per body."""
    groups: list[tuple[xr.Dataset, list[int]]] = []
    for k, i in enumerate(wet):
        body = scene.bodies[i]
        if body.name not in hdbs:
            raise ModelError(f"bodies[{i}].hdb", f"no HDB loaded for body {body.name!r}")
        ds = hdbs[body.name]
        names = [str(b) for b in ds["body"].values]
        if body.hdb_body_name not in names:
            key = f"bodies[{i}].hdb_body" if body.hdb_body else f"bodies[{i}].name"
            raise ModelError(key, f"the HDB {ds.attrs.get('source', '?')!r} has no body "
                                  f"{body.hdb_body_name!r} (it holds {names})")
        for gds, members in groups if scene.hydro.interaction == "full" else ():
            if gds is ds and body.hdb_body_name not in [scene.bodies[wet[m]].hdb_body_name for m in members]:
                members.append(k)
                break
        else:
            groups.append((ds, [k]))
    return groups


class HydroModel:
    """Linear potential-flow forces for one session (see module docstring)."""

    def __init__(self, scene: Scene, hdbs: dict[str, xr.Dataset],
                 wave_elevation: tuple[np.ndarray, np.ndarray] | None = None):
        """``hdbs`` maps each wet body's name to its HDB dataset (bodies sharing a file share the
        same object); ``wave_elevation`` the (time, eta) series of ``[waves] type = "elevation"``
        (read from the scene's file by the client; hello.wave_elevation)."""
        self.scene = scene
        wet = [i for i, b in enumerate(scene.bodies) if b.wet]
        if not wet:
            raise ModelError("bodies", "no wet body (no bodies[i].hdb): a force server has nothing to "
                                       "compute for this scene; simulate it without a server")
        self._scene_index = wet
        self.bodies = [scene.bodies[i].name for i in wet]
        wet_bodies = [scene.bodies[i] for i in wet]
        n_b = len(self.bodies)
        self.n = 6 * n_b
        # one server step per exchange: [coupling] exchange_every client steps of simulation.dt
        self.dt = float(scene.simulation.dt) * int(scene.coupling.exchange_every)
        self.interaction = scene.hydro.interaction
        self.active = np.array([b.active_mask for b in wet_bodies], bool)  # (N, 6)
        self._idx = np.flatnonzero(self.active.reshape(-1))
        na = self._idx.size
        water = scene.water
        rho, g = water.density, water.gravity
        hyd = scene.hydro
        self.radiation = hyd.radiation
        irf_T = float(hyd.irf_duration)
        self.irf_samples = int(round(irf_T / self.dt))
        if self.radiation == "state-space" and self.irf_samples < 2:
            raise ModelError("hydro.irf_duration", f"{irf_T} s: the state-space fit reproduces the IRF over "
                                                   "irf_duration, which must span at least two time steps")
        memory_on = self.radiation in ("convolution", "state-space") and self.irf_samples > 0
        m_og = self.irf_samples if self.irf_samples > 0 else int(round(OGILVIE_DEFAULT_DURATION / self.dt))
        t_irf = np.arange(m_og + 1) * self.dt
        self.warnings: list[str] = []

        a_inf = np.zeros((self.n, self.n))
        c_hs = np.zeros((self.n, self.n))
        refs = np.zeros((n_b, 3))
        self._a_inf_source: dict[str, str] = {}
        self._irf_fit: dict[str, float] = {}
        self._irf_a_fit: dict[str, float] = {}
        self._tail_exponent: dict[str, float] = {}
        memories: list[tuple[np.ndarray, object]] = []
        a_client = np.zeros((self.n, self.n))   # the added mass the client puts in its mass matrix
        self.radiation_frequency = None
        if self.radiation == "constant":
            if getattr(scene.waves, "type", "still") != "regular":
                raise ModelError("hydro.radiation", "\"constant\" takes A(w0) and B(w0) at the regular-wave "
                                 f"frequency: it needs [waves] type = \"regular\" (got {scene.waves.type!r}); use "
                                 "\"convolution\" or \"state-space\"")
            self.radiation_frequency = 2 * np.pi / float(scene.waves.period)
        taper = float(hyd.irf_taper) if self.irf_samples > 0 else 0.0
        window = taper_window(t_irf, irf_T, taper)[:, None, None] if taper > 0 else None
        self._pairs = {"kept": 0, "total": 0, "blocks_total": 0, "blocks_dropped": 0}
        self._ss = {"states": 0, "pairs": 0, "max_order": 0, "max_fit_error": 0.0, "unmet": 0}
        self._coefficients: list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]] = []  # act, w, A, B
        groups = _groups(scene, wet, hdbs)
        self.groups = [[self.bodies[k] for k in members] for _, members in groups]
        self._check_waves()
        lo = max(float(ds["omega"].values[0]) for ds, _ in groups)
        hi = min(float(ds["omega"].values[-1]) for ds, _ in groups)
        if lo >= hi:
            raise ModelError("bodies", f"the bodies' HDB frequency ranges do not overlap ({lo}..{hi} rad/s)")
        try:
            self.waves = wave_components(scene.waves, lo, hi)
        except WaveError as exc:
            raise ModelError(exc.key, exc.why) from None
        x_comp = np.zeros((self.waves.size, self.n), complex)
        self.excitation = getattr(scene.waves, "excitation", "superposition") if self.waves.kind != "still" \
            else "superposition"
        heads = self.waves.heading_of()
        self._headings = np.unique(heads) if self.waves.kind != "elevation" else np.array([self.waves.direction])
        exc_T = float(getattr(scene.waves, "excitation_irf_duration", 0.0))
        kernels = np.zeros((self._headings.size, 2 * max(1, int(round(exc_T / self.dt))) + 1, self.n)) \
            if self.excitation == "convolution" else None
        self._exc_fit = 0.0

        for ds, members in groups:
            src = ds.attrs.get("source", "?")
            first = self._scene_index[members[0]]
            depth = float(ds.attrs["water_depth"])
            if not (depth == water.depth_m or (math.isfinite(depth) and math.isfinite(water.depth_m)
                                               and math.isclose(depth, water.depth_m, rel_tol=1e-4))):
                raise ModelError("water.depth", f"{water.depth!r} but the HDB {src!r} (bodies "
                                 f"{[self.bodies[k] for k in members]}) was computed for depth {depth}")
            try:
                sub = select_bodies(ds, [wet_bodies[k].hdb_body_name for k in members])
            except HDBError as exc:
                raise ModelError(f"bodies[{first}].hdb_body", str(exc)) from None
            s_rho = rho / float(ds.attrs["rho"])
            s_rg = rho * g / (float(ds.attrs["rho"]) * float(ds.attrs["g"]))
            gidx = (6 * np.asarray(members)[:, None] + np.arange(6)).reshape(-1)  # global rows
            loc = np.flatnonzero(self.active.reshape(-1)[gidx])  # active, local to this group
            act = gidx[loc]
            pos = np.searchsorted(self._idx, act)  # position in the reduced (active) vectors
            omega = sub["omega"].values.astype(float)
            refs[members] = sub["reference_point"].values
            c_hs[np.ix_(gidx, gidx)] = s_rg * sub["hydrostatic_stiffness"].values
            am = s_rho * sub["added_mass"].values[:, loc][:, :, loc]
            bd = s_rho * sub["radiation_damping"].values[:, loc][:, :, loc]
            self._coefficients.append((act, omega, am, bd))
            om_k, bd_k = omega, bd          # the grid K(t) is integrated over (resampled, tail)
            if hyd.irf_domega is not None and loc.size:
                om_k, bd_k = resample_damping(omega, bd, float(hyd.irf_domega))
            if hyd.irf_tail == "asymptotic" and loc.size:
                cutoff = hyd.irf_tail_cutoff or TAIL_CUTOFF_FACTOR * om_k[-1]
                om_k, bd_k, n_tail = asymptotic_tail(om_k, bd_k, float(cutoff))
                self._tail_exponent[src] = float(np.median(np.diagonal(n_tail)))
            k = radiation_irf(om_k, bd_k, t_irf)
            if window is not None:
                k = k * window
            if "added_mass_inf" in sub:
                a_loc = s_rho * sub["added_mass_inf"].values[np.ix_(loc, loc)]
                how = "hdb"
            else:
                a_loc = ogilvie_added_mass_inf(omega, am, t_irf, k)
                how = "ogilvie"
            a_inf[np.ix_(act, act)] = a_loc
            a_client[np.ix_(act, act)] = a_loc
            for k_ in members:
                self._a_inf_source[self.bodies[k_]] = how
            if memory_on and loc.size:
                labels = [f"{self.bodies[int(g) // 6]}.{DOF_NAMES[int(g) % 6]}" for g in act]
                body_of = act // 6
                kk = k[:self.irf_samples + 1]
                wt = np.full(kk.shape[0], self.dt)
                wt[[0, -1]] *= 0.5
                norms = np.tensordot(wt, np.abs(kk), axes=(0, 0))
                keep, dropped = prune_pairs(norms, body_of, float(hyd.coupling_tolerance))
                nb_g = np.unique(body_of).size
                self._pairs["kept"] += int(keep.sum())
                self._pairs["total"] += keep.size
                self._pairs["blocks_total"] += nb_g * (nb_g - 1)
                self._pairs["blocks_dropped"] += int(dropped.sum())
                if self.radiation == "convolution":
                    memories.append((pos, RadiationMemory(kk, self.dt, None if keep.all() else keep)))
                else:
                    memories.append((pos, self._state_space(om_k, bd_k, float(omega[-1]), irf_T, taper, keep,
                                                            labels, hyd)))
            elif self.radiation == "constant" and loc.size:
                w0 = self.radiation_frequency
                if not omega[0] <= w0 <= omega[-1]:
                    raise ModelError("waves.period", f"w0 = {w0:.4g} rad/s lies outside the HDB's range "
                                                     f"{omega[0]:.4g}..{omega[-1]:.4g} rad/s")
                memories.append((pos, ConstantDamping(_interp_matrix(omega, bd, w0))))
                a_client[np.ix_(act, act)] = _interp_matrix(omega, am, w0)
            if self.irf_samples > 0 and loc.size:
                rep = irf_report(omega, bd, t_irf, k)
                self._irf_fit[src] = max(rep["worst"], self._irf_fit.get(src, 0.0))
                rep_a = ogilvie_report(omega, am, a_loc, t_irf, k)
                self._irf_a_fit[src] = max(rep_a["worst"], self._irf_a_fit.get(src, 0.0))
                self._check_aliasing(om_k, k, t_irf, irf_T, src, hyd.irf_domega is not None)
            for ih, head in enumerate(self._headings if (self.waves.size or kernels is not None) else ()):
                on = heads == head
                try:
                    if on.any():
                        x_comp[np.ix_(on, gidx)] = s_rg * interpolate_excitation(
                            omega, sub["wave_direction"].values, sub["excitation_force"].values,
                            self.waves.omega[on], float(head))
                    if kernels is not None:
                        x_h = s_rg * interpolate_excitation(omega, sub["wave_direction"].values,
                                                            sub["excitation_force"].values, omega, float(head))
                        kernels[ih][:, gidx] = convolution_kernel(omega, x_h, self.dt, exc_T)
                        band = (omega >= lo) & (omega <= hi)
                        if band.any():
                            err = np.abs(kernel_transfer(kernels[ih][:, gidx], self.dt, omega[band]) - x_h[band])
                            peak = np.abs(x_h[band]).max(axis=0)
                            live = peak > 1e-3 * max(float(peak.max()), 1e-300)  # not the ~0 channels
                            if live.any():
                                self._exc_fit = max(self._exc_fit, float((err.max(axis=0)[live] / peak[live]).max()))
                except WaveError as exc:
                    key = "waves.spreading" if self.waves.headings is not None and exc.key == "waves.direction" \
                        else exc.key
                    why = exc.why
                    if key == "waves.spreading":
                        why += (f" (cos-2s spreading, s = {scene.waves.spreading_s:g}, "
                                f"{scene.waves.spreading_directions} directions: headings "
                                f"{np.round(np.rad2deg(self._headings), 2).tolist()} deg; reduce the spreading or "
                                "give an HDB with headings covering them)")
                    raise ModelError(key, f"{why} (HDB {src!r})") from None
        if self.waves.energy_outside > 0.01:
            self.warnings.append(f"waves: {100 * self.waves.energy_outside:.2g} % of the spectrum's energy lies "
                                 f"outside the HDB range {lo:.3g}-{hi:.3g} rad/s and is left out")

        masses = np.array([b.mass for b in wet_bodies])
        cogs = np.array([b.center_of_mass for b in wet_bodies], float)
        mask = self.active.reshape(-1)
        keep = np.outer(mask, mask)
        self.added_mass_inf = np.where(keep, a_inf, 0.0)
        self.added_mass_client = np.where(keep, a_client, 0.0)
        self.hydrostatic_stiffness = np.where(keep, total_stiffness(c_hs, masses, cogs, refs, g), 0.0)
        self.equilibrium_position = np.hstack([refs, np.zeros((n_b, 3))])
        self._k_hs = np.ascontiguousarray(self.hydrostatic_stiffness[np.ix_(self._idx, self._idx)])
        self._x_eq = self.equilibrium_position.reshape(-1)[self._idx].copy()
        if len(memories) == 1 and memories[0][0].size == na:
            memories = [(slice(None), memories[0][1])]  # one group over every active DOF: no gather
        self._memories = memories
        self.coupled_blocks = sum(len(m) * (len(m) - 1) for _, m in groups)
        self._kernel_entries = self._pairs["kept"]
        self.elevation_series = None
        if kernels is not None:
            self._forcing = ConvolutionForcing(kernels[:, :, self._idx], self._eta_source(scene, wave_elevation, hi),
                                               self.dt, float(self.waves.ramp))
        else:
            self._forcing = WaveForcing(self.waves, x_comp[:, self._idx])
        self._x_comp = x_comp
        self._step = -1           # index of the newest step pushed
        self._sel = slice(None) if na == self.n else self._idx  # a view when every DOF is active
        self._red = np.zeros((3, na))  # scratch: excitation, radiation, hydrostatic (active DOFs)
        self._net_buoyancy = self._buoyancy(groups, rho, g, masses)

    def _eta_source(self, scene: Scene, wave_elevation, omega_max: float):
        """eta(k0, k1) -> (S, k1 - k0) at t = k dt, one row per heading, for ConvolutionForcing:
        synthesized from the components (regular/irregular: no ramp; the forcing applies it) or the
        elevation file put on the grid (type = "elevation")."""
        if self.waves.kind == "elevation":
            if wave_elevation is None:
                raise ModelError("waves.file", "the elevation series did not reach the force server (the client "
                                               "sends it in hello.wave_elevation: SPEC §5.1)")
            time, eta = wave_elevation
            try:
                ser = elevation_on_grid(time, eta, self.dt, int(round(scene.simulation.duration / self.dt)),
                                        float(scene.waves.excitation_irf_duration), scene.waves.start, omega_max)
            except WaveError as exc:
                raise ModelError(exc.key, f"{scene.waves.file}: {exc.why}") from None
            self.elevation_series = ser
            return ser
        comps, dt = self.waves, self.dt
        c = comps.amplitude * np.exp(1j * comps.phase)
        which = np.searchsorted(self._headings, comps.heading_of())
        onehot = np.zeros((comps.size, self._headings.size))
        onehot[np.arange(comps.size), which] = 1.0

        def eta(k0: int, k1: int) -> np.ndarray:
            t = np.arange(k0, k1) * dt
            return (np.real(np.exp(-1j * np.outer(t, comps.omega)) * c[None, :]) @ onehot).T
        return eta

    def _check_aliasing(self, omega_k: np.ndarray, k: np.ndarray, t_irf: np.ndarray, irf_T: float, src: str,
                        resampled: bool) -> None:
        """A badly sampled HDB: the transform of B on a grid of spacing dw repeats with period
        2 pi/dw, so K(t) beyond pi/dw mirrors its start. Warn when irf_duration reaches past pi/dw;
        refuse when the mirrored part is large (ALIAS_REFUSE of max |K|) — docs/stability.md."""
        t_alias = aliasing_time(omega_k)
        if irf_T <= t_alias or not k.size:
            return
        past = t_irf > t_alias
        share = float(np.abs(k[past]).max(initial=0.0)) / max(float(np.abs(k).max()), 1e-300)
        grid = f"the {'resampled grid (hydro.irf_domega)' if resampled else 'HDB grid'} of {src!r}"
        why = (f"{irf_T:g} s reaches past the aliasing time pi/d_omega = {t_alias:.3g} s of {grid}: K(t) "
               f"beyond it is a mirror image of its start (there {100 * share:.2g} % of max |K|); set "
               f"hydro.irf_duration <= {t_alias:.3g} s, or resample with hydro.irf_domega <= "
               f"{np.pi / irf_T:.3g} rad/s, or compute the HDB on a finer frequency grid")
        if share > ALIAS_REFUSE:
            raise ModelError("hydro.irf_duration", why)
        warning = f"hydro.irf_duration: {why}"
        if warning not in self.warnings:
            self.warnings.append(warning)

    def _check_waves(self) -> None:
        """Regular and irregular waves no steeper than the breaking limit H/lambda = 1/7 (lambda of
        the period / peak period by linear dispersion at the scene's depth); a warning above half
        of it, where linear theory loses accuracy."""
        w = self.scene.waves
        kind = getattr(w, "type", "still")
        if kind not in ("regular", "irregular"):
            return
        from hydrolink.server.control import wave_number
        period, height, key = (w.period, w.height, "waves.height") if kind == "regular" else (w.tp, w.hs, "waves.hs")
        water = self.scene.water
        lam = 2 * np.pi / float(wave_number(np.array([2 * np.pi / period]), water.gravity, water.depth_m)[0])
        steep = height / lam
        if steep > BREAKING_STEEPNESS:
            raise ModelError(key, f"{height:g} m at {period:g} s is steeper than the breaking limit: H/lambda = "
                                  f"{steep:.3g} > 1/7 (lambda = {lam:.4g} m): no such wave exists; use "
                                  f"{key} <= {BREAKING_STEEPNESS * lam:.4g} m (or a longer period)")
        if steep > 0.5 * BREAKING_STEEPNESS:
            self.warnings.append(f"{key}: H/lambda = {steep:.3g} is over half the breaking limit 1/7: linear "
                                 "wave theory and linear forces lose accuracy (steep-wave effects are not modelled)")

    def _state_space(self, omega_k, damping_k, w_max, duration, taper, keep, labels, hyd) -> StateSpaceRadiation:
        """Fit every kept, non-zero DOF pair of one group (server/state_space.py) to the transfer
        function of the same IRF the convolution would use, over [0, w_max] of the HDB."""
        n = keep.shape[0]
        wf = np.linspace(0.0, w_max, SS_FIT_POINTS)
        h = irf_transfer(omega_k, damping_k, duration, taper, wf).reshape(wf.size, n * n).T  # (pairs, K)
        peak = np.abs(h).max(axis=1)
        d = peak.reshape(n, n).diagonal()
        scale = np.sqrt(np.outer(d, d)).reshape(-1)
        rows, cols = np.divmod(np.arange(n * n), n)
        use = keep.reshape(-1) & (peak > 1e-12 * max(float(d.max(initial=0.0)), 1e-300))
        cache = self.__dict__.setdefault("_fit_cache", FitCache(default_fit_cache_dir()))  # one per setup
        fits = cache.fit_pairs(wf, h[use], rows[use], cols[use], np.maximum(scale[use], 1e-300),
                               FitSettings(float(hyd.ss_tolerance), hyd.ss_order, int(hyd.ss_max_order),
                                           bool(hyd.ss_enforce_stability)))
        try:
            ss = StateSpaceRadiation(n, fits, self.dt, labels)
        except StateSpaceError as exc:
            raise ModelError("hydro.radiation", str(exc)) from None
        st = self._ss
        st["states"] += ss.states
        st["pairs"] += int(use.sum())
        st["fitted_pairs"] = st.get("fitted_pairs", 0) + fits.fitted  # 0: every fit from the cache
        if use.any():
            st["max_order"] = max(st["max_order"], int(fits.orders.max()))
            worst = int(np.argmax(fits.error))
            if fits.error[worst] > st["max_fit_error"]:
                st["max_fit_error"] = float(fits.error[worst])
                st["worst_pair"] = f"({labels[fits.rows[worst]]}, {labels[fits.cols[worst]]})"
            unmet = int(np.sum(fits.error > hyd.ss_tolerance))
            st["unmet"] += unmet
            if unmet and hyd.ss_order is None:
                self.warnings.append(
                    f"hydro.ss_tolerance: {unmet} of {int(use.sum())} DOF pairs stay above {hyd.ss_tolerance:g} at "
                    f"ss_max_order = {hyd.ss_max_order} (worst {fits.error[worst]:.3g} for "
                    f"{st.get('worst_pair')}); raise ss_max_order, add irf_taper or irf_tail, or use \"convolution\"")
        return ss

    def _buoyancy(self, groups, rho, g, masses) -> list[float | None]:
        """rho g V - m g per wet body (None when the HDB has no displaced volume)."""
        out: list[float | None] = [None] * len(self.bodies)
        for ds, members in groups:
            if "displaced_volume" in ds:
                names = [self.scene.bodies[self._scene_index[k]].hdb_body_name for k in members]
                vol = ds["displaced_volume"].sel(body=names).values
                for k, v in zip(members, vol):
                    out[k] = float(rho * g * v - masses[k] * g)
        return out

    def setup_info(self) -> dict:
        """What the client needs to build its side (matrices in the 6N body-major DOF order, over the
        wet bodies only).

        ``interaction``: the scene's "full" | "none"; ``hydro_groups``: lists of bodies that interact
        hydrodynamically; ``coupled_blocks``: number of off-diagonal body-pair blocks (i, j), i != j,
        in use (ordered pairs: 2 for two interacting bodies); ``radiation_kernel_entries``: DOF
        pairs in the radiation convolution (sum over groups of active DOFs squared)."""
        return {
            "bodies": list(self.bodies),
            "interaction": self.interaction,
            "hydro_groups": [list(g) for g in self.groups],
            "coupled_blocks": self.coupled_blocks,
            "radiation_kernel_entries": self._kernel_entries,
            "dofs": list(DOF_NAMES),
            "active": self.active.copy(),
            "added_mass_inf": self.added_mass_inf.copy(),
            "added_mass_inf_source": dict(self._a_inf_source),
            "hydrostatic_stiffness": self.hydrostatic_stiffness.copy(),
            "equilibrium_position": self.equilibrium_position.copy(),
            "dt": self.dt,
            "irf_samples": self.irf_samples,
            "irf_duration": self.irf_samples * self.dt,
            "irf_fit_error": dict(self._irf_fit),
            "wave_components": self.waves.size,
            "wave_energy_outside_hdb": self.waves.energy_outside,
            "ramp": float(self.waves.ramp),
            "net_buoyancy": list(self._net_buoyancy),
            "warnings": list(self.warnings),
            # radiation options (scene [hydro]; docs/radiation.md)
            "radiation": self.radiation,
            "added_mass": self.added_mass_client.copy(),
            "radiation_frequency": self.radiation_frequency,
            "irf_added_mass_error": dict(self._irf_a_fit),
            "irf_processing": {"domega": self.scene.hydro.irf_domega, "taper": self.scene.hydro.irf_taper,
                               "tail": self.scene.hydro.irf_tail, "tail_exponent": dict(self._tail_exponent)},
            "coupling_tolerance": float(self.scene.hydro.coupling_tolerance),
            "radiation_pairs": self._pairs["kept"],
            "dropped_pair_fraction": (1.0 - self._pairs["kept"] / self._pairs["total"]) if self._pairs["total"] else 0.0,
            "dropped_blocks": self._pairs["blocks_dropped"],
            "dropped_block_fraction": (self._pairs["blocks_dropped"] / self._pairs["blocks_total"]
                                       if self._pairs["blocks_total"] else 0.0),
            "state_space": dict(self._ss) if self.radiation == "state-space" else None,
            # excitation options ([waves] excitation / type = "elevation", spreading; server/waves.py)
            "excitation": self.excitation,
            "excitation_irf_duration": (float(self.scene.waves.excitation_irf_duration)
                                        if self.excitation == "convolution" else 0.0),
            "excitation_irf_error": self._exc_fit,
            "wave_headings": np.rad2deg(self._headings).tolist() if self.waves.kind != "still" else [],
            "elevation_resampled": bool(self.elevation_series.resampled) if self.elevation_series else False,
            "elevation_start": float(self.elevation_series.start) if self.elevation_series else 0.0,
        }

    def radiation_coefficients(self, omega: float) -> tuple[np.ndarray, np.ndarray]:
        """A(omega), B(omega) (6N x 6N over the wet bodies, zero outside the active DOFs and the
        interaction groups, rescaled to the scene's density): linear interpolation in the HDB's
        frequency grid; beyond its last frequency A = A_inf and B = 0 (what a convolution built from
        that grid realises there). For frequency-domain and steady-state solvers."""
        a, b = self.added_mass_inf.copy(), np.zeros((self.n, self.n))
        for act, om, am, bd in self._coefficients:
            if omega > om[-1] or not act.size:
                continue
            ix = np.ix_(act, act)
            w = min(max(float(omega), float(om[0])), float(om[-1]))
            j = int(np.clip(np.searchsorted(om, w) - 1, 0, om.size - 2))
            s = (w - om[j]) / (om[j + 1] - om[j])
            a[ix] = (1 - s) * am[j] + s * am[j + 1]
            b[ix] = (1 - s) * bd[j] + s * bd[j + 1]
        return a, b

    def excitation_phasors(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Wave components: omega (n_c,), complex force phasors (n_c, 6N) and elevation phasors
        (n_c,) such that, after the ramp, F_ex(t) = Re(sum_c F_c e^{-i omega_c t}) and likewise the
        elevation at the origin (server/waves.py convention)."""
        c = self.waves.amplitude * np.exp(1j * self.waves.phase)
        return self.waves.omega.copy(), self._x_comp * c[:, None], c

    def step(self, time: float, position: np.ndarray, velocity: np.ndarray, *,
             replace_last: bool = False) -> dict:
        """Forces at ``time`` (= k dt) for the state at that time; see the module docstring.

        ``replace_last`` recomputes the newest step with a new state (iterative coupling)."""
        if replace_last and self._step < 0:
            raise ModelError("step", "replace_last before any step was computed")
        k = self._step if replace_last else self._step + 1
        if abs(time - k * self.dt) > 1e-6 * self.dt + 1e-12 * abs(time):
            raise ModelError("time", f"expected t = {k * self.dt:.9g} (step {k} of dt {self.dt}), got {time!r}")
        x = np.asarray(position, float).reshape(-1)
        v = np.asarray(velocity, float).reshape(-1)
        if x.size != self.n or v.size != self.n:
            raise ModelError("state", f"position and velocity must be ({len(self.bodies)}, 6), "
                                      f"got {np.shape(position)} and {np.shape(velocity)}")
        sel = self._sel
        red = self._red
        vs = v[sel]
        for pos, memory in self._memories:
            red[1, pos] = memory.push(vs[pos], replace_last)
        red[0], eta = self._forcing(time)
        np.dot(self._k_hs, self._x_eq - x[sel], out=red[2])
        self._step = k
        out = np.zeros((3, len(self.bodies), 6))
        out.reshape(3, self.n)[:, sel] = red
        return {"excitation": out[0], "radiation": out[1], "hydrostatic": out[2], "wave_elevation": eta}
