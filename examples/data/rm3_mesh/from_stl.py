"""Convert WEC-Sim's RM3 STL geometry to WAMIT GDF meshes in hydrolink's global frame at equilibrium.

WEC-Sim's ``examples/RM3/geometry/{float,plate}.stl`` are given about each body's centre of gravity;
the GDF files here are those triangles moved to the global frame (float CG z = -0.72 m, spar/plate
CG z = -21.29 m: the WAMIT body origins of ``../rm3_wamit``), one panel per triangle (its third
vertex repeated), duplicate vertices merged. Needs the ``vtk`` package (its STL reader):

    python examples/data/rm3_mesh/from_stl.py float.stl plate.stl
"""

import sys
from pathlib import Path

import numpy as np
import vtk
from vtk.util.numpy_support import vtk_to_numpy

CG_Z = {"float": -0.72, "plate": -21.29}


def triangles(stl: Path) -> np.ndarray:
    """(F, 3, 3) triangle corners of an STL file, duplicate points merged."""
    reader = vtk.vtkSTLReader()
    reader.SetFileName(str(stl))
    clean = vtk.vtkCleanPolyData()
    clean.SetInputConnection(reader.GetOutputPort())
    clean.Update()
    poly = clean.GetOutput()
    points = vtk_to_numpy(poly.GetPoints().GetData()).astype(float)
    cells = vtk_to_numpy(poly.GetPolys().GetConnectivityArray()).reshape(-1, 3)
    return points[cells]


def write_gdf(path: Path, tri: np.ndarray, title: str) -> None:
    """WAMIT GDF: title, ULEN GRAV, ISX ISY, panel count, four vertices per panel."""
    lines = [title, "1.0 9.81", "0 0", str(len(tri))]
    for a, b, c in tri:
        lines += [" ".join(f"{v:.6f}" for v in p) for p in (a, b, c, c)]
    path.write_text("\n".join(lines) + "\n")


if __name__ == "__main__":
    for name in sys.argv[1:]:
        stl = Path(name)
        tri = triangles(stl) + np.array([0.0, 0.0, CG_Z[stl.stem]])
        write_gdf(Path(__file__).with_name(f"{stl.stem}.gdf"), tri,
                  f"RM3 {stl.stem}: WEC-Sim examples/RM3/geometry/{stl.name}, global frame at equilibrium")
