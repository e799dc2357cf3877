"""``hydrolink run --realtime`` (protocol/pacing.py): exchanges released at wall-clock times,
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
    from hydrolink.protocol.pacing import Pacer
    for bad in (0.0, -1.0, float("nan"), float("inf"), 5e-324, 1e300):
        with pytest.raises(ValueError, match="--realtime"):
            Pacer(0.01, bad)


@pytest.mark.parametrize("where", ["socket", "in-process"])
def test_server_paces_a_session_that_asks(where):
    """hello.realtime = 2 on dt = 0.05 s: no reply of step k leaves before t0 + k·25 ms (t0: step 0's
    arrival, after the client sent it); a client 0.2 s late for one step is an overrun in goodbye."""
    from analytic_hdb import make_body_hdb
    from test_force_server import DT, SCENE

    from hydrolink.clients.lockstep.connection import ServerConnection
    from hydrolink.server.service.force_server import ForceServer, serve_in_thread
    if where == "socket":
        srv, thread = serve_in_thread(session_timeout=60.0)
        address = srv.address
    else:
        srv = ForceServer(None)
        address = srv
    try:
        with ServerConnection(address, timeout=10.0) as c:
            c.hello(SCENE, {"float.nc": make_body_hdb()}, realtime=2.0)
            period = DT / 2.0
            x, v = np.zeros((1, 6)), np.zeros((1, 6))
            sent0 = time.perf_counter()
            early = []
            for k in range(14):
                if k == 13:
                    time.sleep(0.2)
                c.step(k, k * DT, x, v)
                early.append(k * period - (time.perf_counter() - sent0))
            report = c.bye()["realtime"]
    finally:
        if where == "socket":
            srv.stop()
            thread.join(5.0)
        else:
            srv.close()
    print(f"{where}: latest reply ahead of its release by {max(early) * 1e3:.3f} ms; {report}")
    assert max(early) <= 0.0
    assert report["overruns"] >= 1 and report["worst_lateness"] >= 0.2 - period - 1e-3
    assert report["steps"] == 13 and report["factor"] == 2.0


@pytest.mark.parametrize("value", [0, -1.0, "fast", float("inf"), 5e-324, 1e-308, 1e300, 2**62])
def test_server_refuses_a_bad_pace(value):
    from analytic_hdb import make_body_hdb
    from test_force_server import SCENE

    from hydrolink.clients.lockstep.connection import RemoteError, ServerConnection
    from hydrolink.protocol.hdb.wire import to_wire
    from hydrolink.server.service.force_server import ForceServer
    srv = ForceServer(None)
    with ServerConnection(srv, timeout=10.0) as c, pytest.raises(RemoteError) as err:
        c.request("hello", role="multibody", scene=SCENE, hdbs={"float.nc": to_wire(make_body_hdb())}, realtime=value)
    assert err.value.code == 5 and err.value.field == "realtime"
    srv.close()
