"""Optimal mean power against the PTO force limit (the curve a co-design study wants), on the WaveBot:

    python examples/optimal_control/power_vs_force.py [-o power_vs_force.png] [--no-reactive]

One linearisation, then the QP of ``hydrolink optimize`` re-solved for each force limit (only the
limit's bound changes); the unconstrained (complex-conjugate) bound as a line. ``--no-reactive`` adds
the optimum without reactive power (SLSQP, slower).
"""

from __future__ import annotations

import argparse
from dataclasses import replace
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent


def curve(limits: np.ndarray, reactive: bool = True) -> tuple[np.ndarray, float]:
    """Optimal power (W) at each force limit (N) and the unconstrained bound (W)."""
    from hydrolink.clients.analysis.optimal.run import optimize_scene
    from hydrolink.clients.analysis.optimal.solver import solve_optimal
    from hydrolink.clients.scene_inputs import load_scene_hdbs
    from hydrolink.protocol.scene import load_scene

    scene, _ = load_scene(HERE / "wavebot.toml")
    scene = scene.model_copy(update={"optimize": scene.optimize.model_copy(update={"reactive": reactive})})
    prob, sol, _ = optimize_scene(scene, load_scene_hdbs(scene, HERE / "wavebot.toml", progress=False))
    out = []
    for f in limits:
        prob.limits = [replace(lim, bound=float(f)) for lim in prob.limits]
        out.append(solve_optimal(prob).power)
    return np.array(out), sol.unconstrained_power


def main() -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("-o", "--output", type=Path, default=Path("power_vs_force.png"))
    ap.add_argument("--no-reactive", action="store_true", help="also the optimum without reactive power")
    args = ap.parse_args()
    limits = np.linspace(250.0, 6000.0, 24)
    power, bound = curve(limits)
    fig, ax = plt.subplots(figsize=(6.4, 4.0))
    ax.plot(limits, power, "o-", label="optimum under the force limit (order 7)")
    if args.no_reactive:
        ax.plot(limits, curve(limits, reactive=False)[0], "s--", label="optimum without reactive power")
    ax.axhline(bound, color="k", ls=":", label=f"unconstrained bound {bound:.1f} W")
    ax.set_xlabel("PTO force limit (N)")
    ax.set_ylabel("mean absorbed power (W)")
    ax.set_title("WaveBot, regular wave a = 0.0625 m, 0.3 Hz")
    ax.grid(True, alpha=0.3)
    ax.legend()
    fig.tight_layout()
    fig.savefig(args.output, dpi=120)
    for f, p in zip(limits, power):
        print(f"{f:8.0f} N  {p:8.2f} W  {100 * p / bound:5.1f} %")
    print(f"wrote {args.output}")


if __name__ == "__main__":
    main()
