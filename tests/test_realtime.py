"""``hydrolink run --realtime`` (protocol/pacing.py): exchanges released at wall-clock times,
overruns counted, per-step latency in the results. Timing is measured by bench/bench_realtime.py;
here only what holds on any machine: a step made slow on purpose is counted as an overrun with
(at least) its delay as lateness, found in the results at its row with its cause (a sleeping
controller, a slow results write), and a paced run cannot finish before its simulated duration."""

from __future__ import annotations

import json
import os
import signal
import threading
import time

import numpy as np
import pytest

from test_rm3 import scene_text

from conftest import IDLE_S, REPLY_S

SLOW_SEQ, DELAY = 10, 0.3     # the row of step 10 takes 0.3 s more to commit; an exchange is 80 ms


def test_slow_step_is_an_overrun(reference_data, tmp_path, monkeypatch):
    import xarray as xr

    from hydrolink.clients.lockstep.results import ResultWriter
    from hydrolink.clients.run import run_scene_file
    commit = ResultWriter.commit

    def slow(self, *args, **kwargs):   # the row of step SLOW_SEQ (the reference path's or the compiled exchange's)
        if self.rows == SLOW_SEQ:
            time.sleep(DELAY)
        return commit(self, *args, **kwargs)

    monkeypatch.setattr(ResultWriter, "commit", slow)
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


SLEEPY = """
import time
from hydrolink.clients.control import Controller

class Sleepy(Controller):
    def on_start(self, info):
        self.c = float(info["parameters"]["damping"])

    def on_step(self, t, m):
        if round(t / {dt}) == {step}:
            time.sleep({delay})
        return {{p: self.c * v for p, v in zip(self.ptos, m["pto_velocity"].tolist())}}
"""
CTL_STEP, CTL_DELAY = 6, 0.4        # the controller sleeps over its decision of step 6: exchange 6, row 7
ROWS, SLOW_FIRST, IO_DELAY = 5, 25, 1.0   # blocks of 5 rows, two of them; the write of rows 25-29 takes 1 s more


def test_injected_delays_are_found_at_their_step_with_their_cause(reference_data, tmp_path, monkeypatch):
    """A paced run (RM3, 40 ms per exchange) with two delays put in on purpose: the controller (its
    own process, over loopback) sleeps 0.4 s over step 6's command, and the results writer's process
    is stopped for 1 s when rows 25-29 are handed to it while only two blocks of five rows exist, so
    the stepping thread waits for a free block when the next block fills (row 34). Each shows in the results file at its row, as
    an overrun whose largest part is its cause; the file's counts are the summary's, and every
    row's parts add up to its latency. Margins are wide: only the injected rows are asserted on."""
    import xarray as xr

    from test_controllers import controller_block, free_address, run_own, scene_text as controller_scene

    from hydrolink.clients.lockstep import results
    from hydrolink.protocol.pacing import PARTS

    resumes = []

    class SmallBlocks(results.ResultWriter):   # the real writer: small blocks, its process stopped once
        def __init__(self, *args, **kwargs):
            super().__init__(*args, **kwargs, flush_rows=ROWS, blocks=2)

        def _send(self, blk):
            if blk.first == SLOW_FIRST:
                os.kill(self._proc.pid, signal.SIGSTOP)
                resumes.append(threading.Timer(IO_DELAY, os.kill, (self._proc.pid, signal.SIGCONT)))
                resumes[-1].start()
            super()._send(blk)

    monkeypatch.setattr(results, "ResultWriter", SmallBlocks)
    dt = 0.04
    text = controller_scene(reference_data, 2.4, controller_block("force", 1.0e6, 0.0))
    text = text.replace("[simulation]\n", "[simulation]\nflush_seconds = 3600.0\n")   # blocks seal by rows only
    ctl = tmp_path / "sleepy.py"
    ctl.write_text(SLEEPY.format(dt=dt, step=CTL_STEP, delay=CTL_DELAY))
    summary, (rc, err) = run_own(tmp_path, "paced", text, ctl, free_address(), realtime=1.0, timeout=REPLY_S)
    for timer in resumes:
        timer.join()
    assert rc == 0, err
    assert len(resumes) == 1          # the writer was stopped once, over the rows asked for
    rt = summary.realtime
    ds = xr.load_dataset(tmp_path / "paced.nc")
    lat, over, parts = ds["step_latency"].values, ds["overrun"].values, ds["step_time"].values
    assert list(ds["step_part"].values) == list(PARTS) and ds["overrun"].dtype == np.int8
    cause = {p: i for i, p in enumerate(PARTS)}
    print(rt)
    for name, row in (("controller", CTL_STEP + 1), ("io", SLOW_FIRST + 2 * ROWS - 1)):
        print(name, row, lat[row], dict(zip(PARTS, parts[row].round(4))))
    # the controller's sleep: its row, an overrun caused by the controller
    row = CTL_STEP + 1
    assert over[row] == 1 and lat[row] >= CTL_DELAY and np.argmax(parts[row]) == cause["controller"]
    assert parts[row, cause["controller"]] >= CTL_DELAY - 0.1
    assert np.argmax(parts[1:, cause["controller"]]) + 1 == row          # and nowhere is it as large
    # the slow write: felt when the next block fills (row 34), an overrun caused by I/O
    row = SLOW_FIRST + 2 * ROWS - 1
    assert over[row] == 1 and np.argmax(parts[row]) == cause["io"] and parts[row, cause["io"]] >= 0.3
    assert np.argmax(parts[1:, cause["io"]]) + 1 == row
    # the file and the summary agree; the parts are the latency; the initial row is not a step
    assert rt.steps == 60 and over.sum() == rt.overruns == json.loads(ds.attrs["realtime"])["overruns"]
    assert rt.overrun_causes["controller"] >= 1 and rt.overrun_causes["io"] >= 1
    assert sum(rt.overrun_causes.values()) == rt.overruns
    assert np.all((lat[1:] > rt.period) == (over[1:] == 1))
    assert np.allclose(parts[1:].sum(axis=1), lat[1:], rtol=0, atol=1e-9)
    assert np.isnan(lat[0]) and over[0] == 0 and np.all(np.isnan(parts[0]))
    assert rt.latency_max == pytest.approx(np.nanmax(lat), abs=1e-12)


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
        srv, thread = serve_in_thread(session_timeout=IDLE_S)
        address = srv.address
    else:
        srv = ForceServer(None)
        address = srv
    try:
        with ServerConnection(address, timeout=REPLY_S) as c:
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
    with ServerConnection(srv, timeout=REPLY_S) as c, pytest.raises(RemoteError) as err:
        c.request("hello", role="multibody", scene=SCENE, hdbs={"float.nc": to_wire(make_body_hdb())}, realtime=value)
    assert err.value.code == 5 and err.value.field == "realtime"
    srv.close()


def test_blas_pools_hold_one_thread_in_the_loop(reference_data, tmp_path, monkeypatch):
    """The lockstep loop holds every BLAS/OpenMP pool of the process to one thread (threadpoolctl),
    whatever the environment says, and gives them back afterwards (a script importing hydrolink
    gets this too, not only the ``hydrolink`` command)."""
    from threadpoolctl import threadpool_info, threadpool_limits

    from hydrolink.clients.lockstep.results import ResultWriter
    from hydrolink.clients.run import run_scene_file
    commit, seen, rows = ResultWriter.commit, [], []

    def looking(self, t, eta):   # each step's row (every exchange path commits one); the pools while the loop runs
        rows.append(t)
        if len(rows) == 5:
            seen.extend(p["num_threads"] for p in threadpool_info())
        return commit(self, t, eta)

    monkeypatch.setattr(ResultWriter, "commit", looking)
    (tmp_path / "rm3.toml").write_text(scene_text("full", reference_data / "rm3_wamit" / "rm3.1", duration=0.8))
    with threadpool_limits(limits=2):          # as an unset environment leaves them on 2 cores
        before = [p["num_threads"] for p in threadpool_info()]
        run_scene_file(tmp_path / "rm3.toml", tmp_path / "rm3.nc", progress=False)
        after = [p["num_threads"] for p in threadpool_info()]
    assert seen and set(seen) == {1}
    assert after == before


def test_a_late_release_is_a_wake_and_what_it_carries_is_behind():
    """protocol/pacing.py: an exchange released late because its wait ended late (here an idle hook
    that sleeps 0.2 s past the release, as a host that does not run the thread would) is an
    overrun whose cause is ``wake``; the two exchanges after it, which the loop reaches after their
    releases, are overruns caused by ``behind`` (the lateness carried), with no ``wake`` to speak
    of; every exchange's parts add up to its latency. 50 ms per exchange, no work in them."""
    from hydrolink.protocol.pacing import PARTS, Pacer, StepRecord

    late, period, n = 0.2, 0.05, 6
    pacer = Pacer(period)

    slept = []

    def idle(left: float) -> None:      # called in the wait of an exchange with time left
        if not slept and pacer.t0 is not None and time.perf_counter() > pacer.t0 + 1.5 * period:
            slept.append(left)
            time.sleep(left + late)

    pacer.idle = idle
    record = StepRecord(pacer, n)
    for e in range(n):
        pacer.release(e)
        record.step(e, time.perf_counter(), 0.0, 0.0, 0.0)
    parts = dict(zip(PARTS, record.parts.T))
    hit = int(np.argmax(parts["wake"]))
    assert hit >= 2 and parts["wake"][hit] >= late and parts["behind"][hit] == 0.0
    assert record.overrun[hit] and np.argmax(record.parts[hit]) == PARTS.index("wake")
    for e in (hit + 1, hit + 2):          # released when the loop got there, after their releases
        assert record.overrun[e] and np.argmax(record.parts[e]) == PARTS.index("behind")
        assert parts["behind"][e] >= late - (e - hit) * period - 0.01 and parts["wake"][e] < 0.01
    assert np.allclose(record.parts.sum(axis=1), record.latency, rtol=0, atol=1e-9)
    report = record.report()
    assert report.overrun_causes["wake"] >= 1 and report.overrun_causes["behind"] >= 2
