"""examples/controllers/mpc.py against ``hydrolink optimize`` on the WaveBot
(examples/optimal_control/wavebot.toml: regular wave, F <= 2000 N).

The full time-domain cases — the MPC as an external controller in ``hydrolink run`` at 10 and 100 Hz,
preview and gauge predictors, irregular seas — take minutes and are in bench/bench_mpc.py
(docs/optimal-control.md). Here, in a few seconds: the controller closed around the zero-order-hold
plant of the device (the plant it receives at join, ``hydrolink linearize``'s state-space radiation)
in the regular wave, fed the measurements and the perfect preview a run would send; the reference is
the collocation optimum (HDB A(w), B(w), 7 harmonics), an independent model and method. A horizon
shorter than two control periods is refused at join, naming it; a QP that has no solution at run time
is logged and replaced by the fallback command.
"""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "examples" / "optimal_control"))
sys.path.insert(0, str(REPO / "examples" / "controllers"))
SCENE = REPO / "examples" / "optimal_control" / "wavebot.toml"


@pytest.mark.slow      # ~10 s each on the loaded VM (the optimum, the plant, 600 QP steps)
@pytest.mark.parametrize("predictor", ["preview", "gauge"])
def test_mpc_on_the_plant_reaches_the_constrained_optimum(predictor):
    """Perfect preview (>= 90 % of the optimum) and an up-wave gauge 30 m away (>= 70 %; the regular
    wave at the gauge is a cos(w t + k L), deep water k = w^2 / g); no force beyond the limit by 1 %."""
    from mpc import MPC
    from run_mpc import excitation_per_metre

    from hydrolink.clients.analysis.optimal.run import optimize_scene
    from hydrolink.clients.analysis.plant import build_plant
    from hydrolink.clients.scene_inputs import load_scene_hdbs
    from hydrolink.protocol.scene import load_scene

    scene, _ = load_scene(SCENE)
    hdbs = load_scene_hdbs(scene, SCENE, progress=False)
    _, opt, _ = optimize_scene(scene, hdbs)
    ts, horizon = 0.1, 3.0
    plant = build_plant(scene, hdbs).discretize(ts)
    w = 2 * math.pi / scene.waves.period
    x = excitation_per_metre(scene, hdbs, np.array([w]))          # (1, 1) per metre
    a = scene.waves.height / 2                                      # eta = a cos(w t)
    preview = np.arange(1, int(round((horizon + 1.0) / ts)) + 1) * ts
    ctl = MPC()
    ctl.ptos = ["pto"]
    gauge = 30.0
    kl = w ** 2 / 9.81 * gauge
    ctl.on_start({"parameters": {"omega": [w], "excitation_re": list(x.real.ravel()), "excitation_im": list(x.imag.ravel()),
                                 "horizon": horizon, "blocks": 30, "history": 10.0, "predictor": predictor,
                                 "gauge_distance": gauge},
                  "dt": ts, "period": ts, "latency": 1, "plant": plant, "limits": {"max_force": 2000.0},
                  "preview_times": preview, "bodies": ["wavebot"]})
    iu, ie = plant.inputs.index("pto:pto"), plant.inputs.index("excitation:wavebot.heave")
    ipos, ivel = plant.outputs.index("wavebot.heave.position"), plant.outputs.index("wavebot.heave.velocity")
    iv = plant.outputs.index("pto:pto.velocity")
    state, u_now, energy, peak = np.zeros(plant.A.shape[0]), 0.0, 0.0, 0.0
    t_end, t_avg = 60.0, 60.0 - 10 * scene.waves.period
    for k in range(int(round(t_end / ts))):
        t = k * ts
        y = plant.C @ state
        pos, vel = np.zeros((1, 6)), np.zeros((1, 6))
        pos[0, 2], vel[0, 2] = y[ipos], y[ivel]
        at_probe = a * math.cos(w * t) if predictor == "preview" else a * math.cos(w * t + kl)
        m = {"body_position": pos, "body_velocity": vel, "wave_elevation": np.array([at_probe]),
             "wave_preview": np.array([a * np.cos(w * (t + preview))])}
        u_next = ctl.on_step(t, m)["pto"]                            # in force from t + ts (latency one period)
        e = float(np.real(x[0, 0] * a * np.exp(-1j * w * (t + ts / 2))))   # mid-step excitation
        v0 = y[iv]
        state = plant.A @ state + plant.B[:, iu] * u_now + plant.B[:, ie] * e
        if t >= t_avg:
            energy += u_now * 0.5 * (v0 + (plant.C @ state)[iv]) * ts
            peak = max(peak, abs(u_now))
        u_now = u_next
    power = energy / (t_end - t_avg)
    p99 = float(np.percentile(ctl.solve_times[10:], 99))
    print(f"MPC ({predictor}) on the plant {power:.2f} W = {100 * power / opt.power:.1f} % of the optimum {opt.power:.2f} W "
          f"(unconstrained {opt.unconstrained_power:.2f} W); peak force {peak:.1f} N; solve p99 {1e3 * p99:.2f} ms")
    assert power >= (0.9 if predictor == "preview" else 0.7) * opt.power and power <= opt.unconstrained_power
    assert peak <= 2000.0 * 1.01 and ctl.fallbacks == 0


def test_mpc_refuses_a_horizon_shorter_than_its_period():
    from mpc import MPC
    ctl = MPC()
    ctl.ptos = ["pto"]
    info = {"parameters": {"horizon": 0.05, "omega": [1.0], "excitation_re": [1.0], "excitation_im": [0.0]},
            "dt": 0.01, "period": 0.1, "latency": 10, "plant": None, "limits": {"max_force": 1.0},
            "preview_times": [0.1], "bodies": ["b"]}
    with pytest.raises(ValueError, match="horizon 0.05 s is shorter than two control periods"):
        ctl.on_start(info)


def test_mpc_infeasible_qp_falls_back_and_logs(caplog):
    """A stroke the force cannot hold (a mass-spring-damper far out with a 1 N force limit): DAQP
    reports the QP infeasible, the controller logs it and commands the previous plan's next value (0
    without a plan) instead of failing the step."""
    from mpc import MPC

    from hydrolink.clients.analysis.plant import Plant
    m, c, k = 1000.0, 500.0, 2.0e4          # kg, N s/m, N/m
    A = np.array([[0.0, 1.0], [-k / m, -c / m]])
    B = np.array([[0.0, 0.0], [1.0 / m, 1.0 / m]])     # inputs: the PTO's force (same sign), the excitation
    C = np.array([[1.0, 0.0], [0.0, 1.0], [-1.0, 0.0], [0.0, -1.0]])
    plant = Plant(A, B, C, np.zeros((4, 2)), ("b.heave.position", "b.heave.velocity"),
                  ("pto:pto", "excitation:b.heave"),
                  ("b.heave.position", "b.heave.velocity", "pto:pto.displacement", "pto:pto.velocity"))
    ctl = MPC()
    ctl.ptos = ["pto"]
    ctl.on_start({"parameters": {"omega": [1.0], "excitation_re": [0.0], "excitation_im": [0.0], "horizon": 1.0,
                                 "blocks": 5, "stroke_limit": 0.01, "history": 5.0},
                  "dt": 0.1, "period": 0.1, "latency": 1, "plant": plant, "limits": {"max_force": 1.0},
                  "preview_times": [0.1, 0.2], "bodies": ["b"]})
    pos, vel = np.zeros((1, 6)), np.zeros((1, 6))
    pos[0, 2] = 0.5                          # 50 times the stroke limit, a 1 N force cannot bring it back
    m_ = {"body_position": pos, "body_velocity": vel, "wave_elevation": np.array([0.0]),
          "wave_preview": np.zeros((1, 2))}
    with caplog.at_level("WARNING", logger="hydrolink.mpc"):
        out = ctl.on_step(0.0, m_)
    assert out == {"pto": 0.0} and ctl.fallbacks == 1
    assert "QP not solved at t = 0.000 s (infeasible" in caplog.text
