"""A site scatter diagram (occurrence per Hm0 x Te bin) from an NDBC spectral wave density file.

    python examples/rm3/scatter_from_ndbc.py 46042w1996.txt.gz -o scatter.csv --source "NDBC 46042, 1996"

Input: an NDBC historical ``swden`` file (text, optionally gzipped): a header ``YY MM DD hh [mm]
f1 f2 ...`` (band centre frequencies, Hz) and one row per hour of spectral densities (m^2/Hz);
rows with missing values (999) are left out. Per row, with the moments m_n = sum f^n S df over
the bands (df: the band spacing): Hm0 = 4 sqrt(m0), Te = m_-1 / m0 (IEC TS 62600-101). The sea
states are counted in bins of 0.5 m x 1 s (IEC TS 62600-100's largest) with centres at 0.25 + k/2 m
and 0.5 + k s; the output (clients/studies/power_matrix.py's CSV layout) is the hours per bin, its comment
lines saying where the data came from and how the bins were made.
"""

from __future__ import annotations

import argparse
import gzip
from pathlib import Path

import numpy as np


def read_swden(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """(frequencies (Hz), spectra (rows, bands)) of the complete rows of an NDBC swden file."""
    opener = gzip.open if path.suffix == ".gz" else open
    with opener(path, "rt") as fh:
        lines = [ln.split() for ln in fh if ln.strip()]
    head = lines[0]
    n_time = 5 if head[4].lower() == "mm" else 4
    freq = np.array([float(x) for x in head[n_time:]])
    rows = np.array([[float(x) for x in ln[n_time:]] for ln in lines[1:] if not ln[0].startswith("#")])
    return freq, rows[np.all(rows < 999.0, axis=1)]


def sea_states(freq: np.ndarray, spectra: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    df = np.gradient(freq)
    m0 = (spectra * df).sum(axis=1)
    m_1 = (spectra * df / freq).sum(axis=1)
    ok = m0 > 0
    return 4 * np.sqrt(m0[ok]), m_1[ok] / m0[ok]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("swden", type=Path)
    ap.add_argument("-o", "--output", type=Path, required=True)
    ap.add_argument("--source", required=True, help="Where the file came from (written into the CSV).")
    args = ap.parse_args()
    freq, spectra = read_swden(args.swden)
    hm0, te = sea_states(freq, spectra)
    h_edges = np.arange(0.0, 0.5 * np.ceil(hm0.max() / 0.5) + 0.5, 0.5)
    t_edges = np.arange(np.floor(te.min()), np.ceil(te.max()) + 1.0, 1.0)
    counts, _, _ = np.histogram2d(hm0, te, bins=[h_edges, t_edges])
    h_c, t_c = 0.5 * (h_edges[1:] + h_edges[:-1]), 0.5 * (t_edges[1:] + t_edges[:-1])
    lines = [f"# {args.source}",
             f"# {len(hm0)} hourly spectra ({spectra.shape[1]} bands {freq[0]:g}-{freq[-1]:g} Hz); rows with missing "
             "values left out",
             "# Hm0 = 4 sqrt(m0), Te = m-1/m0 (m_n = sum f^n S df over the bands); occurrence in hours per bin "
             "(0.5 m x 1 s), by examples/rm3/scatter_from_ndbc.py",
             "hm0\\te," + ",".join(f"{x:g}" for x in t_c)]
    lines += [f"{h:g}," + ",".join(f"{int(c)}" for c in row) for h, row in zip(h_c, counts)]
    args.output.write_text("\n".join(lines) + "\n")
    print(f"wrote {args.output}: {len(hm0)} sea states, Hm0 {hm0.min():.2f}-{hm0.max():.2f} m, "
          f"Te {te.min():.2f}-{te.max():.2f} s")


if __name__ == "__main__":
    main()
