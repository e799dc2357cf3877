"""A WAMIT run's structure of its generalized modes (server/hdb/wamit/modal_structure.py,
``hydrolink hdb modes``): WEC-Sim's GBM barge's .mmx external force matrices as a scene's
[bodies.modes] table, checked against the run's input, its .frc, read here."""

from __future__ import annotations

import tomllib
from pathlib import Path

import numpy as np
import pytest
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
