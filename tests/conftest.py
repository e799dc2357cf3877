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


@pytest.fixture(scope="session")
def sphere_path(shared_data: Path) -> Path:
    """The IEA Task-10 floating sphere (BEMIO .h5; depth 200 m, rho 1000)."""
    return shared_data / "sphere_task10" / "sphere.h5"


@pytest.fixture(scope="session")
def sphere(sphere_path: Path):
    """The sphere's HDB, loaded once."""
    from hydrolink.server.hdb.io import load_hdb
    return load_hdb(sphere_path)


@pytest.fixture(scope="session", autouse=True)
def _state_space_fit_cache(tmp_path_factory):
    """State-space fits are cached in a temporary folder for the session, never in the user's cache
    (tests that look at the cache point $HYDROLINK_STATE_SPACE_CACHE at their own folder)."""
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("HYDROLINK_STATE_SPACE_CACHE", str(tmp_path_factory.mktemp("state_space_cache")))
        yield
