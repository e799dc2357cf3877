"""The per-session force model: excitation, radiation memory and hydrostatics for a scene.

The scene's served bodies take part, in scene order: the wet bodies (those with an ``hdb``) and the
Morison-only bodies (no HDB, with ``[[morison]]`` members: no radiation, excitation or
hydrostatics; their weight and buoyancy are the client's, as for a dry body, and their reference
point is the dry body's node). Every (N, 6) array and every 6N matrix here is over the served
bodies; other dry bodies belong to the client alone. A scene without any served body is a
ModelError (nothing to compute: SPEC §5.1). "Wet bodies" below means the served ones.

Hydrodynamic interaction (``[hydro] interaction``): with "full" (default), bodies that share one
HDB dataset (the same object in ``hdbs``) keep all their body-to-body blocks of A∞, A(w), B(w),
K(t) and of the hydrostatic stiffness; bodies from different datasets never interact. With "none"
every body uses only its own 6x6 blocks, even when several bodies share one multi-body HDB.
Bodies that interact form a group; each group has its own radiation memory over its active DOFs
only, so no work is spent on blocks that are zero by construction. Every matrix is reduced to the
active DOFs once at setup, so a step is a few small matvecs and no Python loop over DOFs.

Generalized modes (server/modes.py): a body whose HDB has modes beyond its six brings them after
the 6N rigid DOFs (the model's vector is 6N + M; the scene's ``bodies[i].modes`` must name them);
excitation, radiation, A-infinity and the hydrostatic stiffness run over all of it with the HDB's
rigid-mode blocks, the force terms over the rigid DOFs.

The radiation part ([hydro] radiation and the IRF options) is built by the option's builder in
server/radiation/options.py, which also reports its setup fields. The forces beyond this linear
core (viscous, Morison, nonlinear hydrostatics and Froude–Krylov) are force terms
(server/terms/base.py) built from the registry in server/terms/registry.py; a step loops over them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import xarray as xr

from hydrolink.protocol.scene import Scene, wave_peaks
from hydrolink.protocol.setup import IRFProcessing, Setup, StateSpaceReport
from hydrolink.server import compiler
from hydrolink.server.allocation import require_size
from hydrolink.server.fused.step import FusedLinearStep, FusedRadiation
from hydrolink.server.radiation.convolution import RadiationMemory
from hydrolink.server.radiation.irf import irf_samples
from hydrolink.server.rigid_body import rigid_body_mass_matrix
from hydrolink.server.errors import ModelError
from hydrolink.server.terms.hulls import Hull
from hydrolink.protocol.hdb.layout import DOF_NAMES, HDBError, hdb_warnings
from hydrolink.protocol.hdb.schema import select_bodies
from hydrolink.server.hydrostatics import total_stiffness
from hydrolink.server.modes import ModeLayout, mode_layout, structure_file_notes
from hydrolink.server.terms.base import ForceTerm, TermContext
from hydrolink.server.terms.registry import TERMS, build_terms
from hydrolink.server.terms.viscous import ViscousTerm
from hydrolink.server.radiation.options import RadiationGroup, radiation_option
from hydrolink.server.radiation.state_space import Realization
from hydrolink.server.sea.headings import complete_headings, interpolate_excitation
from hydrolink.server.sea.passive_yaw import PassiveYaw, YawingBody, yaw_grid, yawed_excitation
from hydrolink.server.sea.seastate import direction_bands, run_components
from hydrolink.server.sea.waves import ConvolutionForcing, WaveError, WaveForcing, WavePhases, convolution_kernel, elevation_on_grid, kernel_transfer

__all__ = ["HydroModel", "ModelError"]

BREAKING_STEEPNESS = 1.0 / 7.0   # H/lambda above which waves are refused (docs/stability.md)
RESIDUAL_WARNING = 0.05          # share of gauge records a fitted sea may leave unexplained without a warning


@dataclass(frozen=True)
class _GroupData:
    """One interaction group's HDB data: its bodies' sub-dataset in scene units and its DOF rows."""
    members: list[int]      # positions of its bodies among the wet bodies
    source: str             # the HDB's source
    data: xr.Dataset        # the HDB restricted to the group's bodies
    omega: np.ndarray       # (n_w,)
    rho_scale: float        # scene rho / HDB rho (added mass, damping)
    rg_scale: float         # scene rho g / HDB rho g (hydrostatics, excitation)
    rows: np.ndarray        # (sum of 6 + modes over the members,) rows in the model's vector, HDB order


def _groups(scene: Scene, wet: list[int], hdbs: dict[str, xr.Dataset]) -> list[tuple[xr.Dataset, list[int]]]:
    """Wet bodies (positions in ``wet``, a list of scene indices) grouped by interaction.

    "full": bodies sharing a dataset form one group (a repeated HDB body starts a new group);
    "none": one group per body."""
    groups: list[tuple[xr.Dataset, list[int]]] = []
    for k, i in enumerate(wet):
        body = scene.bodies[i]
        if not body.wet:                 # Morison-only: in no group
            continue
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
                 wave_elevation: tuple[np.ndarray, np.ndarray] | None = None, *,
                 hulls: dict[str, Hull] | None = None, term_types: tuple[type[ForceTerm], ...] = TERMS,
                 compiled: bool | None = None):
        """``hdbs`` maps each wet body's name to its HDB dataset (bodies sharing a file share the
        same object); ``wave_elevation`` the (time, eta) series of ``[waves] type = "elevation"``
        (read from the scene's file by the client; hello.wave_elevation); ``hulls`` the closed
        hulls of the bodies with nonlinear hydrostatics by name (hello.meshes); ``term_types`` the
        force terms beyond the linear core to build where the scene has them (server/terms/registry.py);
        ``compiled``: the linear core's step by one compiled call (server/fused/step.py; None: where
        numba is installed and imports, server/compiler.py), else by the numpy path (the reference)."""
        self.scene = scene
        try:
            hdbs = complete_headings(scene, hdbs)    # half ranges of symmetric bodies completed
        except WaveError as exc:
            raise ModelError(exc.key, exc.why) from None
        self.hdbs = dict(hdbs)   # by body name: for what is rebuilt from the same data (a controller's plant, SPEC §5.7)
        served = {b.name for b in scene.served_bodies}
        wet = [i for i, b in enumerate(scene.bodies) if b.name in served]
        if not wet:
            raise ModelError("bodies", "no wet body (no bodies[i].hdb) and no Morison element: a force server "
                                       "has nothing to compute for this scene; simulate it without a server")
        self._scene_index = wet
        self.bodies = [scene.bodies[i].name for i in wet]
        # the model's vector: the 6N rigid DOFs, then the bodies' generalized modes (server/modes.py)
        self.modes: ModeLayout = mode_layout(scene, wet, hdbs)
        self.n_rigid = 6 * len(self.bodies)
        self.n = self.modes.n
        # one server step per exchange: [coupling] exchange_every client steps of simulation.dt
        self.dt = scene.exchange_dt
        self.interaction = scene.hydro.interaction
        self.active = np.array([scene.bodies[i].active_mask for i in wet], bool)  # (N, 6)
        self._active_dofs = np.concatenate((self.active.reshape(-1), np.ones(self.modes.size, bool)))  # (n,)
        self._idx = np.flatnonzero(self._active_dofs)
        self.active_index = self._idx          # the active DOFs' positions in the vector (6N, then the modes)
        option = radiation_option(scene.hydro, scene.waves, self.dt)  # refuses what it cannot run
        self.radiation, self.irf_samples = option.name, option.samples
        self.radiation_frequency = option.radiation_frequency
        self.warnings: list[str] = []
        groups = _groups(scene, wet, hdbs)
        self.groups = [[self.bodies[k] for k in members] for _, members in groups]
        self.coupled_blocks = sum(len(m) * (len(m) - 1) for _, m in groups)
        self._check_waves()
        lo, hi = self._frequency_range(groups)
        if lo >= hi:
            raise ModelError("bodies", f"the bodies' HDB frequency ranges do not overlap ({lo}..{hi} rad/s)")
        try:
            self.waves = run_components(scene.waves, scene, lo, hi)
        except WaveError as exc:
            raise ModelError(exc.key, exc.why) from None
        self._phases = WavePhases(self.waves.omega)   # the step's [cos wt; sin wt], shared with the terms
        data = [self._group_data(ds, members) for ds, members in groups]
        self._hydrostatics(data)
        rad_groups = [self._radiation_group(d) for d in data]
        self._coefficients = [(g.act, g.omega, g.added_mass, g.damping) for g in rad_groups]  # act, w, A, B
        amp = self.waves.amplitude   # the memory's cut is judged at the components of >= 1 % of the peak energy
        radiation = option.build(rad_groups, self.n, self.waves.omega[amp >= 0.1 * amp.max(initial=0.0)])
        self.added_mass_inf, self.added_mass_client = radiation.added_mass_inf, radiation.added_mass
        self._radiation = radiation.report
        self.warnings += radiation.warnings
        memories = radiation.forces
        if len(memories) == 1 and memories[0][0].size == self._idx.size:
            memories = [(slice(None), memories[0][1])]  # one group over every active DOF: no gather
        self._memories = memories
        self.radiation_feedthrough = np.zeros((self.n, self.n))   # dF_rad/dv of the newest sample
        for pos, memory in radiation.forces:
            rows = self._idx[pos]
            self.radiation_feedthrough[np.ix_(rows, rows)] = memory.feedthrough()
        # the last step index a client may send: seq * dt runs to simulation.duration
        self.last_seq = scene.n_exchanges
        self._excitation(data, lo, hi, wave_elevation)
        self._yaw = self._passive_yaw(data)
        self._step = -1           # index of the newest step pushed
        self._still = np.zeros(self.n)   # the velocity a state the body is not in radiates with (step(radiating=False))
        na = self._idx.size
        self._all_active = na == self.n
        self._sel = slice(None) if self._all_active else self._idx  # a view when every DOF is active
        self._red = np.zeros((3, na))  # scratch: excitation, radiation, hydrostatic (active DOFs)
        rigid = slice(0, self.n_rigid)   # the terms act on the rigid DOFs (6N) only
        self.terms = build_terms(TermContext(
            scene, wet, self.active, self._idx[self._idx < self.n_rigid], self.waves, self.equilibrium_position,
            self.hydrostatic_stiffness[rigid, rigid], self._net_buoyancy, hulls or {}, hdbs, self._phases,
            None if self._yaw is None else self._yaw.heading), term_types)
        self._stateful = [term for term in self.terms if not term.stateless]
        self._add_term_contributions()
        self._reply_shape, self._rows_shape = (3, len(self.bodies), 6), (3, self.n)
        self._summed = isinstance(self._forcing, WaveForcing)    # the components' sum (else by convolution)
        self._fused = self._fused_step(compiled)

    def _fused_step(self, compiled: bool | None) -> FusedLinearStep | None:
        """The linear core as one compiled call (server/fused/step.py), or None for the numpy path:
        ``compiled`` False, numba missing or not importing, or radiation in several groups (or in
        one that leaves out an active DOF)."""
        if compiled is None:
            compiled = compiler.AVAILABLE and compiler.imports()
        if not compiled or len(self._memories) > 1 or any(not isinstance(pos, slice) for pos, _ in self._memories):
            return None
        memory = self._memories[0][1] if self._memories else None
        if isinstance(memory, RadiationMemory):   # a held body's columns left out of the convolution
            radiation = memory.fused(self.held_dofs()[self._idx])
        else:
            radiation = memory.fused() if memory is not None else FusedRadiation("none")
        if self._summed:
            exc, omega, ramp = self._forcing.matrix, self.waves.omega, float(self.waves.ramp)
        else:   # by convolution: a lookup of blocks computed by FFT, added to the compiled call's sums
            exc, omega, ramp = np.zeros((self._idx.size + 1, 0)), np.zeros(0), 0.0
        fused = FusedLinearStep(self._idx, exc, omega, ramp, self._k_hs, self._x_eq, radiation,
                                None if self._yaw is None else self._yaw.fused_inputs())
        fused.warm_up(self.n)
        return fused

    def held_dofs(self) -> np.ndarray:
        """(n,) bool over the model's vector: the wet bodies' DOFs whose velocity the scene's joints
        hold at zero at every step — every DOF of a body held to ground (a ``fixed`` joint with
        ``ground``), and of a body on a ``revolute`` or ``prismatic`` joint to ground or to a held
        body with its axis along a coordinate axis, the DOFs that joint does not free (a hinge
        about y frees surge, heave and pitch; a slider along z, heave). The compiled step's
        radiation convolution leaves their columns out (they add K x 0); their force rows are
        still computed (the results and the joints' reactions read them). A client that reports
        such a DOF moving contradicts the scene: that velocity is not read there."""
        anchored = {"ground", *self.scene.fixed_to_ground()}
        free = {name: np.ones(6, bool) for name in self.bodies}
        for name in anchored & set(free):
            free[name][:] = False
        for j in self.scene.joints:
            freed = j.freed_dofs()
            if freed is None:     # another type, or an oblique axis (it frees a mix): none held
                continue
            joint_free = np.zeros(6, bool)
            joint_free[list(freed)] = True
            for this, other in ((j.body1, j.body2), (j.body2, j.body1)):
                if other in anchored and this in free and this not in anchored:
                    free[this] &= joint_free
        mask = np.zeros(self.n, bool)
        for i, name in enumerate(self.bodies):
            mask[6 * i:6 * i + 6] = ~free[name]
        return mask

    def fused_only(self) -> FusedLinearStep | None:
        """The compiled linear core when it is this model's whole step (the excitation a sum of
        components, no passive-yaw body, no force term but a linear damping one — :meth:`linear_damping`,
        which the caller then computes —, no generalized mode): a caller may then take its step on
        arrays of its own (server/service/local_step.py ``LocalStep.compiled``), telling the model
        with :meth:`count_step`; None otherwise."""
        if self._fused is None or not self._summed or self._yaw is not None \
                or (self.terms and self.linear_damping() is None) or self.n != self.n_rigid:
            return None
        return self._fused

    def linear_damping(self) -> tuple[np.ndarray, np.ndarray] | None:
        """Where the model's one force term is linear viscous damping alone (server/terms/viscous.py
        ``ViscousTerm.linear_only``: reply field ``viscous`` = -B_lin v), (B_lin, the active DOFs'
        positions in the 6N vector); None otherwise."""
        if len(self.terms) != 1 or not isinstance(self.terms[0], ViscousTerm):
            return None
        return self.terms[0].linear_only()

    def count_step(self, k: int) -> None:
        """Step ``k`` (the next, ``k`` = the newest + 1) was taken by :meth:`fused_only`'s kernel
        outside :meth:`step`."""
        if k != self._step + 1:
            raise ModelError("step", f"step {k} taken outside the model after step {self._step}")
        self._step = k

    def _add_term_contributions(self) -> None:
        """The terms' setup contributions (server/terms/base.py) and warnings, in registry order."""
        stiff = False
        pad = (0, self.modes.size)      # a term's (6N, 6N) over the model's vector: zero for the modes
        for term in self.terms:
            if term.added_mass is not None:
                self.added_mass_client = self.added_mass_client + np.pad(term.added_mass, pad)
            if term.stiffness is not None:
                self.hydrostatic_stiffness = self.hydrostatic_stiffness + np.pad(term.stiffness, pad)
                stiff = True
            if term.feedthrough is not None:
                self.radiation_feedthrough = self.radiation_feedthrough + np.pad(term.feedthrough, pad)
            self.warnings.extend(term.warnings)
        if stiff:
            self._k_hs = np.ascontiguousarray(self.hydrostatic_stiffness[np.ix_(self._idx, self._idx)])

    def _frequency_range(self, groups: list[tuple[xr.Dataset, list[int]]]) -> tuple[float, float]:
        """The frequencies the waves may use: the HDBs' common range; without any HDB (Morison-only
        bodies) the whole axis for regular waves and 0.2-5 times the peak frequency for irregular
        ones (unless waves.omega_range says otherwise; the energy left out is reported)."""
        if groups:
            return (max(float(ds["omega"].values[0]) for ds, _ in groups),
                    min(float(ds["omega"].values[-1]) for ds, _ in groups))
        waves = self.scene.waves
        if getattr(waves, "type", "") == "irregular":
            return 0.2 * 2 * math.pi / waves.tp, 5.0 * 2 * math.pi / waves.tp
        return 1e-9, math.inf

    def _group_data(self, ds: xr.Dataset, members: list[int]) -> _GroupData:
        """The group's bodies from its HDB, checked against the scene's depth."""
        water = self.scene.water
        src = ds.attrs.get("source", "?")
        depth = float(ds.attrs["water_depth"])
        if not (depth == water.depth_m or (math.isfinite(depth) and math.isfinite(water.depth_m)
                                           and math.isclose(depth, water.depth_m, rel_tol=1e-4))):
            raise ModelError("water.depth", f"{water.depth!r} but the HDB {src!r} (bodies "
                             f"{[self.bodies[k] for k in members]}) was computed for depth {depth}")
        bodies = [self.scene.bodies[self._scene_index[k]] for k in members]
        try:
            sub = select_bodies(ds, [b.hdb_body_name for b in bodies])
        except HDBError as exc:
            raise ModelError(f"bodies[{self._scene_index[members[0]]}].hdb_body", str(exc)) from None
        self.warnings.extend(n for n in hdb_warnings(ds) if n not in self.warnings)   # its reader's
        rho, g = float(ds.attrs["rho"]), float(ds.attrs["g"])
        s_rho = water.density / rho
        s_rg = water.density * water.gravity / (rho * g)
        if s_rho != 1.0 or water.gravity != g:
            note = _water_note(water.density, water.gravity, rho, g, src, s_rho, s_rg)
            if note not in self.warnings:
                self.warnings.append(note)
        self.warnings.extend(self._recorded_body_checks(sub, members, src))
        rows = np.concatenate([self.modes.rows(k) for k in members])
        return _GroupData(members, src, sub, sub["omega"].values.astype(float), s_rho, s_rg, rows)

    def _recorded_body_checks(self, sub: xr.Dataset, members: list[int], src: str) -> list[str]:
        """Setup warnings for a scene body whose mass or centre of gravity differs from what its
        HDB file records (Capytaine's inertia_matrix / center_of_mass): both values, named."""
        notes = []
        for k in members:
            i = self._scene_index[k]
            body = self.scene.bodies[i]
            name = body.hdb_body_name
            if "mass" in sub:
                m = float(sub["mass"].sel(body=name))
                if not math.isclose(body.mass, m, rel_tol=1e-3):
                    notes.append(f"bodies[{i}].mass: the scene's {body.mass:.6g} kg differs from the {m:.6g} kg the "
                                 f"HDB {src!r} records for body {name!r} ({100 * (body.mass / m - 1):+.3g} %); "
                                 "set the scene's mass to the file's if that is not meant")
            if "center_of_mass" in sub and body.center_of_mass is not None:
                c = sub["center_of_mass"].sel(body=name).values
                if np.max(np.abs(np.asarray(body.center_of_mass) - c)) > 1e-3:
                    notes.append(f"bodies[{i}].center_of_mass: the scene's {list(body.center_of_mass)} m differs from "
                                 f"{np.round(c, 6).tolist()} m, the centre of gravity the HDB {src!r} records for body "
                                 f"{name!r}")
        return notes

    def _radiation_group(self, d: _GroupData) -> RadiationGroup:
        """The group's radiation coefficients over its active DOFs, in the scene's density."""
        loc = np.flatnonzero(self._active_dofs[d.rows])  # active, local to this group
        act = d.rows[loc]
        sub = d.data
        inertia = np.zeros(self.n)   # the memory's cut is judged at each DOF's natural frequency too
        for k in d.members:
            body, ref = self.scene.bodies[self._scene_index[k]], self.equilibrium_position[k, :3]
            offset = body.com_or(ref) - ref
            inertia[6 * k:6 * k + 6] = np.diag(rigid_body_mass_matrix(body.mass, body.inertia_matrix, offset))
        inertia[self.modes.n_rigid:] = self.modes.modal_mass
        labels = self.modes.labels()
        return RadiationGroup(
            source=d.source, bodies=tuple(self.bodies[k] for k in d.members), act=act,
            pos=np.searchsorted(self._idx, act),
            labels=tuple(labels[int(g)] for g in act),
            omega=d.omega, added_mass=d.rho_scale * sub["added_mass"].values[:, loc][:, :, loc],
            damping=d.rho_scale * sub["radiation_damping"].values[:, loc][:, :, loc],
            added_mass_inf=(d.rho_scale * sub["added_mass_inf"].values[np.ix_(loc, loc)]
                            if "added_mass_inf" in sub else None),
            inertia=inertia[act], stiffness=np.diag(self.hydrostatic_stiffness)[act])

    def _hydrostatics(self, data: list[_GroupData]) -> None:
        """Hydrostatic plus gravity stiffness over the active DOFs, equilibrium and net buoyancy."""
        n_b = len(self.bodies)
        c_hs, refs = np.zeros((self.n, self.n)), np.zeros((n_b, 3))
        wet_bodies = [self.scene.bodies[i] for i in self._scene_index]
        for k, b in enumerate(wet_bodies):   # Morison-only bodies: the dry body's node
            if not b.wet:
                refs[k] = b.dry_node()
        for d in data:
            refs[d.members] = d.data["reference_point"].values
            c_hs[np.ix_(d.rows, d.rows)] = d.rg_scale * d.data["hydrostatic_stiffness"].values
        # weight: the gravity stiffness of the bodies with an HDB (a Morison-only body's weight is
        # applied by the client, exactly)
        masses = np.array([b.mass if b.wet else 0.0 for b in wet_bodies])
        cogs = np.array([b.com_or(r) for b, r in zip(wet_bodies, refs)], float)
        mask = self._active_dofs
        g = self.scene.water.gravity
        self.hydrostatic_stiffness = np.where(np.outer(mask, mask), total_stiffness(c_hs, masses, cogs, refs, g), 0.0)
        self.equilibrium_position = np.hstack([refs, np.zeros((n_b, 3))])
        self.warnings.extend(structure_file_notes(self.scene, self._scene_index, refs))
        self._k_hs = np.ascontiguousarray(self.hydrostatic_stiffness[np.ix_(self._idx, self._idx)])
        self._x_eq = np.concatenate((self.equilibrium_position.reshape(-1), np.zeros(self.modes.size)))[self._idx]
        self._net_buoyancy = self._buoyancy(data, self.scene.water.density, g, masses)

    def _excitation(self, data: list[_GroupData], lo: float, hi: float,
                    wave_elevation: tuple[np.ndarray, np.ndarray] | None) -> None:
        """Excitation phasors of the wave components, or the excitation IRF kernels per heading
        (``excitation = "convolution"``), and the forcing that sums them each step."""
        scene = self.scene
        require_size("waves.components", "the excitation of every wave component", (self.waves.size, self.n), 16)
        x_comp = np.zeros((self.waves.size, self.n), complex)
        self.excitation = getattr(scene.waves, "excitation", "superposition") if self.waves.kind != "still" \
            else "superposition"
        heads = self.waves.heading_of()
        self._headings = np.unique(heads) if self.waves.kind != "elevation" else np.array([self.waves.direction])
        exc_T = float(getattr(scene.waves, "excitation_irf_duration", 0.0))
        if self.excitation == "convolution":
            require_size("waves.excitation_irf_duration", "the excitation IRF kernels",
                         (self._headings.size, 2 * irf_samples(exc_T, self.dt, at_least=1) + 1, self.n),
                         hint="a shorter excitation_irf_duration or a longer dt")
        kernels = np.zeros((self._headings.size, 2 * irf_samples(exc_T, self.dt, at_least=1) + 1, self.n)) \
            if self.excitation == "convolution" else None
        self._exc_fit = 0.0
        for d in data:
            omega, sub, s_rg, gidx, src = d.omega, d.data, d.rg_scale, d.rows, d.source
            for ih, head in enumerate(self._headings if (self.waves.size or kernels is not None) else ()):
                on = heads == head
                try:
                    if on.any():
                        x_comp[np.ix_(on, gidx)] = s_rg * interpolate_excitation(
                            omega, sub["wave_direction"].values, sub["excitation_force"].values,
                            self.waves.hdb_omega[on], float(head))
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
                    key = (self.waves.heading_key or ("waves.spreading" if self.waves.headings is not None
                                                      else "waves.direction")) if exc.key == "waves.direction" else exc.key
                    why = exc.why
                    if key == "waves.spreading":
                        why += (f" (cos-2s spreading, s = {scene.waves.spreading_s:g}, "
                                f"{scene.waves.spreading_directions} directions: headings "
                                f"{np.round(np.rad2deg(self._headings), 2).tolist()} deg; reduce the spreading or "
                                "give an HDB with headings covering them)")
                    raise ModelError(key, f"{why} (HDB {src!r})") from None
        if self.waves.fit_residual > RESIDUAL_WARNING:      # a sea from gauges the bins do not explain
            self.warnings.append(f"waves.directions: the fitted sea leaves {100 * self.waves.fit_residual:.2g} % of the "
                                 "gauges' records (their variance in the band) unexplained: waves come from directions "
                                 "between or outside the bins; add directions (or gauges to resolve them)")
        if self.waves.energy_outside > 0.01 and scene.waves.omega_range is None:   # irregular only
            self.warnings.append(f"waves: {100 * self.waves.energy_outside:.2g} % of the spectrum's energy lies "
                                 f"outside the HDB range {lo:.3g}-{hi:.3g} rad/s and is left out")

        self.elevation_series = None
        if kernels is not None:
            self._forcing = ConvolutionForcing(kernels[:, :, self._idx], self._eta_source(scene, wave_elevation, hi),
                                               self.dt, float(self.waves.ramp))
        else:
            self._forcing = WaveForcing(self.waves, x_comp[:, self._idx], self._phases)
        self._x_comp = x_comp

    def _passive_yaw(self, data: list[_GroupData]) -> PassiveYaw | None:
        """The passive-yaw bodies' excitation tables (server/sea/passive_yaw.py), None without any;
        refused by ``bodies[i].passive_yaw`` where they cannot be built (excitation by convolution, a
        body whose HDB couples it to others; its drift: server/terms/second_order.py)."""
        scene, bodies = self.scene, []
        for k, i in enumerate(self._scene_index):
            body = scene.bodies[i]
            if not body.passive_yaw:
                continue
            key = f"bodies[{i}].passive_yaw"
            if self.modes.names[k]:
                raise ModelError(key, f"body {body.name!r} has generalized modes {list(self.modes.names[k])}: their "
                                      "excitation is not tabulated by heading; drop passive_yaw for it")
            if self.excitation != "superposition":
                raise ModelError(key, f"needs the excitation summed over wave components; the scene's waves have it "
                                      f"by convolution ({getattr(scene.waves, 'type', '?')} waves, excitation = "
                                      f"{self.excitation!r}): use excitation = \"superposition\"")
            d = next(g for g in data if k in g.members)
            if len(d.members) > 1:
                raise ModelError(key, f"body {body.name!r} interacts hydrodynamically with "
                                      f"{[self.bodies[m] for m in d.members if m != k]} through its HDB {d.source!r}: "
                                      "their coefficients hold one layout, which a turning body changes; set "
                                      "hydro.interaction = \"none\" or give the body an HDB of its own")
            sub = d.data.isel(body=[d.members.index(k)])
            x_hdb = d.rg_scale * sub["excitation_force"].values
            try:
                x_psi = yawed_excitation(d.omega, sub["wave_direction"].values.astype(float), x_hdb, self.waves,
                                         self.waves.wave_numbers(scene.water.gravity, scene.water.depth_m),
                                         sub["reference_point"].values[0], yaw_grid(), key)
            except WaveError as exc:
                raise ModelError(key, exc.why + f" (HDB {d.source!r})") from None
            dofs = np.flatnonzero(self.active[k])
            bodies.append(YawingBody(6 * k + 5, np.searchsorted(self._idx, 6 * k + dofs), dofs, x_psi,
                                     float(body.passive_yaw_filter)))
            if body.passive_yaw_coefficients is None:
                block = slice(6 * k, 6 * k + 6)
                self.warnings.extend(_turning_note(key, body.name, self.hydrostatic_stiffness[block, block],
                                                   self.added_mass_inf[block, block]))
        if not bodies or self.waves.size == 0:    # still water: no excitation to turn
            return None
        return PassiveYaw(self._forcing, bodies, self.dt, f"bodies[{self._scene_index[bodies[0].yaw // 6]}].passive_yaw")

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
                ser = elevation_on_grid(time, eta, self.dt, scene.n_exchanges,
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

    def _check_waves(self) -> None:
        """Waves no steeper than the breaking limit H/lambda = 1/7 (protocol/scene.py ``wave_peaks``:
        a regular wave's height at its period, a sea's significant height at its peak period, each
        system's of a ``sea``, each component's 2a of a component list; lambda by linear dispersion at
        the scene's depth); a warning above half of it, where linear theory loses accuracy."""
        from hydrolink.server.sea.dispersion import wave_number
        peaks = wave_peaks(self.scene.waves)
        if not peaks:
            return
        water = self.scene.water
        periods = np.array([p.period for p in peaks])
        lam = 2 * np.pi / wave_number(2 * np.pi / periods, water.gravity, water.depth_m)
        steep = np.array([p.height for p in peaks]) / lam
        k = int(np.argmax(steep))
        peak, key = peaks[k], peaks[k].height_key
        if steep[k] > BREAKING_STEEPNESS:
            raise ModelError(key, f"{peak.height:g} m at {peak.period:g} s is steeper than the breaking limit: H/lambda = "
                                  f"{steep[k]:.3g} > 1/7 (lambda = {lam[k]:.4g} m): no such wave exists; " + (
                                      f"scale {key} by {(BREAKING_STEEPNESS / steep[k]) ** 2:.3g} or less"
                                      if key.endswith(".density") else
                                      f"use {key} <= {BREAKING_STEEPNESS * lam[k] / peak.per_key:.4g} m")
                             + " (or a longer period)")
        if steep[k] > 0.5 * BREAKING_STEEPNESS:
            self.warnings.append(f"{key}: H/lambda = {steep[k]:.3g} is over half the breaking limit 1/7: linear "
                                 "wave theory and linear forces lose accuracy (steep-wave effects are not modelled)")

    def _buoyancy(self, data: list[_GroupData], rho: float, g: float, masses: np.ndarray) -> list[float | None]:
        """rho g V - m g per wet body (None when the HDB has no displaced volume)."""
        out: list[float | None] = [None] * len(self.bodies)
        for d in data:
            if "displaced_volume" in d.data:
                for k, v in zip(d.members, d.data["displaced_volume"].values):
                    out[k] = float(rho * g * v - masses[k] * g)
        return out

    def setup_info(self) -> Setup:
        """What the client needs to build its side (SPEC §5.1, :class:`~hydrolink.protocol.setup.Setup`):
        matrices in the 6N body-major DOF order over the wet bodies only."""
        rad = self._radiation
        return Setup(
            bodies=tuple(self.bodies), dofs=tuple(DOF_NAMES), active=self.active.copy(),
            added_mass=self.added_mass_client.copy(), added_mass_inf=self.added_mass_inf.copy(),
            added_mass_inf_source=dict(rad.added_mass_inf_source),
            hydrostatic_stiffness=self.hydrostatic_stiffness.copy(),
            equilibrium_position=self.equilibrium_position.copy(),
            net_buoyancy=np.array([0.0 if f is None else f for f in self._net_buoyancy], float),
            dt=float(self.dt),
            interaction=self.interaction, hydro_groups=tuple(tuple(g) for g in self.groups),
            coupled_blocks=int(self.coupled_blocks), radiation_kernel_entries=int(rad.pairs.kept),
            radiation=rad.radiation, radiation_frequency=rad.radiation_frequency,
            irf_samples=int(rad.irf_samples), irf_duration=float(rad.irf_duration),
            irf_fit_error=dict(rad.irf_fit_error), irf_added_mass_error=dict(rad.irf_added_mass_error),
            irf_processing=IRFProcessing(domega=rad.irf_domega, taper=float(rad.irf_taper), tail=str(rad.irf_tail),
                                         tail_exponent=dict(rad.tail_exponent)),
            coupling_tolerance=float(rad.coupling_tolerance),
            radiation_pairs=int(rad.pairs.kept),
            dropped_pair_fraction=float(rad.pairs.dropped_pair_fraction),
            dropped_blocks=int(rad.pairs.blocks_dropped),
            dropped_block_fraction=float(rad.pairs.dropped_block_fraction),
            state_space=None if rad.state_space is None else StateSpaceReport(**rad.state_space),
            wave_components=int(self.waves.size), wave_energy_outside_hdb=float(self.waves.energy_outside),
            ramp=float(self.waves.ramp),
            excitation=self.excitation,
            excitation_irf_duration=(float(self.scene.waves.excitation_irf_duration)
                                     if self.excitation == "convolution" else 0.0),
            excitation_irf_error=float(self._exc_fit),
            wave_headings=tuple(np.rad2deg(self._headings).tolist()) if self.waves.kind != "still" else (),
            wave_energy_by_direction={f"{c:+.0f}": f for c, f in direction_bands(self.waves)},
            elevation_resampled=bool(self.elevation_series.resampled) if self.elevation_series else False,
            elevation_start=float(self.elevation_series.start) if self.elevation_series else 0.0,
            warnings=tuple(self.warnings), last_seq=self.last_seq,
            radiation_feedthrough=self.radiation_feedthrough.copy(),
            modes=self.modes.by_body() or None,
            **self._term_entries())

    def _term_entries(self) -> dict:
        """The setup fields the terms report (``nonlinear``: empty for a linear scene)."""
        entries: dict = {"nonlinear": {}}
        for term in self.terms:
            entries.update(term.setup_entries(tuple(self.bodies)))
        return entries

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

    def radiation_realization(self) -> Realization:
        """The radiation force as one continuous-time linear system over the 6N wet DOFs (states of
        every group stacked; ``rows``/``cols`` in the 6N vector): needs a force object with a
        realisation ("state-space", "constant", "off" or no memory); the convolution has none."""
        parts = []
        for pos, memory in self._memories:
            if not hasattr(memory, "realization"):
                raise ModelError("hydro.radiation", f"{self.radiation!r} has no finite-state realisation; "
                                                    "use \"state-space\"")
            parts.append((self._idx[pos], memory.realization()))
        s = sum(r.a.shape[0] for _, r in parts)
        a, b, c, d = np.zeros((s, s)), np.zeros((s, self.n)), np.zeros((self.n, s)), np.zeros((self.n, self.n))
        rows, cols, k = np.zeros(s, int), np.zeros(s, int), 0
        for dofs, r in parts:
            span = slice(k, k + r.a.shape[0])
            a[span, span], b[span, dofs], c[dofs, span] = r.a, r.b, r.c
            d[np.ix_(dofs, dofs)] += r.d
            rows[span], cols[span] = dofs[r.rows], dofs[r.cols]
            k = span.stop
        return Realization(a, b, c, d, rows, cols)

    def excitation_phasors(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Wave components: omega (n_c,), complex force phasors (n_c, 6N) and elevation phasors
        (n_c,) such that, after the ramp, F_ex(t) = Re(sum_c F_c e^{-i omega_c t}) and likewise the
        elevation at the origin (server/sea/waves.py convention)."""
        c = self.waves.amplitude * np.exp(1j * self.waves.phase)
        return self.waves.omega.copy(), self._x_comp * c[:, None], c

    def state(self) -> tuple:
        """Everything :meth:`step` changes, copied: the newest step's index, the radiation memories,
        the stateful force terms' states and the passive-yaw headings (the rest of the excitation
        and hydrostatics keep none)."""
        memories = self._fused.state() if self._fused is not None else \
            tuple(memory.state() for _, memory in self._memories)
        yaw = self._yaw.state() if self._yaw is not None else None
        return self._step, memories, tuple(term.state() for term in self._stateful), yaw

    def set_state(self, state: tuple) -> None:
        """Back to a :meth:`state` of this model (a session rolled back, SPEC §5.9)."""
        self._step, memories, terms, yaw = state
        if self._yaw is not None:
            self._yaw.set_state(yaw)
        if self._fused is not None:
            self._fused.set_state(memories)
        for (_, memory), saved in zip(self._memories if self._fused is None else (), memories):
            memory.set_state(saved)
        for term, saved in zip(self._stateful, terms):
            term.set_state(saved)

    def _linear_numpy(self, time: float, x: np.ndarray, v: np.ndarray, replace_last: bool, out: np.ndarray) -> float:
        """The linear core's step by numpy (the reference of the compiled one): the excitation,
        radiation and hydrostatic rows of ``out`` (3, N, 6); returns the wave elevation."""
        sel = self._sel
        vs = v[sel]
        red = out.reshape(3, self.n) if self._all_active else self._red
        for pos, memory in self._memories:
            red[1, pos] = memory.push(vs[pos], replace_last)
        red[0], eta = self._forcing(time)
        if self._yaw is not None:
            self._yaw.apply(time, red[0])
        np.dot(self._k_hs, self._x_eq - x[sel], out=red[2])
        if not self._all_active:
            out.reshape(3, self.n)[:, sel] = red
        return eta

    def step(self, time: float, position: np.ndarray, velocity: np.ndarray, *,
             replace_last: bool = False, radiating: bool = True, modal_position: np.ndarray | None = None,
             modal_velocity: np.ndarray | None = None) -> dict:
        """Forces at ``time`` (= k dt) for the state at that time; see the module docstring.

        ``replace_last`` recomputes the newest step with a new state (iterative coupling);
        ``radiating`` False pushes a zero velocity into the radiation memory (the force terms still
        get ``velocity``): a hydrodynamic state that is not the body's at this step (server/hydro_states.py).
        ``modal_position``/``modal_velocity`` (M,): the modes' coordinates (server/modes.py), for a
        session with modes; their forces come back as ``modal_excitation``/``_radiation``/``_hydrostatic``."""
        if replace_last and self._step < 0:
            raise ModelError("step", "replace_last before any step was computed")
        k = self._step if replace_last else self._step + 1
        if abs(time - k * self.dt) > 1e-6 * self.dt + 1e-12 * abs(time):
            raise ModelError("time", f"expected t = {k * self.dt:.9g} (step {k} of dt {self.dt}), got {time!r}")
        x = np.asarray(position, float).reshape(-1)
        v = np.asarray(velocity, float).reshape(-1)
        m = self.n - self.n_rigid   # the generalized modes (ModeLayout.size, without its sum)
        if x.size != self.n_rigid or v.size != self.n_rigid:
            raise ModelError("state", f"position and velocity must be ({len(self.bodies)}, 6), "
                                      f"got {np.shape(position)} and {np.shape(velocity)}")
        if m:
            if modal_position is None or modal_velocity is None or np.size(modal_position) != m \
                    or np.size(modal_velocity) != m:
                raise ModelError("modal_position", f"the session's bodies have {m} generalized modes "
                                 f"{list(self.modes.labels()[self.n_rigid:])}: modal_position and modal_velocity "
                                 f"must be ({m},), got {np.shape(modal_position)} and {np.shape(modal_velocity)}")
            x = np.concatenate((x, np.asarray(modal_position, float).reshape(-1)))
            v = np.concatenate((v, np.asarray(modal_velocity, float).reshape(-1)))
        # the reply's arrays: fresh each step (a reply may be kept, e.g. cached for a retry, and
        # goes out in-process as is), written in place, then made read-only like a frame's arrays
        out = np.zeros(self._reply_shape) if not m else np.zeros(self._rows_shape)
        vr = v if radiating else self._still
        if self._yaw is not None:
            self._yaw.follow(x, replace_last)     # the headings the waves are read at (the compiled step's too)
        if self._fused is not None:
            if self._summed:
                eta = self._fused(time, x, vr, replace_last, out.reshape(self._rows_shape))
            else:
                f_ex, eta_ex = self._forcing(time)
                eta = self._fused(time, x, vr, replace_last, out.reshape(self._rows_shape), f_ex, eta_ex)
        else:
            eta = self._linear_numpy(time, x, vr, replace_last, out)
        self._step = k
        out.flags.writeable = False
        if m:
            rigid, shape, r = out[:, :self.n_rigid], (len(self.bodies), 6), self.n_rigid
            reply = {"excitation": rigid[0].reshape(shape), "radiation": rigid[1].reshape(shape),
                     "hydrostatic": rigid[2].reshape(shape), "wave_elevation": eta,
                     "modal_excitation": out[0, r:], "modal_radiation": out[1, r:], "modal_hydrostatic": out[2, r:]}
        else:
            reply = {"excitation": out[0], "radiation": out[1], "hydrostatic": out[2], "wave_elevation": eta}
        if self.terms:
            pose, rate = x[:self.n_rigid].reshape(-1, 6), v[:self.n_rigid].reshape(-1, 6)
            for term in self.terms:
                for name, f in zip(term.fields, term.force(time, pose, rate)):
                    f.flags.writeable = False
                    reply[name] = f
        return reply


def _turning_note(key: str, name: str, stiffness: np.ndarray, added_mass: np.ndarray) -> list[str]:
    """The setup warning of a passive-yaw body whose hydrostatic stiffness or A-infinity is not
    symmetric about its yaw axis (roll/pitch, surge/sway differ by over 1 %): those stay at the
    initial heading's while the excitation turns (server/sea/passive_yaw.py)."""
    def differ(m: np.ndarray, a: int, b: int) -> bool:
        return abs(m[a, a] - m[b, b]) > 0.01 * max(abs(m[a, a]), abs(m[b, b]), 1e-300)
    if not (differ(stiffness, 3, 4) or differ(added_mass, 0, 1) or differ(added_mass, 3, 4)):
        return []
    return [f"{key}: body {name!r} is not symmetric about its yaw axis (roll/pitch stiffness {stiffness[3, 3]:.4g}/"
            f"{stiffness[4, 4]:.4g}, A-inf surge/sway {added_mass[0, 0]:.4g}/{added_mass[1, 1]:.4g}): its excitation "
            "turns with its yaw but its added mass, radiation damping and hydrostatic stiffness stay those of the "
            "initial heading (as in WEC-Sim): a yaw of more than a few degrees makes its roll, pitch, surge and sway "
            f"dynamics approximate; state {key.replace('passive_yaw', 'passive_yaw_coefficients')} = "
            "\"initial-heading\" to accept it"]


def _water_note(density: float, gravity: float, rho: float, g: float, src: str, s_rho: float, s_rg: float) -> str:
    """The setup warning for a scene whose water differs from an HDB's: it names only the values
    that differ (and the keys to set); a value both share is said as shared."""
    pairs = (("density", density, rho, "kg/m^3"), ("gravity", gravity, g, "m/s^2"))
    differ = [p for p in pairs if p[1] != p[2]]
    shared = "".join(f"; {k} {mine:g} {unit} in both" for k, mine, theirs, unit in pairs if mine == theirs)
    keys = " and ".join(k for k, *_ in differ)
    mine = " and ".join(f"{k} {v:g} {unit}" for k, v, _, unit in differ)
    theirs = ", ".join(f"{t:g} {unit}" for _, _, t, unit in differ)
    one = len(differ) == 1
    return (f"water: the scene's {mine} {'differs' if one else 'differ'} from the HDB {src!r} ({theirs}{shared}): "
            f"its added mass and radiation damping are scaled by {s_rho:.6g}, its excitation and hydrostatic "
            f"stiffness by {s_rg:.6g}; set [water] {keys} to the HDB's {'value' if one else 'values'} if that is "
            f"not meant")
