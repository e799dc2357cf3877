"""The sweep file (clients/studies/sweep_file.py): every kind of bad sweep file is one line naming the file
and the key, before anything runs; cases take the grid's values and the derived energy period."""

from __future__ import annotations

from pathlib import Path

import pytest
from click.testing import CliRunner

from conftest import SPHERE_WATER, irregular_waves, linear_pto, regular_waves, scene_toml, sphere_body, sweep_toml, write_scene
from hydrolink.clients.cli import cli


@pytest.fixture(scope="module")
def sphere_dir(tmp_path_factory, sphere_path) -> Path:
    """A sphere in heave with a damper to ground, in regular waves (sphere.toml) and in JONSWAP
    seas (irregular.toml)."""
    folder = tmp_path_factory.mktemp("sphere_sweep_file")
    for name, waves in (("sphere.toml", regular_waves(1.0, 6.0, ramp=10.0)),
                        ("irregular.toml", irregular_waves(1.0, 8.0, ramp=10.0))):
        write_scene(folder, scene_toml(
            dt=0.04, duration=100.0, water=SPHERE_WATER, waves=waves,
            bodies=[sphere_body(str(sphere_path), mass=261.724e3, dofs=["heave"])],
            ptos=[linear_pto("damper", "sphere", [0, 0, 0], "ground", [0, 0, -50], damping=2e5)]), name)
    return folder


BAD = [
    ({"frobnicate": 1, "grid": {"waves.period": [6.0]}}, "frobnicate: unknown key"),
    ({"grid": {"waves.hs": [1.0]}}, 'grid."waves.hs": not a key of the scene'),
    ({"grid": {"waves.period": ["long"]}}, 'grid."waves.period": Input should be a valid number'),
    ({"grid": {"waves.period": []}}, 'grid."waves.period": a non-empty list'),
    ({"grid": {"ptos.pump.damping": [1e5]}}, 'grid."ptos.pump.damping": not a key of the scene: no ptos entry named'),
    ({"grid": {"bodies.sphere.mass": [-1.0]}}, 'grid."bodies.sphere.mass": Input should be greater than 0'),
    ({}, "grid: no cases"),
    ({"mode": "zip", "grid": {"waves.period": [6.0, 7.0], "ptos.damper.damping": [1e5]}}, 'mode = "zip" needs lists'),
    ({"solver": "quick", "grid": {"waves.period": [6.0]}}, "solver: Input should be 'run', 'steady' or 'auto'"),
    ({"site": {"scatter": "nowhere.csv"}, "grid": {"waves.period": [6.0]}}, "site.scatter:"),
    ({"grid": {"waves.te": [7.0]}}, 'grid."waves.te": the energy period needs irregular waves'),
    ({"cases": [{"label": "x", "simulation.dt": 0.0}]}, 'cases[0]."simulation.dt": Input should be greater than 0'),
    ({"window": [10.0, 5.0], "grid": {"waves.period": [6.0]}}, "window: [start, end]"),
    ({"case_series": "some", "grid": {"waves.period": [6.0]}}, "case_series: Input should be 'tail' or 'full'"),
    ({"tail": 0.0, "grid": {"waves.period": [6.0]}}, "tail: Input should be greater than 0"),
]


@pytest.mark.parametrize("keys,why", BAD, ids=[b[1][:30] for b in BAD])
def test_bad_sweep_files_one_clear_line(sphere_dir, tmp_path, keys, why):
    sweep = tmp_path / "bad.toml"
    sweep.write_text(sweep_toml(sphere_dir / "sphere.toml", **keys))
    out = tmp_path / "out"
    r = CliRunner().invoke(cli, ["sweep", str(sweep), "-o", str(out)])
    assert r.exit_code == 1
    lines = r.output.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"Error: {sweep}: ") and why in lines[0], r.output
    assert not out.exists()                     # nothing ran


def test_missing_scene_and_both_cluster_options(tmp_path):
    sweep = tmp_path / "s.toml"
    sweep.write_text(sweep_toml("nothing.toml", grid={"waves.period": [6.0]}))
    r = CliRunner().invoke(cli, ["sweep", str(sweep)])
    assert r.exit_code == 1 and f"{sweep}: scene: " in r.output and "cannot read the scene file" in r.output
    r = CliRunner().invoke(cli, ["sweep", str(sweep), "--workers", "2", "--scheduler", "tcp://127.0.0.1:1"])
    assert r.exit_code == 1 and "give one" in r.output




@pytest.mark.parametrize("mode,count", [("product", 6), ("zip", 2), ("axes", 5)])
def test_cases_take_the_grid_values(sphere_dir, tmp_path, mode, count):
    """product: every combination; zip: the i-th values together; axes: one key at a time, the
    others as the scene has them. Each case's validated scene holds its values."""
    from hydrolink.clients.studies.sweep_file import load_sweep
    grid = {"waves.period": [6.0, 7.0] if mode == "zip" else [6.0, 7.0, 8.0],
            "ptos.damper.damping": [1e5, 3e5]}
    sweep = tmp_path / "s.toml"
    sweep.write_text(sweep_toml(sphere_dir / "sphere.toml", mode=mode, grid=grid,
                                cases=[{"label": "heavy", "bodies.sphere.mass": 3e5}]))
    s = load_sweep(sweep)
    grid_cases = [c for c in s.cases if c.label != "heavy"]
    assert len(grid_cases) == count and len(s.cases) == count + 1
    for c in grid_cases:
        period = c.overrides.get("waves.period", 6.0)
        damping = c.overrides.get("ptos.damper.damping", 2e5)
        assert c.scene.waves.period == period and c.scene.ptos[0].damping == damping
    heavy = next(c for c in s.cases if c.label == "heavy")
    assert heavy.scene.bodies[0].mass == 3e5 and heavy.scene.waves.period == 6.0
    assert len({c.case_id or c.text for c in s.cases}) == len(s.cases)


def test_energy_period_key_sets_the_peak_period(sphere_dir, tmp_path):
    """waves.te sets waves.tp through the JONSWAP spectrum's own Te/Tp: m_-1/m_0 of the spectrum
    integrated in the test (gamma 3.3, sigma 0.07/0.09)."""
    import numpy as np
    from hydrolink.clients.studies.sweep_file import load_sweep
    sweep = tmp_path / "s.toml"
    sweep.write_text(sweep_toml(sphere_dir / "irregular.toml", grid={"waves.te": [7.5, 9.5]}))
    f = np.linspace(1e-3, 40.0, 2_000_001)     # tp = 1 s; the f^-5 tail matters to 1e-3
    sigma = np.where(f <= 1.0, 0.07, 0.09)
    s_f = f ** -5 * np.exp(-1.25 * f ** -4) * 3.3 ** np.exp(-((f - 1.0) ** 2) / (2 * sigma ** 2))
    ratio = np.trapezoid(s_f / f, f) / np.trapezoid(s_f, f)
    for case in load_sweep(sweep).cases:
        assert case.scene.waves.tp * ratio == pytest.approx(case.overrides["waves.te"], rel=1e-4)


def test_case_files_are_named_by_their_keys_and_values(sphere_dir, tmp_path):
    """Each case's files are named by its index and its keys and values (or its label), unique,
    with nothing a file system or a shell minds; the tail of its series is 5 wave periods unless
    the sweep says ``tail`` (s), and "full" keeps every sample."""
    import re

    from hydrolink.clients.studies.sweep_file import load_sweep
    sweep = tmp_path / "s.toml"
    sweep.write_text(sweep_toml(sphere_dir / "sphere.toml", grid={"waves.period": [6.0, 7.5],
                                                                  "ptos.damper.damping": [1.2e6, 2.5e5]},
                                cases=[{"label": "stiff PTO / v2", "ptos.damper.stiffness": 1e5}]))
    s = load_sweep(sweep)
    names = [c.name for c in s.cases]
    assert names == ["case-000_waves.period=6_ptos.damper.damping=1.2e6",
                     "case-001_waves.period=6_ptos.damper.damping=250000",
                     "case-002_waves.period=7.5_ptos.damper.damping=1.2e6",
                     "case-003_waves.period=7.5_ptos.damper.damping=250000",
                     "case-004_stiff_PTO_v2"]
    assert all(re.fullmatch(r"[A-Za-z0-9.=+,_-]+", n) for n in names) and len(set(names)) == len(names)
    assert [c.tail for c in s.cases] == [30.0, 30.0, 37.5, 37.5, 30.0]
    sweep.write_text(sweep_toml(sphere_dir / "sphere.toml", tail=12.0, grid={"waves.period": [6.0, 7.5]}))
    assert [c.tail for c in load_sweep(sweep).cases] == [12.0, 12.0]
    sweep.write_text(sweep_toml(sphere_dir / "sphere.toml", case_series="full", grid={"waves.period": [6.0]}))
    assert [c.tail for c in load_sweep(sweep).cases] == [None]
