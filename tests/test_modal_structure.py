"""A WAMIT run's structure of its generalized modes (server/hdb/wamit/modal_structure.py,
``hydrolink hdb modes``): WEC-Sim's GBM barge's .mmx external force matrices as a scene's
[bodies.modes] table, checked against the run's input, its .frc, read here."""

from __future__ import annotations

import tomllib
from pathlib import Path

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
    """The flexible-barge example's scene (its HDB's path made absolute), ``duration`` s long."""
    doc = tomllib.loads(BARGE.read_text())
    doc["simulation"]["duration"] = duration
    doc["bodies"][0]["hdb"] = str((BARGE.parent / doc["bodies"][0]["hdb"]).resolve())
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
