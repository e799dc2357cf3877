"""The force model's error: a scene/HDB combination it cannot run, named by its scene key."""

from __future__ import annotations

from hydrolink.protocol.errors import KeyedError


class ModelError(KeyedError):
    """A scene/HDB combination the model cannot run; the message names the scene key and why."""

    def __init__(self, key: str, why: str):
        super().__init__("", key, why)
