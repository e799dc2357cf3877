"""The server's bounds on what multibody hellos may make it hold (SPEC §4.2, §5.6 code 14).

Each set-up holds its hello (up to the message size limit) and each open session its model (IRFs,
tables) until ``bye`` or the idle timeout; without bounds a client sending hellos in a loop grows
the server's memory without end and makes every other user's hello wait behind its set-ups. A
hello beyond a bound is refused at once with error 14 ``busy``: nothing of it is kept, no set-up
starts, no session is touched. Controller hellos join an existing session and are not counted.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

from hydrolink.protocol.codec import Code, ProtocolError

MAX_SETUPS = 8      # hellos being set up (waiting for a worker or running) at once
MAX_SESSIONS = 64   # sessions open or being set up
ISOLATE_STEP_S = 0.5e-3   # s: a session whose model's step takes longer (timed at set-up) steps in a worker
MAX_WORKERS = 4     # worker processes (heavy sessions) at once: a 2-core machine gains nothing from more


def default_memory_mib() -> int:
    """The server-wide budget of the sessions' models by default: half the machine's memory (MiB)."""
    try:
        return max(256, os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE") // 2**21)
    except (ValueError, OSError, AttributeError):   # a platform that does not say
        return 4096


class ServerBusy(ProtocolError):
    """Error 14 ``busy``: a bound of the server is reached; its further fields name it (``limit``:
    ``"setups"`` or ``"sessions"``), its value (``maximum``) and how many are held (``current``)."""

    def __init__(self, limit: str, maximum: int, current: int, message: str):
        super().__init__(Code.BUSY, None, message,
                         extra={"limit": limit, "maximum": maximum, "current": current})


@dataclass(frozen=True)
class HelloLimits:
    """The bounds on set-ups waiting or running (``max_setups``) and on sessions open or being set
    up (``max_sessions``); ``hydrolink serve --max-setups / --max-sessions``."""

    max_setups: int = MAX_SETUPS
    max_sessions: int = MAX_SESSIONS

    def __post_init__(self) -> None:
        for name in ("max_setups", "max_sessions"):
            value = getattr(self, name)
            if type(value) is not int or value < 1:
                raise ValueError(f"{name} must be an int >= 1, got {value!r}")

    def admit(self, setups: int, sessions: int) -> None:
        """Raise :class:`ServerBusy` unless one more hello fits: ``setups`` hellos are being set up
        and ``sessions`` sessions are open (a set-up counts as a session too: it becomes one)."""
        if setups >= self.max_setups:
            raise ServerBusy("setups", self.max_setups, setups,
                             f"server busy: {setups} hellos are being set up, at most {self.max_setups} "
                             "(max_setups; hydrolink serve --max-setups raises it); nothing of this hello "
                             "was kept: send it again after a set-up is done")
        held = sessions + setups
        if held >= self.max_sessions:
            raise ServerBusy("sessions", self.max_sessions, held,
                             f"server busy: {sessions} sessions open and {setups} being set up, at most "
                             f"{self.max_sessions} (max_sessions; hydrolink serve --max-sessions raises it); "
                             "nothing of this hello was kept: send it again after a session closes (bye or "
                             "its idle timeout)")


@dataclass(frozen=True)
class MemoryBudget:
    """The bytes the open sessions' models may hold together (``hydrolink serve --max-memory-mib``):
    a new session whose model would pass it is refused with error 14, ``limit`` ``"memory"``
    (``maximum``, ``current`` in MiB); its model is dropped, the open sessions are untouched."""

    max_bytes: int

    def admit(self, held: int, needed: int) -> None:
        """Raise :class:`ServerBusy` unless a model of ``needed`` bytes fits beside ``held``."""
        if held + needed > self.max_bytes:
            mib = 2**20
            raise ServerBusy("memory", self.max_bytes // mib, -(-held // mib),
                             f"server busy: this session's model takes {needed / mib:.0f} MiB and the open "
                             f"sessions hold {held / mib:.0f} MiB, at most {self.max_bytes / mib:.0f} MiB together "
                             "(max_memory; hydrolink serve --max-memory-mib raises it); nothing of this hello "
                             "was kept: send it again after a session closes, or make the scene smaller (a "
                             "shorter irf_duration, fewer wave components)")

    def out_of_memory(self, held: int) -> ServerBusy:
        """The error of a set-up that ran out of memory while building its model."""
        mib = 2**20
        return ServerBusy("memory", self.max_bytes // mib, -(-held // mib),
                          "server busy: the machine ran out of memory setting this session up (the open sessions "
                          f"hold {held / mib:.0f} MiB); nothing of this hello was kept: send it again after a "
                          "session closes, or make the scene smaller")
