"""The one error shape of bad input: where (a file or a message), the key or field at fault, and why.

Every reader and checker raises a subclass (SceneError, HDBError, ModelError, ...) so a caller can
report any of them in one line, and the server can put ``key`` in its error reply's field.
"""

from __future__ import annotations

from pathlib import Path


class KeyedError(ValueError):
    """An input that cannot be used: ``source`` (a file or message; "" when the key says it all),
    ``key`` (the scene key, file field or message field; "" for the whole source) and ``why``."""

    def __init__(self, source: str | Path, key: str, why: str):
        self.source, self.key, self.why = str(source), key, why
        super().__init__(": ".join(part for part in (self.source, key, why) if part))
