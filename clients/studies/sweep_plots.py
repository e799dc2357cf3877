"""The plots of ``hydrolink sweep`` (matplotlib, from sweep.nc's dataset):

- ``power_matrix.png``: the power matrix as a heat map, kW printed in every bin with a case, one
  panel per combination of the other sweep keys (at most :data:`MAX_PANELS`);
- ``capture_width.png``: capture width against the wave period (Te, or T for regular waves), one
  line per combination of the other swept values (wave height included); combinations whose
  lines coincide (a linear model's capture width is the same at every wave height) are one line
  with one legend entry naming their values.
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


COINCIDE = 0.005      # curves closer than this fraction of the plot's y range are drawn as one line


def _merged_label(ds: xr.Dataset, sels: list[dict[str, int]]) -> str:
    """The legend text of curves drawn as one line: each key with its value, or its values when the
    curves differ in it ("waves.hs = 0.75, 1.25, 1.75"; more than 4: first ... last (n values))."""
    parts = []
    for k in sels[0]:
        vals = list(dict.fromkeys(_fmt(ds[k].values[sel[k]]) for sel in sels))
        text = ", ".join(vals) if len(vals) <= 4 else f"{vals[0]} ... {vals[-1]} ({len(vals)} values)"
        parts.append(f"{k} = {text}")
    return ", ".join(parts) or "all cases"


def _curves(ds: xr.Dataset, combos: list[dict[str, int]], period_key: str) -> list[tuple[list[dict], np.ndarray,
                                                                                             np.ndarray]]:
    """Capture width against the period per combination with data; combinations whose curves
    coincide (same periods, values within :data:`COINCIDE` of the y range) merged into one."""
    raw = []
    for sel in combos:
        sub = ds.isel(sel)
        cw, per = sub["capture_width"], sub["sea_state_period"]
        extra = [d for d in cw.dims if d != period_key]
        if extra:   # keys of size 1 (or not swept): their single value
            cw, per = cw.isel({d: 0 for d in extra}), per.isel({d: 0 for d in extra})
        x, y = per.values, cw.values
        ok = np.isfinite(x) & np.isfinite(y)
        if ok.any():
            o = np.argsort(x[ok])
            raw.append((sel, x[ok][o], y[ok][o]))
    if not raw:
        return []
    ys = np.concatenate([y for _, _, y in raw])
    tol = COINCIDE * max(float(ys.max() - ys.min()), 1e-12 * float(np.abs(ys).max()), 1e-300)
    merged: list[tuple[list[dict], np.ndarray, np.ndarray]] = []
    for sel, x, y in raw:
        same = next((m for m in merged if m[1].shape == x.shape and np.allclose(m[1], x, rtol=1e-9, atol=0)
                     and np.abs(m[2] - y).max() <= tol), None)
        if same is None:
            merged.append(([sel], x, y))
        else:
            same[0].append(sel)
    return merged


def capture_width_figure(ds: xr.Dataset, sweep_keys: list[str], period_key: str | None, title: str):
    """The capture width figure (matplotlib): capture width against the period, one line per
    combination of the other swept values, combinations whose lines coincide drawn (and named in
    the legend) once; None when the dataset has no capture width."""
    if period_key is None or "capture_width" not in ds or not np.isfinite(ds["capture_width"].values).any():
        return None
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    others = [k for k in sweep_keys if k != period_key and ds.sizes[k] > 1]
    curves = _curves(ds, _combos(ds, others), period_key)
    fig, ax = plt.subplots(figsize=(7.0 + 1.5 * max(0, math.ceil(len(curves) / 12) - 1), 4.5))
    colors = plt.cm.viridis(np.linspace(0, 0.9, max(len(curves), 1)))
    for (sels, x, y), color in zip(curves, colors):
        ax.plot(x, y, "-o", ms=3, color=color, label=_merged_label(ds, sels))
    ax.set_xlabel("energy period Te (s)" if "te" in ds.dims or "hm0" in ds.dims else "wave period T (s)")
    ax.set_ylabel("capture width P / J (m)")
    if "characteristic_width" in ds.attrs:
        sec = ax.secondary_yaxis("right", functions=(lambda w: w / ds.attrs["characteristic_width"],
                                                     lambda r: r * ds.attrs["characteristic_width"]))
        sec.set_ylabel(f"capture width ratio (B = {ds.attrs['characteristic_width']:g} m)")
    ax.grid(True, alpha=0.3)
    if len(curves) <= 48:
        ax.legend(fontsize=6 if len(curves) <= 12 else 5, loc="best", ncol=math.ceil(len(curves) / 12))
    ax.set_title(title, fontsize=10)
    fig.tight_layout()
    return fig


def plot_capture_width(ds: xr.Dataset, sweep_keys: list[str], period_key: str | None, path: Path,
                       title: str) -> bool:
    """``capture_width.png`` (:func:`capture_width_figure`); False when there is nothing to plot."""
    fig = capture_width_figure(ds, sweep_keys, period_key, title)
    if fig is None:
        return False
    import matplotlib.pyplot as plt
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return True
