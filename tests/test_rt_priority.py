"""Real-time scheduling (clients/lockstep/rt_priority.py, ``--rt-priority``): the thread is put under
SCHED_FIFO and back, the threads it starts inherit it, a paced thread under it spins less before a
release (protocol/pacing.py), and a value out of range or a process without the right gets an error
naming the option and why."""

from __future__ import annotations

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
        with rt_priority(5):
            held = (os.sched_getscheduler(0), os.sched_getparam(0).sched_priority)
            child = _in_thread(lambda: (os.sched_getscheduler(0), Pacer(0.001).spin))
            spin = Pacer(0.001).spin
        return before, held, child, spin, os.sched_getscheduler(0), Pacer(0.001).spin
    before, held, child, spin, after, spin_after = _in_thread(body)
    assert held == (os.SCHED_FIFO, 5)
    assert child == (os.SCHED_FIFO, RT_SPIN)          # a thread started under it (the results writer's)
    assert spin == RT_SPIN and RT_SPIN < SPIN
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
