"""clients/lockstep/results.py: a run killed with SIGKILL keeps a readable results file holding every row
up to its last flush, and flushes come by wall time (``simulation.flush_seconds``): the work lost
is at most that long. The kill is a real one, of a real ``hydrolink run`` process."""

from __future__ import annotations

import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import netCDF4
import pytest

from conftest import SPHERE_WATER, regular_waves, scene_toml, sphere_body, write_scene

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
        proc.wait(10)
    finally:
        proc.kill()
    lost = killed - last_change
    assert lost <= flush_seconds + 0.3, f"{lost:.2f} s of work since the last flush"
    with netCDF4.Dataset(out) as ds:
        rows = ds.dimensions["time"].size
        assert rows > 100 and ds.getncattr("status") == "running"
        t = ds["time"][:]
        assert abs(t[-1] - (rows - 1) * 0.01) < 1e-9      # every row up to the last flush, in order
