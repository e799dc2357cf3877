"""clients/lockstep/results.py: a run killed with SIGKILL keeps a readable results file holding every row
up to its last flush, and flushes come by wall time (``simulation.flush_seconds``): the work lost
is at most that long (the kill is a real one, of a real ``hydrolink run`` process); the writer
thread's blocks put every row in the file as given, and a slow write makes the stepping thread wait
only when every block is taken."""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import netCDF4
import numpy as np
import pytest

from conftest import EXIT_S, SPHERE_WATER, regular_waves, scene_toml, sphere_body, write_scene

from hydrolink.clients.lockstep.results import ResultWriter

HYDROLINK = [sys.executable, "-m", "hydrolink.clients.cli"]


@pytest.mark.timing
@pytest.mark.parametrize("flush_seconds", [0.25, 1.0])
def test_sigkill_loses_at_most_the_flush_interval(tmp_path: Path, reference_data: Path, flush_seconds: float):
    shutil.copy(reference_data / "sphere_task10" / "sphere.h5", tmp_path / "sphere.h5")
    write_scene(tmp_path, scene_toml(dt=0.01, duration=5000.0, progress=False, water=SPHERE_WATER,
                                     simulation={"flush_seconds": flush_seconds},
                                     waves=regular_waves(1.0, 6.0, ramp=5.0), hydro={"irf_duration": 10.0},
                                     bodies=[sphere_body("sphere.h5", mass=261.8e3, dofs=["heave"])]))
    out = tmp_path / "out.nc"
    proc = subprocess.Popen([*HYDROLINK, "run", "scene.toml", "-o", str(out)], cwd=tmp_path,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        # watch the file: each flush changes its size; the last change before the kill is the last flush
        last_change, size, rows_seen_at = None, -1, time.monotonic() + 60
        while time.monotonic() < rows_seen_at:
            if out.exists() and out.stat().st_size != size:
                size, last_change = out.stat().st_size, time.monotonic()
                if size > 200_000:                   # rows are being written: let it run a while more
                    rows_seen_at = min(rows_seen_at, time.monotonic() + 2.5)
            time.sleep(0.01)
        proc.send_signal(signal.SIGKILL)
        killed = time.monotonic()
    finally:
        proc.kill()
        proc.wait(EXIT_S)
    lost = killed - last_change
    assert lost <= flush_seconds + 0.3, f"{lost:.2f} s of work since the last flush"
    with netCDF4.Dataset(out) as ds:
        rows = ds.dimensions["time"].size
        assert rows > 100 and ds.getncattr("status") == "running"
        t = ds["time"][:]
        assert abs(t[-1] - (rows - 1) * 0.01) < 1e-9      # every row up to the last flush, in order


# ---------------------------------------------------------------- the writer thread's blocks

def _rows(n: int, n_bodies: int = 2):
    """Row k's values: distinct per row, body, dof and variable."""
    base = np.arange(n_bodies * 6, dtype=float).reshape(n_bodies, 6)
    return [tuple(base + 1000.0 * k + 100.0 * j for j in range(5)) for k in range(n)]


def test_blocks_write_every_row_as_given(tmp_path: Path):
    """23 rows through blocks of 5 (two blocks: the stepping thread waits for the writer at times),
    extras staged on some rows only: an unstaged row repeats the previous one, across block
    boundaries too, NaN before the first; a variable with a fill gets it; an integer one keeps its
    type; values amended after commit while the block is held are the ones in the file."""
    w = ResultWriter(tmp_path / "r.nc", scene_text="", bodies=["a", "b"], dt=0.1, flush_rows=5, blocks=2,
                     flush_seconds=3600.0)
    w.add_variable("g", ("pto",), {"pto": ["p", "q"]}, "N", "staged on some rows")
    w.add_variable("lat", (), units="s", fill=np.nan)
    w.add_variable("flag", (), dtype="i1", fill=0)
    rows = _rows(23)
    staged = {1: [1.0, 2.0], 4: [3.0, 4.0], 5: [5.0, 6.0], 12: [7.0, 8.0]}   # rows 0, 2-3, 6-11, 13- not
    amended = {3: 0.5, 4: 0.25, 9: 2.0, 10: 3.0, 22: 4.0}
    w.hold = True
    for k, r in enumerate(rows):
        if k in staged:
            w.stage_extra({"g": np.array(staged[k])})
        w.append(0.1 * k, *r, 0.01 * k)
        if k in amended:
            extra, i = w.amend(k)
            extra["lat"][i], extra["flag"][i] = amended[k], 1
        w.release_held()
    with pytest.raises(ValueError, match="no longer buffered"):
        w.amend(0)
    w.finish("complete")
    w.close()
    with netCDF4.Dataset(tmp_path / "r.nc") as ds:
        assert ds.getncattr("status") == "complete" and ds.getncattr("rows") == 23
        assert np.array_equal(ds["time"][:], 0.1 * np.arange(23))
        assert np.array_equal(ds["wave_elevation"][:], 0.01 * np.arange(23))
        for j, name in enumerate(("position", "velocity", "excitation_force", "radiation_force",
                                  "hydrostatic_force")):
            assert np.array_equal(ds[name][:], np.array([r[j] for r in rows])), name
        g = np.full((23, 2), np.nan)
        last = [np.nan, np.nan]
        for k in range(23):
            last = staged.get(k, last)
            g[k] = last
        assert np.array_equal(np.asarray(ds["g"][:].filled(np.nan)), g, equal_nan=True)
        lat = np.full(23, np.nan)
        lat[list(amended)] = list(amended.values())
        assert np.array_equal(np.asarray(ds["lat"][:].filled(np.nan)), lat, equal_nan=True)
        assert ds["flag"].dtype == np.int8
        assert np.array_equal(ds["flag"][:], np.isin(np.arange(23), list(amended)).astype(np.int8))


def test_slots_fill_the_next_rows_extras_in_place(tmp_path: Path):
    """Values written into ``slots`` (a vector and a scalar variable) are the row's, across block
    boundaries; a row whose slots were not taken repeats the previous one, as with stage_extra."""
    w = ResultWriter(tmp_path / "r.nc", scene_text="", bodies=["a"], dt=0.1, flush_rows=4, blocks=2,
                     flush_seconds=3600.0)
    w.add_variable("g", ("pto",), {"pto": ["p", "q"]}, "N", "filled in place")
    w.add_variable("s", (), units="W")
    rows, taken = _rows(11, 1), {0, 1, 3, 4, 5, 8}
    for k, r in enumerate(rows):
        if k in taken:
            g, total = w.slots(("g", "s"))
            assert g.shape == (1, 2) and total.shape == (1,)
            g[0] = (k, -k)
            total[0] = 10.0 * k
        w.append(0.1 * k, *r, 0.0)
    w.finish("complete")
    w.close()
    last = [max(j for j in taken if j <= k) for k in range(11)]
    with netCDF4.Dataset(tmp_path / "r.nc") as ds:
        assert np.array_equal(ds["g"][:], [[j, -j] for j in last])
        assert np.array_equal(ds["s"][:], [10.0 * j for j in last])


def test_a_slow_write_stalls_the_stepping_thread_only_when_every_block_is_taken(tmp_path: Path):
    """The writer thread takes 0.6 s over the first block: with two blocks the stepping thread waits
    for it (counted in io_seconds, once) when the second fills; with three it does not."""
    waits = {}
    for blocks in (2, 3):
        w = ResultWriter(tmp_path / f"r{blocks}.nc", scene_text="", bodies=["a"], dt=0.1, flush_rows=5,
                         blocks=blocks, flush_seconds=3600.0)
        write, slow = w._write, [True]

        def delayed(blk, write=write, slow=slow):   # the real write, after a delay the first time
            if slow[0]:
                slow[0] = False
                time.sleep(0.6)
            write(blk)

        w._write = delayed
        for k, r in enumerate(_rows(10, 1)):
            w.append(0.1 * k, *r, 0.0)
        waits[blocks] = (w.io_waits, w.io_seconds)
        w.close()
        with netCDF4.Dataset(tmp_path / f"r{blocks}.nc") as ds:
            assert ds.dimensions["time"].size == 10 and np.array_equal(ds["time"][:], 0.1 * np.arange(10))
    print(waits)
    assert waits[2][0] == 1 and waits[2][1] > 0.3
    assert waits[3] == (0, 0.0)


# ---------------------------------------------------------------- the writer's process (a paced run)

def _write_rows(w: ResultWriter, n: int, to_process_at: int | None = None) -> None:
    """``n`` rows with extras (one staged on some rows, one amended while held), the writer moved to
    its process after row ``to_process_at``; then an attribute, finish and close."""
    w.add_variable("g", ("pto",), {"pto": ["p", "q"]}, "N", "staged on some rows")
    w.add_variable("flag", (), dtype="i1", fill=0)
    w.hold = True
    for k, r in enumerate(_rows(n)):
        if k % 3 == 1:
            w.stage_extra({"g": np.array([k, -k], float)})
        w.append(0.1 * k, *r, 0.01 * k)
        extra, i = w.amend(k)
        extra["flag"][i] = k % 2
        w.release_held()
        if k == to_process_at:
            w.write_in_process()
    w.set_attribute("summary", "after the rows")
    w.finish("complete")
    w.close()


def test_the_writers_process_writes_the_file_its_thread_would(tmp_path: Path):
    """A writer moved to its process part way (blocks of 5, the one being filled carried over)
    writes the same file as the writer thread alone: every variable's values, type and chunking,
    every attribute but the creation time; its process, every thread of it, runs under the
    ordinary policy while the run's thread stays under SCHED_FIFO, and has ended once the writer
    is closed."""
    from hydrolink.clients.lockstep.rt_priority import rt_priority

    def writer(name: str) -> ResultWriter:
        return ResultWriter(tmp_path / name, scene_text="s", bodies=["a", "b"], dt=0.1, flush_rows=5, blocks=2,
                            flush_seconds=3600.0)

    _write_rows(writer("thread.nc"), 23)
    policy = {}
    fifo = hasattr(os, "sched_setscheduler") and os.geteuid() == 0
    w2 = writer("moved.nc")
    write_in_process = w2.write_in_process

    def moved():
        write_in_process()
        if fifo:                               # every thread of the writer's process (a BLAS pool's too)
            policy["child"] = {os.sched_getscheduler(int(t)) for t in os.listdir(f"/proc/{w2._proc.pid}/task")}
            policy["run"] = os.sched_getscheduler(0)

    w2.write_in_process = moved
    with rt_priority(5 if fifo else None):
        _write_rows(w2, 23, to_process_at=7)
    assert w2._proc.returncode == 0
    assert not fifo or (policy["child"] == {os.SCHED_OTHER} and policy["run"] == os.SCHED_FIFO)
    with netCDF4.Dataset(tmp_path / "thread.nc") as a, netCDF4.Dataset(tmp_path / "moved.nc") as b:
        assert {k: a.getncattr(k) for k in a.ncattrs() if k != "created"} == \
               {k: b.getncattr(k) for k in b.ncattrs() if k != "created"}
        assert b.getncattr("status") == "complete" and b.getncattr("rows") == 23
        assert list(a.variables) == list(b.variables)
        for name in a.variables:
            va, vb = a[name], b[name]
            assert va.dtype == vb.dtype and va.dimensions == vb.dimensions and va.chunking() == vb.chunking(), name
            assert {k: va.getncattr(k) for k in va.ncattrs()} == {k: vb.getncattr(k) for k in vb.ncattrs()}, name
            x, y = va[:], vb[:]
            if va.dtype is not str and va.dtype.kind == "f":
                assert np.array_equal(np.ma.filled(x, np.nan), np.ma.filled(y, np.nan), equal_nan=True), name
            else:
                assert np.array_equal(x, y), name


def test_a_writers_process_that_dies_is_an_error_naming_the_file(tmp_path: Path):
    """The writer's process killed part way: the next hand-off or flush raises an error naming the
    results file and the process's end (no hang), and so does closing the writer, which still lets
    go of the connection and reaps the process; the file keeps the rows written before the kill."""
    w = ResultWriter(tmp_path / "r.nc", scene_text="", bodies=["a"], dt=0.1, flush_rows=5, blocks=2,
                     flush_seconds=3600.0)
    rows = _rows(40, 1)
    for k in range(12):
        w.append(0.1 * k, *rows[k], 0.0)
        if k == 0:
            w.write_in_process()
    w.flush()
    w._proc.kill()
    w._proc.wait()
    with pytest.raises(RuntimeError, match=r"r\.nc.*writer's process ended \(exit code -9\)"):
        for k in range(12, 40):
            w.append(0.1 * k, *rows[k], 0.0)
        w.flush()
    with pytest.raises(RuntimeError, match=r"r\.nc.*writer's process ended"):
        w.close()
    assert w._conn is None and w._proc.returncode == -9
    with netCDF4.Dataset(tmp_path / "r.nc") as ds:
        assert ds.dimensions["time"].size == 12 and np.array_equal(ds["time"][:], 0.1 * np.arange(12))
