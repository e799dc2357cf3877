"""Shared test fixtures: the leads' reference data lives in ../shared beside the repository."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
SHARED = Path(os.environ.get("HYDROLINK_SHARED", REPO.parent / "shared"))


@pytest.fixture(scope="session")
def shared_data() -> Path:
    """Folder with the reference HDBs (rm3_wamit/, rm3_capytaine/, sphere_task10/)."""
    data = SHARED / "data"
    if not data.is_dir():
        raise RuntimeError(f"reference data not found at {data}: set HYDROLINK_SHARED to the shared/ folder")
    return data
