"""Pseudo-spectral preview control: the optimal (complex-conjugate) PTO force for the wave that is
coming, from the server's wave-elevation preview (``preview`` > 0, ``wave_elevation`` measured at
one probe, ``command = "force"``).

Every control step the elevation over [t - history, t + preview] (measured past + preview) is fitted
with a Fourier basis at the frequencies ``omega`` (least squares): eta = Re sum A_m e^{-i w_m tau}.
For each component the optimal relative velocity is u* = F_th / (2 R) and the optimal PTO tension
T* = conj(Z_th) u*, where F_th = G A is the PTO port's Thevenin force (``excitation_re/_im``: G per
metre of wave amplitude at the probe) and Z_th = R + iX its impedance (``impedance_re/_im``), both
per frequency. The force is evaluated ``lead`` seconds ahead (default latency x dt: the command
acts after a step), plus a velocity-tracking feedback ``feedback`` x (u - u*) that damps transients
and vanishes at the optimum. In a regular wave one frequency suffices; in irregular waves give a
grid over the spectrum and a preview/history of a few peak periods.
"""

import numpy as np

from hydrolink.clients.control import Controller


class PseudoSpectral(Controller):
    def on_start(self, info):
        p = info["parameters"]
        self.w = np.atleast_1d(np.asarray(p["omega"], float))
        g = np.asarray(p["excitation_re"], float) + 1j * np.asarray(p["excitation_im"], float)
        z = np.asarray(p["impedance_re"], float) + 1j * np.asarray(p["impedance_im"], float)
        self.u_gain = g / (2 * z.real)              # optimal velocity per unit wave amplitude
        self.t_gain = np.conj(z) * self.u_gain       # optimal tension per unit wave amplitude
        self.history = float(p.get("history", 0.0))
        self.feedback = float(p.get("feedback", 0.0))
        self.lead = float(p.get("lead", info["latency"] * info["dt"]))
        self.offsets = np.asarray(info["preview_times"], float)
        if not self.offsets.size:
            raise ValueError("pseudospectral: needs preview > 0 in the scene's [[controllers]]")
        self.past_t, self.past_eta = [], []

    def on_step(self, t, m):
        self.past_t.append(t)
        self.past_eta.append(float(m["wave_elevation"][0]))
        while self.past_t[0] < t - self.history - 1e-9:
            self.past_t.pop(0)
            self.past_eta.pop(0)
        tau = np.r_[np.asarray(self.past_t) - t, self.offsets]
        eta = np.r_[self.past_eta[:-1], self.past_eta[-1], m["wave_preview"][0]]
        basis = np.hstack([np.cos(np.outer(tau, self.w)), np.sin(np.outer(tau, self.w))])
        coef = np.linalg.lstsq(basis, eta, rcond=None)[0]
        amp = coef[:self.w.size] + 1j * coef[self.w.size:]        # eta = Re sum A e^{-i w tau}
        force = float(np.real(np.sum(self.t_gain * amp * np.exp(-1j * self.w * self.lead))))
        u_opt = float(np.real(np.sum(self.u_gain * amp)))
        u = m["pto_velocity"].tolist()
        return {p: force + self.feedback * (u[i] - u_opt) for i, p in enumerate(self.ptos)}
