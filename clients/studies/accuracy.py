"""``hydrolink bench accuracy SCENE.toml``: the speed/accuracy trade of a scene's options, measured.

A scene runs (``hydrolink run``: Exudyn client, embedded server) under a grid of options and once
under reference settings; every option's response is compared with the reference run's:

- ``max error``: worst response channel of max_t |x - x_ref| / max_t |x_ref - mean x_ref|;
- ``RMS error``: worst channel of rms(x - x_ref) / rms(x_ref - mean x_ref);
- ``power error``: |mean P - mean P_ref| / |mean P_ref| of total_pto_power (scenes with PTOs);

over the comparison window (default: from the end of the wave ramp to the end), the option's
samples against the reference interpolated to its times (cubic). Response channels: ``position``
(every body, every DOF) whose reference standard deviation is at least 1e-3 of the largest one of
its kind (translations, rotations). Cost: wall time per step and per simulated second of the
whole run (client, server, results file), and the server's compute per step.

The **Pareto front** (per error measure and cost measure): the options no other option beats in
both cost and error (ties in both do not dominate). Outputs in the output folder:
``accuracy.md`` (table), ``accuracy.png`` (error against cost, front joined), ``accuracy.csv``.

The grid (a TOML file, or CLI flags; the shared grid format of clients/studies/grid.py) names scene keys by
their dotted path (entries of arrays of tables by name: ``ptos.pto.damping``) or a short alias::

    duration = 60.0              # s, overrides simulation.duration of every run (optional)
    window = [20.0, 60.0]        # s, comparison window (optional)
    mode = "axes"                # "axes": one key varied at a time, the others at the reference;
                                 # "product": every combination; "zip": the i-th values together
    [reference]                  # the reference run (default: the scene's own values, with the
    dt = 0.005                   #  smallest dt, the longest irf_duration and the most complete
                                 #  nonlinear of the grid)
    [grid]
    dt = [0.01, 0.02, 0.04]
    irf_duration = [5.0, 10.0, 20.0]
    radiation = ["convolution", "state-space", "constant"]
    excitation = ["superposition", "convolution"]
    coupling = ["mass-matrix", "implicit"]
    nonlinear = ["none", "froude-krylov"]   # linear hydrostatics / Froude-Krylov vs the hull's
                                            # instantaneous wetted surface (hydro.nonlinear)
    reduce = [true, false]       # reduced bodies vs the full form ([client] reduce): same results to
                                 # round-off, the per-step cost of the DAE vs the ODE-like model
    [[cases]]                    # extra options, each a set of keys (optional label)
    label = "state-space + taper"
    radiation = "state-space"
    "hydro.irf_taper" = 0.2
"""

from __future__ import annotations

import csv
import json
import math
import shutil
import tempfile
from pathlib import Path
from typing import Any

import numpy as np
from pydantic import Field

from hydrolink.protocol.errors import KeyedError
from hydrolink.clients.studies.grid import ALIASES, SHORT, GridMode, GridSpec, Value, absolute_paths, combinations, dump_toml, effective_value, full_key, get_key, set_key, short_key
from hydrolink.protocol.toml_model import parse_toml, validate_toml


class BenchError(KeyedError):
    """A grid the bench cannot run; the message names the file, the key and why."""


class Grid(GridSpec):
    """The bench's grid file: the shared grid (clients/studies/grid.py; mode "axes" by default) plus the
    reference run's keys, the simulated duration and the comparison window. Keys are held as
    dotted scene keys (aliases resolved)."""
    mode: GridMode = "axes"
    reference: dict[str, Value] = {}
    duration: float | None = Field(default=None, gt=0)
    window: tuple[float, float] | None = None

    @classmethod
    def from_toml(cls, path: str | Path) -> "Grid":
        path = Path(path)
        try:
            text = path.read_text()
        except OSError as exc:
            raise BenchError(path, "", str(exc)) from None
        g = validate_toml(text, path, cls, BenchError)
        g.grid = {full_key(k): v for k, v in g.grid.items()}
        g.reference = {full_key(k): v for k, v in g.reference.items()}
        g.cases = [{(k if k == "label" else full_key(k)): v for k, v in c.items()} for c in g.cases]
        g.check(str(path))
        return g

    def check(self, source: str = "grid") -> None:
        if self.window is not None and (len(self.window) != 2 or not self.window[0] < self.window[1]):
            raise BenchError(source, "window", f"[start, end] with start < end (got {list(self.window)})")
        if not self.grid and not self.cases:
            raise BenchError(source, "", "no options: give [grid] keys, [[cases]] or CLI flags")


# ------------------------------------------------------------------ cases

def _fmt(v) -> str:
    return f"{v:g}" if isinstance(v, float) else str(v)


def scene_value(doc: dict, key: str):
    """A scene key's value: written in the document, else the scene format's default (None if the
    key does not apply, e.g. waves.excitation in still water)."""
    v = get_key(doc, key)
    if v is not None:
        return v
    from hydrolink.protocol.scene import Scene
    try:
        scene = Scene.model_validate(doc)
    except Exception:  # noqa: BLE001 - an invalid document has no defaults to offer
        return None
    obj = effective_value(scene, key)
    return obj if isinstance(obj, (int, float, str, bool)) else None


# the nonlinear hydrostatics modes (hydro.nonlinear, bodies.<name>.nonlinear), least to most complete
NONLINEAR_ORDER = ("none", "hydrostatic", "froude-krylov")


def _is_nonlinear_key(key: str) -> bool:
    parts = key.split(".")
    return key == "hydro.nonlinear" or (len(parts) == 3 and parts[0] == "bodies" and parts[2] == "nonlinear")


def reference_settings(grid: Grid, doc: dict) -> dict[str, Any]:
    """The reference run's keys: grid.reference, else per grid key the scene's value (written or
    default) — except the smallest dt (simulation.dt), the longest IRFs (hydro.irf_duration,
    waves.excitation_irf_duration) and the most complete nonlinear hydrostatics (hydro.nonlinear,
    bodies.<name>.nonlinear: none < hydrostatic < froude-krylov), which take the finest of the grid
    and the scene."""
    ref: dict[str, Any] = {}
    keys = list(grid.grid) + [k for c in grid.cases for k in c if k != "label"]
    for key in dict.fromkeys(keys):
        if key in grid.reference:
            continue
        values = list(grid.grid.get(key, []))
        scene_v = scene_value(doc, key)
        if key == "simulation.dt":
            ref[key] = min(values + ([scene_v] if scene_v is not None else []))
        elif key in ("hydro.irf_duration", "waves.excitation_irf_duration"):
            ref[key] = max(values + ([scene_v] if scene_v is not None else []))
        elif _is_nonlinear_key(key) and any(v in NONLINEAR_ORDER for v in values):
            # a misspelt mode is never the reference: it fails as an option, naming the key
            known = [v for v in values + [scene_v] if v in NONLINEAR_ORDER]
            ref[key] = max(known, key=NONLINEAR_ORDER.index)
        elif scene_v is not None:
            ref[key] = scene_v
        elif values:
            ref[key] = values[0]
    ref.update(grid.reference)
    return ref


def make_cases(grid: Grid, reference: dict[str, Any]) -> list[tuple[str, dict[str, Any]]]:
    """(label, overrides) of every option, the reference excluded and duplicates dropped."""
    out: list[tuple[str, dict[str, Any]]] = []

    def signature(d: dict[str, Any]) -> str:
        return json.dumps({k: float(v) if isinstance(v, (int, float)) and not isinstance(v, bool) else v
                           for k, v in d.items()}, sort_keys=True, default=str)
    seen = {signature(reference)}

    def add(label: str, over: dict[str, Any]) -> None:
        full = {**reference, **over}
        sig = signature(full)
        if sig not in seen:
            seen.add(sig)
            out.append((label, full))
    for over in combinations(grid.grid, grid.mode):
        if grid.mode == "product":
            changed = [f"{short_key(k)}={_fmt(v)}" for k, v in over.items() if reference.get(k) != v]
            add(", ".join(changed) or "reference", over)
        else:
            add(", ".join(f"{short_key(k)}={_fmt(v)}" for k, v in over.items()), over)
    for c in grid.cases:
        over = {k: v for k, v in c.items() if k != "label"}
        add(c.get("label") or ", ".join(f"{short_key(k)}={_fmt(v)}" for k, v in over.items()), over)
    return out


# ------------------------------------------------------------------ comparison

def _channels(x_ref: np.ndarray) -> np.ndarray:
    """Mask (body, dof) of the response channels that move (see module docstring)."""
    std = x_ref.std(axis=0)
    keep = np.zeros(std.shape, bool)
    for sl in (slice(0, 3), slice(3, 6)):
        top = std[:, sl].max() if std[:, sl].size else 0.0
        if top > 0:
            keep[:, sl] = std[:, sl] >= 1e-3 * top
    return keep


def _reference_at(tr: np.ndarray, x_ref: np.ndarray, t: np.ndarray) -> np.ndarray:
    """The reference positions (t, body, dof) at times ``t``: its own samples where a time is one of
    its sample times, the cubic spline through them elsewhere (a spline evaluated at a knot rounds
    differently from the sample it passes through: identical runs must compare at zero)."""
    from scipy.interpolate import CubicSpline
    out = CubicSpline(tr, x_ref.reshape(tr.size, -1), axis=0)(t).reshape((-1,) + x_ref.shape[1:])
    i = np.minimum(np.searchsorted(tr, t), tr.size - 1)
    at_sample = tr[i] == t
    out[at_sample] = x_ref[i[at_sample]]
    return out


def compare(ref: dict, run: dict, window: tuple[float, float]) -> dict[str, float]:
    """Errors of ``run`` against ``ref`` (dicts of time, position (t, body, dof), power (t,) or None)."""
    t = run["time"]
    sel = (t >= window[0] - 1e-9) & (t <= window[1] + 1e-9)
    tr = ref["time"]
    sr = (tr >= window[0] - 1e-9) & (tr <= window[1] + 1e-9)
    if sel.sum() < 2 or sr.sum() < 2:
        raise BenchError("", "window", f"[{window[0]:g}, {window[1]:g}] s holds too few samples")
    x_ref_w = ref["position"][sr]
    keep = _channels(x_ref_w)
    if not keep.any():
        raise BenchError("", "reference", "the reference run does not move (no response channel to compare)")
    xr_at = _reference_at(tr, ref["position"], t[sel])
    x = run["position"][sel]
    if not np.all(np.isfinite(x)):
        return {"max_error": math.inf, "rms_error": math.inf, "power_error": math.inf}
    dev = x_ref_w - x_ref_w.mean(axis=0)
    amp = np.abs(dev).max(axis=0)
    rms_ref = np.sqrt((dev ** 2).mean(axis=0))
    d = x - xr_at
    max_err = float((np.abs(d).max(axis=0)[keep] / amp[keep]).max())
    rms_err = float((np.sqrt((d ** 2).mean(axis=0))[keep] / rms_ref[keep]).max())
    p_err = math.nan
    if ref.get("power") is not None and run.get("power") is not None:
        p0 = float(np.mean(ref["power"][sr]))
        p1 = float(np.mean(run["power"][sel]))
        p_err = abs(p1 - p0) / abs(p0) if p0 != 0 else math.nan
    return {"max_error": max_err, "rms_error": rms_err, "power_error": p_err}


def pareto_front(cost, error) -> np.ndarray:
    """True for the points no other point dominates (cost <= and error <=, one of them <)."""
    c = np.asarray(cost, float)
    e = np.asarray(error, float)
    ok = np.isfinite(c) & np.isfinite(e)
    front = np.zeros(c.size, bool)
    for i in np.flatnonzero(ok):
        dominated = ok & (c <= c[i]) & (e <= e[i]) & ((c < c[i]) | (e < e[i]))
        front[i] = not dominated.any()
    return front


# ------------------------------------------------------------------ running

def _read(path: Path) -> dict:
    import xarray as xr
    with xr.open_dataset(path, engine="netcdf4") as ds:
        pos = ds["position"].values - ds["equilibrium_position"].values[None]
        out = {"time": ds["time"].values.astype(float), "position": pos,
               "power": ds["total_pto_power"].values.astype(float) if "total_pto_power" in ds else None}
    return out


def run_option(doc: dict, settings: dict[str, Any], duration: float | None, workdir: Path, name: str,
               hdbs: dict | None, progress: bool = False) -> tuple[dict, dict]:
    """Run the scene with ``settings`` applied; returns (results arrays, cost summary)."""
    from hydrolink.clients.scene_inputs import load_scene_hdbs
    from hydrolink.clients.run import run_scene_file
    from hydrolink.protocol.scene import load_scene
    case = json.loads(json.dumps(doc))
    for k, v in settings.items():
        set_key(case, k, v)
    if isinstance(case.get("client"), dict):
        case["client"].setdefault("type", "exudyn")   # client.reduce alone: the default client
    if duration is not None:
        set_key(case, "simulation.duration", float(duration))
    set_key(case, "simulation.progress", False)
    path = workdir / f"{name}.toml"
    path.write_text(dump_toml(case))
    if hdbs is not None and not hdbs:
        scene, _ = load_scene(path)
        hdbs.update(load_scene_hdbs(scene, path, progress=progress))
    s = run_scene_file(path, workdir / f"{name}.nc", progress=False, hdbs=hdbs or None)
    steps = max(int(s.steps), 1)
    sim_time = float(s.time or steps * float(get_key(case, "simulation.dt")))
    cost = {"us_per_step": 1e6 * s.wall_time / steps, "wall_per_sim_s": s.wall_time / sim_time,
            "server_us_per_step": float((s.server_compute_us_per_step or math.nan)), "steps": steps,
            "wall_time": float(s.wall_time)}
    return _read(workdir / f"{name}.nc"), cost


def _best_of(repeat: int, doc, settings, duration, work, name, hdbs, progress=False) -> tuple[dict, dict]:
    """run_option ``repeat`` times: the first run's results, the cheapest run's cost (other jobs on
    the machine only ever add time)."""
    res, cost = run_option(doc, settings, duration, work, name, hdbs, progress)
    for _ in range(repeat - 1):
        _, c = run_option(doc, settings, duration, work, name + "_again", hdbs)
        if c["wall_time"] < cost["wall_time"]:
            cost = c
    return res, cost


def bench_accuracy(scene_path: str | Path, grid: Grid, outdir: str | Path, *, title: str | None = None,
                   keep_runs: bool = False, progress: bool = True, log=print, repeat: int = 1) -> list[dict]:
    """Run the grid and the reference, write accuracy.md / .png / .csv to ``outdir``; returns the rows
    (the reference first). ``repeat``: runs per option, the cheapest counted."""
    from hydrolink.protocol.scene import load_scene
    scene_path = Path(scene_path)
    scene, text = load_scene(scene_path)     # validates the scene as it is
    doc = absolute_paths(parse_toml(text, scene_path, BenchError), scene_path)
    outdir = Path(outdir)
    outdir.mkdir(parents=True, exist_ok=True)
    reference = reference_settings(grid, doc)
    cases = make_cases(grid, reference)
    duration = grid.duration or float(scene.simulation.duration)
    ramp = float(getattr(scene.waves, "ramp", 0.0) or 0.0)
    window = grid.window or (min(ramp, 0.5 * duration), duration)
    if keep_runs:   # runs straight into OUTDIR/runs (made as the user makes folders: the umask's mode)
        work = outdir / "runs"
        work.mkdir(exist_ok=True)
    else:
        work = Path(tempfile.mkdtemp(prefix="hydrolink-accuracy-"))
    hdbs: dict = {}
    rows: list[dict] = []
    try:
        log(f"reference: {', '.join(f'{short_key(k)}={_fmt(v)}' for k, v in reference.items())}")
        ref, cost = _best_of(repeat, doc, reference, duration, work, "reference", hdbs, progress)
        rows.append({"label": "reference", "settings": dict(reference), **cost,
                     **{"max_error": 0.0, "rms_error": 0.0,
                        "power_error": 0.0 if ref["power"] is not None else math.nan}})
        log(f"  {cost['us_per_step']:.0f} us/step")
        for i, (label, settings) in enumerate(cases):
            log(f"[{i + 1}/{len(cases)}] {label}")
            try:
                res, cost = _best_of(repeat, doc, settings, duration, work, f"case{i}", hdbs)
                err = compare(ref, res, window)
                note = ""
            except Exception as exc:  # noqa: BLE001 - a failing option is a result (unstable, refused)
                cost = {"us_per_step": math.nan, "wall_per_sim_s": math.nan, "server_us_per_step": math.nan,
                        "steps": 0, "wall_time": math.nan}
                err = {"max_error": math.nan, "rms_error": math.nan, "power_error": math.nan}
                note = f"{type(exc).__name__}: {str(exc).splitlines()[0][:160]}"
            rows.append({"label": label, "settings": dict(settings), **cost, **err, "note": note})
            log(f"  {cost['us_per_step']:.0f} us/step, RMS error {100 * err['rms_error']:.3g} % {note}")
    finally:
        if not keep_runs:
            shutil.rmtree(work, ignore_errors=True)
    mark_fronts(rows)
    meta = {"scene": str(scene_path), "duration": duration, "window": list(window), "mode": grid.mode,
            "title": title or scene_path.stem, "repeat": repeat}
    write_report(rows, outdir, meta)
    return rows


def mark_fronts(rows: list[dict]) -> None:
    """Pareto flags per (error, cost) pair: front_<error>_<cost> on every row."""
    for e in ("max_error", "rms_error", "power_error"):
        for c in ("us_per_step", "wall_per_sim_s"):
            f = pareto_front([r[c] for r in rows], [r[e] for r in rows])
            for r, v in zip(rows, f):
                r[f"front_{e}_{c}"] = bool(v)


# ------------------------------------------------------------------ report

def _pct(v: float) -> str:
    if v is None or (isinstance(v, float) and math.isnan(v)):
        return "–"
    if math.isinf(v):
        return "diverged"
    return "0" if v == 0 else f"{100 * v:.3g}"


def write_report(rows: list[dict], outdir: Path, meta: dict) -> None:
    has_power = any(not math.isnan(r["power_error"]) for r in rows)
    lines = [f"# Accuracy bench: {meta['title']}", "",
             f"Scene `{Path(meta['scene']).name}`, {meta['duration']:g} s simulated, errors over "
             f"[{meta['window'][0]:g}, {meta['window'][1]:g}] s against the reference (first row); mode "
             f"`{meta['mode']}`. Errors in % (worst response channel); cost = wall time of the whole run "
             f"(client + server + results; the cheapest of {meta.get('repeat', 1)} run(s) per option), "
             "excluding setup. ★ = on the Pareto front of RMS error vs µs/step, "
             "☆ = of RMS error vs wall time per simulated second.", ""]
    head = "| option | µs/step | wall s / sim s | server µs/step | max err % | RMS err % |"
    sep = "|---|---|---|---|---|---|"
    if has_power:
        head += " PTO power err % |"
        sep += "---|"
    head += " front |"
    sep += "---|"
    lines += [head, sep]
    for r in rows:
        front = ("★" if r["front_rms_error_us_per_step"] else "") + ("☆" if r["front_rms_error_wall_per_sim_s"] else "")
        cells = [r["label"] if r["label"] != "reference" else "**reference**",
                 f"{r['us_per_step']:.0f}" if not math.isnan(r["us_per_step"]) else "–",
                 f"{r['wall_per_sim_s']:.3g}" if not math.isnan(r["wall_per_sim_s"]) else "–",
                 f"{r['server_us_per_step']:.0f}" if not math.isnan(r["server_us_per_step"]) else "–",
                 _pct(r["max_error"]), _pct(r["rms_error"])]
        if has_power:
            cells.append(_pct(r["power_error"]))
        cells.append(front)
        lines.append("| " + " | ".join(cells) + " |")
    notes = [r for r in rows if r.get("note")]
    if notes:
        lines += ["", "Failed options:", ""] + [f"- {r['label']}: {r['note']}" for r in notes]
    ref = rows[0]["settings"]
    lines += ["", "Reference settings: " + ", ".join(f"`{k} = {_fmt(v)}`" for k, v in ref.items()), ""]
    (outdir / "accuracy.md").write_text("\n".join(lines))
    with open(outdir / "accuracy.csv", "w", newline="") as fh:
        cols = ["label", "us_per_step", "wall_per_sim_s", "server_us_per_step", "max_error", "rms_error",
                "power_error", "front_rms_error_us_per_step", "front_rms_error_wall_per_sim_s", "note"]
        w = csv.writer(fh)
        w.writerow(cols)
        for r in rows:
            w.writerow([r.get(c, "") for c in cols])
    plot_report(rows, outdir / "accuracy.png", meta, has_power)


def report_figure(rows: list[dict], meta: dict, has_power: bool):
    """The error-against-cost figure (matplotlib): one panel per error and cost, the options, the
    reference and the Pareto front; the legend (first panel) names only what that panel draws."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    errs = [("max_error", "max error"), ("rms_error", "RMS error")] + ([("power_error", "PTO power error")]
                                                                      if has_power else [])
    costs = [("us_per_step", "wall time per step (µs)"), ("wall_per_sim_s", "wall time per simulated s (s)")]
    fig, axes = plt.subplots(len(costs), len(errs), figsize=(4.2 * len(errs), 3.6 * len(costs)), squeeze=False)
    finite = [r[e] for r in rows for e, _ in errs if np.isfinite(r[e]) and r[e] > 0]
    floor = 0.3 * min(finite) if finite else 1e-6
    for i, (c, clabel) in enumerate(costs):
        for j, (e, elabel) in enumerate(errs):
            ax = axes[i][j]
            x = np.array([r[c] for r in rows], float)
            y = np.array([max(r[e], floor) if np.isfinite(r[e]) else np.nan for r in rows], float)
            shown = np.isfinite(x) & np.isfinite(y)
            front = np.array([r[f"front_{e}_{c}"] for r in rows]) & shown
            options, o = np.flatnonzero(shown[1:]) + 1, np.argsort(x[front])
            if options.size:
                ax.scatter(x[options], 100 * y[options], s=18, color="tab:blue", label="options")
            if shown[0]:
                ax.scatter(x[:1], 100 * y[:1], s=60, marker="*", color="k", label="reference (0, at the floor)")
            if front.any():
                ax.plot(x[front][o], 100 * y[front][o], "-o", color="tab:red", mfc="none", ms=9, label="Pareto front")
            for k, r in enumerate(rows):
                if front[k] and k:
                    ax.annotate(r["label"], (x[k], 100 * y[k]), fontsize=6, xytext=(3, 3), textcoords="offset points")
            for values, set_lim in ((x[shown], ax.set_xlim), (100 * y[shown], ax.set_ylim)):
                if values.size and np.ptp(values) == 0 and values[0] > 0:    # one value: a decade about it
                    set_lim(values[0] / 3.0, values[0] * 3.0)
            ax.set_xscale("log")
            ax.set_yscale("log")
            ax.set_xlabel(clabel)
            ax.set_ylabel(f"{elabel} (%)")
            ax.grid(True, which="both", alpha=0.3)
            if i == 0 and j == 0 and ax.get_legend_handles_labels()[0]:
                ax.legend(fontsize=6)
    fig.suptitle(f"{meta['title']}: error against cost", fontsize=10)
    fig.tight_layout()
    return fig


def plot_report(rows: list[dict], path: Path, meta: dict, has_power: bool) -> None:
    """``accuracy.png`` (:func:`report_figure`)."""
    import matplotlib.pyplot as plt
    fig = report_figure(rows, meta, has_power)
    fig.savefig(path, dpi=80)
    plt.close(fig)


def grid_from_flags(base: Grid | None, flags: dict[str, str | None], refs: tuple[str, ...], mode: str | None,
                    duration: float | None, window: tuple[float, float] | None) -> Grid:
    """A Grid from a TOML grid (optional) plus CLI flags (comma-separated values) and --ref KEY=VALUE."""
    g = base or Grid()
    for key, text in flags.items():
        if text:
            g.grid[full_key(key)] = [_parse_value(v) for v in text.split(",") if v.strip()]
    for item in refs:
        k, sep, v = item.partition("=")
        if not sep:
            raise BenchError("--ref", "", f"{item!r}: KEY=VALUE")
        g.reference[full_key(k.strip())] = _parse_value(v)
    if mode:
        g.mode = mode
    if duration:
        g.duration = duration
    if window:
        g.window = window
    g.check("command line")
    return g


def _parse_value(v: str):
    v = v.strip()
    for conv in (int, float):
        try:
            return conv(v)
        except ValueError:
            pass
    if v in ("true", "false"):
        return v == "true"
    return v
