"""A WAMIT run's structure of its generalized modes (server/hdb/wamit/modal_structure.py,
``hydrolink hdb modes``): WEC-Sim's GBM barge's .mmx external force matrices as a scene's
[bodies.modes] table, checked against the run's input, its .frc, read here."""

from __future__ import annotations

import re
import shutil
import tomllib
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import xarray as xr
from click.testing import CliRunner

from hydrolink.clients.cli import cli
from hydrolink.protocol.hdb.layout import BodyDofs, HDBError
from hydrolink.protocol.scene import BodyModes
from hydrolink.server.hdb.wamit.modal_structure import modes_table

GBM = Path(__file__).resolve().parents[1] / "examples" / "data" / "wamit_gbm_barge"
SCENE = f"""[simulation]
dt = 0.1
duration = 10.0
[water]
density = 1000.0
[waves]
type = "regular"
height = 1.0
period = 10.65
[hydro]
radiation = "constant"          # the trimmed run's periods (23 of 0.15-150 s) alias any IRF
[[bodies]]
name = "barge"
hdb = "{GBM / 'barge.1'}"
mass = 4.0e6
center_of_mass = [0.0, 0.0, 0.0]
inertia = [6.666667e7, 2.166667e9, 2.166667e9]
[bodies.wamit]
iperout = 1
"""


def frc_matrices() -> tuple[np.ndarray, np.ndarray]:
    """The .frc's external mass and stiffness (IALTFRC = 2: a flag line then 10 rows each; damping
    flagged 0), read here."""
    lines = [line.split() for line in (GBM / "barge.frc").read_text().splitlines()[4:] if line.strip()]
    assert lines[0] == ["1"] and lines[11] == ["0"] and lines[12] == ["1"]
    mass = np.array([[float(v) for v in row] for row in lines[1:11]])
    stiffness = np.array([[float(v) for v in row] for row in lines[13:23]])
    return mass, stiffness


def test_the_cli_prints_the_frc_s_modal_block_as_a_scene_table(tmp_path):
    scene = tmp_path / "scene.toml"
    scene.write_text(SCENE)
    result = CliRunner().invoke(cli, ["hdb", "modes", str(scene)])
    assert result.exit_code == 0, result.output
    assert result.output.startswith("# bodies[0] (barge)")
    table = BodyModes(**tomllib.loads(result.output)["bodies"]["modes"])
    mass, stiffness = frc_matrices()
    assert table.names == ["mode1", "mode2", "mode3", "mode4"]
    np.testing.assert_allclose(table.matrix("mass"), mass[6:, 6:], rtol=1e-6)
    np.testing.assert_allclose(table.matrix("stiffness"), stiffness[6:, 6:], rtol=1e-6)
    assert not table.matrix("damping").any()
    scene.write_text(SCENE + "\n" + result.output)      # pasted, the scene sets up (without IRF settings)
    from hydrolink.clients.scene_inputs import load_scene_hdbs
    from hydrolink.protocol.scene import load_scene
    from hydrolink.server.model import HydroModel
    parsed, _ = load_scene(scene)
    model = HydroModel(parsed, {"barge": load_scene_hdbs(parsed, scene, progress=False)[str(GBM / "barge.1")]},
                       compiled=False)
    assert model.setup_info().modes == {"barge": table.names}
    assert not [w for w in model.setup_info().warnings if "irf" in w]


def test_a_coupling_is_said_and_a_file_without_matrices_is_an_error(tmp_path):
    text = (GBM / "barge.mmx").read_text()
    coupled = tmp_path / "coupled.mmx"   # mass(3, 7) = 5e4: heave coupled to mode1
    coupled.write_text(text.replace("     3     7     0.000000E+00", "     3     7     5.000000E+04", 1))
    dofs = BodyDofs(("barge",), (("mode1", "mode2", "mode3", "mode4"),))
    assert "couples the rigid DOFs and the modes in mass" in modes_table(coupled, dofs, "barge")
    empty = tmp_path / "empty.mmx"
    empty.write_text(text.split("External force matrices")[0])
    with pytest.raises(HDBError, match=r"empty\.mmx: External force matrices: none in the file"):
        modes_table(empty, dofs, "barge")


# ------------------------------------------------------------------ the structure read from the .mmx

BARGE = Path(__file__).resolve().parents[1] / "examples" / "flexible_barge" / "barge.toml"


def write_mmx(path: Path, mass: np.ndarray, damping: np.ndarray, stiffness: np.ndarray) -> Path:
    """A WAMIT .mmx of one body's external force matrices (every pair, WAMIT's layout), each value
    written to 17 digits (so it reads back to the same float)."""
    rows = [f"{i + 1:6d}{j + 1:6d}  {mass[i, j]: .16E}  {damping[i, j]: .16E}  {stiffness[i, j]: .16E}"
            for i in range(len(mass)) for j in range(len(mass))]
    path.write_text(" WAMIT -- Force Output File -- test\n\n NBODY =     1       IALTFRC = 2\n\n"
                    " WAMIT  Ouputs for body N =     1    IALTFRCN = 2\n\n External force matrices:\n"
                    "     I     J      MASS(I,J)      DAMP(I,C)      STIF(I,J)\n" + "\n".join(rows) + "\n")
    return path


def example_scene(duration: float) -> dict:
    """The flexible-barge example's scene (its HDB's and build spec's paths made absolute),
    ``duration`` s long."""
    from hydrolink.clients.studies.grid import absolute_paths
    doc = absolute_paths(tomllib.loads(BARGE.read_text()), BARGE)
    doc["simulation"]["duration"] = duration
    return doc


def example_mmx(path: Path, doc: dict, *, rigid_mass: bool = True) -> Path:
    """The example's structure (its body's rigid mass about the reference point, the centre of mass
    there; each mode's modal mass, stiffness, damping) as the .mmx of a run numbered 6 + 3."""
    body = doc["bodies"][0]
    modes = body["modes"]
    rigid = [body["mass"]] * 3 + body["inertia"] if rigid_mass else [0.0] * 6
    return write_mmx(path, np.diag(rigid + modes["mass"]), np.diag([0.0] * 6 + modes["damping"]),
                     np.diag([0.0] * 6 + modes["stiffness"]))


def with_file(doc: dict, mmx: Path, **modes) -> dict:
    """``doc`` with its body's modes' structure from ``mmx`` (names kept, or as given)."""
    out = {**doc, "bodies": [{**doc["bodies"][0], "modes": {"names": doc["bodies"][0]["modes"]["names"],
                                                           "mmx": mmx.name, **modes}}]}
    return out


def test_the_example_s_structure_from_an_mmx_runs_bit_for_bit(tmp_path):
    """The example's hand-given structure and the same numbers in an .mmx beside the scene (names
    listed in another order there) give the same run, every variable of every row identical; the
    file's rigid block, the body's mass matrix, draws no warning."""
    from conftest import toml_document
    from hydrolink.clients.run import run_scene_file

    doc = example_scene(duration=5.0)
    example_mmx(tmp_path / "barge.mmx", doc)
    (tmp_path / "tables.toml").write_text(toml_document(doc))
    (tmp_path / "file.toml").write_text(toml_document(with_file(doc, tmp_path / "barge.mmx")))
    reordered = with_file(doc, tmp_path / "barge.mmx")
    reordered["bodies"][0]["modes"]["names"] = ["twist1", "bend_z1", "bend_z2"]
    (tmp_path / "reordered.toml").write_text(toml_document(reordered))
    runs = {}
    for name in ("tables", "file", "reordered"):
        run_scene_file(tmp_path / f"{name}.toml", tmp_path / f"{name}.nc", progress=False)
        runs[name] = xr.load_dataset(tmp_path / f"{name}.nc")
    ref = runs["tables"]
    assert ref.sizes["time"] == 101 and np.abs(ref["modal_position"].values).max() > 1e-4
    for name in ("file", "reordered"):
        ds = runs[name]
        assert set(ds.data_vars) == set(ref.data_vars), name
        for var in ref.data_vars:
            if "time" in ref[var].dims:
                assert np.array_equal(ds[var].values, ref[var].values), (name, var)
    assert ds.attrs["warnings"] == ref.attrs["warnings"]


def _load(tmp_path: Path, doc: dict):
    """The scene ``doc`` written beside its files, parsed and its structure files read (as
    ``hydrolink run`` does before any step)."""
    from conftest import toml_document
    from hydrolink.clients.scene_inputs import load_modal_structures, load_scene_hdbs
    from hydrolink.protocol.scene import load_scene

    path = tmp_path / "scene.toml"
    path.write_text(toml_document(doc))
    scene, _ = load_scene(path)
    return load_modal_structures(scene, path, load_scene_hdbs(scene, path, progress=False))


def test_bad_structure_files_are_refused_naming_the_file_and_key(tmp_path):
    """Each bad .mmx input is a SceneError naming bodies[0].modes.mmx and the file: the mode count of
    another run (WEC-Sim's 6 + 4 against the barge's 6 + 3: both files named), a missing file, a file
    with no matrices, a singular modal mass, a rigid–mode coupling, matrices both in the file and in
    the scene."""
    from hydrolink.protocol.scene import SceneError

    doc = example_scene(duration=1.0)
    modes = doc["bodies"][0]["modes"]
    shutil.copy(GBM / "barge.mmx", tmp_path / "gbm.mmx")
    singular = np.diag([0.0] * 6 + modes["mass"])
    singular[7, 7] = 0.0
    write_mmx(tmp_path / "singular.mmx", singular, np.zeros((9, 9)), np.diag([0.0] * 6 + modes["stiffness"]))
    coupled = np.diag([0.0] * 6 + modes["mass"])
    coupled[2, 6] = coupled[6, 2] = 1.0e3
    write_mmx(tmp_path / "coupled.mmx", coupled, np.zeros((9, 9)), np.zeros((9, 9)))
    (tmp_path / "empty.mmx").write_text((GBM / "barge.mmx").read_text().split("External force matrices")[0])
    cases = [("gbm.mmx", {}, r"gbm\.mmx.*flexible_barge\.nc.*numbers 10 DOFs \(4 mode\(s\).*has 9 \(3 mode"),
             ("absent.mmx", {}, r"absent\.mmx"),
             ("empty.mmx", {}, r"empty\.mmx.*none in the file"),
             ("singular.mmx", {}, r"singular\.mmx: the modal mass must be positive definite"),
             ("coupled.mmx", {}, r"coupled\.mmx couples the rigid DOFs and the modes in its external mass"),
             ("singular.mmx", {"mass": modes["mass"]}, r"comes from 'singular\.mmx', and \['mass'\]")]
    for name, extra, why in cases:
        with pytest.raises(SceneError) as e:
            _load(tmp_path, with_file(doc, tmp_path / name, **extra))
        assert e.value.key == "bodies[0].modes.mmx", (name, str(e.value))
        assert re.search(why, str(e.value)), (name, str(e.value))


def test_the_file_s_rigid_block_is_checked_against_the_scene_s_body(tmp_path, server):
    """The file's rigid mass matrix against the body's (about the HDB's reference point): the same —
    no warning; a zero block — none (the file gives the modes alone); another mass or inertia — a
    setup warning naming bodies[0].mass / .inertia; a rigid external stiffness — a warning naming
    bodies[0].modes.mmx (the run does not apply it). The server refuses a scene naming an .mmx
    without its matrices (error 8 naming it)."""
    from hydrolink.server.hdb.io import load_hdb
    from hydrolink.server.model import HydroModel
    from conftest import REPLY_S, toml_document
    from hydrolink.clients.lockstep.connection import RemoteError, ServerConnection

    doc = example_scene(duration=1.0)
    doc["hydro"] = {"radiation": "off"}
    body, modes = doc["bodies"][0], doc["bodies"][0]["modes"]
    hdb = load_hdb(body["hdb"])
    damping, stiffness = np.diag([0.0] * 6 + modes["damping"]), np.diag([0.0] * 6 + modes["stiffness"])
    heavier = np.diag([1.01 * body["mass"]] * 3 + body["inertia"] + modes["mass"])
    spun = np.diag([body["mass"]] * 3 + [body["inertia"][0], 1.05 * body["inertia"][1], body["inertia"][2]]
                   + modes["mass"])
    moored = stiffness.copy()
    moored[0, 0] = 2.0e4
    cases = {"same": (example_mmx(tmp_path / "same.mmx", doc), None),
             "zero": (example_mmx(tmp_path / "zero.mmx", doc, rigid_mass=False), None),
             "heavier": (write_mmx(tmp_path / "heavier.mmx", heavier, damping, stiffness), "bodies[0].mass: "),
             "spun": (write_mmx(tmp_path / "spun.mmx", spun, damping, stiffness), "bodies[0].inertia: "),
             "moored": (write_mmx(tmp_path / "moored.mmx", np.diag([0.0] * 6 + modes["mass"]), damping, moored),
                        "bodies[0].modes.mmx: moored.mmx gives the rigid DOFs an external stiffness")}
    for name, (mmx, said) in cases.items():
        scene, _ = _load(tmp_path, with_file(doc, mmx))
        notes = [w for w in HydroModel(scene, {"barge": hdb}, compiled=False).setup_info().warnings
                 if "mmx" in w or w.startswith(("bodies[0].mass", "bodies[0].inertia"))]
        assert notes == ([] if said is None else [next(w for w in notes if w.startswith(said))]), (name, notes)
    text = toml_document(with_file(doc, cases["same"][0]))     # the tables not sent: refused by key
    with ServerConnection(server, timeout=REPLY_S) as conn:
        with pytest.raises(RemoteError) as e:
            conn.hello(text, {body["hdb"]: hdb})
        assert (e.value.code, e.value.field) == (8, "scene.bodies[0].modes.mmx") and "hello.modal_structure" in str(e.value)
        _, blocks = _load(tmp_path, with_file(doc, cases["same"][0]))
        bad = {k: SimpleNamespace(**{**vars(b), "mass": b.mass[:6, :6]}) for k, b in blocks.items()}
        with pytest.raises(RemoteError) as e:      # a block of the wrong size: the message's field
            conn.hello(text, {body["hdb"]: hdb}, modal_structure=bad)
        assert (e.value.code, e.value.field) == (5, 'modal_structure["bodies[0].modes.mmx"].mass'), str(e.value)
        setup = conn.hello(text, {body["hdb"]: hdb}, modal_structure=blocks)
        assert setup.modes == {"barge": modes["names"]}
