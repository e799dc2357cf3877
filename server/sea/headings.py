"""Wave headings of HDB data: interpolation on the circle, and mirrored half ranges.

One rule for every quantity given per heading (linear excitation, mean drift, QTF heading pairs):
a heading ``beta`` (rad, any labelling) is put on the circle, and the HDB's headings too, whatever
range they are listed in (0..360, -180..180, 0..345, a half range); headings that coincide on the
circle (0 and 360) are one point whose value is their mean. Between two neighbouring points on the
circle the value is interpolated linearly in angle, **except across the largest gap when it is
larger than every other gap**: that gap is the range the data leave out (a half range 0..180 leaves
out 180..360; 0..90 leaves out 90..360), and a heading inside it is refused (a ``WaveError`` naming
the scene key). A full circle at even spacing (0..345 every 15 deg) has no such gap, so 350 deg is
interpolated between 345 and 0, and -170 deg (= 190) between 180 and 195: the same value however the
file labels its headings. A single heading serves only itself.

A half range of a body symmetric about a vertical plane through the origin is completed by its
mirror images (``bodies[i].heading_symmetry``, :func:`mirror_headings`): for the plane y = 0 ("xz",
port-starboard symmetry) the wave from -beta gives the force of beta with sway, roll and yaw
reversed; for x = 0 ("yz", fore-aft) the wave from pi - beta, with surge, pitch and yaw reversed
(the moments are pseudovectors: a reflection R turns M into det(R) R M).
"""

from __future__ import annotations

import numpy as np
import xarray as xr

from hydrolink.protocol.scene import Scene
from hydrolink.server.sea.waves import WaveError

TOL = 1e-6   # rad: two headings closer than this on the circle are one point

#: per plane of symmetry: the mirrored heading and the sign of each DOF's force under the mirror
MIRRORS = {
    "xz": (lambda b: -b, np.array([1.0, -1.0, 1.0, -1.0, 1.0, -1.0])),
    "yz": (lambda b: np.pi - b, np.array([-1.0, 1.0, 1.0, 1.0, -1.0, -1.0])),
}
SYMMETRY_PLANES = {"none": (), "xz": ("xz",), "yz": ("yz",), "both": ("xz", "yz")}


def _circle(grid: np.ndarray) -> tuple[np.ndarray, list[np.ndarray]]:
    """The distinct points of ``grid`` on [0, 2 pi) (sorted) and the grid indices at each."""
    m = np.mod(np.asarray(grid, float), 2 * np.pi)
    m[m > 2 * np.pi - TOL] = 0.0
    order = np.argsort(m, kind="stable")
    points: list[float] = []
    members: list[list[int]] = []
    for i in order:
        if points and m[i] - points[-1] <= TOL:
            members[-1].append(int(i))
        else:
            points.append(float(m[i]))
            members.append([int(i)])
    return np.array(points), [np.array(g) for g in members]


def _degrees(values) -> list[float]:
    return np.round(np.rad2deg(np.asarray(values, float)), 4).tolist()


def heading_weights(grid, beta, key: str, what: str = "the HDB's headings") -> np.ndarray:
    """(n_beta, n_grid) weights W so that f(beta_k) = sum_h W[k, h] f(grid_h) (module docstring);
    WaveError(key) for a heading in the gap the data leave out."""
    grid = np.atleast_1d(np.asarray(grid, float))
    beta = np.atleast_1d(np.asarray(beta, float))
    points, members = _circle(grid)
    n = points.size
    w = np.zeros((beta.size, grid.size))
    gaps = np.diff(np.append(points, points[0] + 2 * np.pi)) if n > 1 else np.array([2 * np.pi])
    widest = int(np.argmax(gaps))
    others = np.delete(gaps, widest)
    hole = widest if (n == 1 or gaps[widest] > (others.max() if others.size else 0.0) + TOL) else -1
    b = np.mod(beta, 2 * np.pi)
    for k, bk in enumerate(b):
        d = np.abs(np.angle(np.exp(1j * (points - bk))))
        near = int(np.argmin(d))
        if d[near] <= TOL:
            w[k, members[near]] = 1.0 / members[near].size
            continue
        j = int(np.searchsorted(points, bk) - 1) % n   # the point before bk on the circle
        if j == hole:
            lo, hi = points[j], points[(j + 1) % n]
            raise WaveError(key, f"{np.rad2deg(beta[k]):.6g} deg is not covered by {what} "
                                 f"{_degrees(grid)} deg: it lies in the gap {np.rad2deg(lo):.6g}..."
                                 f"{np.rad2deg(hi) + (360.0 if hi <= lo else 0.0):.6g} deg they leave out (headings "
                                 "are interpolated around the circle except across that gap); give data covering it, "
                                 "or bodies[i].heading_symmetry for the half range of a symmetric body")
        s = float(np.mod(bk - points[j], 2 * np.pi) / gaps[j])
        w[k, members[j]] += (1.0 - s) / members[j].size
        w[k, members[(j + 1) % n]] += s / members[(j + 1) % n].size
    return w


def interpolate_excitation(omega_hdb: np.ndarray, directions: np.ndarray, x: np.ndarray,
                           omega: np.ndarray, beta: float, key: str = "waves.direction") -> np.ndarray:
    """X at (omega, beta): x (n_w, n_b, n) complex -> (n_c, n); linear in re/im in w, and in heading
    around the circle (:func:`heading_weights`; WaveError(key) for a heading the data leave out)."""
    wb = heading_weights(directions, beta, key)[0]
    xb = sum(wb[h] * x[:, h, :] for h in np.flatnonzero(wb))  # (n_w, n): at most a few headings
    omega = np.asarray(omega, float)
    if omega.size == 0:
        return np.zeros((0, x.shape[2]), complex)
    re = np.stack([np.interp(omega, omega_hdb, xb[:, m].real) for m in range(xb.shape[1])], axis=1)
    im = np.stack([np.interp(omega, omega_hdb, xb[:, m].imag) for m in range(xb.shape[1])], axis=1)
    return re + 1j * im


def _new_headings(existing: np.ndarray, mirrored: np.ndarray) -> np.ndarray:
    """Indices of ``mirrored`` not already on the circle among ``existing``."""
    keep = []
    for i, b in enumerate(mirrored):
        if np.all(np.abs(np.angle(np.exp(1j * (existing - b)))) > TOL) and \
                all(abs(np.angle(np.exp(1j * (mirrored[j] - b)))) > TOL for j in keep):
            keep.append(i)
    return np.array(keep, int)


def _mirror_axis(ds: xr.Dataset, dim: str, plane: str, sign: np.ndarray) -> xr.Dataset:
    """``ds`` with the mirror images of its headings along ``dim`` (a 1-D heading coordinate) added."""
    flip, _ = MIRRORS[plane]
    old = ds[dim].values.astype(float)
    add = _new_headings(old, flip(old))
    if add.size == 0:
        return ds
    names = [v for v in ds.data_vars if dim in ds[v].dims]
    mirrored = ds[names].isel({dim: add}).assign_coords({dim: flip(old[add])})
    mirrored = mirrored * xr.DataArray(sign, dims=("influenced_dof",))
    out = xr.concat([ds[names], mirrored], dim=dim).sortby(dim)
    return ds.drop_dims(dim).assign(out.data_vars).assign_coords({dim: out[dim]})


def _mirror_pairs(ds: xr.Dataset, plane: str, sign: np.ndarray) -> xr.Dataset:
    """``ds`` with the mirror images of its QTF heading pairs added."""
    flip, _ = MIRRORS[plane]
    bi, bj = ds["qtf_direction_i"].values.astype(float), ds["qtf_direction_j"].values.astype(float)
    pairs = np.exp(1j * bi) + 2 * np.exp(1j * bj)   # a pair as one point (distinct pairs stay distinct)
    mi, mj = flip(bi), flip(bj)
    mp = np.exp(1j * mi) + 2 * np.exp(1j * mj)
    add = [k for k in range(bi.size) if np.all(np.abs(pairs - mp[k]) > TOL)]
    add = [k for n, k in enumerate(add) if all(abs(mp[k] - mp[q]) > TOL for q in add[:n])]
    if not add:
        return ds
    names = [v for v in ds.data_vars if "qtf_heading" in ds[v].dims]
    part = ds[names].isel(qtf_heading=add) * xr.DataArray(sign, dims=("influenced_dof",))
    part = part.assign_coords(qtf_direction_i=("qtf_heading", mi[add]), qtf_direction_j=("qtf_heading", mj[add]))
    out = xr.concat([ds[names], part], dim="qtf_heading")
    return ds.drop_dims("qtf_heading").assign(out.data_vars)


def mirror_headings(ds: xr.Dataset, symmetry: str, key: str) -> xr.Dataset:
    """The HDB ``ds`` completed by the mirror images of its headings (excitation, mean drift and QTF
    heading pairs) for a body symmetric about the plane(s) ``symmetry`` ("none", "xz", "yz", "both";
    module docstring). Every body of the HDB must lie on the plane (its reference point): else the
    mirror maps it onto another place and a WaveError names ``key``."""
    planes = SYMMETRY_PLANES[symmetry]
    if not planes:
        return ds
    refs = ds["reference_point"].values
    n_bodies = refs.shape[0]
    for plane in planes:
        axis = 1 if plane == "xz" else 0
        off = np.flatnonzero(np.abs(refs[:, axis]) > 1e-6)
        if off.size:
            raise WaveError(key, f"{symmetry!r}: the HDB {ds.attrs.get('source', '?')!r} body "
                                 f"{str(ds['body'].values[off[0]])!r} has its reference point at "
                                 f"{'y' if axis else 'x'} = {refs[off[0], axis]:g} m, off the plane of symmetry "
                                 f"{'y' if axis else 'x'} = 0: its mirror image is another layout")
        sign = np.tile(MIRRORS[plane][1], n_bodies)
        out = _mirror_axis(ds, "wave_direction", plane, sign)
        if "drift_direction" in ds.dims:
            out = _mirror_axis(out, "drift_direction", plane, sign)
        if "qtf_heading" in ds.dims:
            out = _mirror_pairs(out, plane, sign)
        out.attrs = dict(ds.attrs)
        ds = out
    return ds


def complete_headings(scene: Scene, hdbs: dict[str, xr.Dataset]) -> dict[str, xr.Dataset]:
    """The bodies' HDBs (by body name) completed by :func:`mirror_headings` as each body's
    ``heading_symmetry`` says; bodies that share one dataset share the completed one, and must
    state the same symmetry (it is the HDB's, not the body's): else WaveError naming the key."""
    done: dict[int, tuple[str, int, xr.Dataset]] = {}
    out = dict(hdbs)
    for i, body in enumerate(scene.bodies):
        ds = hdbs.get(body.name)
        if ds is None:
            continue
        key = f"bodies[{i}].heading_symmetry"
        if id(ds) in done:
            symmetry, first, completed = done[id(ds)]
            if symmetry != body.heading_symmetry:
                raise WaveError(key, f"{body.heading_symmetry!r} but bodies[{first}] shares its HDB and states "
                                     f"{symmetry!r}: the symmetry is the HDB's, state the same for both")
            out[body.name] = completed
            continue
        completed = mirror_headings(ds, body.heading_symmetry, key)
        done[id(ds)] = (body.heading_symmetry, i, completed)
        out[body.name] = completed
    return out
