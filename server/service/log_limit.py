"""How often the server writes a log line for the same kind of event: a client sending bad messages
in a loop, or a flood of hellos refused ``busy``, would otherwise write one line for each (a shared
server's log filling its disk). Per kind (an error code), at most ``burst`` lines a ``window``;
the rest are counted, and the next line of that kind after the window says how many were left out.
The replies themselves are never limited: each request still gets its own.

:func:`limit_lines` applies the same rule to every line of the ``hydrolink`` loggers written
while a server's loop runs (its thread, and the set-ups it hands to workers), per message: a late
controller command repeated, a session opened and closed in a loop, each writes at most ``burst``
lines a minute of its kind. Elsewhere (another thread, a local run) nothing is filtered."""

from __future__ import annotations

import contextvars
import logging
import threading
import time
from collections.abc import Callable, Hashable
from dataclasses import dataclass, field

__all__ = ["LimitedLog", "limit_lines"]

_ADMITTED = "_hydrolink_limited"   # a record LimitedLog.log wrote (already counted under its own kind)


@dataclass
class LimitedLog:
    """A logger's lines, at most ``burst`` per kind in each ``window`` [s] (module docstring)."""
    logger: logging.Logger
    burst: int = 20
    window: float = 60.0
    clock: Callable[[], float] = time.monotonic
    _kinds: dict[Hashable, tuple[float, int, int]] = field(default_factory=dict)   # window start, written, left out
    _lock: threading.Lock = field(default_factory=threading.Lock)

    def _admit(self, kind: Hashable) -> tuple[bool, int]:
        """(write this line?, how many of its kind the last window left out: to be said now)."""
        with self._lock:
            now = self.clock()
            start, written, left_out = self._kinds.get(kind, (now, 0, 0))
            said = 0
            if now - start >= self.window:
                said = left_out
                start, written, left_out = now, 0, 0
            write = written < self.burst
            if write:
                written += 1
            else:
                left_out += 1
            self._kinds[kind] = (start, written, left_out)
            return write, said

    def log(self, kind: Hashable, level: int, msg: str, *args: object, exc_info: BaseException | None = None) -> None:
        """``logger.log(level, msg, *args, exc_info=...)`` unless ``kind`` has had ``burst`` lines in
        this window."""
        write, said = self._admit(kind)
        if said:
            self.logger.log(level, "%d more like the next were not logged (at most %d a %g s window)",
                            said, self.burst, self.window, extra={_ADMITTED: True})
        if write:
            self.logger.log(level, msg, *args, exc_info=exc_info, extra={_ADMITTED: True})

    def filter(self, record: logging.LogRecord) -> bool:
        """As a logging filter: ``record`` unless its kind (logger, level, message template) had
        ``burst`` lines in this window; the first line after a window that left some out says how
        many, at its end."""
        if getattr(record, _ADMITTED, False):
            return True
        template = record.msg if isinstance(record.msg, str) else type(record.msg).__name__
        write, said = self._admit((record.name, record.levelno, template))
        if write and said:
            record.msg, record.args = (f"{record.getMessage()} ({said} more like this were not logged: at most "
                                       f"{self.burst} a {self.window:g} s window)"), None
        return write


_ACTIVE: contextvars.ContextVar[LimitedLog | None] = contextvars.ContextVar("hydrolink_log_limit", default=None)


class _ActiveFilter(logging.Filter):
    """The filter on every ``hydrolink`` logger: the limiter of the loop running in this context."""

    def filter(self, record: logging.LogRecord) -> bool:
        limiter = _ACTIVE.get()
        return True if limiter is None else limiter.filter(record)


_FILTER = _ActiveFilter()


class _Limiting:
    def __init__(self, token: contextvars.Token):
        self._token = token

    def close(self) -> None:
        """Stop limiting (in the thread that started it)."""
        if self._token is not None:
            _ACTIVE.reset(self._token)
            self._token = None


def limit_lines(limiter: LimitedLog, prefix: str = "hydrolink") -> _Limiting:
    """From now on, in this thread (and what it runs in a copy of its context: contextvars), every
    line of the loggers named ``prefix``… passes ``limiter`` (per logger, level and message
    template); ``.close()`` ends it. The filter goes on each such logger that exists now (the
    server's modules create theirs at import)."""
    for name, logger in list(logging.Logger.manager.loggerDict.items()):
        if (name == prefix or name.startswith(prefix + ".")) and isinstance(logger, logging.Logger) \
                and _FILTER not in logger.filters:
            logger.addFilter(_FILTER)
    root = logging.getLogger(prefix)
    if _FILTER not in root.filters:
        root.addFilter(_FILTER)
    return _Limiting(_ACTIVE.set(limiter))
