"""Compare two hydrolink results files bit for bit: every variable, its dims and coordinates.

    python bench/compare_results.py before.nc after.nc [--tolerance 0]

Prints one line per variable that differs (largest absolute and relative difference) and the
variables only one file has; exits 1 when anything differs beyond ``--tolerance`` (relative to
the variable's largest magnitude; 0 = bit for bit). Attributes (versions, wall times, the scene
text) are not compared. Used to check that a refactoring left the examples' results unchanged.
"""

from __future__ import annotations

import argparse
import sys

import numpy as np
import xarray as xr


def compare(a: xr.Dataset, b: xr.Dataset, tolerance: float = 0.0) -> list[str]:
    """The differences between two results datasets, one line each (empty: equal)."""
    out = []
    for name in sorted(set(a.variables) | set(b.variables)):
        if name not in a.variables or name not in b.variables:
            out.append(f"{name}: only in {'the first' if name in a.variables else 'the second'} file")
            continue
        va, vb = a[name], b[name]
        if va.dims != vb.dims or va.shape != vb.shape:
            out.append(f"{name}: dims {va.dims} {va.shape} vs {vb.dims} {vb.shape}")
            continue
        x, y = va.values, vb.values
        if x.dtype.kind not in "fc":
            if not np.array_equal(x, y):
                out.append(f"{name}: values differ")
            continue
        if np.array_equal(x, y, equal_nan=True):
            continue
        diff = float(np.nanmax(np.abs(x - y)))
        scale = float(np.nanmax(np.abs(x))) if x.size else 0.0
        if diff > tolerance * scale:
            out.append(f"{name}: max |difference| {diff:.3g} ({diff / scale if scale else np.inf:.3g} of its largest value)")
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("first")
    ap.add_argument("second")
    ap.add_argument("--tolerance", type=float, default=0.0)
    args = ap.parse_args(argv)
    with xr.open_dataset(args.first) as a, xr.open_dataset(args.second) as b:
        lines = compare(a.load(), b.load(), args.tolerance)
    for line in lines:
        print(line)
    print(f"{args.first} vs {args.second}: " + ("equal" if not lines else f"{len(lines)} difference(s)"))
    return 1 if lines else 0


if __name__ == "__main__":
    sys.exit(main())
