"""On-disk cache of state-space radiation fits (:func:`hydrolink.server.radiation.state_space.fit_pairs`).

A group's fit (poles, residues, D and error of every DOF pair) depends only on the fit frequencies,
the pairs' transfer-function samples H(w) (which carry the HDB, irf_duration, irf_taper, irf_tail,
irf_domega and the fluid density), their error scales, the fit settings (ss_tolerance, ss_order,
ss_max_order, ss_enforce_stability) and the fitting recipe (``FIT_RECIPE_VERSION``): the key is the
sha256 of exactly these, so identical groups share an entry whatever the bodies are called. The time
step is not part of it: the fit is in continuous time and its discretisation for dt
(StateSpaceRadiation, microseconds) is redone every run.

Folder, by priority: ``$HYDROLINK_STATE_SPACE_CACHE`` (the folder itself),
``$HYDROLINK_CACHE/state_space``, ``$XDG_CACHE_HOME/hydrolink/state_space``,
``~/.cache/hydrolink/state_space``; one ``fit-<key>.npz`` per entry, written atomically. An
unreadable entry is refitted (and rewritten) and a folder that cannot be written is given up for
the rest of the setup; both are reported once in :attr:`FitCache.warnings`, which the model passes on
with its other setup warnings.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from hydrolink.server.disk_cache import env_dir, user_cache_dir, write_atomic
from hydrolink.server.radiation.state_space import FIT_RECIPE_VERSION, PairFits, fit_pairs


@dataclass(frozen=True)
class FitSettings:
    """The [hydro] settings a fit depends on (besides its samples)."""
    tolerance: float
    order: int | None
    max_order: int
    enforce_stability: bool


def default_cache_dir() -> Path:
    """``$HYDROLINK_STATE_SPACE_CACHE``, else ``$HYDROLINK_CACHE/state_space``, else
    ``$XDG_CACHE_HOME/hydrolink/state_space``, else ``~/.cache/hydrolink/state_space``."""
    shared = env_dir("HYDROLINK_CACHE")
    return (env_dir("HYDROLINK_STATE_SPACE_CACHE") or (shared / "state_space" if shared else None)
            or user_cache_dir("state_space"))


def fit_key(omega: np.ndarray, h: np.ndarray, scale: np.ndarray, settings: FitSettings) -> str:
    """sha256 of the fit's inputs: frequencies, samples (P, K), scales (P,), settings, recipe."""
    digest = hashlib.sha256()
    for a, kind in ((omega, float), (h, complex), (scale, float)):
        a = np.ascontiguousarray(a, kind)
        digest.update(f"{a.dtype.str}{a.shape};".encode())
        digest.update(a.tobytes())
    digest.update(json.dumps({**asdict(settings), "recipe": FIT_RECIPE_VERSION}, sort_keys=True).encode())
    return digest.hexdigest()


def _arrays(fits: PairFits) -> dict[str, np.ndarray]:
    """A fit as flat arrays (ragged poles/residues concatenated, ``orders`` to split them)."""
    cat = (lambda x: np.concatenate(x)) if fits.poles else (lambda x: np.zeros(0, complex))
    return {"orders": fits.orders, "poles": cat(fits.poles), "residues": cat(fits.residues),
            "d": np.asarray(fits.d, float), "error": np.asarray(fits.error, float)}


def _pair_fits(arrays: dict[str, np.ndarray], rows: np.ndarray, cols: np.ndarray) -> PairFits:
    """Back to PairFits for the caller's (rows, cols); checks the arrays fit together."""
    orders = np.asarray(arrays["orders"], int)
    poles, residues = np.asarray(arrays["poles"], complex), np.asarray(arrays["residues"], complex)
    d, error = np.asarray(arrays["d"], float), np.asarray(arrays["error"], float)
    if not (orders.shape == d.shape == error.shape == (len(rows),) and np.all(orders > 0) and np.all(orders % 2 == 0)
            and poles.shape == residues.shape == (int(orders.sum()) // 2,)):
        raise ValueError(f"inconsistent arrays (orders {orders.shape}, poles {poles.shape}, residues "
                         f"{residues.shape}, d {d.shape}, error {error.shape}) for {len(rows)} DOF pairs")
    cuts = np.cumsum(orders // 2)[:-1]
    split = (lambda x: np.split(x, cuts)) if orders.size else (lambda x: [])
    return PairFits(np.asarray(rows, int), np.asarray(cols, int), split(poles), split(residues), d, error)


class FitCache:
    """State-space fits of one model setup: in memory (identical groups fitted once) and on disk
    in ``folder`` (None: memory only). ``fitted`` counts distinct pair fits computed, ``hits`` the
    groups taken from memory or disk; ``warnings`` holds what went wrong with the folder."""

    def __init__(self, folder: Path | None):
        self.folder = folder
        self.fitted = 0
        self.hits = 0
        self.warnings: list[str] = []
        self._memory: dict[str, dict[str, np.ndarray]] = {}

    def take_warnings(self) -> list[str]:
        """The warnings so far, handed over once."""
        out, self.warnings = self.warnings, []
        return out

    def path(self, key: str) -> Path | None:
        """The entry's file (None without a folder)."""
        return self.folder / f"fit-{key[:40]}.npz" if self.folder is not None else None

    def fit_pairs(self, omega: np.ndarray, h: np.ndarray, rows: np.ndarray, cols: np.ndarray, scale: np.ndarray,
                  settings: FitSettings) -> PairFits:
        """:func:`~hydrolink.server.radiation.state_space.fit_pairs` of these inputs, from the cache when it
        holds them, else fitted and stored."""
        key = fit_key(omega, h, scale, settings)
        arrays = self._memory.get(key) or self._read(key, rows, cols)
        if arrays is not None:
            self.hits += 1
            self._memory[key] = arrays
            return _pair_fits(arrays, rows, cols)
        fits = fit_pairs(omega, h, rows, cols, scale, **asdict(settings))
        self.fitted += fits.fitted
        self._memory[key] = _arrays(fits)
        self._write(key, self._memory[key])
        return fits

    def _read(self, key: str, rows: np.ndarray, cols: np.ndarray) -> dict[str, np.ndarray] | None:
        path = self.path(key)
        try:
            if path is None or not path.is_file():
                return None
            with np.load(path, allow_pickle=False) as npz:
                if str(npz["key"]) != key:
                    raise ValueError(f"it holds the fit of another key ({str(npz['key'])[:16]}...)")
                arrays = {name: npz[name] for name in ("orders", "poles", "residues", "d", "error")}
            _pair_fits(arrays, rows, cols)
            return arrays
        except Exception as exc:  # noqa: BLE001 - a damaged cache entry is refitted, not fatal
            self.warnings.append(f"ignoring unreadable cached state-space fit {path}: {exc}; fitted again")
            return None

    def _write(self, key: str, arrays: dict[str, np.ndarray]) -> None:
        path = self.path(key)
        if path is None:
            return

        def save(tmp: str) -> None:
            with open(tmp, "wb") as f:
                np.savez(f, key=np.array(key), **arrays)

        try:
            write_atomic(path, save)
        except OSError as exc:
            self.warnings.append(f"could not write the state-space fit cache {path}: {exc}; going on without a "
                                 "disk cache (set $HYDROLINK_STATE_SPACE_CACHE to a writable folder)")
            self.folder = None
