"""The grid of scene keys shared by ``hydrolink sweep`` and ``hydrolink bench accuracy``
(clients/studies/grid.py): combinations per mode, keys into arrays of tables by name or index, and the
errors that name the part of a key that does not exist."""

from __future__ import annotations

import pytest

from hydrolink.clients.studies.grid import GridSpec, absolute_paths, combinations, get_key, scene_location, set_key

DOC = {"simulation": {"dt": 0.1},
       "ptos": [{"name": "pto", "damping": 1e6}, {"name": "aux", "damping": 2e5}],
       "joints": [{"type": "revolute"}]}


def test_combinations_per_mode():
    grid = {"a": [1, 2, 3], "b": [10, 20, 30]}
    assert combinations(grid, "product") == [{"a": a, "b": b} for a in (1, 2, 3) for b in (10, 20, 30)]
    assert combinations(grid, "zip") == [{"a": 1, "b": 10}, {"a": 2, "b": 20}, {"a": 3, "b": 30}]
    assert combinations(grid, "axes") == [{"a": 1}, {"a": 2}, {"a": 3}, {"b": 10}, {"b": 20}, {"b": 30}]
    assert combinations({}, "product") == []


def test_zip_needs_equal_lengths_and_grids_need_values():
    with pytest.raises(ValueError, match='mode = "zip" needs lists of one length'):
        GridSpec(mode="zip", grid={"a": [1, 2], "b": [1]})
    with pytest.raises(ValueError, match="non-empty list"):
        GridSpec(grid={"a": []})


def test_keys_reach_entries_by_name_and_index():
    doc = {k: (v.copy() if isinstance(v, dict) else [dict(e) for e in v]) for k, v in DOC.items()}
    set_key(doc, "ptos.aux.damping", 3e5)
    set_key(doc, "joints.0.friction", 0.1)
    set_key(doc, "hydro.radiation", "state-space")           # a missing table is created
    assert doc["ptos"][1]["damping"] == 3e5 and doc["ptos"][0]["damping"] == 1e6
    assert doc["joints"][0]["friction"] == 0.1 and doc["hydro"] == {"radiation": "state-space"}
    assert get_key(doc, "ptos.pto.damping") == 1e6 and get_key(doc, "ptos.nope.damping", "x") == "x"
    assert scene_location(doc, "ptos.aux.damping") == "ptos[1].damping"


@pytest.mark.parametrize("key,why", [
    ("ptos.pump.damping", "no ptos entry named 'pump' (known: ['pto', 'aux'])"),
    ("joints.4.friction", "no joints entry '4' (1 entries, unnamed: use an index)"),
    ("simulation.dt.x", "simulation.dt is a value, not a table"),
    ("ptos.damping", "ptos is an array of tables: name an entry (ptos.<name>.damping)"),
])
def test_missing_parts_are_named(key, why):
    doc = {k: (v.copy() if isinstance(v, dict) else [dict(e) for e in v]) for k, v in DOC.items()}
    with pytest.raises(KeyError) as err:
        set_key(doc, key, 1.0)
    assert why in str(err.value)


def test_absolute_paths_include_the_hull_mesh(tmp_path):
    """A scene run from another folder (the bench's and the sweep's temporary copies) still finds
    the files it names relative to itself: the HDB, the nonlinear body's hull mesh, the modes'
    structure file and build spec."""
    doc = {"bodies": [{"name": "float", "hdb": "float.nc", "mesh": "hulls/float.gdf",
                       "modes": {"names": ["bend1"], "mmx": "run/float.mmx", "shapes": "float_hdb.toml"}},
                      {"name": "dry", "mass": 1.0}]}
    absolute_paths(doc, tmp_path / "cases" / "scene.toml")
    assert doc["bodies"][0]["hdb"] == str((tmp_path / "cases" / "float.nc").resolve())
    assert doc["bodies"][0]["mesh"] == str((tmp_path / "cases" / "hulls" / "float.gdf").resolve())
    assert doc["bodies"][0]["modes"] == {"names": ["bend1"], "mmx": str((tmp_path / "cases" / "run" / "float.mmx").resolve()),
                                         "shapes": str((tmp_path / "cases" / "float_hdb.toml").resolve())}
    assert "mesh" not in doc["bodies"][1] and "hdb" not in doc["bodies"][1]
