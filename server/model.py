"""The per-session force model: excitation, radiation memory and hydrostatics for a scene.

Bodies that share one HDB dataset (the same object in ``hdbs``) keep their body-to-body blocks;
bodies from different datasets do not interact hydrodynamically. Every matrix is reduced to the
active DOFs once at setup, so a step is three small matvecs and no Python loop over DOFs/bodies.
"""

from __future__ import annotations

import math

import numpy as np
import xarray as xr

from hydrolink.protocol.scene import Scene
from hydrolink.server.hdb.schema import DOF_NAMES, HDBError, select_bodies
from hydrolink.server.hydrostatics import total_stiffness
from hydrolink.server.irf import aliasing_time, irf_report, ogilvie_added_mass_inf, radiation_irf
from hydrolink.server.radiation import RadiationMemory
from hydrolink.server.waves import WaveError, WaveForcing, interpolate_excitation, wave_components

OGILVIE_DEFAULT_DURATION = 40.0  # s of IRF used for Ogilvie's A_inf when hydro.irf_duration = 0


class ModelError(ValueError):
    """A scene/HDB combination the model cannot run; the message names the scene key and why."""

    def __init__(self, key: str, why: str):
        self.key, self.why = key, why
        super().__init__(f"{key}: {why}")


def _groups(scene: Scene, hdbs: dict[str, xr.Dataset]) -> list[tuple[xr.Dataset, list[int]]]:
    """Scene bodies grouped by shared dataset (a repeated HDB body starts a new group)."""
    groups: list[tuple[xr.Dataset, list[int]]] = []
    for i, body in enumerate(scene.bodies):
        if body.name not in hdbs:
            raise ModelError(f"bodies[{i}].hdb", f"no HDB loaded for body {body.name!r}")
        ds = hdbs[body.name]
        names = [str(b) for b in ds["body"].values]
        if body.hdb_body_name not in names:
            key = f"bodies[{i}].hdb_body" if body.hdb_body else f"bodies[{i}].name"
            raise ModelError(key, f"the HDB {ds.attrs.get('source', '?')!r} has no body "
                                  f"{body.hdb_body_name!r} (it holds {names})")
        for gds, members in groups:
            if gds is ds and body.hdb_body_name not in [scene.bodies[k].hdb_body_name for k in members]:
                members.append(i)
                break
        else:
            groups.append((ds, [i]))
    return groups


class HydroModel:
    """Linear potential-flow forces for one session (see module docstring)."""

    def __init__(self, scene: Scene, hdbs: dict[str, xr.Dataset]):
        self.scene = scene
        self.bodies = [b.name for b in scene.bodies]
        n_b = len(self.bodies)
        self.n = 6 * n_b
        self.dt = float(scene.simulation.dt)
        self.active = np.array([b.active_mask for b in scene.bodies], bool)  # (N, 6)
        self._idx = np.flatnonzero(self.active.reshape(-1))
        na = self._idx.size
        water = scene.water
        rho, g = water.density, water.gravity
        irf_T = float(scene.hydro.irf_duration)
        self.irf_samples = int(round(irf_T / self.dt))
        m_og = self.irf_samples if self.irf_samples > 0 else int(round(OGILVIE_DEFAULT_DURATION / self.dt))
        t_irf = np.arange(m_og + 1) * self.dt
        self.warnings: list[str] = []

        a_inf = np.zeros((self.n, self.n))
        c_hs = np.zeros((self.n, self.n))
        kernel = np.zeros((m_og + 1, na, na))
        refs = np.zeros((n_b, 3))
        self._a_inf_source: dict[str, str] = {}
        self._irf_fit: dict[str, float] = {}
        groups = _groups(scene, hdbs)
        lo = max(float(ds["omega"].values[0]) for ds, _ in groups)
        hi = min(float(ds["omega"].values[-1]) for ds, _ in groups)
        if lo >= hi:
            raise ModelError("bodies", f"the bodies' HDB frequency ranges do not overlap ({lo}..{hi} rad/s)")
        try:
            self.waves = wave_components(scene.waves, lo, hi)
        except WaveError as exc:
            raise ModelError(exc.key, exc.why) from None
        x_comp = np.zeros((self.waves.size, self.n), complex)

        for ds, members in groups:
            src = ds.attrs.get("source", "?")
            depth = float(ds.attrs["water_depth"])
            if not (depth == water.depth_m or (math.isfinite(depth) and math.isfinite(water.depth_m)
                                               and math.isclose(depth, water.depth_m, rel_tol=1e-4))):
                raise ModelError("water.depth", f"{water.depth!r} but the HDB {src!r} (bodies "
                                 f"{[self.bodies[k] for k in members]}) was computed for depth {depth}")
            try:
                sub = select_bodies(ds, [scene.bodies[k].hdb_body_name for k in members])
            except HDBError as exc:
                raise ModelError(f"bodies[{members[0]}].hdb_body", str(exc)) from None
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
            k = radiation_irf(omega, bd, t_irf)
            if self.irf_samples > 0:
                kernel[np.ix_(np.arange(m_og + 1), pos, pos)] = k
            if "added_mass_inf" in sub:
                a_inf[np.ix_(act, act)] = s_rho * sub["added_mass_inf"].values[np.ix_(loc, loc)]
                how = "hdb"
            else:
                a_inf[np.ix_(act, act)] = ogilvie_added_mass_inf(omega, am, t_irf, k)
                how = "ogilvie"
            for k_ in members:
                self._a_inf_source[self.bodies[k_]] = how
            if self.irf_samples > 0 and loc.size:
                rep = irf_report(omega, bd, t_irf, k)
                self._irf_fit[src] = rep["worst"]
                if irf_T > aliasing_time(omega):
                    self.warnings.append(f"hydro.irf_duration: {irf_T} s exceeds pi/d_omega = "
                                         f"{aliasing_time(omega):.3g} s of {src!r}: the IRF tail is aliased")
            if self.waves.size:
                try:
                    x_comp[:, gidx] = s_rg * interpolate_excitation(
                        omega, sub["wave_direction"].values, sub["excitation_force"].values,
                        self.waves.omega, self.waves.direction)
                except WaveError as exc:
                    raise ModelError(exc.key, f"{exc.why} (HDB {src!r})") from None
        if self.waves.energy_outside > 0.01:
            self.warnings.append(f"waves: {100 * self.waves.energy_outside:.2g} % of the spectrum's energy lies "
                                 f"outside the HDB range {lo:.3g}-{hi:.3g} rad/s and is left out")

        masses = np.array([b.mass for b in scene.bodies])
        cogs = np.array([b.center_of_mass for b in scene.bodies], float)
        mask = self.active.reshape(-1)
        keep = np.outer(mask, mask)
        self.added_mass_inf = np.where(keep, a_inf, 0.0)
        self.hydrostatic_stiffness = np.where(keep, total_stiffness(c_hs, masses, cogs, refs, g), 0.0)
        self.equilibrium_position = np.hstack([refs, np.zeros((n_b, 3))])
        self._k_hs = np.ascontiguousarray(self.hydrostatic_stiffness[np.ix_(self._idx, self._idx)])
        self._x_eq = self.equilibrium_position.reshape(-1)[self._idx].copy()
        self._memory = RadiationMemory(kernel[:self.irf_samples + 1], self.dt)
        self._forcing = WaveForcing(self.waves, x_comp[:, self._idx])
        self._step = -1           # index of the newest step pushed
        self._sel = slice(None) if na == self.n else self._idx  # a view when every DOF is active
        self._red = np.zeros((3, na))  # scratch: excitation, radiation, hydrostatic (active DOFs)
        self._net_buoyancy = self._buoyancy(hdbs, groups, rho, g, masses)

    def _buoyancy(self, hdbs, groups, rho, g, masses) -> list[float | None]:
        """rho g V - m g per body (None when the HDB has no displaced volume)."""
        out: list[float | None] = [None] * len(self.bodies)
        for ds, members in groups:
            if "displaced_volume" in ds:
                vol = ds["displaced_volume"].sel(body=[self.scene.bodies[k].hdb_body_name for k in members]).values
                for k, v in zip(members, vol):
                    out[k] = float(rho * g * v - masses[k] * g)
        return out

    def setup_info(self) -> dict:
        """What the client needs to build its side (matrices in the 6N body-major DOF order)."""
        return {
            "bodies": list(self.bodies),
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
        }

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
        red[1] = self._memory.push(v[sel], replace_last)
        red[0], eta = self._forcing(time)
        np.dot(self._k_hs, self._x_eq - x[sel], out=red[2])
        self._step = k
        out = np.zeros((3, len(self.bodies), 6))
        out.reshape(3, self.n)[:, sel] = red
        return {"excitation": out[0], "radiation": out[1], "hydrostatic": out[2], "wave_elevation": eta}
