"""What an HDB's reader or builder finds doubtful travels with the HDB (issue 40 item 5).

A reader says it with ``warnings.warn(message, HDBWarning)``; :func:`recorded` around a read or a
build collects those messages instead of showing them, and the caller keeps them in the HDB's
``warnings`` attribute (:func:`hydrolink.protocol.hdb.layout.with_hdb_warnings`). From there they
go wherever the HDB goes — a hello's HDB map, the child process that parses files sent by hash, a
cached build — and the force server puts them in ``setup.warnings`` (SPEC §5.1), which every client
shows and keeps with its results. ``hydrolink hdb info``/``hdb build`` and the Python API show them
from the attribute. Other warnings (a library's) are shown as usual.

``warnings.catch_warnings`` is process-wide: HDBs read in two threads at once may swap notes.
"""

from __future__ import annotations

import warnings
from contextlib import contextmanager
from typing import Iterator

__all__ = ["HDBWarning", "recorded"]


class HDBWarning(UserWarning):
    """A doubt about an HDB its reader or builder could not settle: the message names the file and
    the key (scene or file) to change."""


@contextmanager
def recorded(notes: list[str]) -> Iterator[list[str]]:
    """Collect the :class:`HDBWarning` messages raised inside into ``notes`` (each one plain line,
    once) instead of showing them; any other warning is shown as it would have been."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", HDBWarning)
        yield notes
    for w in caught:
        if issubclass(w.category, HDBWarning):
            text = " ".join(str(w.message).split())
            if text not in notes:
                notes.append(text)
        else:
            warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
