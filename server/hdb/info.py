"""``hdb info``: a text summary of an HDB and a PNG of its coefficients and radiation IRFs."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import xarray as xr
from scipy.optimize import brentq

from hydrolink.protocol.hdb.layout import DOF_NAMES
from hydrolink.protocol.hdb.schema import hdb_dofs
from hydrolink.protocol.hdb.second_order import drift_methods, qtf_kinds
from hydrolink.server.radiation.irf import aliasing_time, irf_report, ogilvie_added_mass_inf, ogilvie_report, radiation_irf

_TRANSLATIONS = DOF_NAMES[:3]
_ROTATIONS = DOF_NAMES[3:]
# the plot's columns: (what, units of A, B, |F|, K) by kind of DOF
_KINDS = {"translations": ("kg", "N s/m", "N/m", "N/(m s)"),
          "rotations": ("kg m²", "N m s/rad", "N m/m", "N m/(rad s)"),
          "generalized modes": ("kg (modal)", "N s/m (modal)", "N/m (modal)", "N/(m s) (modal)")}


def _diag(da: xr.DataArray) -> np.ndarray:
    """Diagonal over (influenced_dof, radiating_dof) as (..., n_dof)."""
    return np.diagonal(np.asarray(da.values), axis1=-2, axis2=-1)


def _length_scale(ds: xr.Dataset, body: str) -> float:
    if "displaced_volume" in ds and float(ds["displaced_volume"].sel(body=body)) > 0:
        return float(ds["displaced_volume"].sel(body=body)) ** (1 / 3)
    return 1.0


def active_dofs(ds: xr.Dataset, rel_tol: float = 1e-4) -> list[str]:
    """DOF labels whose diagonal A, B or excitation is not negligible (e.g. not an axisymmetric
    body's yaw): each is made dimensionless with rho, g and L = V^(1/3) before the comparison."""
    rho, g = float(ds.attrs["rho"]), float(ds.attrs["g"])
    omega = ds["omega"].values
    a, b = _diag(ds["added_mass"]), _diag(ds["radiation_damping"])
    f = np.abs(ds["excitation_force"].values).max(axis=(0, 1))
    out = []
    for j, label in enumerate(map(str, ds["influenced_dof"].values)):
        body, dof = label.split(".", 1)
        L = _length_scale(ds, body)
        p = 5 if dof in _ROTATIONS else 3          # generalized modes: scaled like translations
        scale = np.array([np.abs(a[:, j]).max() / (rho * L ** p),
                          np.abs(b[:, j] / omega).max() / (rho * L ** p),
                          f[j] / (rho * g * L ** (p - 1))])
        if np.any(scale > rel_tol):
            out.append(label)
    return out


def heave_natural_period(ds: xr.Dataset, body: str) -> tuple[float | None, str]:
    """Undamped heave period T = 2 pi / w_n with w_n^2 (m + A33(w_n)) = C33, m the mass the file
    records, else rho V (a freely floating body), A33 interpolated on the grid (A_inf above it, if known). Returns (T, note)."""
    label = f"{body}.heave"
    if "mass" in ds:                    # the mass the file records
        m, which = float(ds["mass"].sel(body=body)), "the file's mass"
    elif "displaced_volume" in ds:      # a freely floating body
        m, which = float(ds.attrs["rho"]) * float(ds["displaced_volume"].sel(body=body)), "rho V"
    else:
        return None, "needs the body's mass or displaced_volume (neither is in this HDB): give the mass in the scene"
    c = float(ds["hydrostatic_stiffness"].sel(influenced_dof=label, radiating_dof=label))
    if not c > 0 or not m > 0:
        return None, "no heave restoring (C33 <= 0): no natural period"
    omega = ds["omega"].values
    a = ds["added_mass"].sel(influenced_dof=label, radiating_dof=label).values
    f = omega ** 2 * (m + a) - c
    if f[0] > 0:
        w = math.sqrt(c / (m + a[0]))
        return 2 * math.pi / w, f"below the frequency grid: used A33(w_min) (m = {which} = {m:.4g} kg)"
    if f[-1] < 0:
        if "added_mass_inf" in ds:
            a_inf = float(ds["added_mass_inf"].sel(influenced_dof=label, radiating_dof=label))
            w = math.sqrt(c / (m + a_inf))
            return 2 * math.pi / w, f"above the frequency grid: used A_inf (m = {which} = {m:.4g} kg)"
        return None, "above the frequency grid and A_inf unknown"
    i = int(np.flatnonzero((f[:-1] <= 0) & (f[1:] >= 0))[0])  # first upward crossing
    w = brentq(lambda x: x ** 2 * (m + np.interp(x, omega, a)) - c, omega[i], omega[i + 1])
    return 2 * math.pi / w, f"self-consistent with A33(w_n) = {np.interp(w, omega, a):.4g} kg (m = {which} = {m:.4g} kg)"


def _fmt_grid(omega: np.ndarray) -> str:
    d = np.diff(omega)
    spacing = f"uniform dw = {d[0]:.4g}" if np.allclose(d, d[0], rtol=1e-6) else \
        f"dw {d.min():.3g}..{d.max():.3g}"
    return (f"{omega.size} frequencies, w = {omega[0]:.4g} .. {omega[-1]:.4g} rad/s ({spacing}); "
            f"T = {2 * np.pi / omega[-1]:.3g} .. {2 * np.pi / omega[0]:.3g} s")


def _stiffness_lines(ds: xr.Dataset, body: str) -> list[str]:
    labels = [f"{body}.{d}" for d in DOF_NAMES]
    k = ds["hydrostatic_stiffness"].sel(influenced_dof=labels, radiating_dof=labels).values
    d = np.abs(np.diag(k))
    floor = 1e-9 * max(d.max(), 1e-300)
    units = {(True, True): "N/m", (True, False): "N/rad", (False, True): "N m/m", (False, False): "N m/rad"}

    def shown(i: int, j: int) -> bool:  # off-diagonal noise (e.g. 1e-7 of the diagonal) is hidden
        return abs(k[i, j]) > (floor if i == j else max(floor, 1e-6 * math.sqrt(d[i] * d[j])))

    entries = [f"C{i + 1}{j + 1} = {k[i, j]:.5g} {units[(i < 3, j < 3)]}"
               for i in range(6) for j in range(6) if shown(i, j)]
    return entries or ["all zero (fully submerged or no waterplane)"]


def hdb_summary(ds: xr.Dataset) -> str:
    """Human-readable summary of an HDB (schema layout)."""
    a = ds.attrs
    omega = ds["omega"].values
    depth = float(a["water_depth"])
    lines = [f"HDB: {a.get('source', '?')}",
             f"water: rho = {float(a['rho']):g} kg/m^3, g = {float(a['g']):g} m/s^2, depth = "
             + ("infinite" if math.isinf(depth) else f"{depth:g} m"),
             f"frequencies: {_fmt_grid(omega)}",
             f"  radiation IRF K(t) resolved for t < pi/dw_max = {aliasing_time(omega):.3g} s",
             "wave headings: " + ", ".join(f"{math.degrees(b):g}" for b in ds["wave_direction"].values) + " deg",
             f"time convention of the file's complex amplitudes: {a.get('time_convention_in_file', '?')} "
             f"({a.get('time_convention_from', 'not recorded')}); held as exp(-iwt)"]
    if "n_panels" in a:
        lines.append(f"built with Capytaine {a.get('capytaine_version', '?')}: {a['n_panels']} hull panels + "
                     f"{a.get('n_lid_panels', 0)} lid panels, {float(a.get('build_seconds', float('nan'))):.3g} s")
    lines += second_order_lines(ds)
    active = set(active_dofs(ds))
    has_inf = "added_mass_inf" in ds
    dofs = hdb_dofs(ds)
    for body in map(str, ds["body"].values):
        labels = [f"{body}.{d}" for d in DOF_NAMES]
        ref = ds["reference_point"].sel(body=body).values
        lines += ["", f"body {body!r}: reference point ({ref[0]:g}, {ref[1]:g}, {ref[2]:g}) m"]
        if "displaced_volume" in ds:
            v = float(ds["displaced_volume"].sel(body=body))
            lines.append(f"  displaced volume {v:.5g} m^3 (rho V = {float(a['rho']) * v:.5g} kg)")
        if "center_of_buoyancy" in ds:
            cb = ds["center_of_buoyancy"].sel(body=body).values
            lines.append(f"  centre of buoyancy ({cb[0]:.4g}, {cb[1]:.4g}, {cb[2]:.4g}) m")
        act = [lab.split(".", 1)[1] for lab in labels if lab in active]
        idle = [lab.split(".", 1)[1] for lab in labels if lab not in active]
        lines.append(f"  DOFs: {', '.join(DOF_NAMES)}; with non-negligible coefficients: {', '.join(act) or 'none'}"
                     + (f" (negligible: {', '.join(idle)})" if idle else ""))
        if has_inf:
            ainf = _diag(ds["added_mass_inf"].sel(influenced_dof=labels, radiating_dof=labels))
            lines.append("  A_inf (from the data) diagonal: " + ", ".join(
                f"{d} {v:.4g}" for d, v in zip(DOF_NAMES, ainf)))
        else:
            lines.append("  A_inf: missing -> computed from A(w), B(w) with Ogilvie's relation when loaded")
        lines.append("  hydrostatic stiffness (buoyancy + waterplane, no gravity terms): "
                     + "; ".join(_stiffness_lines(ds, body)))
        lines += _mode_lines(ds, body, dofs.of(body), has_inf)
        t, note = heave_natural_period(ds, body)
        lines.append(f"  heave natural period: {t:.4g} s ({note})" if t is not None
                     else f"  heave natural period: n/a ({note})")
        lines.append("  roll/pitch natural periods: need the body's inertia and centre of gravity "
                     "(not in an HDB; they come from the scene)")
    lines += ["", *irf_consistency(ds)]
    return "\n".join(lines)


def _mode_lines(ds: xr.Dataset, body: str, modes: tuple[str, ...], has_inf: bool) -> list[str]:
    """A body's generalized modes (issue 38): names, the diagonals of A_inf and of the hydrostatic
    stiffness, and the largest rigid-mode coupling of the stiffness."""
    if not modes:
        return []
    labels = [f"{body}.{m}" for m in modes]
    out = [f"  generalized modes ({len(modes)}, after the six rigid DOFs): {', '.join(modes)}"]
    if has_inf:
        ainf = _diag(ds["added_mass_inf"].sel(influenced_dof=labels, radiating_dof=labels))
        out.append("    A_inf diagonal: " + ", ".join(f"{m} {v:.4g}" for m, v in zip(modes, ainf)))
    k = ds["hydrostatic_stiffness"]
    out.append("    hydrostatic stiffness diagonal: " + ", ".join(
        f"{m} {v:.5g}" for m, v in zip(modes, _diag(k.sel(influenced_dof=labels, radiating_dof=labels)))))
    rigid = [f"{body}.{d}" for d in DOF_NAMES]
    block = np.concatenate([k.sel(influenced_dof=labels, radiating_dof=rigid).values,
                            k.sel(influenced_dof=rigid, radiating_dof=labels).values.T])
    if np.any(block):
        i, j = np.unravel_index(np.argmax(np.abs(block)), block.shape)
        which = (f"C({modes[i]}, {DOF_NAMES[j]})" if i < len(modes) else
                 f"C({DOF_NAMES[j]}, {modes[i - len(modes)]})")
        out.append(f"    largest rigid-mode stiffness coupling: {which} = {block[i, j]:.5g}")
    return out


def _degrees(values: np.ndarray) -> str:
    return ", ".join(f"{math.degrees(b):g}" for b in values)


def second_order_lines(ds: xr.Dataset) -> list[str]:
    """What second-order data the HDB holds: mean drift methods and QTFs with their grids."""
    methods, kinds = drift_methods(ds), qtf_kinds(ds)
    if not methods and not kinds:
        return ["second order: none (no mean drift coefficients, no QTFs)"]
    out = ["second order:"]
    if methods:
        note = ds.attrs.get("mean_drift_note")
        out.append(f"  mean drift ({', '.join(methods)}): {_fmt_grid(ds['drift_omega'].values)}; headings "
                   f"{_degrees(ds['drift_direction'].values)} deg" + (f" ({note})" if note else ""))
    if kinds:
        pairs = ", ".join(f"({math.degrees(a):g}, {math.degrees(b):g})" for a, b in
                          zip(ds["qtf_direction_i"].values, ds["qtf_direction_j"].values))
        out.append(f"  {' and '.join(kinds)} QTF from {ds.attrs.get('qtf_source', '?')}: "
                   f"{_fmt_grid(ds['qtf_omega_i'].values)} (full square); heading pairs {pairs} deg")
    return out


def _plot_mean_drift(ax, ds: xr.Dataset) -> None:
    """Surge mean drift coefficient per method, body and heading."""
    omega = ds["drift_omega"].values
    styles = ("-", "--", "-.", ":")
    for m, method in enumerate(drift_methods(ds)):
        for body in map(str, ds["body"].values):
            for h, beta in enumerate(ds["drift_direction"].values):
                ax.plot(omega, ds["mean_drift"].sel(drift_method=method, influenced_dof=f"{body}.surge").values[:, h],
                        ls=styles[m % 4], label=f"{method}, {body}, {math.degrees(beta):g}°")
    ax.set(title="Mean drift coefficient, surge (F = A² T(ω, ω))", xlabel="ω [rad/s]", ylabel="T [N/m²]")
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8)


def _select_dofs(ds: xr.Dataset, dofs: list[str] | None) -> list[str]:
    labels = [str(v) for v in ds["influenced_dof"].values]
    if dofs is None:
        return active_dofs(ds) or labels
    out = []
    for d in dofs:
        if d in labels:
            out.append(d)
        elif any(lab.endswith("." + d) for lab in labels):     # a rigid DOF or a mode of every body having it
            out += [lab for lab in labels if lab.endswith("." + d)]
        else:
            raise ValueError(f"dofs: unknown DOF {d!r} (use one of {list(DOF_NAMES)}, a mode's name or labels "
                             f"like {labels[0]!r})")
    return list(dict.fromkeys(out))


def _irf_time(omega: np.ndarray, k: np.ndarray, t: np.ndarray) -> float:
    """End of the K(t) plot: where all |K| stay below 2 % of their peaks, with some margin."""
    peak = np.abs(k).max(axis=0)
    big = np.abs(k) > 0.02 * np.where(peak > 0, peak, np.inf)
    last = t[np.flatnonzero(big.any(axis=1))[-1]] if big.any() else t[-1]
    return float(min(t[-1], max(1.3 * last, 10 * 2 * np.pi / omega[-1])))


def plot_hdb(ds: xr.Dataset, path: str | Path, dofs: list[str] | None = None) -> Path:
    """PNG of A(w) (A_inf dashed), B(w), |F_ex(w)| (every heading) and K(t) for the chosen DOFs'
    diagonal terms (default: the active ones); translations, rotations and generalized modes in
    separate columns; a last row with the surge mean drift coefficient per method when the HDB has one."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    chosen = _select_dofs(ds, dofs)
    kind_of = {d: "translations" if d.split(".", 1)[1] in _TRANSLATIONS else
               "rotations" if d.split(".", 1)[1] in _ROTATIONS else "generalized modes" for d in chosen}
    groups = [g for g in ([d for d in chosen if kind_of[d] == kind] for kind in _KINDS) if g]
    omega = ds["omega"].values
    t = np.linspace(0.0, aliasing_time(omega), 800)
    rows = 4 + bool(drift_methods(ds))
    fig = Figure(figsize=(6.5 * len(groups), 3.25 * rows), layout="constrained")
    FigureCanvasAgg(fig)
    axes = fig.subplots(rows, len(groups), squeeze=False)
    if rows == 5:
        _plot_mean_drift(axes[4, 0], ds)
        for ax in axes[4, 1:]:
            ax.set_visible(False)
    headings = ds["wave_direction"].values
    for col, group in enumerate(groups):
        kind = kind_of[group[0]]
        ua, ub, uf, uk = _KINDS[kind]
        pairs = dict(influenced_dof=group, radiating_dof=group)
        a = _diag(ds["added_mass"].sel(**pairs))
        b = _diag(ds["radiation_damping"].sel(**pairs))
        k = radiation_irf(omega, b[:, :, None], t)[:, :, 0]  # diagonal terms only
        t_end = _irf_time(omega, k, t)
        f = np.abs(ds["excitation_force"].sel(influenced_dof=group).values)
        ax_a, ax_b, ax_f, ax_k = axes[:4, col]
        for j, label in enumerate(group):
            style = dict(ls=("-", "--", "-.")[j % 3], lw=(2.2, 1.6, 1.2)[j % 3])  # overlaps stay visible
            line, = ax_a.plot(omega, a[:, j], label=label, **style)
            if "added_mass_inf" in ds:
                ax_a.axhline(float(ds["added_mass_inf"].sel(influenced_dof=label, radiating_dof=label)),
                             color=line.get_color(), ls=":", lw=1)
            ax_b.plot(omega, b[:, j], color=line.get_color(), label=label, **style)
            for h, beta in enumerate(headings):
                ax_f.plot(omega, f[:, h, j], color=line.get_color(), alpha=1 - 0.6 * h / len(headings),
                          label=f"{label}, {math.degrees(beta):g}°" if len(headings) > 1 else label, **style)
            keep = t <= t_end
            ax_k.plot(t[keep], k[keep, j], color=line.get_color(), label=label, **style)
        ax_a.set(title=f"Added mass ({kind})" + (", A∞ dotted" if "added_mass_inf" in ds else ""),
                 xlabel="ω [rad/s]", ylabel=f"A [{ua}]")
        ax_b.set(title=f"Radiation damping ({kind})", xlabel="ω [rad/s]", ylabel=f"B [{ub}]")
        ax_f.set(title=f"Excitation per metre of wave amplitude ({kind})", xlabel="ω [rad/s]",
                 ylabel=f"|F_ex| [{uf}]")
        ax_k.set(title=f"Radiation IRF K(t) = (2/π)∫B cos ωt dω ({kind})", xlabel="t [s]",
                 ylabel=f"K [{uk}]")
        for ax in (ax_a, ax_b, ax_f, ax_k):
            ax.grid(True, alpha=0.3)
            ax.legend(fontsize=8)
    fig.suptitle(f"HDB: {ds.attrs.get('source', '?')}", fontsize=10)
    path = Path(path)
    fig.savefig(path, dpi=90)
    return path


def irf_consistency(ds: xr.Dataset, duration: float | None = None) -> list[str]:
    """How well the radiation IRF of this grid reproduces B(w) (re-transform) and A(w) (Ogilvie),
    per active diagonal DOF, for an IRF of ``duration`` (default min(40 s, pi/dw_max))."""
    omega = ds["omega"].values
    labels = [lab for lab in active_dofs(ds)]
    if not labels:
        return ["radiation IRF: no DOF with damping"]
    duration = duration or min(40.0, aliasing_time(omega))
    t = np.arange(0.0, duration + 1e-12, min(0.05, math.pi / (4 * float(omega[-1]))))
    b = ds["radiation_damping"].sel(influenced_dof=labels, radiating_dof=labels).values
    a = ds["added_mass"].sel(influenced_dof=labels, radiating_dof=labels).values
    k = radiation_irf(omega, b, t)
    a_inf = (ds["added_mass_inf"].sel(influenced_dof=labels, radiating_dof=labels).values
             if "added_mass_inf" in ds else ogilvie_added_mass_inf(omega, a, t, k))
    # periods the IRF spans at least once, away from the grid's top edge (where truncating B(w)
    # always spoils the Ogilvie transform)
    band = (omega >= 2 * math.pi / duration) & (omega <= 0.8 * omega[-1])
    if band.sum() < 2:
        return [f"radiation IRF over {duration:.3g} s: shorter than every period of the grid"]
    om, a, b = omega[band], a[band], b[band]
    rb, ra = irf_report(om, b, t, k)["rel_error"], ogilvie_report(om, a, a_inf, t, k)["rel_error"]
    out = [f"radiation IRF over {duration:.3g} s (scene [hydro] irf_duration; a run reports the same for its "
           f"settings): max error for {om[0]:.3g} <= w <= {om[-1]:.3g} rad/s (2 pi / T .. 0.8 w_max), relative to each "
           "DOF's range"]
    for n, lab in enumerate(labels):
        out.append(f"  {lab}: B(w) re-transformed {_pct(rb[n, n])}, A(w) by Ogilvie {_pct(ra[n, n])}")
    return out


def _pct(x: float) -> str:
    return "n/a" if not np.isfinite(x) else f"{100 * x:.2g} %"
