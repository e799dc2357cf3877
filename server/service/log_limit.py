"""How often the server writes a log line for the same kind of event: a client sending bad messages
in a loop, or a flood of hellos refused ``busy``, would otherwise write one line for each (a shared
server's log filling its disk). Per kind (an error code), at most ``burst`` lines a ``window``;
the rest are counted, and the next line of that kind after the window says how many were left out.
The replies themselves are never limited: each request still gets its own."""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Hashable
from dataclasses import dataclass, field

__all__ = ["LimitedLog"]


@dataclass
class LimitedLog:
    """A logger's lines, at most ``burst`` per kind in each ``window`` [s] (module docstring)."""
    logger: logging.Logger
    burst: int = 20
    window: float = 60.0
    clock: Callable[[], float] = time.monotonic
    _kinds: dict[Hashable, tuple[float, int, int]] = field(default_factory=dict)   # window start, written, left out

    def log(self, kind: Hashable, level: int, msg: str, *args: object, exc_info: BaseException | None = None) -> None:
        """``logger.log(level, msg, *args, exc_info=...)`` unless ``kind`` has had ``burst`` lines in
        this window."""
        now = self.clock()
        start, written, left_out = self._kinds.get(kind, (now, 0, 0))
        if now - start >= self.window:
            if left_out:
                self.logger.log(level, "%d more like the next were not logged (at most %d a %g s window)",
                                left_out, self.burst, self.window)
            start, written, left_out = now, 0, 0
        if written < self.burst:
            self.logger.log(level, msg, *args, exc_info=exc_info)
            written += 1
        else:
            left_out += 1
        self._kinds[kind] = (start, written, left_out)
