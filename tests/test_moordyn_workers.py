"""MoorDyn in worker processes (``[[moorings]] workers``, clients/exudyn/moordyn_workers.py and
moordyn_split.py) against the reference path, MoorDyn in the run's own process: the same run to the
bit with the whole file in one worker, to round-off with its legs split over several; the split's
groups from MoorDyn's own reading; a worker's failure or death one error naming the mooring."""

from __future__ import annotations

import os
import signal
from pathlib import Path

import numpy as np
import pytest
import xarray as xr

from conftest import REPO
from test_moordyn_mooring import _decay_scene, constant_hdb, moordyn_file, silenced

from hydrolink.protocol.scene import SceneError, parse_scene

moordyn = pytest.importorskip("moordyn")

HEADINGS = [0.0, 120.0, 240.0]
RESULTS = ("position", "velocity", "mooring_force", "line_tension", "line_end_force")


def with_outputs(path: Path) -> Path:
    """The test spread with every line's node file (``tp``), the fairlead tensions' channels and a log."""
    text = path.read_text().replace(" -\n", " tp\n").replace("OUTPUTS ----------------------\nEND",
                                                              "OUTPUTS ----------------------\nFairTen1 FairTen2 FairTen3")
    text = text.replace("OPTIONS ----------------------\n", "OPTIONS ----------------------\n2 writeLog\n")
    path.write_text(text + "\n")
    return path


def _run(tmp_path: Path, workers: int, scheme: str, duration: float = 1.0, **keys) -> tuple[xr.Dataset, Path]:
    from hydrolink.clients.run import run_scene_file
    folder = tmp_path / f"{scheme}_{workers}"
    folder.mkdir()
    with_outputs(moordyn_file(folder / "lines.dat", HEADINGS, segments=24))
    scene = _decay_scene(folder, 0.05, duration, scheme, workers=workers, **keys)
    summary = run_scene_file(scene, folder / "out.nc", progress=False, hdbs={"float.nc": constant_hdb()})
    assert summary.status == "complete" and not summary.warnings
    return xr.load_dataset(folder / "out.nc"), folder


def _rows(path: Path) -> list[list[float]]:
    """A MoorDyn output file's numbers (its header lines, names and units, left out)."""
    out = []
    for ln in path.read_text().splitlines():
        try:
            out.append([float(v) for v in ln.split()])
        except ValueError:
            continue
    return [r for r in out if r]


@pytest.mark.parametrize("scheme", ["mass-matrix", "implicit"])
def test_workers_equal_moordyn_in_the_run_process(tmp_path, scheme):
    """The surge decay on three lines: the whole file in one worker (steps started ahead with the
    mass-matrix scheme; saved and restored on every redo with the implicit one) is the in-process
    run to the bit, results and MoorDyn's own output files alike; each line in a worker of its own
    differs by round-off only (the coupled body's load is summed per group: F - M a in another
    order, ~1e-16 a step, which the stiff chains carry into the motion), its files the same rows."""
    ref, ref_dir = _run(tmp_path, 0, scheme)
    one, one_dir = _run(tmp_path, 1, scheme)
    three, three_dir = _run(tmp_path, 3, scheme)
    assert ref["position"].values[-1, 0, 0] < ref["position"].values[0, 0, 0] - 0.01        # it moves
    for var in RESULTS:
        np.testing.assert_array_equal(one[var].values, ref[var].values, err_msg=var)
        scale = np.abs(ref[var].values).max()
        np.testing.assert_allclose(three[var].values, ref[var].values, rtol=0, atol=1e-9 * scale, err_msg=var)
    names = sorted(p.name for p in ref_dir.iterdir() if p.suffix == ".out")
    assert {"lines.out", "lines_Line3.out", "lines_Body1.out"} <= set(names)
    for name in names:
        assert (one_dir / name).read_text() == (ref_dir / name).read_text(), name
        if scheme == "mass-matrix":     # (a redo writes its rows too: their count follows the iterations)
            a, b = np.array(_rows(ref_dir / name)), np.array(_rows(three_dir / name))
            assert a.shape == b.shape and a.shape[0] == 21, name
            np.testing.assert_allclose(b, a, rtol=1e-6, atol=1e-9 * np.abs(a).max(), err_msg=name)
            assert (three_dir / name).read_text().splitlines()[0] == (ref_dir / name).read_text().splitlines()[0]
    # the log: the whole file's (its initial-condition solve) as in-process, then the groups'
    # (the first line names the file MoorDyn ran: here a copy in the run's temporary folder)
    whole_log = (ref_dir / "lines.log").read_text().splitlines()
    log = (three_dir / "lines.log").read_text().splitlines()
    assert log[1:len(whole_log)] == whole_log[1:] and sum(ln.startswith("--- hydrolink: group") for ln in log) == 3


def test_record_nodes_and_tensions_from_the_workers(tmp_path):
    """line_node_position from the workers' lines, in the file's line order, as in-process."""
    ref, _ = _run(tmp_path, 0, "mass-matrix", duration=0.5, record_nodes=True)
    three, _ = _run(tmp_path, 3, "mass-matrix", duration=0.5, record_nodes=True)
    a, b = ref["line_node_position"].values, three["line_node_position"].values
    assert a.shape == b.shape == (11, 3, 25, 3)
    np.testing.assert_allclose(b, a, rtol=0, atol=1e-9)


def _layout(path: Path):
    from hydrolink.clients.exudyn.moordyn_mooring import read_layout
    return read_layout(path)


def test_split_groups_follow_moordyns_reading_of_the_file(tmp_path, monkeypatch):
    """SEA-Stack's RM3 file (three legs, each an anchor chain to a clump weight, a free point, and a
    chain up to the spar): one group per leg, the free point with its two lines; the groups' states
    cut from the whole file's are the states MoorDyn loads (the lines' tensions to the bit)."""
    from hydrolink.clients.exudyn.moordyn_split import split, split_state
    path = tmp_path / "rm3_lines.txt"
    path.write_text((REPO / "bench" / "suite" / "rm3_lines.txt").read_text())
    layout = _layout(path)
    groups = split(path.read_text(), layout.graph, 3).groups
    assert [g.lines for g in groups] == [(1, 4), (2, 5), (3, 6)]
    assert [g.points for g in groups] == [(1, 2, 7), (3, 4, 8), (5, 6, 9)]
    assert [g.channels for g in groups] == [(0,), (1,), (2,)]              # FairTen4, 5, 6
    two = split(path.read_text(), layout.graph, 2).groups
    assert sorted(len(g.lines) for g in two) == [2, 4]
    # the states: the whole file after its initial-condition solve, each group loaded from its cut
    x = [0.0, 0.0, -21.29, 0.0, 0.0, 0.0]
    monkeypatch.chdir(tmp_path)          # MoorDyn writes its outputs beside the file it was given
    with silenced():
        m = moordyn.Create(str(path))
        moordyn.Init(m, x, [0.0] * 6)
        moordyn.SaveState(m, str(tmp_path / "whole.state"))
        states = split_state((tmp_path / "whole.state").read_bytes(), split(path.read_text(), layout.graph, 3))
        v = [0.2, 0.0, 0.1, 0.0, 0.01, 0.0]
        for _ in range(3):
            moordyn.Step(m, x, v, 0.0, 0.01)
        for k, (g, state) in enumerate(zip(groups, states)):
            (tmp_path / f"g{k}").mkdir()
            gp = tmp_path / f"g{k}" / "rm3_lines.txt"
            gp.write_text(g.text)
            (tmp_path / f"g{k}" / "s.state").write_bytes(state)
            gm = moordyn.Create(str(gp))
            moordyn.Init_NoIC(gm, x, [0.0] * 6)
            moordyn.LoadState(gm, str(tmp_path / f"g{k}" / "s.state"))
            for _ in range(3):
                moordyn.Step(gm, x, v, 0.0, 0.01)
            for j, line in enumerate(g.lines, start=1):
                for node in (0, 3, 15 if line <= 3 else 5):
                    assert moordyn.GetLineNodeTen(moordyn.GetLine(gm, j), node) == \
                        moordyn.GetLineNodeTen(moordyn.GetLine(m, line), node)
            moordyn.Close(gm)
        moordyn.Close(m)


def test_a_file_that_cannot_be_split_is_refused_naming_the_key_and_why(tmp_path):
    from hydrolink.clients.exudyn.moordyn_mooring import load_moordyn_files
    from test_moordyn_mooring import dry_float, mooring
    from conftest import scene_toml, write_scene
    moordyn_file(tmp_path / "lines.dat", [0.0])                       # one line: one group
    text = scene_toml(dt=0.1, duration=1.0, bodies=[dry_float()], moorings=[mooring(workers=2)])
    path = write_scene(tmp_path, text)
    with pytest.raises(SceneError, match=r"moorings\[0\]\.workers: lines\.dat cannot be stepped in 2 worker processes: "
                                         r"its lines are all joined .*\(workers = 1 steps it whole in one\)"):
        load_moordyn_files(parse_scene(text, path), path)
    f = moordyn_file(tmp_path / "lines.dat", HEADINGS)               # the body with a mass of its own
    f.write_text(f.read_text().replace("1 Coupled 0.0 0.0 -2.0 0 0 0 0 0", "1 Coupled 0.0 0.0 -2.0 0 0 0 500 0"))
    with pytest.raises(SceneError, match=r"moorings\[0\]\.workers: .*body 1 has its own mass, volume or drag area"):
        load_moordyn_files(parse_scene(text, path), path)
    with pytest.raises(SceneError, match=r"moorings\[0\]\.workers"):
        parse_scene(scene_toml(dt=0.1, duration=1.0, bodies=[dry_float()], moorings=[mooring(workers=-1)]))


def test_a_moordyn_failure_in_a_worker_names_the_mooring_and_keeps_the_rows(tmp_path):
    """dtM too large: MoorDyn fails in its worker a few steps in; the run stops with one line naming
    the mooring, its file and the step, the rows before it kept, as in-process."""
    from hydrolink.clients.lockstep.driver import RunInterrupted
    from hydrolink.clients.run import run_scene_file
    moordyn_file(tmp_path / "lines.dat", HEADINGS, dtm=0.01)
    with pytest.raises(RunInterrupted, match=r"^MoorDyn failed at step (\d+) \(t = [\d.]+ s\): moorings\[0\] \(.*lines\.dat\), "
                                             r"group \d of 3: .*; the \1 rows before it are saved in .*out\.nc$") as info:
        run_scene_file(_decay_scene(tmp_path, 0.05, 5.0, "mass-matrix", workers=3), tmp_path / "out.nc", progress=False,
                       hdbs={"float.nc": constant_hdb()})
    ds = xr.load_dataset(tmp_path / "out.nc")
    assert ds.sizes["time"] == info.value.rows > 0 and ds.attrs["status"].startswith("interrupted: MoorDyn failed")


def test_a_worker_that_dies_is_one_error_and_every_worker_is_reaped(tmp_path):
    """A worker killed mid-run: the next step is one error naming the mooring, the group and the
    signal; close() reaps the others (no process left) and still writes the outputs beside the file."""
    from hydrolink.clients.exudyn.moordyn_mooring import MoorDynSystem
    from hydrolink.clients.exudyn.moordyn_workers import MoorDynWorkerDied
    from hydrolink.protocol.scene import MoorDynMooring
    path = with_outputs(moordyn_file(tmp_path / "lines.dat", HEADINGS, segments=12))
    spec = MoorDynMooring(type="moordyn", name="spread", file=str(path), bodies=["float"], workers=3)
    pose = np.array([[0.0, 0.0, -2.0, 0.0, 0.0, 0.0]])
    moved = pose + [[0.01, 0, 0, 0, 0, 0]]
    system = MoorDynSystem(spec, _layout(path), "moorings[0]", {"float": 0}, pose)
    try:
        system.start(pose)
        system.step(0.0, 0.05, pose, moved)
        pids = system._groups.pids
        assert len(pids) == 3
        os.kill(pids[1], signal.SIGKILL)
        with pytest.raises(MoorDynWorkerDied, match=r"moorings\[0\] \(.*lines\.dat\), group 2 of 3: its worker process "
                                                    r"\(pid \d+\) was killed by signal 9"):
            system.step(0.05, 0.05, moved, moved)
    finally:
        system.close()
    for pid in pids:                                   # reaped: no process, no zombie
        assert not Path(f"/proc/{pid}").exists()
    assert (tmp_path / "lines.out").exists() and len(_rows(tmp_path / "lines.out")) >= 2
