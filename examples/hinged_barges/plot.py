"""Heave RAO of barge 2 of the hinged two-barge device: a sweep of `hydrolink run`s in regular waves
against the frequency-domain solution of the same linear model.

    python examples/hinged_barges/plot.py                    # 12 frequencies 2.61-7.85 rad/s, ~40 s
    python examples/hinged_barges/plot.py --omegas 2.61,5.2,7.85 -o rao.png --csv rao.csv

Each run is scene.toml at one frequency: dt = T/100, a 30 s ramp, 65 s; the barge 2 heave amplitude
is fitted over the last ten periods (a0 + a cos wt + b sin wt). The frequency-domain curves solve the
planar (surge, heave, pitch) model of both barges reduced to the hinge's 4 DOFs, with the scene's
masses, CoGs, inertias, hinge, PTO line and mooring (see README.md):
- "effective": A, B of the truncated radiation convolution the co-simulation realises
  (irf_duration of the scene, the run's dt), the curve the runs should follow;
- "HDB": the HDB's A(w), B(w). The two differ where the IRF truncation matters (README.md).
"""

from __future__ import annotations

import argparse
import re
import tempfile
from pathlib import Path

import numpy as np
import scipy.linalg as sla

HERE = Path(__file__).resolve().parent
PLANAR = [0, 2, 4]          # surge, heave, pitch within a body's six DOFs
STEPS_PER_PERIOD, RAMP, DURATION, FIT_PERIODS = 100, 30.0, 65.0, 10


def run_one(scene_text: str, hdb: Path, w: float, workdir: Path) -> float:
    """Barge 2 heave amplitude (m) of one run at w."""
    import xarray as xr

    from hydrolink.clients.run import run_scene_file

    period = 2 * np.pi / w
    text = scene_text
    for key, value in {"dt": period / STEPS_PER_PERIOD, "duration": DURATION, "period": period,
                       "ramp": RAMP}.items():
        text = re.sub(rf"(?m)^{key} = [0-9.eE+-]+", f"{key} = {float(value)!r}", text)
    text = text.replace("progress = true", "progress = false")
    text = text.replace('"hinged_barges_hdb.toml"', f'"{hdb.as_posix()}"')
    scene = workdir / "scene.toml"
    scene.write_text(text)
    run_scene_file(scene, workdir / "run.nc", progress=False)
    ds = xr.load_dataset(workdir / "run.nc")
    t = ds["time"].values
    z = (ds["position"] - ds["equilibrium_position"]).sel(body="barge2", dof="heave").values
    sel = t > t[-1] - FIT_PERIODS * period + 1e-9
    basis = np.c_[np.cos(w * t[sel]), np.sin(w * t[sel]), np.ones(sel.sum())]
    a, b, _ = np.linalg.lstsq(basis, z[sel], rcond=None)[0]
    return float(np.hypot(a, b))


class FrequencyDomain:
    """The planar two-barge model of the scene, reduced to the hinge's null space."""

    def __init__(self, scene, hdb):
        self.hdb = hdb
        names = [b.name for b in scene.bodies]
        hdb_names = [str(n) for n in hdb["body"].values]
        self.idx = [6 * hdb_names.index(b.hdb_body_name) + k for b in scene.bodies for k in PLANAR]
        refs = [hdb["reference_point"].sel(body=b.hdb_body_name).values for b in scene.bodies]
        g = scene.water.gravity
        blocks = []
        self.stiffness = hdb["hydrostatic_stiffness"].values[np.ix_(self.idx, self.idx)].copy()
        for i, (body, ref) in enumerate(zip(scene.bodies, refs)):
            dx, _, dz = np.asarray(body.center_of_mass) - ref
            m, iyy = body.mass, body.inertia_matrix[1][1]
            blocks.append(np.array([[m, 0, m * dz], [0, m, -m * dx], [m * dz, -m * dx, iyy + m * (dx * dx + dz * dz)]]))
            self.stiffness[3 * i + 2, 3 * i + 2] -= m * g * dz          # gravity term of pitch
        self.mass = sla.block_diag(*blocks)

        def point(p, i):   # (x, z) displacement of a body-fixed point from body i's (surge, heave, pitch)
            out = np.zeros((2, 3 * len(names)))
            rx, _, rz = np.asarray(p, float) - refs[i]
            out[:, 3 * i:3 * i + 3] = [[1, 0, rz], [0, 1, -rx]]
            return out

        (joint,) = scene.joints
        jac = point(joint.point, names.index(joint.body1)) - point(joint.point, names.index(joint.body2))
        self.null = sla.null_space(jac)
        self.damping = np.zeros_like(self.mass)
        for pto in scene.ptos:
            e = np.asarray(pto.point2, float) - pto.point1
            e = (e / np.linalg.norm(e))[[0, 2]]
            row = e @ (point(pto.point2, names.index(pto.body2)) - point(pto.point1, names.index(pto.body1)))
            self.damping += pto.damping * np.outer(row, row)
            self.stiffness += pto.stiffness * np.outer(row, row)
        for moor in scene.moorings:
            i = names.index(moor.body)
            k6 = np.asarray(moor.stiffness, float)
            k6 = np.diag(k6) if k6.ndim == 1 else k6
            assert np.allclose(np.asarray(moor.point) - refs[i], 0.0), "mooring point off the reference point"
            self.stiffness[3 * i:3 * i + 3, 3 * i:3 * i + 3] += k6[np.ix_(PLANAR, PLANAR)]
        self.amplitude = scene.waves.height / 2
        self.irf, self._h2 = scene.hydro.irf_duration, 3 * names.index("barge2") + 1

    def _at(self, w, values):
        om = self.hdb["omega"].values
        flat = values.reshape(om.size, -1)
        return np.array([np.interp(w, om, f.real) + 1j * np.interp(w, om, f.imag) for f in flat.T]
                        ).reshape(values.shape[1:])

    def radiation(self, w: float, kind: str):
        ix = np.ix_(range(self.hdb.sizes["omega"]), self.idx, self.idx)
        b_hdb = self.hdb["radiation_damping"].values[ix]
        if kind == "HDB":
            return self._at(w, self.hdb["added_mass"].values[ix]).real, self._at(w, b_hdb).real
        dt = 2 * np.pi / w / STEPS_PER_PERIOD
        om = np.r_[0.0, self.hdb["omega"].values]
        b = np.concatenate([np.zeros((1, *b_hdb.shape[1:])), b_hdb])
        t = np.arange(int(round(self.irf / dt)) + 1) * dt
        wo = (np.r_[np.diff(om), 0.0] + np.r_[0.0, np.diff(om)]) / 2     # trapezoid weights in w
        k = (2 / np.pi) * np.tensordot(np.cos(np.outer(t, om)) * wo, b, axes=(1, 0))
        wt = np.full(t.size, dt)
        wt[[0, -1]] *= 0.5
        a_inf = self.hdb["added_mass_inf"].values[np.ix_(self.idx, self.idx)]
        return (a_inf - np.tensordot(wt * np.sin(w * t), k, axes=(0, 0)) / w,
                np.tensordot(wt * np.cos(w * t), k, axes=(0, 0)))

    def heave2(self, w: float, kind: str) -> float:
        a, b = self.radiation(w, kind)
        x_ex = self._at(w, self.hdb["excitation_force"].values[:, 0, self.idx])
        z = -w ** 2 * (self.mass + a) - 1j * w * (b + self.damping) + self.stiffness
        n = self.null
        q = n @ np.linalg.solve(n.T @ z @ n, n.T @ x_ex * self.amplitude)
        return float(abs(q[self._h2]))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scene", default=str(HERE / "scene.toml"))
    parser.add_argument("--omegas", help="comma-separated rad/s (default: 12 values 2.61-7.85)")
    parser.add_argument("--hdb", help="a built HDB file to use instead of building the scene's spec")
    parser.add_argument("-o", "--output", default="hinged_barges_rao.png", help="PNG to write")
    parser.add_argument("--csv", help="also write omega, RAO (TD, FD effective, FD HDB) here")
    args = parser.parse_args()

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from hydrolink.protocol.scene import load_scene, resolve_path
    from hydrolink.server.hdb.io import load_hdb

    scene_path = Path(args.scene)
    scene, text = load_scene(scene_path)
    if args.hdb:
        hdb_path = Path(args.hdb).resolve()
        hdb = load_hdb(hdb_path)
    else:
        from hydrolink.server.hdb.build.builder import build_hdb
        from hydrolink.protocol.hdb.schema import to_netcdf
        hdb = build_hdb(resolve_path(scene_path, scene.bodies[0].hdb), progress=False)
    omegas = (np.array([float(w) for w in args.omegas.split(",")]) if args.omegas
              else np.linspace(2.61, 7.85, 12))
    fd = FrequencyDomain(scene, hdb)
    amp = fd.amplitude
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        if not args.hdb:
            hdb_path = tmp / "hdb.nc"
            to_netcdf(hdb, hdb_path)
        td = []
        for w in omegas:
            td.append(run_one(text, hdb_path, float(w), tmp) / amp)
            print(f"w = {w:.3f} rad/s: barge 2 heave RAO {td[-1]:.5f} (FD effective "
                  f"{fd.heave2(w, 'effective') / amp:.5f}, HDB {fd.heave2(w, 'HDB') / amp:.5f})", flush=True)
    fine = np.linspace(omegas.min(), omegas.max(), 120) if omegas.size > 1 else omegas
    fd_eff = [fd.heave2(w, "effective") / amp for w in fine]
    fd_hdb = [fd.heave2(w, "HDB") / amp for w in fine]
    fig, axes = plt.subplots(2, 1, figsize=(8, 8), sharex=True)
    for ax in axes:
        ax.plot(fine, fd_eff, "-", label="frequency domain (effective A, B of the convolution)")
        ax.plot(fine, fd_hdb, "--", label="frequency domain (HDB A(ω), B(ω))")
        ax.plot(omegas, td, "o", label="hydrolink run (time domain, steady state)")
        ax.set_ylabel("barge 2 heave RAO [m/m]")
        ax.grid(alpha=0.3, which="both")
    axes[1].set_yscale("log")
    axes[1].set_xlabel("ω [rad/s]")
    axes[0].set_title(f"Hinged barges: barge 2 heave, wave amplitude {amp * 1e3:.0f} mm")
    axes[0].legend()
    fig.tight_layout()
    fig.savefig(args.output, dpi=100)
    print(f"wrote {args.output}")
    if args.csv:
        rows = [(w, r, fd.heave2(w, "effective") / amp, fd.heave2(w, "HDB") / amp) for w, r in zip(omegas, td)]
        np.savetxt(args.csv, rows, delimiter=",", fmt="%.8g", header="omega,rao_td,rao_fd_effective,rao_fd_hdb",
                   comments="")
        print(f"wrote {args.csv}")


if __name__ == "__main__":
    main()
