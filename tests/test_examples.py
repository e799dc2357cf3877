"""Every shipped example sets up without a warning about its own settings: each scene under
examples/ goes through the scene model and the server's setup (HDBs built or read as ``hydrolink
run`` does), and each sweep file through its validation; any setup warning or Python warning fails.
A new example is picked up by the glob, so it cannot ship noisy."""

from __future__ import annotations

import tomllib
import warnings
from pathlib import Path

import pytest

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"


def _kind(path: Path) -> str:
    doc = tomllib.loads(path.read_text())
    if "scene" in doc:
        return "sweep"
    if "frequencies" in doc:
        return "hdb build spec"
    return "scene"


FILES = sorted(p for p in EXAMPLES.rglob("*.toml") if _kind(p) != "hdb build spec")


@pytest.mark.parametrize("path", FILES, ids=[str(p.relative_to(EXAMPLES)) for p in FILES])
def test_example_sets_up_without_warnings(path: Path, reference_data):
    from hydrolink.clients.scene_inputs import load_scene_hdbs, load_wave_elevation
    from hydrolink.clients.studies.sweep_file import load_sweep
    from hydrolink.protocol.scene import load_scene
    from hydrolink.server.hydro_states import hydro_model, state_datasets
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        if _kind(path) == "sweep":
            load_sweep(path)
            setup_warnings: list[str] = []
        else:
            scene, _ = load_scene(path)
            hdbs = load_scene_hdbs(scene, path, progress=False)
            model = hydro_model(scene, {b.name: hdbs[b.hdb] for b in scene.bodies if b.wet},
                                state_datasets(scene, hdbs), load_wave_elevation(scene, path))
            setup_warnings = list(model.setup_info().warnings)
    assert setup_warnings == [], f"{path.name}: setup warnings {setup_warnings}"
    assert not caught, f"{path.name}: " + "; ".join(f"{w.category.__name__}: {w.message}" for w in caught)
