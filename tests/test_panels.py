"""The panel set of an HDB build (server/hdb/build/panels.py, ``panel_pressures = true``): each
problem's pressure on every hull panel, stored beside the HDB. Its pressures integrated over the hull
as forces on the six rigid DOFs (the rigid motions written here) must give the HDB's A(w), B(w),
A-infinity and X(w, beta) of the same solve; a spec that cannot have one is refused by key."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from conftest import unit_rigid_motions

from hydrolink.server.hdb.build.builder import build_hdb
from hydrolink.server.hdb.build.panels import read_panel_pressures
from hydrolink.server.hdb.build.spec import SpecError, parse_spec

BOX = """
panel_pressures = true
[body]
name = "box"
shape = "box"
length = 20.0
width = 6.0
draft = 2.0
freeboard = 1.0
panel_size = 2.0
center = [0.0, 0.0, 0.0]
[frequencies]
values = [0.6, 1.0]
[waves]
directions = [0.0, 30.0]
[water]
density = 1025.0
"""




def test_panel_pressures_integrate_to_the_hdb_of_the_same_solve(tmp_path: Path):
    spec = tmp_path / "box.toml"
    spec.write_text(BOX)
    ds = build_hdb(spec, cache_dir=tmp_path / "cache", progress=False)
    ps = read_panel_pressures(Path(ds.attrs["panel_pressure_file"]))
    assert ps.panels > 50 and ps.dofs == tuple(str(d) for d in ds["radiating_dof"].values)
    assert np.all(ps.normal[ps.center[:, 2] < -1.99, 2] < -0.99)   # the bottom's normals point down, into the water
    a, b, a_inf, x = ps.hdb_rows(unit_rigid_motions(ps.center))
    for mine, name in ((a, "added_mass"), (b, "radiation_damping"), (a_inf, "added_mass_inf"), (x, "excitation_force")):
        ref = ds[name].values
        assert np.abs(mine - ref).max() <= 1e-9 * np.abs(ref).max(), name
    again = build_hdb(spec, cache_dir=tmp_path / "cache", progress=False)   # from the cache: the same file named
    assert again.attrs["cache_hit"] == 1 and again.attrs["panel_pressure_file"] == ds.attrs["panel_pressure_file"]


def test_panel_pressures_are_refused_where_they_cannot_be_built(tmp_path: Path):
    with pytest.raises(SpecError, match="panel_pressures"):
        parse_spec(BOX.replace("values = [0.6, 1.0]", "values = [0.6, 1.0]\ninfinite = false"), tmp_path / "s.toml")
