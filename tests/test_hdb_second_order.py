"""Second-order HDB data (issue 23, data half): mean drift and QTFs read from WAMIT .7/.8/.9/.12d/.12s,
BEMIO h5 and NEMOH QTF files, converted once (SI, exp(-iwt)); round trips through NetCDF and the
wire; ``hdb info``. Every expected value is computed here from the files' numbers with the formulas
of the formats (F = rho g A^2 L^m Fbar; T = rho g L^m conj(Re + i Im); one triangle filled by
conjugate / plain symmetry), never taken from the reader."""

from __future__ import annotations

import shutil
import re
from pathlib import Path

import h5py
import numpy as np
import pytest

from hydrolink.protocol import codec
from hydrolink.protocol.hdb.layout import HDBError, hdb_warnings
from hydrolink.protocol.hdb.schema import from_netcdf_dataset, to_netcdf
from hydrolink.protocol.hdb.second_order import drift_methods, qtf_kinds
from hydrolink.protocol.hdb.schema import with_second_order
from hydrolink.protocol.hdb.wire import from_wire, to_wire
from hydrolink.server.hdb.bemio import read_bemio
from hydrolink.server.hdb.info import hdb_summary, plot_hdb
from hydrolink.server.hdb.io import file_set, load_hdb
from hydrolink.server.hdb.nemoh_qtf import read_nemoh_qtf

# One pytest-xdist worker runs this whole module (pyproject: --dist loadgroup): its module fixtures (two
# Capytaine builds) cost ~7 s, paid once per worker otherwise.
pytestmark = pytest.mark.xdist_group("hdb_second_order")

RHO, G, ULEN = 1025.0, 9.81, 2.0
PERIODS = (8.0, 5.0, 3.0)          # in file order (not sorted): the reader sorts by omega
SURGE, HEAVE, PITCH, YAW = 0, 2, 4, 5


def _scale(mode: int) -> float:
    """WAMIT's L^m for a second-order force (m = 1) or moment (m = 2); mode is 1-based."""
    return ULEN ** (1 if mode <= 3 else 2)


def _drift_bar(per: float, beta: float, mode: int, method: int) -> float:
    """The nondimensional drift written into the test files (any distinct numbers will do)."""
    return 0.01 * per + 0.1 * mode - 0.003 * beta + method


def _qtf_bar(per_i: float, per_j: float, mode: int) -> complex:
    return complex(0.1 * per_i + 0.01 * per_j + mode, 0.05 * per_i - 0.02 * per_j - 0.1 * mode)


def _write_run(folder: Path, name: str = "cyl") -> Path:
    """A one-body WAMIT run: .1/.3/.hst/.cfg (ULEN = 2, periods), .pot (deep water, XBODY at the
    origin), .frc (VCG 0), .8 and .9 mean drift, .12d and .12s QTFs."""
    folder.mkdir(parents=True, exist_ok=True)
    stem = folder / name
    (stem.with_suffix(".cfg")).write_text(f"ULEN = {ULEN}\nGRAV = {G}\nIPEROUT = 1\n")
    (stem.with_suffix(".pot")).write_text(f"{name}.pot\n0.0  HBOT\n1 1\n1\n{PERIODS[0]}\n1\n0.0\n1\n"
                                          f"{name}.gdf\n0.0 0.0 0.0 0.0\n1 1 1 1 1 1\n")
    (stem.with_suffix(".frc")).write_text(f"{name}.frc\n1 0 1 0 0 0 0 0 0\n0.0\n0 0 0\n0 0 0\n0 0 0\n0\n0\n")
    rows1 = ["   0.0  1  1  1.2"] + [f"{p}  {i}  {i}  {1 + 0.1 * i}  {0.5 + 0.01 * i}" for p in PERIODS for i in range(1, 7)]
    (stem.with_suffix(".1")).write_text("\n".join(rows1) + "\n")
    rows3 = [f"{p}  0.0  {i}  1.0  0.0  {0.3 * i}  {0.1 * i}" for p in PERIODS for i in range(1, 7)]
    (stem.with_suffix(".3")).write_text("\n".join(rows3) + "\n")
    (stem.with_suffix(".hst")).write_text("3 3 3.14\n4 4 0.5\n5 5 0.5\n")
    for suffix, method, modes in ((".8", 0, (1, 2, 6)), (".9", 2, range(1, 7))):
        rows = ["header line of the drift file", f"  0.0  0.0  0.0  1  1.0  0.0  {2.0 + method}  0.0"]   # PER = 0 limit
        for p in PERIODS:
            for beta in (0.0, 90.0):
                for i in modes:
                    f = _drift_bar(p, beta, i, method)
                    rows.append(f"{p}  {beta}  {beta}  {i}  {abs(f)}  0.0  {f}  0.0")
                rows.append(f"{p}  {beta}  {90.0 - beta}  1  9.0  0.0  9.0  0.0")   # bidirectional: dropped
                if suffix == ".9":
                    rows += [f"{p}  {beta}  {beta}  {i}  7.0  0.0  7.0  0.0" for i in (-4, -5, -6)]   # dropped
        (stem.with_suffix(suffix)).write_text("\n".join(rows) + "\n")
    for suffix in (".12d", ".12s"):
        rows = []
        for a, pi in enumerate(PERIODS):
            for pj in PERIODS[a:]:          # one triangle
                for i in (1, 3, 5):
                    t = _qtf_bar(pi, pj, i) if (pi != pj or suffix == ".12s") else complex(_qtf_bar(pi, pj, i).real, 0)
                    rows.append(f"{pi} {pj} 0.0 0.0 {i} {abs(t)} {np.degrees(np.angle(t))} {t.real} {t.imag}")
        (folder / f"{name}{suffix}").write_text("\n".join(rows) + "\n")
    return stem.with_suffix(".1")


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    path = _write_run(tmp_path_factory.mktemp("wamit2"))
    return path, load_hdb(path, rho=RHO)


def test_wamit_mean_drift_in_si(run):
    """.8 (momentum: surge, sway, yaw) and .9 (pressure: 6 DOFs) -> rho g A^2 L^m Fbar, sorted by omega;
    PER <= 0, bidirectional and I = -4..-6 rows dropped."""
    _, ds = run
    assert drift_methods(ds) == ("momentum", "pressure")
    omega = ds["drift_omega"].values
    assert np.allclose(omega, 2 * np.pi / np.array(sorted(PERIODS, reverse=True)))
    assert np.allclose(np.degrees(ds["drift_direction"].values), [0.0, 90.0])
    for method, k, modes in (("momentum", 0, (1, 2, 6)), ("pressure", 2, range(1, 7))):
        got = ds["mean_drift"].sel(drift_method=method).values   # (omega, direction, dof)
        for w, per in enumerate(sorted(PERIODS, reverse=True)):
            for b, beta in enumerate((0.0, 90.0)):
                for mode in range(1, 7):
                    want = RHO * G * _scale(mode) * _drift_bar(per, beta, mode, k) if mode in modes else 0.0
                    assert got[w, b, mode - 1] == pytest.approx(want, rel=1e-12), (method, per, beta, mode)


def test_wamit_qtfs_filled_and_conjugated(run):
    """.12d: the stored triangle T = rho g L^m conj(Re + i Im), the other T_ji = conj(T_ij);
    .12s: T_ji = T_ij. DOFs without rows are 0."""
    _, ds = run
    assert qtf_kinds(ds) == ("difference", "sum")
    assert "cyl.12d (WAMIT direct)" in ds.attrs["qtf_source"]
    omega = ds["qtf_omega_i"].values
    per = 2 * np.pi / omega
    diff = ds["difference_qtf"].isel(qtf_heading=0).values
    summ = ds["sum_qtf"].isel(qtf_heading=0).values
    for a, pa in enumerate(per):
        for b, pb in enumerate(per):
            lo, hi = (pa, pb) if list(PERIODS).index(round(pa, 6)) <= list(PERIODS).index(round(pb, 6)) else (pb, pa)
            for mode in (1, 3, 5):
                bar = _qtf_bar(lo, hi, mode)
                stored = RHO * G * _scale(mode) * np.conj(bar)      # the internal value of the stored row
                if lo == hi:                                        # the .12d diagonal is real
                    stored_d = RHO * G * _scale(mode) * bar.real
                else:
                    stored_d = stored if (lo, hi) == (pa, pb) else np.conj(stored)
                assert diff[a, b, mode - 1] == pytest.approx(stored_d, rel=1e-12)
                assert summ[a, b, mode - 1] == pytest.approx(stored, rel=1e-12)
            assert diff[a, b, 1] == 0 and summ[a, b, YAW] == 0


def test_netcdf_and_wire_round_trips_are_exact(run, tmp_path):
    _, ds = run
    to_netcdf(ds, tmp_path / "cyl.nc")
    back = load_hdb(tmp_path / "cyl.nc")
    msg = codec.unpack(codec.pack(codec.message("hello", 1, None, hdbs={"cyl": to_wire(ds)})))
    wired = from_wire(codec.decode_tree(msg["hdbs"]["cyl"]), "cyl")
    for other in (back, wired):
        for name in ("mean_drift", "difference_qtf", "sum_qtf", "drift_omega", "drift_direction",
                     "qtf_omega_i", "qtf_direction_i", "qtf_direction_j"):
            assert np.array_equal(other[name].values, ds[name].values), name
        assert drift_methods(other) == drift_methods(ds)
        assert other.attrs["qtf_source"] == ds.attrs["qtf_source"]


def test_file_set_carries_the_second_order_files(run):
    path, _ = run
    names = {p.name for p in file_set(path, rho=RHO).paths}
    assert {"cyl.8", "cyl.9", "cyl.12d", "cyl.12s", "cyl.1"} <= names


def test_multibody_momentum_drift_is_left_out(reference_data, tmp_path):
    """RM3 (two bodies): a .8 is the total on both, so it is left out with a warning; a .9 is read."""
    for ext in (".1", ".3", ".hst", ".out"):
        shutil.copy(reference_data / "rm3_wamit" / f"rm3{ext}", tmp_path / f"rm3{ext}")
    per = (8.0, 10.0, 12.0)     # the drift has its own grid
    rows = [f"{p} 0.0 0.0 {i} 1.0 0.0 {0.1 * i} 0.0" for p in per for i in range(1, 13)]
    (tmp_path / "rm3.9").write_text("\n".join(rows) + "\n")
    (tmp_path / "rm3.8").write_text("\n".join(rows) + "\n")
    ds = load_hdb(tmp_path / "rm3.1")
    assert [re.search("rm3.8.*total on all bodies", n) is not None for n in hdb_warnings(ds)] == [True]
    assert drift_methods(ds) == ("pressure",)
    spar_heave = ds["mean_drift"].sel(drift_method="pressure", influenced_dof="spar.heave").values
    assert np.allclose(spar_heave, 1000.0 * ds.attrs["g"] * 0.1 * 9)   # mode 9 = body 2 heave, rho 1000, L 1


@pytest.mark.parametrize("edit, field", [
    (lambda t: t.replace("3.0 3.0 0.0 0.0 5", "3.0 3.0 0.0 0.0 17"), "line"),     # mode beyond 6
    (lambda t: "\n".join(line for line in t.splitlines() if not line.startswith("5.0 3.0 ")), "difference_qtf"),
])
def test_bad_qtf_file_names_the_file_and_field(tmp_path, edit, field):
    path = _write_run(tmp_path)
    qtf = tmp_path / "cyl.12d"
    qtf.write_text(edit(qtf.read_text()))
    with pytest.raises(HDBError, match=rf"cyl\.12d.*{field}"):
        load_hdb(path, rho=RHO)


def test_bad_drift_mode_names_the_line(tmp_path):
    path = _write_run(tmp_path)
    drift = tmp_path / "cyl.8"
    drift.write_text(drift.read_text() + "3.0 0.0 0.0 -2 1.0 0.0 1.0 0.0\n")
    with pytest.raises(HDBError, match=r"cyl\.8: line \d+: mode I must be"):
        load_hdb(path, rho=RHO)


def test_bemio_mean_drift(reference_data, tmp_path):
    """BEMIO h5: mean_drift/<method>/val laid out like the excitation, normalised by rho g."""
    path = tmp_path / "sphere.h5"
    shutil.copy(reference_data / "sphere_task10" / "sphere.h5", path)
    with h5py.File(path, "r+") as fh:
        rho, g = float(np.ravel(fh["simulation_parameters/rho"][()])[0]), float(np.ravel(fh["simulation_parameters/g"][()])[0])
        w = np.ravel(fh["simulation_parameters/w"][()])
        shape = fh["body1/hydro_coeffs/excitation/re"].shape     # (6, n_beta, n_w)
        val = np.arange(np.prod(shape), dtype=float).reshape(shape) / 100.0
        fh["body1/hydro_coeffs/mean_drift/control_surface/val"] = val
        fh["body1/hydro_coeffs/mean_drift/momentum_conservation/val"] = 2 * val
    ds = read_bemio(path)
    assert drift_methods(ds) == ("momentum", "control-surface")
    order = np.argsort(w)
    for method, factor in (("momentum", 2.0), ("control-surface", 1.0)):
        got = ds["mean_drift"].sel(drift_method=method).values          # (omega, direction, dof)
        want = factor * rho * g * np.transpose(val, (2, 1, 0))[order]
        assert np.allclose(got, want, rtol=1e-12)
    assert np.allclose(ds["drift_omega"].values, w[order])


def test_nemoh_qtf_lower_triangle_and_convention(run, tmp_path):
    """NEMOH OUT_QTFM/OUT_QTFP: rho g (Re + i Im), rad/s, lower triangle filled; exp(+iwt) conjugated."""
    _, ds = run
    w = np.array([0.5, 0.8, 1.1])
    rows_m, rows_p = ["header"], ["header"]
    for a in range(3):
        for b in range(a + 1):        # lower triangle: w1 >= w2
            for dof in (1, 2):
                t = complex(a + 0.1 * b + dof, 0.0 if a == b else 0.2 * (a - b) + dof)
                rows_m.append(f"{w[a]} {w[b]} 0.0 0.0 {dof} {abs(t)} 0 {t.real} {t.imag}")
                rows_p.append(f"{w[a]} {w[b]} 0.0 0.0 {dof} {abs(t)} 0 {t.real} {t.imag + 1}")
    (tmp_path / "OUT_QTFM_N.dat").write_text("\n".join(rows_m) + "\n")
    (tmp_path / "OUT_QTFP_N.dat").write_text("\n".join(rows_p) + "\n")
    for convention, conj in (("exp(-iwt)", False), ("exp(+iwt)", True)):
        qtf = read_nemoh_qtf(difference=tmp_path / "OUT_QTFM_N.dat", total_sum=tmp_path / "OUT_QTFP_N.dat",
                             rho=RHO, g=G, n_dof=6, frequency_unit="rad/s", convention=convention)
        full = with_second_order(ds, qtf=qtf)
        d = full["difference_qtf"].isel(qtf_heading=0).values
        s = full["sum_qtf"].isel(qtf_heading=0).values
        for a in range(3):
            for b in range(3):
                hi, lo = max(a, b), min(a, b)
                for dof in (1, 2):
                    t = complex(hi + 0.1 * lo + dof, 0.0 if a == b else 0.2 * (hi - lo) + dof)
                    tp = RHO * G * complex(t.real, t.imag + 1)
                    t = RHO * G * t
                    if conj:
                        t, tp = np.conj(t), np.conj(tp)
                    assert d[a, b, dof - 1] == pytest.approx(t if a >= b else np.conj(t), rel=1e-12)
                    assert s[a, b, dof - 1] == pytest.approx(tp, rel=1e-12)
        assert drift_methods(full) == ("momentum", "pressure")      # the drift is kept
    with pytest.raises(HDBError, match="frequency_unit"):
        read_nemoh_qtf(difference=tmp_path / "OUT_QTFM_N.dat", rho=RHO, g=G, n_dof=6, frequency_unit="rpm",
                       convention="exp(-iwt)")


def test_summary_lists_second_order_and_plot(run, tmp_path):
    _, ds = run
    text = hdb_summary(ds)
    assert "mean drift (momentum, pressure): 3 frequencies" in text
    assert "headings 0, 90 deg" in text
    assert "difference and sum QTF from cyl.12d (WAMIT direct); cyl.12s (WAMIT direct)" in text
    out = plot_hdb(ds, tmp_path / "hdb.png")
    assert out.stat().st_size > 10_000


def test_schema_refuses_a_half_square(run):
    _, ds = run
    bad = ds.copy()
    bad["difference_qtf"] = bad["difference_qtf"].copy()
    bad["difference_qtf"][0, 1, 0, 0] += 1.0
    with pytest.raises(HDBError, match="difference_qtf.*full square"):
        with_second_order(bad)


# ------------------------------------------------------------------------------------------------
# hdb build: Capytaine's far-field drift of a fixed surface-piercing vertical cylinder
# ------------------------------------------------------------------------------------------------

CYL_R, CYL_OMEGA = 1.0, (2.0, 6.3)     # kR = omega^2 R / g = 0.41 and 4.05


@pytest.fixture(scope="module")
def built_cylinder(tmp_path_factory):
    from hydrolink.server.hdb.build.builder import build_hdb

    tmp = tmp_path_factory.mktemp("drift_build")
    spec = tmp / "cyl.toml"
    spec.write_text(f"""
[body]
name = "cyl"
shape = "vertical_cylinder"
radius = {CYL_R}
draft = 2.0
freeboard = 0.5
panel_size = 0.1
[frequencies]
values = {list(CYL_OMEGA)}
infinite = false
[water]
density = {RHO}
gravity = {G}
[second_order]
mean_drift = "far-field"
""")
    return spec, build_hdb(spec, cache_dir=tmp / "cache", progress=False)


def test_build_drift_against_the_short_wave_limit(built_cylinder):
    """Surge drift at kR = 4.05 against Faltinsen's short-wave limit (2/3) rho g A^2 R, approached
    from below. Measured on this cylinder (R 1 m, draft 2 m) at kR = 4.05: 0.610, 0.622, 0.634 of
    rho g R for panels of 0.15, 0.1, 0.07 m (882, 1890, 3960 hull panels), i.e. 8.5, 6.7, 4.9 %
    below the limit, the gap closing as the mesh is refined: 10 % is the tolerance at 0.1 m."""
    _, ds = built_cylinder
    assert drift_methods(ds) == ("far-field",) and "fixed" in ds.attrs["mean_drift_note"]
    surge = ds["mean_drift"].sel(drift_method="far-field", influenced_dof="cyl.surge").values[:, 0]
    limit = 2 / 3 * RHO * G * CYL_R
    assert 0.90 * limit < surge[-1] < limit
    assert 0 < surge[0] < 0.5 * surge[-1]               # long waves pass the cylinder: little drift
    other = ds["mean_drift"].sel(drift_method="far-field", influenced_dof=["cyl.sway", "cyl.yaw"]).values
    # head seas on an axisymmetric body: sway and yaw vanish but for the mesh's asymmetry (1.8 N/m^2,
    # 9.4 N m/m^2 measured at kR = 4 against 6254 N/m^2 surge)
    assert np.abs(other).max() < 3e-3 * surge[-1] * CYL_R
    assert "mean drift (far-field)" in hdb_summary(ds)


def test_build_drift_equals_capytaines_own_wamit_8(built_cylinder, tmp_path):
    """The same fixed body solved here with Capytaine directly (diffraction only; its own Kochin
    grid, 720 steps against the build's 360), its far-field drift written by Capytaine's
    export_wamit_8 and read back by hydrolink's WAMIT drift reader: equal to the built HDB's."""
    import capytaine as cpt
    import xarray as xr
    from capytaine.io.wamit import export_wamit_8
    from capytaine.io.xarray import kochin_data_array
    from capytaine.post_pro.mean_drift_force import far_field_mean_drift_force

    from hydrolink.server.hdb.build.builder import load_spec, make_meshes
    from hydrolink.server.hdb.wamit.second_order import read_drift
    from hydrolink.server.hdb.wamit.table import Units

    spec_path, ds = built_cylinder
    spec = load_spec(spec_path)
    hull, lid = make_meshes(spec, spec_path)
    body = cpt.FloatingBody(mesh=hull, lid_mesh=lid, dofs=cpt.rigid_body_dofs(rotation_center=(0, 0, 0)), name="cyl")
    solver = cpt.BEMSolver()
    results = [solver.solve(cpt.DiffractionProblem(body=body, omega=w, wave_direction=0.0, rho=RHO, g=G,
                                                   water_depth=spec.water.depth_m), keep_details=True)
               for w in CYL_OMEGA]
    step = 2 * np.pi / 720
    theta = xr.DataArray(step * np.arange(-4, 725), dims=("theta",))
    theta[4], theta[724] = 0.0, 2 * np.pi
    kochin = kochin_data_array(results, theta)
    cds = cpt.assemble_dataset(results, hydrostatics=False)
    dofs = list(body.dofs)
    kochin["kochin_radiation"] = xr.zeros_like(kochin["kochin_diffraction"]).isel(wave_direction=0, drop=True) \
        .expand_dims(radiating_dof=dofs)                 # the body is held fixed: no radiated waves
    kochin = kochin.assign_coords(wavenumber=cds["wavenumber"])
    rao = xr.DataArray(np.zeros((len(CYL_OMEGA), 1, 6), complex), dims=("omega", "wave_direction", "radiating_dof"),
                       coords={"omega": cds["omega"].values, "wave_direction": [0.0], "radiating_dof": dofs})
    drift = far_field_mean_drift_force(rao, kochin).assign_coords(rho=RHO, g=G, period=cds["period"])
    export_wamit_8(drift, str(tmp_path / "cpt.8"))
    read = read_drift(tmp_path / "cpt", Units(RHO, G, 1.0, 1), 6)
    assert read.methods == ("momentum",)                 # WAMIT's .8 slot; the numbers are far-field
    assert np.allclose(read.omega, ds["drift_omega"].values, rtol=1e-6)
    built = ds["mean_drift"].sel(drift_method="far-field").values
    # measured: 1.1e-6 of the largest value (the .8 prints 7 digits; Kochin grids of 720 and 360 steps)
    assert np.allclose(read.values[0], built, rtol=1e-5, atol=1e-5 * np.abs(built).max())


def test_build_drift_of_a_free_body_equals_capytaines_own_rao_route(tmp_path):
    """``motions = "free"``: the far-field drift of the cylinder floating freely equals the one
    computed here with Capytaine alone: its FloatingBody given the mass rho V and centre of mass,
    its own rigid-body inertia (uniform solid, compute_rigid_body_inertia) and hydrostatic stiffness
    (gravity included), its assembled dataset's RAO (capytaine.post_pro.rao) and Kochin functions.
    The spec states that centre of mass and those principal moments; the built HDB says the drift is
    not of a fixed body. Near the heave resonance the free drift differs from the fixed one."""
    import capytaine as cpt
    import xarray as xr
    from capytaine.io.xarray import kochin_data_array
    from capytaine.post_pro.mean_drift_force import far_field_mean_drift_force
    from capytaine.post_pro.rao import rao as capytaine_rao

    from hydrolink.protocol.hdb.second_order import drift_body_fixed
    from hydrolink.server.hdb.build.builder import build_hdb, load_spec, make_meshes

    omegas, draft = (1.2, 2.2, 3.0), 2.0
    base = f"""
[body]
name = "cyl"
shape = "vertical_cylinder"
radius = {CYL_R}
draft = {draft}
freeboard = 0.5
panel_size = 0.2
[frequencies]
values = {list(omegas)}
infinite = true      # the omega = inf radiation solve beside the drift's finite ones
[water]
density = {RHO}
gravity = {G}
"""
    fixed_spec = tmp_path / "fixed.toml"
    fixed_spec.write_text(base)
    hull, lid = make_meshes(load_spec(fixed_spec), fixed_spec)
    solid = cpt.FloatingBody(mesh=hull, dofs=cpt.rigid_body_dofs(rotation_center=(0, 0, 0)),
                             center_of_mass=(0.0, 0.0, -draft / 2), mass=RHO * np.pi * CYL_R ** 2 * draft)
    mass, cog = float(solid.mass), np.array([0.0, 0.0, -draft / 2])
    inertia6 = np.asarray(solid.compute_rigid_body_inertia(rho=RHO).values)   # uniform solid, about (0, 0, 0)
    r = cog
    inertia_g = np.diag(inertia6[3:, 3:] - mass * (r @ r * np.eye(3) - np.outer(r, r)))
    spec = tmp_path / "free.toml"
    spec.write_text(base + f"""[second_order]
mean_drift = "far-field"
motions = "free"
center_of_mass = {cog.tolist()}
inertia = {inertia_g.tolist()}
""")
    fixed_spec.write_text(base + '[second_order]\nmean_drift = "far-field"\n')
    ds = build_hdb(spec, cache_dir=tmp_path / "cache", progress=False)
    fixed = build_hdb(fixed_spec, cache_dir=tmp_path / "cache", progress=False)
    assert not drift_body_fixed(ds) and drift_body_fixed(fixed) and "freely" in ds.attrs["mean_drift_note"]

    body = cpt.FloatingBody(mesh=hull, lid_mesh=lid, dofs=cpt.rigid_body_dofs(rotation_center=(0, 0, 0)),
                            center_of_mass=tuple(cog), mass=mass, name="cyl")
    body.inertia_matrix = body.compute_rigid_body_inertia(rho=RHO)
    # the stiffness on the hull with a 2-point Gauss rule per panel, as hdb build integrates it (the
    # default one-point rule is 4e-4 off in this drift near the heave resonance)
    exact = cpt.FloatingBody(mesh=hull.with_quadrature("Gauss-Legendre 2"), center_of_mass=tuple(cog), mass=mass,
                             dofs=cpt.rigid_body_dofs(rotation_center=(0, 0, 0)), name="cyl")
    body.hydrostatic_stiffness = exact.compute_hydrostatic_stiffness(rho=RHO, g=G)
    solver = cpt.BEMSolver()
    problems = [cpt.RadiationProblem(body=body, omega=w, radiating_dof=d, rho=RHO, g=G) for w in omegas for d in body.dofs]
    problems += [cpt.DiffractionProblem(body=body, omega=w, wave_direction=0.0, rho=RHO, g=G) for w in omegas]
    results = [solver.solve(pb, keep_details=True) for pb in problems]
    # (assemble_dataset's own hydrostatics step fails on this body in Capytaine 3.0.0: attached here)
    cds = cpt.assemble_dataset(results, hydrostatics=False).assign(
        inertia_matrix=body.inertia_matrix, hydrostatic_stiffness=body.hydrostatic_stiffness)
    step = 2 * np.pi / 720
    theta = xr.DataArray(step * np.arange(-4, 725), dims=("theta",))
    theta[4], theta[724] = 0.0, 2 * np.pi
    kochin = kochin_data_array(results, theta).assign_coords(wavenumber=cds["wavenumber"])
    rao = capytaine_rao(cds).transpose("omega", "wave_direction", "radiating_dof")
    surge = far_field_mean_drift_force(rao, kochin)["drift_force_surge"].values[:, 0, 0].real
    built = ds["mean_drift"].sel(drift_method="far-field", influenced_dof="cyl.surge").values[:, 0]
    # measured: equal to 1e-9 (the Kochin integral over 360 and 720 steps alike)
    np.testing.assert_allclose(built, surge, rtol=1e-6, atol=1e-6 * np.abs(surge).max())
    held = fixed["mean_drift"].sel(drift_method="far-field", influenced_dof="cyl.surge").values[:, 0]
    assert np.max(np.abs(built - held) / np.abs(held)) > 0.1


@pytest.mark.parametrize("edit, field", [
    (lambda d: d.pop("drift_omega"), "drift_omega"),
    (lambda d: d.update(drift_method=["momentum", 7]), "drift_method"),
    (lambda d: d.update(drift_method=["momentum", "guess"]), "drift_method"),
    (lambda d: d.update(drift_omega=d["drift_omega"][::-1].copy()), "drift_omega"),
    (lambda d: d.update(mean_drift=np.full_like(d["mean_drift"], np.inf)), "mean_drift"),
    (lambda d: d.update(mean_drift=d["mean_drift"][:, :2]), ""),
    (lambda d: d.pop("qtf_direction_j"), "qtf_direction_j"),
    (lambda d: d.update(qtf_direction_j=d["qtf_direction_j"] + 1.0), "qtf_heading"),
    (lambda d: d.update(sum_qtf=d["sum_qtf"] + np.triu(np.ones(d["sum_qtf"].shape[:2]))[:, :, None, None]), "sum_qtf"),
    (lambda d: d.update(difference_qtf=np.full_like(d["difference_qtf"], 2 ** 70 * (1 + 1j))), "difference_qtf"),
])
def test_bad_second_order_map_names_the_field(run, edit, field):
    """A second-order HDB map that breaks the layout is an HDBError naming the entry and the field;
    extreme but valid numbers (1e300, subnormals) pass."""
    _, ds = run
    data = to_wire(ds)
    edit(data)
    with pytest.raises(HDBError, match=rf"cyl.*{field}"):
        from_wire(data, "cyl")
    data = to_wire(ds)
    data["mean_drift"] = data["mean_drift"] * 1e-320 + 1e300 * (data["mean_drift"] > 0)
    assert from_wire(data, "cyl")["mean_drift"].values.max() == 1e300


def test_kochin_angles_hold_every_heading():
    """[0, 2 pi] sampled with both ends exact (Capytaine integrates over it), headings such as
    -30 deg and 400 deg strictly inside the range."""
    from hydrolink.server.hdb.build.drift import kochin_angles

    theta = kochin_angles(360, np.radians([-30.0, 0.0, 400.0]))
    assert np.all(np.diff(theta) > 0) and np.allclose(np.diff(theta), 2 * np.pi / 360)
    assert 0.0 in theta and 2 * np.pi in theta
    assert theta[0] < np.radians(-30.0) - 3 * 2 * np.pi / 360 and theta[-1] > np.radians(400.0) + 3 * 2 * np.pi / 360


def test_a_file_with_both_triangles_is_made_exactly_symmetric(tmp_path):
    """Both triangles stored, agreeing to the printed digits only: the square is their mean."""
    path = _write_run(tmp_path)
    qtf = tmp_path / "cyl.12s"
    extra = []
    for line in qtf.read_text().splitlines():
        pi, pj, bi, bj, i, mod, pha, re, im = line.split()
        if pi != pj:
            extra.append(f"{pj} {pi} {bj} {bi} {i} {mod} {pha} {float(re) * (1 + 2e-7)} {im}")
    qtf.write_text(qtf.read_text() + "\n".join(extra) + "\n")
    ds = load_hdb(path, rho=RHO)
    t = ds["sum_qtf"].isel(qtf_heading=0).values
    assert np.array_equal(t, np.swapaxes(t, 0, 1))
    w = ds["qtf_omega_i"].values
    a, b = int(np.argmin(np.abs(w - 2 * np.pi / 8.0))), int(np.argmin(np.abs(w - 2 * np.pi / 5.0)))
    bar = _qtf_bar(8.0, 5.0, 1)
    want = RHO * G * _scale(1) * complex(bar.real * (1 + 1e-7), -bar.imag)
    assert t[a, b, 0] == pytest.approx(want, rel=1e-9)


@pytest.mark.parametrize("extra, why", [
    ('[second_order]\nmean_drift = "near-field"\n', "second_order.mean_drift"),
    ('[second_order]\nmean_drift = "far-field"\nmotions = "moving"\n', "second_order.motions"),
    # "free" needs the mass properties of the RAO; "fixed" takes none
    ('[second_order]\nmean_drift = "far-field"\nmotions = "free"\ninertia = [1.0, 1.0, 1.0]\n',
     "second_order.center_of_mass"),
    ('[second_order]\nmean_drift = "far-field"\nmotions = "free"\ncenter_of_mass = [0.0, 0.0, -0.5]\n',
     "second_order.inertia"),
    ('[second_order]\nmean_drift = "far-field"\ninertia = [1.0, 1.0, 1.0]\n', "second_order.inertia"),
    ('[second_order]\nmotions = "free"\ncenter_of_mass = [0.0, 0.0, -0.5]\ninertia = [1.0, 1.0, 1.0]\n',
     "second_order.motions"),
    ('[second_order]\nmean_drift = "far-field"\nkochin_directions = 10\n', "second_order.kochin_directions"),
])
def test_bad_second_order_spec_names_the_key(extra, why):
    from hydrolink.server.hdb.build.spec import SpecError, parse_spec

    base = '[body]\nname = "c"\nshape = "vertical_cylinder"\nradius = 1.0\ndraft = 1.0\n[frequencies]\nvalues = [1.0, 2.0]\n'
    with pytest.raises(SpecError, match=why):
        parse_spec(base + extra, "c.toml")


def test_far_field_drift_of_several_bodies_is_refused():
    from hydrolink.server.hdb.build.spec import SpecError, parse_spec

    text = "".join(f'[[bodies]]\nname = "c{i}"\nshape = "vertical_cylinder"\nradius = 1.0\ndraft = 1.0\n'
                   f'center = [{5 * i}.0, 0.0, 0.0]\n' for i in range(2))
    with pytest.raises(SpecError, match="second_order.mean_drift.*one-body"):
        parse_spec(text + '[frequencies]\nvalues = [1.0, 2.0]\n[second_order]\nmean_drift = "far-field"\n', "two.toml")
