"""The radiated and diffracted waves of any run, from the HDB build's ``[free_surface]`` solution on
a grid of frequencies (server/hdb/build/free_surface.py): an irregular or directional sea, several
components, a regular wave between the stored frequencies, motions that are not sinusoidal.

Radiation, from the bodies' velocity history through the radiated-elevation impulse response (as
the radiation force's memory). With H(x, w) = i eta_R,dof(x, w) / w the elevation per unit
*velocity* amplitude of a DOF (eta_R per unit motion; v = -i w xi in exp(-i w t)),

    eta_R(x, t) = sum_dof int K(x, tau) v_dof(t - tau) dtau,   K(x, tau) = (1/pi) Re int_0^inf H(x, w) e^{-i w tau} dw,

K the exact transform of H continued piecewise-linearly as the excitation IRF continues X
(server/sea/waves.py: to Re H(w_1) at w = 0 and to 0 at 1.1 w_n), sampled at the file's row step
every q-th row (q the largest with 40 samples a period of 1.1 w_n) over |tau| <= ``hydro.irf_duration`` (both sides: the tail before tau = 0 is what the truncated
frequency band leaves; the results file holds the future rows), the sum the trapezoid rule.
Velocities before the first row and after the last are zero: the first and last
``hydro.irf_duration`` seconds of a run carry that start-up.

Diffraction, per incident component c (heading b_c, one of the build's ``[waves] directions``):

    eta_D(x, t) = r(t) Re sum_c a_c e^{i phi_c} eta_D(x; w_c, b_c) e^{-i w_c t},

eta_D per unit incident amplitude interpolated linearly in w between the stored frequencies;
components outside them are left out (a note gives their share of the variance)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from hydrolink.clients.view.results import RunFile, read_rows
from hydrolink.clients.view.surface import PhasorField
from hydrolink.server.allocation import require_size
from hydrolink.server.radiation.irf import irf_samples
from hydrolink.server.sea.waves import WaveComponents, convolution_kernel

KERNEL_BLOCK_BYTES = 32 << 20   # the kernel's transform is computed this many bytes of columns at a time
SAMPLES_PER_PERIOD = 40         # the kernel's step: at most this fraction of the period of its top frequency


@dataclass
class ConvolvedField:
    """``kernel`` (2M+1, B 6, P): h-weighted samples of K at tau_j = j h, j = -M..M, h = ``step``
    rows of the file, for the DOFs of the results' bodies ``rows``; ``diffraction`` the diffracted
    field over the components."""
    rows: np.ndarray
    kernel: np.ndarray
    step: int
    diffraction: PhasorField
    _v: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))   # the block's velocities, rows +- M
    _first: int = 0                                                    # the row of _v[0]
    _chunk: np.ndarray = field(default_factory=lambda: np.zeros(0, int))

    @property
    def half(self) -> int:
        return (self.kernel.shape[0] - 1) // 2

    def prepare(self, run: RunFile, chunk: np.ndarray) -> None:
        """Read the velocities the frames at ``chunk`` convolve (zero outside the file)."""
        m = self.half * self.step
        lo, hi = int(chunk[0]) - m, int(chunk[-1]) + m + 1
        a, b = max(lo, 0), min(hi, run.time.size)
        vel = read_rows(run.path, ["velocity"], np.arange(a, b))["velocity"][:, self.rows].reshape(b - a, -1)
        self._v = np.zeros((hi - lo, vel.shape[1]))
        self._v[a - lo:b - lo] = vel
        self._first, self._chunk = lo, chunk

    def at(self, k: int, t: float) -> dict[str, np.ndarray]:
        """The radiated and diffracted elevation (P,) of the block's ``k``-th frame at time ``t``."""
        m, q, row = self.half, self.step, int(self._chunk[k])
        s = row - m * q - self._first
        window = self._v[s:s + 2 * m * q + 1:q][::-1]      # window[i] = v(row + (m - i) q): tau = (i - m) h
        radiated = np.tensordot(window, self.kernel, axes=([0, 1], [0, 1]))
        return {"radiated": radiated, "diffracted": self.diffraction(t)}


def kernel_step(omega: np.ndarray, dt: float) -> int:
    """Rows between the kernel's samples: the most with SAMPLES_PER_PERIOD samples a period of the
    transform's top frequency 1.1 w_n (at least 1)."""
    return max(1, int(2 * np.pi / (SAMPLES_PER_PERIOD * 1.1 * float(omega[-1])) / dt))


def radiation_kernel(omega: np.ndarray, radiated: np.ndarray, dt: float, duration: float) -> np.ndarray:
    """The dt-weighted samples (2M+1, B 6, P) of K at the step ``dt`` from the elevation per unit
    motion ``radiated`` (n_w, B, 6, P) at the frequencies ``omega`` (n_w >= 2); size checked first."""
    n_w, n_b, _, n_p = radiated.shape
    m = irf_samples(duration, dt, at_least=1)
    require_size("[free_surface] cells", "the radiated-wave impulse response (samples x DOFs x grid points)",
                 (2 * m + 1, 6 * n_b, n_p), hint="fewer cells, a shorter hydro.irf_duration or a larger --stride")
    per_velocity = (1j * radiated / omega[:, None, None, None]).reshape(n_w, -1)
    out = np.empty((2 * m + 1, per_velocity.shape[1]))
    step = max(1, KERNEL_BLOCK_BYTES // (16 * (2 * m + 1)))
    for c in range(0, per_velocity.shape[1], step):
        out[:, c:c + step] = convolution_kernel(omega, per_velocity[:, c:c + step], dt, duration)
    return out.reshape(2 * m + 1, 6 * n_b, n_p)


def diffraction_phasor(comps: WaveComponents, omega: np.ndarray, directions: np.ndarray,
                       diffracted: np.ndarray) -> tuple[np.ndarray, float]:
    """(P, C) complex amplitudes a_c e^{i phi_c} eta_D(x_p; w_c, b_c) from ``diffracted`` (n_w, n_dir, P)
    interpolated in w, and the share of the components' variance outside ``omega`` (left out).
    Every component's heading must be one of ``directions`` (the caller checks)."""
    require_size("[free_surface] cells", "the diffracted wave's phasors (grid points x wave components)",
                 (diffracted.shape[-1], comps.size), itemsize=16, hint="fewer cells or wave components")
    w = comps.hdb_omega
    heads = comps.heading_of()
    out = np.zeros((diffracted.shape[-1], comps.size), complex)
    inside = (w >= omega[0] * (1 - 1e-12)) & (w <= omega[-1] * (1 + 1e-12))
    hi = np.clip(np.searchsorted(omega, w), 1, omega.size - 1)
    frac = np.clip((w - omega[hi - 1]) / (omega[hi] - omega[hi - 1]), 0.0, 1.0)
    for j, beta in enumerate(directions):
        cs = np.flatnonzero(inside & same_direction(heads, beta))
        d = diffracted[:, j]
        out[:, cs] = ((1 - frac[cs])[:, None] * d[hi[cs] - 1] + frac[cs][:, None] * d[hi[cs]]).T
    out *= (comps.amplitude * np.exp(1j * comps.phase))[None]
    var = comps.amplitude ** 2
    return out, float(var[~inside].sum() / var.sum()) if var.sum() > 0 else 0.0


def same_direction(a, b) -> np.ndarray:
    """Headings equal modulo 2 pi (to 1e-9 rad)."""
    return np.isclose(np.angle(np.exp(1j * (np.asarray(a) - b))), 0.0, atol=1e-9)
