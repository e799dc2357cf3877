"""MoorDyn coupling cost per step, beside the same device without moorings and with Exudyn ANCF ropes;
and how far the same line is apart as an ANCF rope and as MoorDyn.

    python bench/bench_moordyn.py [--duration 80] [--dry-duration 12] [--repeat 3]

Device: examples/rm3_moordyn (RM3, spar in surge/heave/pitch, float on a prismatic joint, PTO;
regular wave H = 2.5 m, T = 8 s, dt = 0.08 s). Cases:

- ``none``: no moorings;
- ``moordyn-3``: the example's three chain lines (24 segments, dtM = 0.002 s: 40 MoorDyn substeps
  per step);
- ``moordyn-9``: nine lines (three per anchor heading, 10° apart), same line type;

The ANCF ropes need a finite scene depth (their seabed), which the RM3 HDB (infinite depth) refuses;
so the ropes are compared on the spar alone, dry (neutrally buoyant, surge only, pushed off at
0.2 m/s from the reference position, where the ropes' static shapes are computed; no force server,
70 m depth, spectral radius 0.8 and dt = 0.02 s for every case, 12 s: the ropes' Newton iteration
failed at dt = 0.08 s after 1.3 s, and at 12.9 s with dt = 0.02 or 0.01 s — the ANCF ropes' seabed
contact under motion, their known limit): ``none``, ``moordyn-3`` and ``ropes-3`` (the three lines as
``type = "rope"``, 24 ANCF cable elements each, seabed contact).

Per-step figures are the run's wall time over its steps (set-up excluded: HDB load, MoorDyn's
initial-condition solve, the rope's static solve), medians over ``--repeat`` runs [min-max]; this
2-core machine is shared and noisy. The comparison: static fairlead tension of one line at three
spar offsets (MoorDyn's IC solve, the rope's static equilibrium, the elastic catenary), and over
the dynamic runs the fairlead tension and spar motion of moordyn-3 against ropes-3.
"""

from __future__ import annotations

import argparse
import logging
import math
import re
import shutil
import statistics
import tempfile
from pathlib import Path

import numpy as np
import xarray as xr

from hydrolink.clients.scene_inputs import load_scene_hdbs
from hydrolink.clients.run import run_scene_file
from hydrolink.protocol.scene import load_scene

REPO = Path(__file__).resolve().parents[1]
EXAMPLE = REPO / "examples" / "rm3_moordyn"
DEPTH, ANCHOR_R, FAIR_R, FAIR_Z, LENGTH = 70.0, 230.0, 6.0, -21.29, 250.0
DIAMETER, MU, EA, SEGMENTS = 0.08, 40.0, 3.0e8, 24
HEADINGS = (0.0, 120.0, 240.0)


def example_text() -> str:
    """The example scene with its HDB path made absolute and progress off."""
    text = (EXAMPLE / "rm3_moordyn.toml").read_text()
    hdb = (EXAMPLE / "../data/rm3_wamit/rm3.1").resolve()
    text = text.replace('"../data/rm3_wamit/rm3.1"', f'"{hdb}"')
    return text.replace("[simulation]\n", "[simulation]\nprogress = false\n", 1)


def without_moorings(text: str) -> str:
    return text[:text.index("[[moorings]]")]


def nine_lines(lines_dat: str) -> str:
    """The example's MoorDyn file with three lines per anchor heading (±10°)."""
    head, rest = lines_dat.split("---------------------- POINTS", 1)
    _, after = rest.split("---------------------- OPTIONS", 1)
    anchors, fairs, lines = [], [], []
    k = 0
    for h0 in HEADINGS:
        for dh in (-10.0, 0.0, 10.0):
            h = math.radians(h0 + dh)
            k += 1
            anchors.append(f"{k} Fixed {ANCHOR_R * math.cos(h):.6f} {ANCHOR_R * math.sin(h):.6f} {-DEPTH} 0 0 0 0")
            fairs.append(f"{9 + k} Body1 {FAIR_R * math.cos(h):.6f} {FAIR_R * math.sin(h):.6f} 0.0 0 0 0 0")
            lines.append(f"{k} chain {k} {9 + k} {LENGTH} {SEGMENTS} -")
    points = ("---------------------- POINTS ----------------------\nID Attachment X Y Z Mass Volume CdA Ca\n"
              "(#) (word/ID) (m) (m) (m) (kg) (m^3) (m^2) (-)\n" + "\n".join(anchors + fairs) + "\n")
    lines_sec = ("---------------------- LINES ----------------------\nID LineType AttachA AttachB UnstrLen NumSegs "
                 "LineOutputs\n(#) (name) (#) (#) (m) (-) (-)\n" + "\n".join(lines) + "\n")
    after = re.sub(r"FairTen1\nFairTen2\nFairTen3\n", "", after)
    return head + points + lines_sec + "---------------------- OPTIONS" + after


def dry_spar_text(moorings: str) -> str:
    """A dry body with the spar's mass and reference point, neutrally buoyant, in surge only, pushed
    off at 0.2 m/s (no HDB, no force server: finite depth for the ropes' seabed), dt 0.02 s,
    spectral radius 0.8 (what slack ropes on the seabed need; the same for every case)."""
    return (f"[simulation]\ndt = 0.02\nduration = 80.0\nprogress = false\nspectral_radius = 0.8\n"
            f"[water]\ndensity = 1000.0\ngravity = 9.81\ndepth = {DEPTH}\n"
            f'[[bodies]]\nname = "spar"\nmass = 886687.0\ncenter_of_mass = [0.0, 0.0, {FAIR_Z}]\n'
            f"inertia = [94419614.57, 94407091.24, 28542224.82]\nbuoyancy_volume = 886.687\n"
            f'dofs = ["surge"]\ninitial_velocity = [0.2, 0.0, 0.0, 0.0, 0.0, 0.0]\n' + moorings)


def rope_blocks() -> str:
    """The three lines as ANCF ropes (24 cable elements, seabed contact)."""
    text = ""
    for k, h in enumerate(map(math.radians, HEADINGS)):
        c, s = math.cos(h), math.sin(h)
        text += (f'\n[[moorings]]\ntype = "rope"\nname = "rope{k + 1}"\nanchor = [{ANCHOR_R * c:.6f}, {ANCHOR_R * s:.6f}, '
                 f'{-DEPTH}]\nattach_to = "spar"\npoint = [{FAIR_R * c:.6f}, {FAIR_R * s:.6f}, {FAIR_Z}]\n'
                 f"length = {LENGTH}\naxial_stiffness = {EA}\nmass_per_length = {MU}\ndiameter = {DIAMETER}\n"
                 f"elements = {SEGMENTS}\nseabed = true\n")
    return text


MOORDYN_BLOCK = '\n[[moorings]]\ntype = "moordyn"\nname = "spread"\nfile = "lines.dat"\nbodies = ["spar"]\nstatic_offset = false\n'


def run_case(folder: Path, text: str, duration: float, hdbs, out: str) -> tuple[dict, Path]:
    text = re.sub(r"duration = [\d.]+", f"duration = {duration}", text, count=1)
    scene = folder / f"{out}.toml"
    scene.write_text(text)
    summary = run_scene_file(scene, folder / f"{out}.nc", progress=False, hdbs=hdbs)
    return summary, folder / f"{out}.nc"


def static_comparison(folder: Path) -> list[tuple[float, float, float, float]]:
    """Fairlead tension of line 1 with the anchor moved ``dx`` towards the spar (the spar held at its
    reference: where the ropes' static shapes are computed): MoorDyn's IC solve, the ANCF rope
    (the spar's attachment-joint force after Exudyn's initial accelerations), the elastic catenary
    with a frictionless seabed."""
    from scipy.optimize import fsolve

    from hydrolink.clients.exudyn.client import build_model
    from hydrolink.clients.exudyn.moordyn_mooring import load_moordyn_files
    from hydrolink.clients.exudyn.moorings import rope_properties
    from hydrolink.protocol.scene import RopeMooring, Water, parse_scene

    water = Water(density=1000.0, gravity=9.81, depth=DEPTH)
    w = rope_properties(RopeMooring(type="rope", anchor=[0, 0, 0], attach_to="spar", length=LENGTH, axial_stiffness=EA,
                                    mass_per_length=MU, diameter=DIAMETER), water)["weight_per_length"]

    def catenary(span: float, height: float) -> float:
        def eqs(p):
            h, v = math.exp(p[0]), p[1]
            x = LENGTH - v / w + h / w * math.asinh(v / h) + h * LENGTH / EA
            z = h / w * (math.sqrt(1 + (v / h) ** 2) - 1) + v * v / (2 * EA * w)
            return [x - span, z - height]
        h, v = fsolve(eqs, [math.log(w * LENGTH / 4), w * height], xtol=1e-13)
        return math.hypot(math.exp(h), v)

    def one_line(anchor_x: float) -> str:
        text = (EXAMPLE / "lines.dat").read_text()
        text = re.sub(r"\n1   Fixed       230.0 ", f"\n1   Fixed       {anchor_x} ", text)
        text = re.sub(r"\n2   Fixed.*\n3   Fixed.*\n", "\n", text).replace("4   Body1", "2   Body1")
        text = re.sub(r"\n5   Body1.*\n6   Body1.*\n", "\n", text)
        text = text.replace("1   chain     1        4 ", "1   chain     1        2 ")
        text = re.sub(r"\n2   chain .*\n3   chain .*\n", "\n", text)
        return text.replace("FairTen1\nFairTen2\nFairTen3\n", "")

    out = []
    for dx in (-5.0, 0.0, 5.0):
        anchor_x = ANCHOR_R - dx
        (folder / "one.dat").write_text(one_line(anchor_x))
        rope = (f'\n[[moorings]]\ntype = "rope"\nname = "rope"\nanchor = [{anchor_x}, 0.0, {-DEPTH}]\nattach_to = "spar"\n'
                f"point = [{FAIR_R}, 0.0, {FAIR_Z}]\nlength = {LENGTH}\naxial_stiffness = {EA}\nmass_per_length = {MU}\n"
                f"diameter = {DIAMETER}\nelements = {SEGMENTS}\nseabed = true\n")
        tension = []
        for block in (MOORDYN_BLOCK.replace("lines.dat", "one.dat"), rope):
            text = dry_spar_text(block).replace("initial_velocity = [0.2, 0.0, 0.0, 0.0, 0.0, 0.0]", "")
            path = folder / "static.toml"
            path.write_text(text)
            scene = parse_scene(text, path)
            model = build_model(scene, None, moordyn_files=load_moordyn_files(scene, path))
            try:
                model.initialize()
                tension.append(float(np.linalg.norm(model.moorings.sample(model.mbs)[0, :3])))
            finally:
                model.close()
        out.append((dx, tension[0], tension[1], catenary(anchor_x - FAIR_R, FAIR_Z + DEPTH)))
    return out


def timed(folder: Path, cases: dict[str, str], duration: float, repeat: int, hdbs=None) -> tuple[dict, dict]:
    """Median wall time per step of each case (and the last run's results file)."""
    per_step: dict[str, list[float]] = {k: [] for k in cases}
    files: dict[str, Path] = {}
    for _ in range(repeat):
        for name, text in cases.items():
            summary, files[name] = run_case(folder, text, duration, hdbs, name)
            per_step[name].append(summary.wall_time / summary.steps * 1e6)
    return per_step, files


def report(title: str, per_step: dict[str, list[float]]) -> None:
    print(title)
    base_us = statistics.median(per_step["none"])
    for name, vals in per_step.items():
        med = statistics.median(vals)
        print(f"  {name:10s} {med:8.0f} us/step [{min(vals):.0f}-{max(vals):.0f}]  (+{med - base_us:.0f} us over none)")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--duration", type=float, default=80.0, help="simulated seconds per run")
    parser.add_argument("--dry-duration", type=float, default=12.0, help="simulated seconds, spar alone")
    parser.add_argument("--repeat", type=int, default=3)
    args = parser.parse_args()
    logging.basicConfig(level=logging.ERROR)

    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        shutil.copy(EXAMPLE / "lines.dat", folder / "lines.dat")
        (folder / "lines9.dat").write_text(nine_lines((EXAMPLE / "lines.dat").read_text()))
        base = example_text().replace("static_offset", "#")
        base += "static_offset = false\n"
        rm3 = {"none": without_moorings(base), "moordyn-3": base,
               "moordyn-9": base.replace('file = "lines.dat"', 'file = "lines9.dat"')}
        scene0, _ = load_scene(EXAMPLE / "rm3_moordyn.toml")
        hdbs = {str((EXAMPLE / k).resolve()): v for k, v in load_scene_hdbs(scene0, EXAMPLE / "rm3_moordyn.toml").items()}
        per_step, _ = timed(folder, rm3, args.duration, args.repeat, hdbs)
        report(f"RM3 in regular waves (examples/rm3_moordyn), dt = 0.08 s, {args.duration:g} s, {args.repeat} runs "
               "each: wall time per step", per_step)

        dry = {"none": dry_spar_text(""), "moordyn-3": dry_spar_text(MOORDYN_BLOCK), "ropes-3": dry_spar_text(rope_blocks())}
        per_step, files = timed(folder, dry, args.dry_duration, args.repeat)
        report(f"the spar alone (dry, surge, pushed off at 0.2 m/s, 70 m depth), dt = 0.02 s, {args.dry_duration:g} s: "
               "wall time per step", per_step)

        md, ro = xr.load_dataset(files["moordyn-3"]), xr.load_dataset(files["ropes-3"])
        t_md = md["line_end_force"].values    # the pull on the fairlead, as the rope's mooring_force
        t_ro = np.linalg.norm(ro["mooring_force"].values[:, :, :3], axis=2)
        print("the same three lines, MoorDyn vs ANCF ropes (the spar pushed off at 0.2 m/s):")
        for k in range(3):
            d = t_md[:, k] - t_ro[:, k]
            print(f"  line {k + 1}: tension at t = 0 {t_md[0, k] / 1e3:.2f} vs {t_ro[0, k] / 1e3:.2f} kN, range "
                  f"{np.ptp(t_md[:, k]) / 1e3:.2f} vs {np.ptp(t_ro[:, k]) / 1e3:.2f} kN, rms difference "
                  f"{np.sqrt(np.mean(d * d)) / 1e3:.2f} kN")
        a = md["position"].sel(body="spar", dof="surge").values
        b = ro["position"].sel(body="spar", dof="surge").values
        print(f"  spar surge: max {a.max():.3f} vs {b.max():.3f} m, min {a.min():.3f} vs {b.min():.3f} m, rms "
              f"difference {np.sqrt(np.mean((a - b) ** 2)):.3f} m")
        print("one line held statically, fairlead tension (kN): anchor moved towards the spar, MoorDyn IC, ANCF rope, "
              "elastic catenary")
        for dx, a, b, c in static_comparison(folder):
            print(f"  {dx:+5.1f} m  {a / 1e3:8.3f}  {b / 1e3:8.3f}  {c / 1e3:8.3f}   "
                  f"(MoorDyn {100 * (a / c - 1):+.2f} %, rope {100 * (b / c - 1):+.2f} %)")


if __name__ == "__main__":
    main()
