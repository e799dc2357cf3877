"""The radiated and diffracted waves on the free surface, from the Capytaine free-surface solution an
HDB build stores when its spec asks for it (``[free_surface]``, server/hdb/build/free_surface.py),
combined linearly with the run's motion (regular waves: the motion's complex amplitude at the
wave's frequency, fitted over one period around each frame)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from hydrolink.clients.view.results import RunFile
from hydrolink.clients.view.surface import Grid


@dataclass
class DisturbedField:
    """Placeholder filled in below."""


def disturbed_field(run: RunFile, grid: Grid) -> tuple[DisturbedField | None, str]:
    """The field for the run's HDB builds' stored free-surface solution (None and a note when there
    is none)."""
    return None, ""
