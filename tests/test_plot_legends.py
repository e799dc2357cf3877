"""Plots without empty legend entries: every legend handle of the sweep's capture-width plot and of
the accuracy study's figure is a drawn line (or point set) with data, and every drawn line that can
be told apart from the others has its entry (lines that coincide are one line, one entry)."""

from __future__ import annotations

import math

import matplotlib
import numpy as np
import pytest
import xarray as xr

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

HS = [0.75, 1.25, 1.75, 2.25, 2.75, 3.25, 3.75, 4.25, 4.75]
TE = [6.5, 7.5, 8.5, 9.5, 10.5, 11.5, 12.5, 13.5]
DAMPING = [1.2e6, 2.4e6]
KEYS = ["waves.hs", "waves.te", "ptos.pto.damping"]


def sweep_dataset(cw) -> xr.Dataset:
    """sweep.nc's variables the plot reads, on the example's dims: capture width cw(hs, te, c)."""
    h, t, c = np.meshgrid(HS, TE, DAMPING, indexing="ij")
    return xr.Dataset({"capture_width": (KEYS, cw(h, t, c)),
                       "sea_state_period": (KEYS, t.astype(float))},
                      coords={"waves.hs": HS, "waves.te": TE, "ptos.pto.damping": DAMPING},
                      attrs={"characteristic_width": 20.0})


def legend_against_lines(ax) -> list[str]:
    """Each legend handle is one of the axes' lines with finite data; each line has an entry; no two
    lines lie on each other (within 0.5 % of the y range). Returns the labels."""
    legend = ax.get_legend()
    handles, labels = legend.legend_handles, [t.get_text() for t in legend.get_texts()]
    lines = ax.get_lines()
    assert len(handles) == len(lines) == len(labels)
    by_label = {line.get_label(): line for line in lines}
    for label in labels:
        line = by_label[label]
        assert np.isfinite(np.asarray(line.get_ydata(), float)).sum() >= 1, label
    ys = [np.asarray(line.get_ydata(), float) for line in lines]
    span = max(float(np.ptp(np.concatenate(ys))), 1e-12)
    for i in range(len(ys)):
        for j in range(i):
            assert not (ys[i].shape == ys[j].shape and np.abs(ys[i] - ys[j]).max() <= 0.005 * span), (labels[i],
                                                                                                        labels[j])
    return labels


def test_capture_width_of_a_linear_model_has_one_entry_per_visible_line():
    """The RM3 example's case: the capture width does not depend on Hm0 (a linear model); 9 heights x
    2 dampings were 18 entries over 2 visible lines: now 2 lines, 2 entries naming the 9 heights."""
    from hydrolink.clients.studies.sweep_plots import capture_width_figure
    rng = np.random.default_rng(1)
    ds = sweep_dataset(lambda h, t, c: 40.0 / t * (c / 1e6) ** 0.3 * (1 + 1e-9 * rng.normal(size=h.shape)))
    fig = capture_width_figure(ds, KEYS, "waves.te", "example")
    try:
        labels = legend_against_lines(fig.axes[0])
    finally:
        plt.close(fig)
    assert labels == ["waves.hs = 0.75 ... 4.75 (9 values), ptos.pto.damping = 1.2e+06",
                      "waves.hs = 0.75 ... 4.75 (9 values), ptos.pto.damping = 2.4e+06"]


def test_capture_width_that_depends_on_every_key_keeps_every_line_and_skips_empty_ones():
    """A capture width that falls with Hm0 (drag): 18 distinct lines, 18 entries; combinations
    without a finite case (failed) get no line and no entry."""
    from hydrolink.clients.studies.sweep_plots import capture_width_figure

    def cw(h, t, c):
        out = 40.0 / t * (c / 1e6) ** 0.3 / (1 + 0.2 * h)
        out[h == 4.75] = math.nan          # every case at 4.75 m failed
        return out
    fig = capture_width_figure(sweep_dataset(cw), KEYS, "waves.te", "drag")
    try:
        labels = legend_against_lines(fig.axes[0])
    finally:
        plt.close(fig)
    assert len(labels) == 16 and not any("4.75" in label for label in labels)
    assert "waves.hs = 0.75, ptos.pto.damping = 1.2e+06" in labels


@pytest.mark.filterwarnings("error:Attempting to set identical")     # one value on a log axis: limits set, no warning
def test_accuracy_figure_names_only_what_it_draws():
    """Every option failed (errors NaN; the front is the reference alone): the legend holds the
    reference and its front, no "options"; with options it holds all three, each a drawn artist
    with data."""
    from hydrolink.clients.studies.accuracy import report_figure
    errs, costs = ("max_error", "rms_error"), ("us_per_step", "wall_per_sim_s")

    def row(label, err, cost, front):
        return {"label": label, **{e: err for e in errs}, **{c: cost for c in costs},
                **{f"front_{e}_{c}": front for e in errs for c in costs}}
    for rows, want in (([row("reference", 0.0, 100.0, True), row("dt=0.1", math.nan, 10.0, False),
                         row("dt=0.2", math.nan, 5.0, False)], ["reference (0, at the floor)", "Pareto front"]),
                       ([row("reference", 0.0, 100.0, True), row("dt=0.1", 0.01, 10.0, True),
                         row("dt=0.2", 0.05, 12.0, False)], ["options", "reference (0, at the floor)", "Pareto front"])):
        fig = report_figure(rows, {"title": "t"}, has_power=False)
        try:
            ax = fig.axes[0]
            legend = ax.get_legend()
            labels = [t.get_text() for t in legend.get_texts()]
            assert labels == want
            artists = {a.get_label(): a for a in ax.collections + ax.get_lines()}
            for label in labels:
                a = artists[label]
                data = a.get_offsets() if hasattr(a, "get_offsets") else np.c_[a.get_xdata(), a.get_ydata()]
                assert np.isfinite(np.asarray(data, float)).all(axis=1).any(), label
        finally:
            plt.close(fig)
