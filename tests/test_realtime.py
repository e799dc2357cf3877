"""``hydrolink run --realtime`` (clients/lockstep/pacing.py): exchanges released at wall-clock times,
overruns counted, per-step latency in the results. Timing is measured by bench/bench_realtime.py;
here only what holds on any machine: a step made slow on purpose is counted as an overrun with
(at least) its delay as lateness, and a paced run cannot finish before its simulated duration."""

from __future__ import annotations

import json
import time

import numpy as np
import pytest

from test_rm3 import scene_text

SLOW_SEQ, DELAY = 10, 0.3     # the server sample of step 10 takes 0.3 s more; an exchange is 80 ms


def test_slow_step_is_an_overrun(reference_data, tmp_path, monkeypatch):
    import xarray as xr

    from hydrolink.clients.lockstep.driver import ForceLink
    from hydrolink.clients.run import run_scene_file
    sample = ForceLink.sample

    def slow(self, seq, *args, **kwargs):
        if seq == SLOW_SEQ:
            time.sleep(DELAY)
        return sample(self, seq, *args, **kwargs)

    monkeypatch.setattr(ForceLink, "sample", slow)
    (tmp_path / "rm3.toml").write_text(scene_text("full", reference_data / "rm3_wamit" / "rm3.1", duration=1.6))
    t0 = time.perf_counter()
    summary = run_scene_file(tmp_path / "rm3.toml", tmp_path / "rm3.nc", progress=False, realtime=1.0)
    wall = time.perf_counter() - t0
    rt = summary.realtime
    print(rt)
    assert rt.factor == 1.0 and rt.period == pytest.approx(0.08) and rt.steps == 20
    assert rt.overruns >= 1 and rt.worst_lateness >= DELAY - 0.08 - 1e-3
    assert rt.latency_max >= DELAY and rt.latency_p50 <= rt.latency_p99 <= rt.latency_max
    assert wall >= 1.6            # released at wall-clock times: never faster than the simulated time
    ds = xr.load_dataset(tmp_path / "rm3.nc")
    lat = ds["step_latency"]
    assert lat.dims == ("time",) and np.isnan(lat.values[0])        # the initial row is not paced
    assert lat.values[SLOW_SEQ] >= DELAY                             # the row that ends the slow exchange
    assert json.loads(ds.attrs["realtime"])["overruns"] == rt.overruns


def test_unpaced_run_has_no_latency_variable(reference_data, tmp_path):
    import xarray as xr

    from hydrolink.clients.run import run_scene_file
    (tmp_path / "rm3.toml").write_text(scene_text("full", reference_data / "rm3_wamit" / "rm3.1", duration=0.8))
    summary = run_scene_file(tmp_path / "rm3.toml", tmp_path / "rm3.nc", progress=False)
    assert summary.realtime is None
    assert "step_latency" not in xr.load_dataset(tmp_path / "rm3.nc")


def test_pace_factor_must_be_positive():
    from hydrolink.clients.lockstep.pacing import Pacer
    for bad in (0.0, -1.0, float("nan"), float("inf")):
        with pytest.raises(ValueError, match="--realtime"):
            Pacer(0.01, bad)
