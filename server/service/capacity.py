"""The server's bounds on what multibody hellos may make it hold (SPEC §4.2, §5.6 code 14).

Each set-up holds its hello (up to the message size limit) and each open session its model (IRFs,
tables) until ``bye`` or the idle timeout; without bounds a client sending hellos in a loop grows
the server's memory without end and makes every other user's hello wait behind its set-ups. A
hello beyond a bound is refused at once with error 14 ``busy``: nothing of it is kept, no set-up
starts, no session is touched. Controller hellos join an existing session and are not counted.
"""

from __future__ import annotations

from dataclasses import dataclass

from hydrolink.protocol.codec import Code, ProtocolError

MAX_SETUPS = 8      # hellos being set up (waiting for a worker or running) at once
MAX_SESSIONS = 64   # sessions open or being set up


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
