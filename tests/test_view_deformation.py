"""The deformed mesh of a flexible body (issue 38; clients/view/deformation.py): the flexible
barge's free vibration run through the force server and the Exudyn client, drawn by ``hydrolink
view``: every vertex at p + R (v − r + Σ q_k φ_k(v)) with the free-free beam and torsion shapes
written here (not the build's) and R = Rx Ry Rz of the run's angles, in the frames and in the
ParaView file; a body whose modes' shapes are unknown is drawn rigid with a note naming the key."""

from __future__ import annotations

import math
import shutil
import tomllib
from dataclasses import replace
from pathlib import Path

import h5py
import netCDF4
import numpy as np
import pytest
import xarray as xr

from conftest import toml_document
from test_hdb_build_modes import free_free

from hydrolink.clients.run import run_scene_file
from hydrolink.clients.view.deformation import modal_shapes
from hydrolink.clients.view.frames import ViewOptions, frames, make_stage
from hydrolink.clients.view.results import ViewError, open_run
from hydrolink.clients.view.series import view_results
from hydrolink.protocol.scene import parse_scene

EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "flexible_barge"
LENGTH = 40.0          # the barge's beam: x from -20 to 20 m, reference point at the origin


def rotation(roll: float, pitch: float, yaw: float) -> np.ndarray:
    cx, sx, cy, sy, cz, sz = (math.cos(roll), math.sin(roll), math.cos(pitch), math.sin(pitch), math.cos(yaw),
                              math.sin(yaw))
    rx = np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
    ry = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    rz = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
    return rx @ ry @ rz


def shapes(v: np.ndarray) -> np.ndarray:
    """bend_z1, bend_z2 (Euler-Bernoulli: w = phi, u = -z phi') and twist1 (cos(pi xi) e_x x p) at
    the points ``v`` (3, V, 3)."""
    xi = (v[:, 0] + LENGTH / 2) / LENGTH
    out = np.zeros((3, *v.shape))
    for k in (1, 2):
        phi, d1, _ = free_free(xi, k)
        out[k - 1, :, 2] = phi
        out[k - 1, :, 0] = -v[:, 2] * d1 / LENGTH
    out[2] = np.cos(math.pi * xi)[:, None] * np.cross([1.0, 0.0, 0.0], v)
    return out


def test_the_drawn_barge_deforms_by_its_mode_shapes_times_the_coordinates(tmp_path):
    doc = tomllib.loads((EXAMPLE / "barge.toml").read_text())
    doc["simulation"].update(duration=2.0, dt=0.05)
    doc["waves"] = {"type": "still"}
    doc["hydro"] = {"radiation": "off"}
    body = doc["bodies"][0]
    body["hdb"] = str((EXAMPLE / body["hdb"]).resolve())
    body["initial_displacement"] = [0.0, 0.0, 0.1, 0.04, 0.03, 0.02]
    body["modes"].update(initial_displacement=[0.3, -0.2, 0.05], shapes=str(EXAMPLE / "barge_hdb.toml"))
    scene = tmp_path / "barge.toml"
    scene.write_text(toml_document(doc))
    run_scene_file(scene, tmp_path / "barge.nc", progress=False)

    run = open_run(tmp_path / "barge.nc")
    stage = make_stage(run, ViewOptions(parts=("bodies",)))
    assert stage.notes == [] and stage.meshes[0].shapes is not None
    mesh = stage.meshes[0]
    phi = shapes(mesh.vertices)
    rows = np.arange(0, run.time.size, 8)
    ds = xr.load_dataset(tmp_path / "barge.nc")
    q, x = ds["modal_position"].values, ds["position"].values[:, 0]
    assert np.abs(q[rows]).max() > 0.05 and np.abs(x[rows, 3:]).max() > 0.01
    for row, frame in zip(rows, frames(stage, rows)):
        moved = frame.bodies[0][0]
        r = rotation(*x[row, 3:])
        deformation = np.tensordot(q[row], phi, axes=1)
        np.testing.assert_allclose(moved, x[row, :3] + (mesh.vertices + deformation) @ r.T, rtol=0,
                                   atol=1e-10 * LENGTH)
        # taken apart: the rigid motion of the body's frame, and in it each vertex displaced by q phi
        np.testing.assert_allclose((moved - x[row, :3]) @ r - mesh.vertices, deformation, rtol=0, atol=1e-10 * LENGTH)
    summary, _, written = view_results(tmp_path / "barge.nc", tmp_path / "view", ViewOptions(parts=("bodies",)),
                                       progress=False)
    with h5py.File(tmp_path / "view" / "barge.vtkhdf") as f:
        points = f["VTKHDF/Points"][:].reshape(written.size, -1, 3)
    last = written[-1]
    np.testing.assert_allclose(points[-1], x[last, :3] + (mesh.vertices + np.tensordot(q[last], phi, axes=1))
                               @ rotation(*x[last, 3:]).T, rtol=0, atol=1e-10 * LENGTH)

    body["modes"].pop("shapes")     # the HDB a file and no spec named: drawn rigid, said by key
    rigid = replace(run, scene=parse_scene(toml_document(doc)))
    shapes_of, note = modal_shapes(rigid, 0, mesh.vertices)
    assert shapes_of is None and note.startswith("bodies[0].modes.shapes: body 'barge' is drawn rigid")

    # another spec than the HDB's (a longer barge, same mode names): its shapes would be drawn on
    # these modes' coordinates -- refused by key; an HDB that records no spec: drawn, and said
    other = tmp_path / "other_hdb.toml"
    other.write_text((EXAMPLE / "barge_hdb.toml").read_text().replace("length = 40.0", "length = 44.0"))
    body["modes"]["shapes"] = str(other)
    with pytest.raises(ViewError, match=r"bodies\[0\]\.modes\.shapes.*other_hdb\.toml is not the spec"):
        modal_shapes(replace(run, scene=parse_scene(toml_document(doc))), 0, mesh.vertices)
    unrecorded = tmp_path / "unrecorded.nc"
    shutil.copy(body["hdb"], unrecorded)
    with netCDF4.Dataset(unrecorded, "a") as hdb:
        hdb.delncattr("build_spec_sha256")
    body["hdb"], body["modes"]["shapes"] = str(unrecorded), str(EXAMPLE / "barge_hdb.toml")
    shapes_of, note = modal_shapes(replace(run, scene=parse_scene(toml_document(doc))), 0, mesh.vertices)
    assert shapes_of is not None and "records no build spec" in note
