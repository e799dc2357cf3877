"""Real-time scheduling for a paced run and its controllers (Linux ``SCHED_FIFO``; docs/realtime.md).

A controlled 1 kHz step is a ping-pong between two processes (the run and its controller), each
woken by the other's message. On a host with more runnable work than cores, an ordinary
(``SCHED_OTHER``) process woken by a message waits its turn behind that work, and the sender can
lose its core to the process it woke: the round trip then costs scheduler slices, not the work.
A ``SCHED_FIFO`` thread runs as soon as it is runnable, ahead of every ordinary thread, so the
step's time is its own work again. The kernel's real-time throttling (``sched_rt_runtime_us``,
95 % of each second by default) keeps a busy real-time thread from starving the host.

The priority is the loop's, not the process's: a command checks it may be had before any set-up
work (:func:`check_rt_priority`), and the loop holds it (:func:`rt_priority`) from its first
step to its last — the run's from its first exchange (after the HDBs, the model, the compiled
kernels, the results file and its writer, the controllers' join) to its last, a controller's from
its first measurement to ``stop``. Seconds of set-up under ``SCHED_FIFO`` would starve every
ordinary process on the core, and the threads started during it would inherit the policy. The
loop's priority covers the process's other threads too, for the loop only (:func:`companion_threads`:
ZeroMQ's I/O threads carry its messages, Python threads take its GIL).
"""

from __future__ import annotations

import os
import threading
from contextlib import contextmanager
from typing import Iterator

#: the range ``--rt-priority`` accepts: 1 (lowest) to 98 (99 is left to the kernel's own threads)
PRIORITIES = (1, 98)


class PriorityError(ValueError):
    """The real-time priority asked for cannot be had (the option, the value and why)."""


def hold_rt_priority(priority: int, option: str = "--rt-priority") -> tuple[int, int]:
    """Run the calling thread (and the threads it starts afterwards) under ``SCHED_FIFO`` at
    ``priority``; returns the thread's previous (policy, priority) for
    :func:`restore_priority`. PriorityError naming ``option`` when the value is out of range, the
    platform has no ``SCHED_FIFO`` or the process may not take it (it needs CAP_SYS_NICE or an
    ``ulimit -r`` of at least ``priority``)."""
    lo, hi = PRIORITIES
    if type(priority) is not int or not lo <= priority <= hi:
        raise PriorityError(f"{option} {priority!r}: a real-time priority is an integer from {lo} to {hi}")
    if not hasattr(os, "sched_setscheduler"):
        raise PriorityError(f"{option} {priority}: this platform has no SCHED_FIFO (Linux only)")
    before = (os.sched_getscheduler(0), os.sched_getparam(0).sched_priority)
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
    except PermissionError:
        raise PriorityError(f"{option} {priority}: the process may not take SCHED_FIFO (it needs CAP_SYS_NICE, "
                            f"or `ulimit -r` >= {priority}; `ulimit -r` is {_rtprio_limit()})") from None
    except OSError as exc:
        raise PriorityError(f"{option} {priority}: SCHED_FIFO refused ({exc})") from None
    return before


def check_rt_priority(priority: int, option: str = "--rt-priority") -> None:
    """The :class:`PriorityError` :func:`hold_rt_priority` would raise, now: ``SCHED_FIFO`` at
    ``priority`` taken and given back at once, so that a command refuses the option before its
    set-up and takes the priority for its loop only."""
    restore_priority(hold_rt_priority(priority, option))


def restore_priority(before: tuple[int, int]) -> None:
    """Put the calling thread back under the (policy, priority) :func:`hold_rt_priority` returned."""
    os.sched_setscheduler(0, before[0], os.sched_param(before[1]))


@contextmanager
def rt_priority(priority: int | None, option: str = "--rt-priority") -> Iterator[None]:
    """A loop's priority: :func:`hold_rt_priority` for the block, and the same for the process's
    other threads (:func:`companion_threads`: started in the set-up, under the ordinary policy);
    then every one's previous policy back. Nothing when ``priority`` is None."""
    if priority is None:
        yield
        return
    before = hold_rt_priority(priority, option)
    raised = []
    try:
        for tid in companion_threads():
            try:
                was = (os.sched_getscheduler(tid), os.sched_getparam(tid).sched_priority)
                os.sched_setscheduler(tid, os.SCHED_FIFO, os.sched_param(priority))
            except OSError:   # ended meanwhile
                continue
            raised.append((tid, was))
        yield
    finally:
        for tid, (policy, level) in raised:
            try:
                os.sched_setscheduler(tid, policy, os.sched_param(level))
            except OSError:
                pass
        restore_priority(before)


def companion_threads() -> list[int]:
    """The ids of this process's other threads (none where there is no /proc). A loop works
    through threads its set-up started under the ordinary policy: ZeroMQ's I/O threads (a message
    over ZeroMQ passes through one on each side), Python threads (one preempted by ordinary work
    while it holds the GIL would hold the loop), libraries' own: with only the I/O and Python
    threads raised, every controlled run on ZeroMQ measured had a stall of 16-46 ms
    (docs/realtime.md, "The priority for the loop only")."""
    me = threading.get_native_id()
    try:
        return sorted(tid for tid in map(int, os.listdir("/proc/self/task")) if tid != me)
    except OSError:
        return []


@contextmanager
def ordinary_policy() -> Iterator[None]:
    """The calling thread under the ordinary policy (``SCHED_OTHER``) for the block, so that what it
    starts meanwhile (a helper process: the results writer's) does not inherit a real-time one
    (every thread that process makes at its start, a BLAS pool's, would); then its policy back.
    Nothing to do for a thread already ordinary, or without ``SCHED_FIFO``."""
    get = getattr(os, "sched_getscheduler", None)
    before = (get(0), os.sched_getparam(0).sched_priority) if get is not None else (None, 0)
    if before[0] in (None, os.SCHED_OTHER):
        yield
        return
    os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
    try:
        yield
    finally:
        restore_priority(before)


def _rtprio_limit() -> str:
    import resource
    soft, _ = resource.getrlimit(resource.RLIMIT_RTPRIO)
    return "unlimited" if soft == resource.RLIM_INFINITY else str(soft)
