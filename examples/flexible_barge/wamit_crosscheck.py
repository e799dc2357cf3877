"""Cross-check of the WAMIT reader's generalized modes against hydrolink's own Capytaine build of
the same geometry and modes (issue 38).

WEC-Sim's flexible barge (examples/data/wamit_gbm_barge: WAMIT 7, an 80 x 10 m box of draft 5 m,
four beam modes given by WAMIT's DEFMOD as a vertical displacement w = phi_k(x) interpolated in
``modes.txt``, u = v = 0) is built here with ``hdb build``: the box as a mesh file and each mode as
a per-vertex displacement table (0, 0, phi_k(x)), at a few of the WAMIT run's periods. The script
prints, for the modes' diagonal added mass, damping and excitation and their hydrostatic
stiffness, the Capytaine build beside the WAMIT file at five of its periods.

    python examples/flexible_barge/wamit_crosscheck.py [--panel 2.0] [--keep DIR]
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import numpy as np

DATA = Path(__file__).resolve().parent.parent / "data" / "wamit_gbm_barge"
LENGTH, WIDTH, HEIGHT, DRAFT = 80.0, 10.0, 10.0, 5.0
PERIODS = (6.150002, 7.650003, 9.150001, 12.14999, 16.64998)   # s: periods of the WAMIT files, as printed
SPEC = """[body]
name = "barge"
shape = "mesh"
mesh = "box.gdf"
{modes}
[frequencies]
values = {omega}
[waves]
directions = [0.0]
[water]
density = 1000.0
gravity = 9.81
"""


def write_inputs(folder: Path, panel: float) -> Path:
    """The closed box mesh (box.gdf), one table per mode (mode<k>.csv) and the build spec."""
    import capytaine as cpt

    n = [max(2, round(s / panel)) for s in (LENGTH, WIDTH, HEIGHT)]
    box = cpt.mesh_parallelepiped(size=(LENGTH, WIDTH, HEIGHT), center=(0.0, 0.0, HEIGHT / 2 - DRAFT),
                                  resolution=tuple(n), name="barge")
    corners = np.asarray(box.vertices)[np.asarray(box.faces)].reshape(-1, 3)     # WAMIT GDF: 4 corners a panel
    (folder / "box.gdf").write_text("\n".join(["box barge", "1.0 9.81", "0 0", str(box.nb_faces)]
                                             + [" ".join(f"{c:.9g}" for c in p) for p in corners]) + "\n")
    vertices = cpt.load_mesh(str(folder / "box.gdf")).vertices      # the table's rows: the mesh as read
    table = np.loadtxt(DATA / "modes.txt")                  # x/L from 0, then the four shapes
    xi = (vertices[:, 0] + LENGTH / 2) / LENGTH
    modes = []
    for k in range(1, table.shape[1]):
        w = np.interp(xi, table[:, 0], table[:, k])
        np.savetxt(folder / f"mode{k}.csv", np.c_[np.zeros_like(w), np.zeros_like(w), w], delimiter=",")
        modes.append(f'[[body.modes]]\nkind = "table"\nname = "mode{k}"\nfile = "mode{k}.csv"\n')
    omega = sorted(float(2 * np.pi / t) for t in PERIODS)    # written with 12 digits: the WAMIT rows match
    spec = folder / "barge_gbm.toml"
    spec.write_text(SPEC.format(modes="\n".join(modes), omega=[round(w, 12) for w in omega]))
    return spec


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--panel", type=float, default=2.0, help="panel size of the box mesh (m)")
    parser.add_argument("--keep", type=Path, help="folder to write the mesh, tables and spec to (kept)")
    args = parser.parse_args()
    from hydrolink.server.hdb.build.builder import build_hdb_uncached, load_spec
    from hydrolink.server.hdb.io import load_hdb

    folder = args.keep or Path(tempfile.mkdtemp(prefix="gbm_"))
    folder.mkdir(parents=True, exist_ok=True)
    spec = write_inputs(folder, args.panel)
    built = build_hdb_uncached(load_spec(spec), spec, progress=True)
    wamit = load_hdb(DATA / "barge.1", rho=1000.0, wamit={"iperout": 1})
    omega = built["omega"].values
    rows = [int(np.argmin(np.abs(wamit["omega"].values - w))) for w in omega]   # the same periods
    print(f"panels: {built.attrs['n_panels']} hull + {built.attrs['n_lid_panels']} lid; periods {PERIODS} s")
    print("mode   quantity        " + "  ".join(f"T={2 * np.pi / w:5.1f} s" for w in omega))
    for k in range(6, 10):
        for name, part in (("added_mass", "A"), ("radiation_damping", "B")):
            ours = built[name].values[:, k, k]
            theirs = wamit[name].values[rows, k, k]
            print(f"mode{k - 5}  {part} Capytaine  " + "  ".join(f"{v:10.4g}" for v in ours))
            print(f"       {part} WAMIT      " + "  ".join(f"{v:10.4g}" for v in theirs))
        ours = np.abs(built["excitation_force"].values[:, 0, k])
        theirs = np.abs(wamit["excitation_force"].values[rows, 0, k])
        print(f"       |X| Capytaine  " + "  ".join(f"{v:10.4g}" for v in ours))
        print(f"       |X| WAMIT      " + "  ".join(f"{v:10.4g}" for v in theirs))
        c_ours, c_theirs = built["hydrostatic_stiffness"].values[k, k], wamit["hydrostatic_stiffness"].values[k, k]
        print(f"       C: Capytaine {c_ours:.5g}, WAMIT {c_theirs:.5g} ({100 * (c_ours / c_theirs - 1):+.2f} %)")
    print(f"inputs in {folder}")


if __name__ == "__main__":
    main()
