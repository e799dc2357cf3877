"""WECCCOMP's WaveStar (examples/wavestar): the float on its arm, hinged to ground at A, the HDB read
from the WAMIT report alone (examples/data/wavestar/wavestar.out).

Free decay of the arm's rotation against the one-DOF hinge model written here from the HDB: about
the hinge axis through A = (-0.438, 0, 0.302), a rotation th moves the float's HDB reference point
O by th (dz, 0, -dx) (d = O - A) and turns it by th, so T = (dz, 0, -dx, 0, 1, 0) and

    I_A = I_float + m_f |c_f - A|^2 + I_arm + m_a |c_a - A|^2      (pitch inertias, parallel axes)
    A_inf = T'A_inf T, B(w) = T'B(w)T                                (about A)
    K_A = T'C T + rho g V dz - m_f g (z_cf - z_A) - m_a g (z_ca - z_A)

(C the HDB's buoyancy-and-waterplane stiffness about O: its transfer to A is T'CT plus the
buoyancy's own moment arm, rho g V dz; each weight's is -m g (z_c - z_A)); b = 1.8 N m s/rad, the
float's linear pitch damping.

- Without radiation memory ([hydro] radiation = "off") the decay is the oscillator
  (I_A + A_inf) th'' + b th' + K_A th = 0: its damped period, within 1 %.
- With the scene's state-space radiation the float is heavily damped (B(w_n) ~ 2.8 N m s/rad,
  zeta ~ 0.2) and its added mass falls from 0.80 to 0.47 kg m^2 between 4 and 10 rad/s, so no
  single-frequency formula gives the period to 2 % (A(w_n) gives 0.76 s, A_inf 0.74 s; the decay
  runs at 0.82 s). The reference integrates the same equation with the radiation memory written
  here, (I_A + A_inf) th'' + b th' + int_0^2s K(t) th'(t - s) ds + K_A th = 0,
  K(t) = (2/pi) int B(w) cos(wt) dw (the scene's 2 s of memory and its taper): its period, within 2 %.

The WAPPAC adapter (clients/control.py, WappacController): examples/wavestar/wappac_damping.py, which only defines
``my_controller(x, v, t, eta10)``, run by ``hydrolink control`` in its own process against the
scene: the PTO force of each step is the damper's c v of the velocity measured the step before.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
import xarray as xr

from hydrolink.clients.control import ControllerError, load_controller
from hydrolink.clients.run import run_scene_file
from hydrolink.server.hdb.io import load_hdb

from conftest import REPLY_S, controller_process

REPO = Path(__file__).resolve().parents[1]
EXAMPLE = REPO / "examples" / "wavestar"
HDB = REPO / "examples" / "data" / "wavestar" / "wavestar.out"
HINGE = np.array([-0.438, 0.0, 0.302])
FLOAT_MASS, FLOAT_COM, FLOAT_IYY = 3.075, np.array([0.001292, 0.0, 0.0533]), 0.00145
ARM_MASS, ARM_COM, ARM_IYY = 1.157, np.array([-0.3301, 0.0, 0.2551]), 0.0606
PITCH_DAMPING = 1.8
RHO, G = 1000.0, 9.80665


@dataclass(frozen=True)
class Hinge:
    """The arm's rotation about A as one DOF (module docstring)."""
    inertia: float
    added_mass_inf: float
    stiffness: float
    omega: np.ndarray
    damping: np.ndarray

    def period_without_memory(self) -> float:
        mass = self.inertia + self.added_mass_inf
        w = np.sqrt(self.stiffness / mass)
        return 2 * np.pi / (w * np.sqrt(1 - (PITCH_DAMPING / (2 * w * mass)) ** 2))

    def decay_with_memory(self, theta: float, dt: float, duration: float, memory: float = 2.0,
                          taper: float = 0.3) -> tuple:
        """(time, pitch rate) of the decay with radiation memory: Newmark average acceleration, the
        memory K(t) = (2/pi) int B(w) cos(wt) dw (trapezoids over the HDB's w, B(0) = 0) times the
        scene's cosine taper (1, then 1/2 (1 + cos) over the last ``taper`` of ``memory``), summed
        by trapezoids over the last ``memory`` s, its current-velocity term implicit."""
        lags = np.arange(int(round(memory / dt)) + 1) * dt
        om, b = np.r_[0.0, self.omega], np.r_[0.0, self.damping]
        start = (1 - taper) * memory           # the scene's cosine taper over the memory's last part
        window = np.ones_like(lags) if taper == 0 else np.where(
            lags < start, 1.0, 0.5 * (1 + np.cos(np.pi * (np.maximum(lags, start) - start) / (memory - start))))
        kernel = 2 / np.pi * np.trapezoid(b * np.cos(np.outer(lags, om)), om, axis=1) * window * dt
        kernel[-1] *= 0.5
        mass, k = self.inertia + self.added_mass_inf, self.stiffness
        c = PITCH_DAMPING + 0.5 * kernel[0]
        n = int(round(duration / dt))
        v = np.zeros(n + 1 + lags.size)            # velocities, zeros before t = 0
        x, a = theta, -k * theta / mass
        for i in range(n):
            past = v[i + 2:lags.size + i + 1][::-1]      # v_i, v_(i-1), ..., v_(i+1-J)
            history = kernel[1:] @ past
            v_star, x_star = v[lags.size + i] + 0.5 * dt * a, x + dt * v[lags.size + i] + 0.25 * dt * dt * a
            a = -(c * v_star + k * x_star + history) / (mass + 0.5 * dt * c + 0.25 * dt * dt * k)
            v[lags.size + i + 1] = v_star + 0.5 * dt * a
            x = x_star + 0.25 * dt * dt * a
        return np.arange(n + 1) * dt, v[lags.size:]


@functools.lru_cache(maxsize=1)
def wavestar_hdb():
    return load_hdb(HDB, rho=RHO)


def hinge_model() -> Hinge:
    h = wavestar_hdb()
    d = h.reference_point.values[0] - HINGE
    t = np.array([d[2], 0.0, -d[0], 0.0, 1.0, 0.0])
    inertia = (FLOAT_IYY + FLOAT_MASS * np.sum((FLOAT_COM - HINGE)[[0, 2]] ** 2)
               + ARM_IYY + ARM_MASS * np.sum((ARM_COM - HINGE)[[0, 2]] ** 2))
    stiffness = (t @ h.hydrostatic_stiffness.values @ t + RHO * G * float(h.displaced_volume[0]) * d[2]
                 - FLOAT_MASS * G * (FLOAT_COM[2] - HINGE[2]) - ARM_MASS * G * (ARM_COM[2] - HINGE[2]))
    return Hinge(float(inertia), float(t @ h.added_mass_inf.values @ t), float(stiffness), h.omega.values,
                 np.einsum("i,wij,j->w", t, h.radiation_damping.values, t))


def released(theta: float, point: np.ndarray) -> list[float]:
    """The displacement of a body point (and pitch) when the arm is turned by ``theta`` about A."""
    c, s = np.cos(theta), np.sin(theta)
    r = point - HINGE
    moved = np.array([c * r[0] + s * r[2], r[1], -s * r[0] + c * r[2]])
    return [*(moved - r).tolist()[:3], 0.0, theta, 0.0]


def decay_scene(tmp_path: Path, theta: float, dt: float, duration: float, radiation: str = "state-space") -> Path:
    text = (EXAMPLE / "wavestar_passive.toml").read_text()
    h = wavestar_hdb()
    start = {"float": released(theta, h.reference_point.values[0]), "arm": released(theta, ARM_COM)}
    waves = text[text.index("[waves]"):text.index("[hydro]")]
    for a, b in ((waves, '[waves]\ntype = "still"\n\n'), ("dt = 0.001 ", f"dt = {dt} "),
                 ("duration = 141.2 ", f"duration = {duration} "), ("progress = true", "progress = false"),
                 ('"../data/wavestar/wavestar.out"', f'"{HDB.as_posix()}"'),
                 ("damping = 400.0 ", "damping = 0.0 "), ('radiation = "state-space"', f'radiation = "{radiation}"'),
                 ('name = "float"\n', f'name = "float"\ninitial_displacement = {start["float"]}\n'),
                 ('name = "arm"  ', f'initial_displacement = {start["arm"]}\nname = "arm"  ')):
        assert a in text, a
        text = text.replace(a, b)
    path = tmp_path / f"decay_{radiation}.toml"
    path.write_text(text)
    return path


def decay_period(scene: Path, out: Path) -> tuple[float, np.ndarray]:
    """The decay's period from the arm's pitch rate (its zero crossings, interpolated: peaks and
    troughs, which a static offset does not move) and the pitch angle."""
    run_scene_file(scene, out, progress=False)
    ds = xr.load_dataset(out)
    return rate_period(ds.time.values, ds.velocity.sel(body="arm", dof="pitch").values), \
        ds.position.sel(body="arm", dof="pitch").values


def rate_period(t: np.ndarray, rate: np.ndarray) -> float:
    """Twice the mean spacing of the rate's first 5 zero crossings after t = 0 (linearly
    interpolated; two periods, while the motion is well above round-off)."""
    k = np.flatnonzero((np.sign(rate[1:]) != np.sign(rate[:-1])) & (t[:-1] > 0))[:5]
    crossings = t[k] - rate[k] * (t[k + 1] - t[k]) / (rate[k + 1] - rate[k])
    assert len(crossings) == 5
    return (crossings[-1] - crossings[0]) / 2


def test_free_decay_period_about_the_hinge(tmp_path):
    hinge = hinge_model()
    plain = decay_scene(tmp_path, theta=0.03, dt=0.005, duration=2.4, radiation="off")
    period, angle = decay_period(plain, tmp_path / "plain.nc")
    assert abs(period - hinge.period_without_memory()) < 0.01 * period, (period, hinge.period_without_memory())
    assert abs(angle[0] - 0.03) < 1e-9
    scene = decay_scene(tmp_path, theta=0.03, dt=0.005, duration=2.4)
    period, angle = decay_period(scene, tmp_path / "memory.nc")
    reference = rate_period(*hinge.decay_with_memory(0.03, 0.005, 2.4))
    assert abs(period - reference) < 0.02 * reference, (period, reference)
    assert np.ptp(angle[-len(angle) // 5:]) < 0.2 * np.ptp(angle[: len(angle) // 5])


def test_wappac_signature_loads_as_a_controller():
    controller = load_controller(EXAMPLE / "wappac_damping.py")
    info = {"name": "wappac", "ptos": ["pto"], "command": "force",
            "measurements": ["pto_displacement", "pto_velocity"]}
    with pytest.raises(ControllerError) as err:
        controller.on_start(info)
    assert "wave_elevation" in str(err.value) and "measurements" in str(err.value)
    controller.on_start({**info, "measurements": [*info["measurements"], "wave_elevation"]})
    controller.ptos = ["pto"]
    m = {"pto_displacement": np.array([0.01]), "pto_velocity": np.array([0.02]), "wave_elevation": np.array([0.0])}
    assert controller.on_step(1.0, m) == {"pto": pytest.approx(400.0 * 0.02)}


def test_wappac_controller_process_drives_the_pto(tmp_path, server):
    token = "wavestar-test-token-" + "x" * 16
    text = (EXAMPLE / "wavestar.toml").read_text()
    for a, b in (("duration = 141.2 ", "duration = 0.3 "), ("progress = true", "progress = false"),
                 ('"../data/wavestar/wavestar.out"', f'"{HDB.as_posix()}"'), ("timeout = 0.05 ", "timeout = 10.0 ")):
        assert a in text, a
        text = text.replace(a, b)
    scene = tmp_path / "wavestar.toml"
    scene.write_text(text)
    with controller_process(EXAMPLE / "wappac_damping.py", server, token) as ended:
        run_scene_file(scene, tmp_path / "out.nc", server=server, progress=False, timeout=REPLY_S, control_token=token)
    assert ended.returncode == 0, ended.stderr
    ds = xr.load_dataset(tmp_path / "out.nc")
    force = ds.pto_force.sel(pto="pto").values
    velocity = ds.pto_velocity.sel(pto="pto").values
    # latency 1: the command from the measurements at t_k acts over t_k -> t_k+1 (recorded at k+1)
    np.testing.assert_allclose(force[2:], 400.0 * velocity[1:-1], rtol=1e-9, atol=1e-12)
    assert np.all(force[2:] * velocity[1:-1] >= 0.0) and np.any(force != 0.0)
