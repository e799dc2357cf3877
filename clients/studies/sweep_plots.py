"""The plots of ``hydrolink sweep`` (matplotlib, from sweep.nc's dataset):

- ``power_matrix.png``: the power matrix as a heat map, kW printed in every bin with a case, one
  panel per combination of the other sweep keys (at most :data:`MAX_PANELS`);
- ``capture_width.png``: capture width against the wave period (Te, or T for regular waves), one
  line per combination of the other swept values (wave height included).
"""

from __future__ import annotations

import itertools
import math
from pathlib import Path

import numpy as np
import xarray as xr

MAX_PANELS = 12


def _fmt(v) -> str:
    return f"{v:g}" if isinstance(v, (float, np.floating)) else str(v)


def _combos(ds: xr.Dataset, keys: list[str]) -> list[dict[str, int]]:
    return [dict(zip(keys, idx)) for idx in itertools.product(*(range(ds.sizes[k]) for k in keys))]


def _label(ds: xr.Dataset, sel: dict[str, int]) -> str:
    return ", ".join(f"{k} = {_fmt(ds[k].values[i])}" for k, i in sel.items()) or "all cases"


def plot_power_matrix(ds: xr.Dataset, path: Path, title: str) -> bool:
    """Heat map(s) of ``power_matrix``; False when the dataset has none."""
    if "power_matrix" not in ds:
        return False
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    pm = ds["power_matrix"]
    hname, tname = pm.dims[-2], pm.dims[-1]
    others = list(pm.dims[:-2])
    combos = _combos(ds, others)[:MAX_PANELS]
    n = len(combos)
    cols = min(n, 3)
    rows = math.ceil(n / cols)
    h, t = ds[hname].values, ds[tname].values
    fig, axes = plt.subplots(rows, cols, figsize=(1.0 + max(4.0, 0.55 * t.size) * cols,
                                                   0.8 + max(3.0, 0.38 * h.size) * rows), squeeze=False)
    top = np.nanmax(pm.values) / 1e3 if np.isfinite(pm.values).any() else 1.0
    for ax, sel in zip(axes.ravel(), combos):
        p = pm.isel(sel).values / 1e3
        im = ax.imshow(np.ma.masked_invalid(p), origin="lower", aspect="auto", cmap="viridis", vmin=0, vmax=top,
                       extent=(-0.5, t.size - 0.5, -0.5, h.size - 0.5))
        for i, j in zip(*np.nonzero(np.isfinite(p))):
            ax.text(j, i, f"{p[i, j]:.3g}", ha="center", va="center", fontsize=7,
                    color="white" if p[i, j] < 0.6 * top else "black")
        ax.set_xticks(range(t.size), [_fmt(x) for x in t], fontsize=7, rotation=90 if t.size > 12 else 0)
        ax.set_yticks(range(h.size), [_fmt(x) for x in h], fontsize=7)
        ax.set_xlabel("Te (s)" if tname == "te" else "T (s)")
        ax.set_ylabel("Hm0 (m)" if hname == "hm0" else "H (m)")
        ax.set_title(_label(ds, sel), fontsize=8)
        fig.colorbar(im, ax=ax, label="mean power (kW)")
    for ax in axes.ravel()[n:]:
        ax.axis("off")
    more = len(_combos(ds, others)) - n
    fig.suptitle(title + (f" (first {n} of {n + more} panels)" if more > 0 else ""), fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return True


def plot_capture_width(ds: xr.Dataset, sweep_keys: list[str], period_key: str | None, path: Path,
                       title: str) -> bool:
    """Capture width against the period, one line per combination of the other swept values."""
    if period_key is None or "capture_width" not in ds or not np.isfinite(ds["capture_width"].values).any():
        return False
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    others = [k for k in sweep_keys if k != period_key and ds.sizes[k] > 1]
    fig, ax = plt.subplots(figsize=(7.0 + 1.5 * max(0, math.ceil(len(_combos(ds, others)) / 12) - 1), 4.5))
    combos = _combos(ds, others)
    colors = plt.cm.viridis(np.linspace(0, 0.9, max(len(combos), 1)))
    for sel, color in zip(combos, colors):
        sub = ds.isel(sel)
        cw = sub["capture_width"]
        extra = [d for d in cw.dims if d != period_key]
        if extra:   # keys of size 1 (or not swept): their single value
            cw = cw.isel({d: 0 for d in extra})
            per = sub["sea_state_period"].isel({d: 0 for d in extra})
        else:
            per = sub["sea_state_period"]
        x, y = per.values, cw.values
        ok = np.isfinite(x) & np.isfinite(y)
        if ok.any():
            o = np.argsort(x[ok])
            ax.plot(x[ok][o], y[ok][o], "-o", ms=3, color=color, label=_label(ds, sel))
    ax.set_xlabel("energy period Te (s)" if "te" in ds.dims or "hm0" in ds.dims else "wave period T (s)")
    ax.set_ylabel("capture width P / J (m)")
    if "characteristic_width" in ds.attrs:
        sec = ax.secondary_yaxis("right", functions=(lambda w: w / ds.attrs["characteristic_width"],
                                                     lambda r: r * ds.attrs["characteristic_width"]))
        sec.set_ylabel(f"capture width ratio (B = {ds.attrs['characteristic_width']:g} m)")
    ax.grid(True, alpha=0.3)
    if len(combos) <= 48:
        ax.legend(fontsize=6 if len(combos) <= 12 else 5, loc="best", ncol=math.ceil(len(combos) / 12))
    ax.set_title(title, fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return True
