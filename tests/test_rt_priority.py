"""Real-time scheduling (clients/lockstep/rt_priority.py, ``--rt-priority``): the thread is put under
SCHED_FIFO and back, the threads it starts inherit it, a paced thread under it spins less before a
release (protocol/pacing.py), a value out of range or a process without the right gets an error
naming the option and why, before any set-up; a run and its controller hold it for their loops only."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import threading

import pytest

from hydrolink.clients.lockstep.rt_priority import PriorityError, hold_rt_priority, rt_priority
from hydrolink.protocol.pacing import RT_SPIN, SPIN, Pacer

linux_fifo = pytest.mark.skipif(not hasattr(os, "sched_setscheduler"), reason="SCHED_FIFO is Linux's")


def _may_take_fifo() -> bool:
    import resource
    return os.geteuid() == 0 or resource.getrlimit(resource.RLIMIT_RTPRIO)[0] >= 5


def _spin() -> float:
    """The spin of a Pacer released by the calling thread (taken at its first release)."""
    pacer = Pacer(0.001)
    pacer.release(0)
    return pacer.spin


def _in_thread(fn):
    """``fn()`` in a new thread (its scheduling is the thread's own: the test's stays as it was)."""
    out = {}

    def body():
        try:
            out["value"] = fn()
        except BaseException as exc:   # handed to the test's thread
            out["error"] = exc
    t = threading.Thread(target=body)
    t.start()
    t.join(30)
    if "error" in out:
        raise out["error"]
    return out["value"]


@linux_fifo
@pytest.mark.skipif(not _may_take_fifo(), reason="this process may not take SCHED_FIFO")
def test_fifo_held_inherited_by_new_threads_and_restored():
    def body():
        before = os.sched_getscheduler(0)
        made_before = Pacer(0.001)   # as a run's: made in its set-up, released in its loop
        with rt_priority(5):
            held = (os.sched_getscheduler(0), os.sched_getparam(0).sched_priority)
            child = _in_thread(lambda: (os.sched_getscheduler(0), _spin()))
            spin = _spin()
            made_before.release(0)
        return before, held, child, spin, os.sched_getscheduler(0), _spin(), made_before.spin
    before, held, child, spin, after, spin_after, made_before = _in_thread(body)
    assert held == (os.SCHED_FIFO, 5)
    assert child == (os.SCHED_FIFO, RT_SPIN)          # a thread started under it
    assert spin == made_before == RT_SPIN and RT_SPIN < SPIN
    assert after == before == os.SCHED_OTHER and spin_after == SPIN


@pytest.mark.parametrize("value", [0, 99, -3])
def test_priority_out_of_range_names_the_option(value):
    with pytest.raises(PriorityError, match=rf"--rt-priority {value}: a real-time priority is an integer from 1 to 98"):
        hold_rt_priority(value)


@linux_fifo
@pytest.mark.skipif(os.geteuid() != 0, reason="needs to drop to an unprivileged user in a child")
def test_refused_without_the_right_says_why():
    """A process without CAP_SYS_NICE and with ``ulimit -r`` 0 (a child that drops to user nobody)."""
    code = ("import os, resource\n"   # imported before the drop (nobody may not read the interpreter's files)
            "from hydrolink.clients.lockstep.rt_priority import PriorityError, hold_rt_priority\n"
            "resource.setrlimit(resource.RLIMIT_RTPRIO, (0, 0)); os.setgid(65534); os.setuid(65534)\n"
            "try:\n    hold_rt_priority(20)\nexcept PriorityError as exc:\n    print(exc)\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == ("--rt-priority 20: the process may not take SCHED_FIFO (it needs CAP_SYS_NICE, "
                                  "or `ulimit -r` >= 20; `ulimit -r` is 0)")


def test_cli_control_rt_priority_out_of_range_is_one_line(tmp_path):
    from click.testing import CliRunner

    from hydrolink.clients.cli import cli

    ctl = tmp_path / "c.py"
    ctl.write_text("def my_controller(x, v, t, eta10):\n    return 0.0\n")
    r = CliRunner().invoke(cli, ["control", str(ctl), "--server", "tcp://127.0.0.1:9", "--token", "t" * 32,
                                 "--rt-priority", "0"], prog_name="hydrolink")
    assert r.exit_code != 0
    assert "--rt-priority 0: a real-time priority is an integer from 1 to 98" in r.output


OBSERVER = '''
import json, os
from hydrolink.clients.control import Controller

RUN, OUT, AT = {run}, {out!r}, {at}


def threads(pid):
    """[comm, policy] of each thread of process ``pid``."""
    seen = []
    for tid in sorted(os.listdir(f"/proc/{{pid}}/task"), key=int):
        with open(f"/proc/{{pid}}/task/{{tid}}/comm") as f:
            seen.append([f.read().strip(), os.sched_getscheduler(int(tid))])
    return seen


class Observer(Controller):
    """A damper that notes its own policy and the run's stepping thread's (the run's main thread)."""

    def on_start(self, info):
        self.c = float(info["parameters"]["damping"])
        self.seen = {{"start": [os.sched_getscheduler(0), os.sched_getscheduler(RUN)], "steps": [],
                     "run_threads_at_start": threads(RUN), "own_threads_at_start": threads(os.getpid())}}

    def on_step(self, t, m):
        self.seen["steps"].append([os.sched_getscheduler(0), os.sched_getscheduler(RUN)])
        if len(self.seen["steps"]) == AT:   # the run in its loop: every thread of it and of its children
            with open(f"/proc/{{RUN}}/task/{{RUN}}/children") as f:
                children = [int(p) for p in f.read().split()]
            self.seen["run_threads"] = threads(RUN)
            self.seen["children_threads"] = [threads(p) for p in children]
            self.seen["own_threads"] = threads(os.getpid())
        return {{p: self.c * v for p, v in zip(self.ptos, m["pto_velocity"].tolist())}}

    def on_stop(self):
        self.seen["stop"] = threads(os.getpid())
        with open(OUT, "w") as f:
            json.dump(self.seen, f)
'''


@linux_fifo
@pytest.mark.skipif(not _may_take_fifo(), reason="this process may not take SCHED_FIFO")
def test_run_and_controller_hold_fifo_for_their_loops_only(reference_data, tmp_path):
    """``hydrolink run --realtime --rt-priority 5`` with a ``hydrolink control --rt-priority 5``
    controller, observed by the controller from outside the run (/proc, ``sched_getscheduler`` of
    the run's stepping thread): at the join (the run's set-up done but for its first sample) both,
    and every thread their set-ups started, are ordinary; at every step after the run's first
    exchange both are SCHED_FIFO, and so are those threads (ZeroMQ's I/O thread carries the
    controller's messages), but not the run's results writer's process; at ``stop`` the controller
    is ordinary again."""
    from conftest import EXIT_S, REPLY_S, controller_process
    from test_controllers import TOKEN, controller_block, free_address, scene_text

    at = 20
    (tmp_path / "rm3.toml").write_text(scene_text(reference_data, 2.4, controller_block("force", 1.0e6, 0.0)))
    address = free_address()
    run = subprocess.Popen([sys.executable, "-m", "hydrolink.clients.cli", "run", str(tmp_path / "rm3.toml"), "-o",
                            str(tmp_path / "rm3.nc"), "--no-progress", "--listen", address, "--control-token", TOKEN,
                            "--realtime", "--rt-priority", "5", "--reply-timeout", str(REPLY_S)],
                           stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        ctl = tmp_path / "observer.py"
        ctl.write_text(OBSERVER.format(run=run.pid, out=str(tmp_path / "seen.json"), at=at))
        with controller_process(ctl, address, TOKEN, "--rt-priority", "5") as ended:
            out, err = run.communicate(timeout=EXIT_S)
    finally:
        if run.poll() is None:
            run.kill()
            run.communicate()
    assert run.returncode == 0, err
    assert ended.returncode == 0, ended.stderr
    seen = json.loads((tmp_path / "seen.json").read_text())
    other, fifo = os.SCHED_OTHER, os.SCHED_FIFO
    assert seen["start"] == [other, other]
    steps = seen["steps"]
    assert len(steps) == 60 and all(own == fifo for own, _ in steps)
    assert all(theirs == fifo for _, theirs in steps[2:])    # steps 0-1 may be answered before the loop's first exchange

    def policies(threads: list) -> set:
        return {policy for _, policy in threads}

    # the set-up's threads (ZeroMQ's, numpy's, tqdm's...) ordinary in the set-up, under FIFO in the loop
    assert len(seen["run_threads_at_start"]) > 2 and policies(seen["run_threads_at_start"]) == {other}
    assert len(seen["own_threads_at_start"]) > 2 and policies(seen["own_threads_at_start"]) == {other}
    for at_start, in_loop in ((seen["run_threads_at_start"], seen["run_threads"]),
                              (seen["own_threads_at_start"], seen["own_threads"])):
        assert policies(in_loop) == {fifo} and {n for n, _ in at_start} <= {n for n, _ in in_loop}, in_loop
    assert seen["children_threads"] and all(policies(t) == {other} for t in seen["children_threads"])
    assert seen["stop"] and policies(seen["stop"]) == {other}


def test_cli_run_refuses_the_priority_before_its_set_up(tmp_path):
    """A bad --rt-priority is said before the scene is read (the file does not exist)."""
    from conftest import cli_here

    r = cli_here("run", str(tmp_path / "absent.toml"), "--rt-priority", "99", cwd=tmp_path)
    assert r.returncode != 0
    assert "--rt-priority 99: a real-time priority is an integer from 1 to 98" in r.stderr
    assert "absent.toml" not in r.stderr
