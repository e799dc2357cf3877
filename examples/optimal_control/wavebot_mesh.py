"""Write the immersed hull of Sandia's WaveBot (WecOptTool's tutorial device, wecopttool.geom.WaveBot
defaults: a cylinder of radius r1 = 0.88 m from the waterline down to h1 - freeboard = 0.16 m, then a
cone to radius r2 = 0.35 m at 0.53 m, and a flat bottom) as a WAMIT GDF panel mesh, revolved from
its profile: ``python examples/optimal_control/wavebot_mesh.py`` writes examples/data/wavebot/wavebot.gdf,
which examples/optimal_control/wavebot_hdb.toml builds (``hydrolink hdb build``)."""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

R1, R2, H1, H2, FREEBOARD = 0.88, 0.35, 0.17, 0.37, 0.01     # m, wecopttool.geom.WaveBot()


def profile(side: int, cone: int, bottom: int) -> np.ndarray:
    """(r, z) points from the waterline to the axis: ``side``, ``cone``, ``bottom`` segments."""
    z1, z2 = -(H1 - FREEBOARD), -(H1 - FREEBOARD + H2)
    parts = [np.column_stack([np.full(side + 1, R1), np.linspace(0.0, z1, side + 1)]),
             np.column_stack([np.linspace(R1, R2, cone + 1), np.linspace(z1, z2, cone + 1)])[1:],
             np.column_stack([np.linspace(R2, 0.0, bottom + 1), np.full(bottom + 1, z2)])[1:]]
    return np.vstack(parts)


def revolve(points: np.ndarray, sectors: int) -> np.ndarray:
    """Quadrilateral panels (n, 4, 3), normals out of the body (into the water)."""
    th = np.linspace(0.0, 2 * np.pi, sectors + 1)
    panels = []
    for (r0, z0), (r1, z1) in zip(points[:-1], points[1:]):
        for a, b in zip(th[:-1], th[1:]):
            panels.append([[r0 * np.cos(a), r0 * np.sin(a), z0], [r1 * np.cos(a), r1 * np.sin(a), z1],
                           [r1 * np.cos(b), r1 * np.sin(b), z1], [r0 * np.cos(b), r0 * np.sin(b), z0]])
    return np.asarray(panels)


def write_gdf(path: Path, panels: np.ndarray) -> None:
    lines = ["WaveBot immersed hull (examples/optimal_control/wavebot_mesh.py)", "1.0 9.81", "0 0", str(len(panels))]
    lines += [" ".join(f"{c:.9g}" for c in corner) for corner in panels.reshape(-1, 3)]
    path.write_text("\n".join(lines) + "\n")


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("-o", "--output", type=Path, default=Path(__file__).parents[1] / "data" / "wavebot" / "wavebot.gdf")
    ap.add_argument("--sectors", type=int, default=64)
    args = ap.parse_args()
    write_gdf(args.output, revolve(profile(2, 7, 4), args.sectors))
    print(f"wrote {args.output}")
