"""Meshes for ``hdb build``: primitives, compound bodies, mesh files, lids, xOz symmetry.

Every hull is the **immersed part** only; surface-piercing parts get a lid just below the free
surface against irregular frequencies. A lone primitive body keeps Capytaine's own symmetries
(axisymmetric cylinder/sphere, mirror-symmetric box at the origin); compound bodies and the bodies
of a multi-body build are plain meshes, turned into one xOz mirror-symmetric problem when every
hull and lid is symmetric about y = 0 (half the panels in the influence matrices: about 4x faster).
"""

from __future__ import annotations

import math
import warnings
from pathlib import Path

import numpy as np

from hydrolink.server.hdb.reader_warnings import HDBWarning
from hydrolink.server.hdb.build.spec import BodySpec, BuildSpec, PartSpec, SpecError, mesh_path
from hydrolink.server.hdb.build.overlap import Hull, overlap


def default_panel_size(spec: BuildSpec, body: BodySpec | None = None) -> float:
    """A modest default: a sixth of the body's smallest dimension (radius, half length/width, the
    draft of a surface-piercing part; a submerged part's thickness is not counted, so a thin
    plate does not force tiny panels), and at most lambda_min / 8 for the shortest wave (Capytaine
    warns when a panel's radius, about 0.7 x its edge, exceeds lambda / 8)."""
    body = body if body is not None else spec.all_bodies[0]
    dims = []
    for p in body.global_parts():
        dims += [d for d in (p.radius, p.length and p.length / 2, p.width and p.width / 2) if d]
        if p.draft and p.pierces:
            dims.append(p.draft)
    w_max = float(spec.frequencies.omega.max())
    k_max = w_max ** 2 / spec.water.gravity  # deep-water wavenumber: shortest wave (conservative)
    return min([d / 6 for d in dims] + [(2 * np.pi / k_max) / 8])


def _lid_depth(hull) -> float:
    """Lid just below the free surface (1 % of the immersed depth). A lid at depth d moves the
    first irregular frequency up to roughly sqrt(g k coth(k d)), i.e. far above any grid here;
    deeper lids (e.g. Capytaine's ``lowest_lid_position``) gave visibly noisier damping and
    excitation on coarse meshes of the example cylinder, a lid at 1 % converged smoothly."""
    return -0.01 * max(1e-3, -float(hull.z_span[0]))


def _axisymmetric_lid(hull, z: float, n_theta: int, h: float, axis_xy: tuple[float, float]):
    """A disk lid at depth z inside an axisymmetric hull of n_theta sectors: its radius is the
    hull's radius at z (from the panel edges crossing z) times cos(pi/n), so it stays inside."""
    import capytaine as cpt

    merged = hull.merged() if hasattr(hull, "merged") else hull
    v = merged.vertices
    radii = []
    for face in merged.faces:
        pts = v[face]
        for a, b in zip(pts, np.roll(pts, -1, axis=0)):
            if (a[2] - z) * (b[2] - z) <= 0 and a[2] != b[2]:
                p = a + (z - a[2]) / (b[2] - a[2]) * (b - a)
                radii.append(math.hypot(p[0] - axis_xy[0], p[1] - axis_xy[1]))
    if not radii:
        return None
    r = min(radii) * math.cos(np.pi / n_theta)
    if r <= 0:
        return None
    return _downward(cpt.mesh_disk(radius=r, center=(axis_xy[0], axis_xy[1], z), normal=(0, 0, 1),
                                   resolution=(max(1, int(math.ceil(r / h))), n_theta),
                                   axial_symmetry=True, name="lid"))


def _rectangle(x0: float, x1: float, y0: float, y1: float, z: float, nx: int, ny: int):
    """Horizontal rectangle of nx x ny quads at height z, normals pointing down (as a lid's)."""
    import capytaine as cpt

    xs, ys = np.linspace(x0, x1, nx + 1), np.linspace(y0, y1, ny + 1)
    vertices = np.array([(x, y, z) for x in xs for y in ys])
    at = lambda i, j: i * (ny + 1) + j  # noqa: E731
    # (i,j) -> (i,j+1) -> (i+1,j+1) -> (i+1,j) turns clockwise seen from above: normal down
    faces = np.array([(at(i, j), at(i, j + 1), at(i + 1, j + 1), at(i + 1, j))
                      for i in range(nx) for j in range(ny)])
    return cpt.Mesh(vertices=vertices, faces=faces, name="lid")


def _box_lid(p: PartSpec, z: float, res: tuple[int, int], symmetric: bool):
    """Lid covering the box's interior waterplane; mirrors the hull's nested symmetry if any."""
    import capytaine as cpt

    nx, ny = res
    if symmetric:  # mesh_parallelepiped(reflection_symmetry=True): xOz of (yOz of the x<0, y<0 quarter)
        quarter = _rectangle(-p.length / 2, 0, -p.width / 2, 0, z, nx // 2, ny // 2)
        return cpt.ReflectionSymmetricMesh(cpt.ReflectionSymmetricMesh(quarter, plane="yOz"), plane="xOz",
                                           name="lid")
    cx, cy = p.center[:2]
    return _rectangle(cx - p.length / 2, cx + p.length / 2, cy - p.width / 2, cy + p.width / 2, z, nx, ny)


def _downward(mesh):
    """The same mesh with normals pointing down, keeping its rotation symmetry (Capytaine would
    otherwise flip it itself, with a warning)."""
    import capytaine as cpt

    if isinstance(mesh, cpt.RotationSymmetricMesh):
        return cpt.RotationSymmetricMesh(_downward(mesh.wedge), mesh.n, axis=mesh.axis, name=mesh.name)
    if np.all(mesh.faces_normals[:, 2] > 0):
        return cpt.Mesh(vertices=mesh.vertices, faces=mesh.faces[:, ::-1], name=mesh.name)
    return mesh


def _closed_primitive(p: PartSpec, h: float, name: str, *, symmetric: bool, even_theta: bool, top: float | None):
    """The closed mesh of one primitive with panel size h, from -draft up to ``top`` (cylinders and
    boxes; None for a sphere), and its number of sectors and horizontal resolution (for lids)."""
    import capytaine as cpt

    cx, cy, cz = p.center
    n_theta, res_xy = 0, (0, 0)
    if p.shape in ("vertical_cylinder", "sphere"):
        n_theta = max(12, int(math.ceil(2 * np.pi * p.radius / h)))
        n_theta += (-n_theta) % 4 if even_theta else 0  # Capytaine's sectors straddle y = 0 when n/2 is odd
    if p.shape == "vertical_cylinder":
        # equal-area polygon: the waterplane area and displaced volume are exact
        r_mesh = p.radius * math.sqrt(2 * np.pi / (n_theta * math.sin(2 * np.pi / n_theta)))
        n_r = max(2, int(math.ceil(p.radius / h)))
        n_z = max(2, int(math.ceil((top + p.draft) / h)))
        if p.top >= 0:
            n_z += n_z % 2
        full = cpt.mesh_vertical_cylinder(length=top + p.draft, radius=r_mesh,
                                          center=(0, 0, (top - p.draft) / 2),
                                          resolution=(n_r, n_theta, n_z), axial_symmetry=symmetric, name=name)
        full = full.translated((cx, cy, 0.0), name=name) if (cx or cy) else full
    elif p.shape == "sphere":
        n_z = max(8, int(math.ceil(np.pi * p.radius / h)))
        n_z += n_z % 2
        unit = cpt.mesh_sphere(radius=p.radius, center=(0, 0, 0), resolution=(n_z, n_theta),
                               axial_symmetry=True, name=name)
        # volume-preserving polyhedron: scale so the closed mesh holds (4/3) pi R^3
        scale = ((4 / 3) * np.pi * p.radius ** 3 / unit.volume) ** (1 / 3)
        full = cpt.mesh_sphere(radius=p.radius * scale, center=(cx, cy, cz), resolution=(n_z, n_theta),
                               axial_symmetry=symmetric, name=name)
    else:
        n_z = max(1 if p.top < 0 else 2, int(math.ceil((top + p.draft) / h)))
        if p.top >= 0:
            n_z += n_z % 2
        res_xy = tuple(max(2, 2 * int(math.ceil(L / (2 * h)))) for L in (p.length, p.width))
        full = cpt.mesh_parallelepiped(size=(p.length, p.width, top + p.draft),
                                       center=(cx, cy, (top - p.draft) / 2), resolution=res_xy + (n_z,),
                                       reflection_symmetry=symmetric and cx == 0 and cy == 0, name=name)
    return full, n_theta, res_xy


def _primitive(p: PartSpec, h: float, name: str, depth: float, *, lid: bool, symmetric: bool,
               even_theta: bool = False):
    """Hull (immersed part) and lid (or None) of one primitive with panel size h.

    ``symmetric``: use Capytaine's symmetric meshes (only for a lone body). ``even_theta``: a
    number of sectors divisible by 4, so the merged mesh can be split at y = 0 (xOz symmetry)."""
    import capytaine as cpt

    cx, cy, _ = p.center
    # top at +draft when it pierces the surface, so z = 0 falls on a panel edge before clipping
    full, n_theta, res_xy = _closed_primitive(p, h, name, symmetric=symmetric, even_theta=even_theta,
                                              top=None if p.shape == "sphere" else p.draft if p.top >= 0 else p.top)
    hull = full.immersed_part(water_depth=depth)
    if not (lid and p.pierces and hull.nb_faces):
        return hull, None
    if p.shape == "box":
        z_lid = -0.01 * p.draft
        return hull, _box_lid(p, z_lid, res_xy, symmetric=isinstance(hull, cpt.ReflectionSymmetricMesh))
    return hull, _axisymmetric_lid(hull, _lid_depth(hull), n_theta, h, (cx, cy))


def _merged(mesh):
    return mesh.merged() if hasattr(mesh, "merged") else mesh


def _join(meshes: list, name: str):
    """One plain mesh from several (symmetries dropped first: no Capytaine warning)."""
    meshes = [_merged(m) for m in meshes if m is not None and m.nb_faces]
    if not meshes:
        return None
    return meshes[0].join_meshes(*meshes[1:], name=name) if len(meshes) > 1 else meshes[0]


def read_mesh_file(body: BodySpec, key: str, spec_path: str | Path):
    """A mesh body's whole mesh from its file, moved to the body's ``center``."""
    import capytaine as cpt

    path = mesh_path(body, spec_path)
    if not path.is_file():
        raise SpecError(spec_path, f"{key}.mesh", f"mesh file not found: {path}")
    try:
        full = cpt.load_mesh(str(path), body.mesh_format) if body.mesh_format else cpt.load_mesh(str(path))
    except Exception as exc:  # noqa: BLE001 - any reader failure is a bad spec input
        raise SpecError(spec_path, f"{key}.mesh", f"cannot read mesh {path}: {exc}") from None
    return full.translated(tuple(body.center), name=body.name) if any(body.center) else full


def _file_mesh(body: BodySpec, key: str, spec_path: str | Path, depth: float):
    full = read_mesh_file(body, key, spec_path)
    hull = full.immersed_part(water_depth=depth)
    if hull.nb_faces == 0 or not body.lid or hull.z_span[1] < -1e-9:
        return hull, None
    z_lid = _lid_depth(hull)
    lid = hull.generate_lid(z=z_lid)
    if lid.nb_faces == 0 and hasattr(hull, "merged"):
        lid = hull.merged().generate_lid(z=z_lid)
    if lid.nb_faces == 0:
        warnings.warn(f"{spec_path}: {key}.lid: Capytaine could not generate a lid for this mesh; "
                      f"solving without one (irregular frequencies may show up)", HDBWarning, stacklevel=4)
        return hull, None
    return hull, lid


def body_meshes(spec: BuildSpec, index: int, spec_path: str | Path, *, lone: bool):
    """Hull (immersed part) and lid (or None) of ``spec.all_bodies[index]`` in the global frame.
    ``lone``: the only body of the build (keeps Capytaine's symmetric primitive meshes)."""
    body, key = spec.all_bodies[index], spec.body_keys[index]
    depth = spec.water.depth_m
    if body.shape == "mesh":
        hull, lid = _file_mesh(body, key, spec_path, depth)
    else:
        h_body = body.panel_size or default_panel_size(spec, body)
        parts = body.global_parts()
        symmetric = lone and body.shape != "compound"
        pieces = [_primitive(p, p.panel_size or h_body, body.name, depth, lid=body.lid, symmetric=symmetric,
                             even_theta=not symmetric) for p in parts]
        if symmetric:
            hull, lid = pieces[0]
        else:
            hull = _join([hl for hl, _ in pieces], body.name)
            lid = _join([ld for _, ld in pieces], "lid")
    if hull is None or hull.nb_faces == 0:
        raise SpecError(spec_path, f"{key}.mesh" if body.shape == "mesh" else f"{key}.center",
                        "no part of the body is below the free surface z = 0")
    if body.lid and lid is None and body.shape != "mesh" and any(p.pierces for p in body.global_parts()):
        warnings.warn(f"{spec_path}: {key}.lid: no lid could be built; solving without one", HDBWarning, stacklevel=3)
    return hull, lid


def closed_hull(spec: BuildSpec, index: int, spec_path: str | Path):
    """The whole closed hull of ``spec.all_bodies[index]`` (freeboard and deck included, no lid),
    global frame, as (vertices (V, 3), faces (F, 4)): what nonlinear hydrostatics integrate over
    (server/terms/nonlinear/term.py). Primitives use the body's panel size; a mesh body is its file."""
    body, key = spec.all_bodies[index], spec.body_keys[index]
    if body.shape == "mesh":
        meshes = [read_mesh_file(body, key, spec_path)]
    else:
        h_body = body.panel_size or default_panel_size(spec, body)
        meshes = [_closed_primitive(p, p.panel_size or h_body, body.name, symmetric=False, even_theta=False,
                                    top=None if p.shape == "sphere" else p.top)[0] for p in body.global_parts()]
    joined = _join(meshes, body.name)
    return np.asarray(joined.vertices, float), np.asarray(joined.faces)


def xoz_symmetric(mesh, tol: float = 1e-9):
    """The mesh as Capytaine's xOz ReflectionSymmetricMesh when it is mirror-symmetric about y = 0
    with no panel crossing the plane, else None."""
    import capytaine as cpt

    if isinstance(mesh, cpt.ReflectionSymmetricMesh) and mesh.plane == "xOz":
        return mesh
    m = _merged(mesh)
    centers = m.faces_centers
    neg, pos = centers[:, 1] < -tol, centers[:, 1] > tol
    if np.any(~(neg | pos)) or neg.sum() != pos.sum():
        return None
    half = m.extract_faces(np.flatnonzero(neg))
    if half.vertices[half.faces][..., 1].max() > tol * max(1.0, float(np.abs(m.vertices).max())):
        return None
    mirrored = half.mirrored("xOz")
    want = np.round(centers[pos] / tol ** 0.5) * tol ** 0.5
    got = np.round(mirrored.faces_centers / tol ** 0.5) * tol ** 0.5
    if not np.array_equal(np.unique(want, axis=0), np.unique(got, axis=0)):
        return None
    return cpt.ReflectionSymmetricMesh(half, plane="xOz", name=m.name)


def check_apart(hulls: list, spec: BuildSpec, spec_path: str | Path) -> None:
    """Bodies whose immersed hulls intersect, hold one another or touch are an error naming both
    (the meshes themselves are compared: mesh_overlap.py). Mesh-file bodies are only checked here;
    primitives were checked when the spec was read."""
    bodies, keys = spec.all_bodies, spec.body_keys
    solids = [None] * len(hulls)
    for j in range(len(hulls)):
        for i in range(j):
            if "mesh" not in (bodies[i].shape, bodies[j].shape):
                continue
            for k in (i, j):
                if solids[k] is None:
                    m = _merged(hulls[k])
                    solids[k] = Hull.from_mesh(m.vertices, m.faces)
            found = overlap(solids[i], solids[j])
            if found.how is not None:
                verb = {"intersect": "intersects", "contains": "is inside or holds", "touch": "touches"}[found.how]
                raise SpecError(spec_path, f"{keys[j]}.center",
                                f"the immersed hull of {bodies[j].name!r} {verb} that of {keys[i]} ({bodies[i].name!r}): "
                                f"{found.detail}; move the bodies apart")


__all__ = ["read_mesh_file", "body_meshes", "check_apart", "default_panel_size", "xoz_symmetric"]
