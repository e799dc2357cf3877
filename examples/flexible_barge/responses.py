"""The flexible barge's rigid and modal responses in regular waves, in the frequency domain, from
its HDB (6 rigid DOFs + 2 vertical bending modes + 1 torsion mode, examples/data/flexible_barge).

The same equations `hydrolink run` integrates in time (barge.toml; tests/test_modes.py holds the
two against each other), solved here at each HDB frequency,

    (-w^2 (M + A(w)) - i w B(w) + K) X(w) = F(w)          (exp(-iwt), per metre of wave amplitude)

with the structure an idealised uniform beam on the barge's axis through the reference point
(0, 0, 0): mass per metre m = rho V / L (it floats), bending stiffness EI and torsional stiffness
GJ chosen below, modal masses and stiffnesses from the build's own mode shapes (Rayleigh). K is the
HDB's hydrostatic stiffness (rigid and modal rows) plus the modes' structural stiffness (the weight
acts on the axis through the reference point: no gravity terms). It prints each mode's natural
frequency in vacuum and in water (with the HDB's hydrostatics and added mass) and plots the RAOs.

    python examples/flexible_barge/responses.py [-o barge_raos.png]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
from scipy.integrate import trapezoid
from scipy.optimize import brentq

import hydrolink
from hydrolink.server.hdb.build.modes import bending_shape

HERE = Path(__file__).resolve().parent
HDB = HERE.parent / "data" / "flexible_barge" / "flexible_barge.nc"
LENGTH, WIDTH, HEIGHT = 40.0, 8.0, 3.0            # as barge_hdb.toml (draft 2 m + freeboard 1 m)
EI = 2.0e7                                        # N m^2: first bending mode at 0.49 rad/s in vacuum
GJ = 5.0e7                                        # N m^2 / rad: torsion at 1.75 rad/s in vacuum


def structure(ds) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """Mass and structural stiffness matrices over the 9 DOFs (rigid six, then the modes) of the
    uniform beam, and the DOF names."""
    rho = float(ds.attrs["rho"])
    volume = float(ds["displaced_volume"].values[0])
    mass = rho * volume
    per_metre = mass / LENGTH
    polar = per_metre * (WIDTH ** 2 + HEIGHT ** 2) / 12              # mass moment of inertia per metre
    xi = np.linspace(0.0, 1.0, 4001)
    names = [str(v).split(".", 1)[1] for v in ds["influenced_dof"].values]
    n = len(names)
    m, k = np.zeros((n, n)), np.zeros((n, n))
    m[:3, :3] = mass * np.eye(3)
    m[3, 3] = polar * LENGTH
    m[4, 4] = m[5, 5] = per_metre * LENGTH ** 3 / 12
    for i, name in enumerate(names[6:], start=6):
        if name.startswith("bend_z"):
            phi, _, d2 = bending_shape(xi, int(name[len("bend_z"):]))
            m[i, i] = per_metre * LENGTH * trapezoid(phi ** 2, xi)
            k[i, i] = EI / LENGTH ** 3 * trapezoid(d2 ** 2, xi)
        elif name.startswith("twist"):
            order = int(name[len("twist"):])
            m[i, i] = polar * LENGTH * trapezoid(np.cos(order * np.pi * xi) ** 2, xi)
            k[i, i] = GJ / LENGTH * (order * np.pi) ** 2 * trapezoid(np.sin(order * np.pi * xi) ** 2, xi)
    return m, k, names


def responses(ds, m: np.ndarray, k_structure: np.ndarray) -> np.ndarray:
    """X(w, heading, dof): the motion per metre of wave amplitude at each HDB frequency."""
    omega = ds["omega"].values
    a, b = ds["added_mass"].values, ds["radiation_damping"].values
    k = ds["hydrostatic_stiffness"].values + k_structure
    f = ds["excitation_force"].values                                  # (w, heading, dof)
    out = np.empty_like(f)
    for i, w in enumerate(omega):
        z = -w ** 2 * (m + a[i]) - 1j * w * b[i] + k
        out[i] = np.linalg.solve(z, f[i].T).T
    return out


def natural_frequencies(ds, m: np.ndarray, k_structure: np.ndarray, names: list[str]) -> list[tuple[str, float, float]]:
    """Each mode's natural frequency in vacuum (structure only) and in water (with its diagonal
    hydrostatic stiffness and added mass A(w) at that frequency, interpolated in the HDB)."""
    omega = ds["omega"].values
    out = []
    for i, name in enumerate(names[6:], start=6):
        dry = float(np.sqrt(k_structure[i, i] / m[i, i]))
        stiffness = k_structure[i, i] + float(ds["hydrostatic_stiffness"].values[i, i])
        added = lambda w: np.interp(w, omega, ds["added_mass"].values[:, i, i])   # noqa: E731
        gap = lambda w: w ** 2 * (m[i, i] + added(w)) - stiffness                 # noqa: E731
        wet = brentq(gap, omega[0], omega[-1]) if gap(omega[0]) < 0 < gap(omega[-1]) else float("nan")
        out.append((name, dry, wet))
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("-o", "--output", default="barge_raos.png", help="PNG of the RAOs")
    args = parser.parse_args()
    ds = hydrolink.load_hdb(HDB)
    m, k, names = structure(ds)
    top = float(ds["omega"].values[-1])
    print("mode        in vacuum [rad/s]   in water [rad/s]")
    for name, dry, wet in natural_frequencies(ds, m, k, names):
        wet_text = f"{wet:16.3f}" if np.isfinite(wet) else f"above {top:g} (the HDB's last)"
        print(f"{name:10s}  {dry:17.3f}   {wet_text}")
    x = responses(ds, m, k)

    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    omega, headings = ds["omega"].values, np.degrees(ds["wave_direction"].values)
    shown = ["heave", "roll", "pitch", *names[6:]]
    fig, axes = plt.subplots(2, 3, figsize=(12, 6.5), sharex=True)
    for ax, name in zip(axes.ravel(), shown):
        j = names.index(name)
        for h, heading in enumerate(headings):
            ax.plot(omega, np.abs(x[:, h, j]), marker=".", label=f"{heading:g}°")
        unit = "m/m" if name in ("heave",) or name.startswith("bend") else "rad/m"
        ax.set(title=name + (" (modal)" if j >= 6 else " (rigid)"), ylabel=f"|X| [{unit}]")
        ax.grid(True, alpha=0.3)
    for ax in axes[1]:
        ax.set_xlabel("ω [rad/s]")
    axes[0, 0].legend(title="heading")
    fig.suptitle("Flexible barge: rigid and modal RAOs (frequency domain, uniform-beam structure)")
    fig.tight_layout()
    fig.savefig(args.output, dpi=110)
    print(f"wrote {args.output}")


if __name__ == "__main__":
    main()
