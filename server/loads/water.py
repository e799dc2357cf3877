"""The water's linear wave and radiation loads on parts of a body over a run, from the panel pressures
of its HDB build (server/hdb/build/panels.py): any R linear functionals of the panels' pressure (a
part's force and moment: sections.py; each panel's own pressure: pressures.py) made into their own
excitation and radiation coefficients, then summed over the model's wave components and convolved with
the recorded velocity through the model's own IRF stage (server/radiation/options.py)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from hydrolink.protocol.scene import Scene
from hydrolink.server.allocation import require_size
from hydrolink.server.errors import ModelError
from hydrolink.server.hdb.build.panels import PanelPressures
from hydrolink.server.radiation.options import RadiationGroup, interp_matrix, radiation_option
from hydrolink.server.sea.headings import interpolate_excitation
from hydrolink.server.sea.waves import WaveComponents, WaveError, ramp_factor


@dataclass(frozen=True)
class RecordedMotion:
    """One body's recorded rows: times (T,), displacement from equilibrium, velocity, acceleration (T, 6)."""
    time: np.ndarray
    displacement: np.ndarray
    velocity: np.ndarray
    acceleration: np.ndarray


def recorded_motion(time: np.ndarray, position: np.ndarray, velocity: np.ndarray, equilibrium: np.ndarray,
                    ) -> RecordedMotion:
    """The rows of one body with its acceleration by central differences (second order, one-sided at the ends)."""
    return RecordedMotion(time, position - equilibrium, velocity, np.gradient(velocity, time, axis=0, edge_order=2))


@dataclass(frozen=True)
class LinearRows:
    """R linear functionals of the panels' pressure as coefficients of the body's motion and the waves:
    value = W p for weights W (R, P); p's radiation part -a x'' - b x' (per frequency), its wave part e."""
    excitation: np.ndarray       # (W, D, R) complex, per unit wave amplitude
    added_mass: np.ndarray       # (W, R, n)
    damping: np.ndarray          # (W, R, n)
    added_mass_inf: np.ndarray   # (R, n)


def linear_rows(ps: PanelPressures, weights: np.ndarray | None) -> LinearRows:
    """The rows of ``weights`` (R, P) over the panel set; None: each panel's own pressure (R = P)."""
    if weights is None:
        return LinearRows(ps.excitation, ps.added_mass.transpose(0, 2, 1), ps.damping.transpose(0, 2, 1),
                          ps.added_mass_inf.T)
    return LinearRows(np.einsum("rp,wdp->wdr", weights, ps.excitation), np.einsum("rp,wnp->wrn", weights, ps.added_mass),
                      np.einsum("rp,wnp->wrn", weights, ps.damping), weights @ ps.added_mass_inf.T)


def water_series(rows: LinearRows, ps: PanelPressures, motion: RecordedMotion, scene: Scene, waves: WaveComponents,
                 body: str) -> np.ndarray:
    """(T, R) the rows' wave and radiation part over the recorded rows: the model's components and ramp,
    and its radiation option ("constant": -a(w0) x'' - b(w0) x'; "off": -a_inf x''; else -a_inf x''
    minus the memory of the IRF made as the model makes it, at the rows' spacing); scaled from the
    build's water to the scene's."""
    rho_scale = scene.water.density / ps.rho
    rg_scale = rho_scale * scene.water.gravity / ps.g
    t = motion.time
    dt = float(np.median(np.diff(t))) if t.size > 1 else scene.exchange_dt
    require_size("bodies.sections", "the water's loads over the run", (t.size, rows.added_mass_inf.shape[0]))
    try:
        out = _excitation(rows, ps, waves, t, rg_scale)
    except WaveError as exc:
        raise ModelError(exc.key, f"{exc.why} (the panel pressures of {ps.source})") from None
    return out - _radiation(rows, ps, motion, radiation_option(scene.hydro, scene.waves, dt), rho_scale, dt, body)


def _excitation(rows: LinearRows, ps: PanelPressures, waves: WaveComponents, t: np.ndarray, scale: float,
                ) -> np.ndarray:
    """(T, R) the rows' wave part (the model's components, phases and ramp)."""
    out = np.zeros((t.size, rows.excitation.shape[2]))
    if waves.size == 0:
        return out
    heads = waves.heading_of()
    c = waves.amplitude * np.exp(1j * waves.phase)
    for head in np.unique(heads):
        on = heads == head
        x = interpolate_excitation(ps.omega, ps.wave_direction, rows.excitation, waves.hdb_omega[on], float(head))
        out += np.real((np.exp(-1j * np.outer(t, waves.omega[on])) * c[on]) @ x)
    return scale * ramp_factor(t, waves.ramp)[:, None] * out


def _convolve(kernel: np.ndarray, v: np.ndarray, dt: float) -> np.ndarray:
    """dt sum_j w_j K_j v_{n-j} (trapezoid weights as RadiationMemory's): (M+1, R, n) x (T, n) -> (T, R)."""
    m = kernel.shape[0]
    w = np.ones(m)
    w[0] = w[-1] = 0.5
    size = v.shape[0] + m - 1
    k_f = np.fft.rfft(kernel * (dt * w)[:, None, None], size, axis=0)
    v_f = np.fft.rfft(v, size, axis=0)
    return np.fft.irfft(np.einsum("frn,fn->fr", k_f, v_f), size, axis=0)[:v.shape[0]]


def _radiation(rows: LinearRows, ps: PanelPressures, motion: RecordedMotion, option, scale: float, dt: float,
               body: str) -> np.ndarray:
    """(T, R) minus the rows' radiation part: a x'' + the memory (or b(w0) x')."""
    n = rows.added_mass_inf.shape[1]
    acc, vel = motion.acceleration[:, :n], motion.velocity[:, :n]
    if option.name == "constant":
        w0 = option.radiation_frequency
        return scale * (acc @ interp_matrix(ps.omega, rows.added_mass, w0).T
                        + vel @ interp_matrix(ps.omega, rows.damping, w0).T)
    out = scale * acc @ rows.added_mass_inf.T
    if option.name == "off" or option.samples == 0:
        return out
    require_size("hydro.irf_duration", "the IRF of the loads' rows", (option.samples + 1, *rows.added_mass_inf.shape))
    group = RadiationGroup(source=ps.source, bodies=(body,), act=np.arange(n), pos=np.arange(n), labels=ps.dofs,
                           omega=ps.omega, added_mass=scale * rows.added_mass, damping=scale * rows.damping,
                           added_mass_inf=scale * rows.added_mass_inf)
    return out + _convolve(option.irf(group).kernel, vel, dt)
