"""HDB readers (WAMIT, BEMIO, Capytaine, hydrolink NetCDF) against independent reference numbers."""

from __future__ import annotations

import shutil
import subprocess
import sys
import warnings
import re
from pathlib import Path

import h5py
import numpy as np
import pytest
import xarray as xr

from conftest import EXIT_S
from hydrolink.server.hdb.capytaine_io import from_capytaine_dataset, read_capytaine, short_body_names
from hydrolink.server.hdb.io import load_hdb
from hydrolink.protocol.hdb.layout import HDBError, hdb_warnings
from hydrolink.protocol.hdb.schema import to_netcdf
from hydrolink.server.hdb.wamit.reader import read_wamit

W_T8 = 2 * np.pi / 8.0  # RM3 standard case, T = 8 s
HEAVE = dict(influenced_dof="float.heave", radiating_dof="float.heave")


@pytest.fixture(scope="module")
def rm3_wamit(reference_data: Path) -> xr.Dataset:
    return load_hdb(reference_data / "rm3_wamit" / "rm3.1", rho=1000.0)


@pytest.fixture(scope="module")
def rm3_capytaine(reference_data: Path) -> xr.Dataset:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)  # rotation centre not recorded in this file
        return load_hdb(reference_data / "rm3_capytaine" / "rm3_hydrodynamics.nc")


@pytest.fixture(scope="module")
def sphere(reference_data: Path) -> xr.Dataset:
    return load_hdb(reference_data / "sphere_task10" / "sphere.h5")


def _copy_wamit(reference_data: Path, tmp_path: Path, exts=(".1", ".3", ".hst", ".out")) -> Path:
    for ext in exts:
        shutil.copy(reference_data / "rm3_wamit" / f"rm3{ext}", tmp_path / f"rm3{ext}")
    return tmp_path / "rm3"


def _at(ds: xr.Dataset, name: str, w: float, **sel) -> complex:
    """Linear interpolation (real and imaginary parts) of one coefficient at w."""
    series = ds[name].sel(**sel).squeeze().values
    return np.interp(w, ds["omega"].values, series.real) + 1j * np.interp(w, ds["omega"].values, series.imag)


# ---------------------------------------------------------------- WAMIT (RM3)

def test_wamit_rm3_float_heave_matches_reference(rm3_wamit):
    a33 = _at(rm3_wamit, "added_mass", W_T8, **HEAVE).real
    b33 = _at(rm3_wamit, "radiation_damping", W_T8, **HEAVE).real
    f3 = abs(_at(rm3_wamit, "excitation_force", W_T8, influenced_dof="float.heave"))
    assert a33 == pytest.approx(1.4468e6, rel=5e-3)
    assert b33 == pytest.approx(5.873e5, rel=5e-3)
    assert f3 == pytest.approx(1.512e6, rel=5e-3)
    assert rm3_wamit["added_mass_inf"].sel(**HEAVE).item() == pytest.approx(1.2328e6, rel=5e-3)


def test_a_wamit_read_imports_no_h5py(reference_data):
    """h5py is the BEMIO reader's alone (server/hdb/io.py imports it for an .h5 file only): a fresh
    process reading RM3's WAMIT run gets the same coefficients without it."""
    probe = ("import sys\nfrom hydrolink.server.hdb.io import load_hdb\n"
             f"ds = load_hdb({str(reference_data / 'rm3_wamit' / 'rm3.1')!r}, rho=1000.0)\n"
             "print(float(ds['added_mass'].sum()), 'h5py' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, timeout=EXIT_S)
    assert out.returncode == 0, out.stderr
    assert out.stdout.split() == [repr(float(load_hdb(reference_data / "rm3_wamit" / "rm3.1", rho=1000.0)
                                             ["added_mass"].sum())), "False"]


def test_wamit_rm3_run_facts(rm3_wamit):
    assert list(rm3_wamit["body"].values) == ["float", "spar"]
    assert rm3_wamit.attrs["g"] == 9.81 and np.isinf(rm3_wamit.attrs["water_depth"])
    np.testing.assert_allclose(rm3_wamit["reference_point"].values, [[0, 0, -0.72], [0, 0, -21.29]])
    np.testing.assert_allclose(rm3_wamit["displaced_volume"].values, [725.833, 886.687], rtol=1e-6)
    omega = rm3_wamit["omega"].values
    assert omega.size == 260 and omega[0] == pytest.approx(0.02) and omega[-1] == pytest.approx(5.2)
    # hydrostatic heave stiffness = rho g A_wp; equilibrium: rho g V z_b ... check C33 against the .out
    k33 = rm3_wamit["hydrostatic_stiffness"].sel(**HEAVE).item()
    assert k33 == pytest.approx(1000 * 9.81 * 285.52, rel=1e-4)  # rm3.out: C(3,3) = 285.52 (nondim.)
    # the centre of buoyancy of a floating body lies below the waterline, inside the draft
    assert -2.0 < rm3_wamit["center_of_buoyancy"].sel(body="float", xyz="z").item() < 0.0


def test_wamit_stem_and_shuffled_frequencies(reference_data, tmp_path, rm3_wamit):
    """The stem alone, rows shuffled, no .out: XBODY, depth and names from the .pot, VCG from the
    .frc, what no file states (ULEN, g, IPEROUT) from the scene's wamit table: the full set's HDB."""
    stem = _copy_wamit(reference_data, tmp_path, exts=(".1", ".3", ".hst", ".pot", ".frc", ".cfg"))
    rng = np.random.default_rng(0)
    for ext in (".1", ".3"):
        lines = (tmp_path / f"rm3{ext}").read_text().splitlines()
        body = lines[1:]
        rng.shuffle(body)
        (tmp_path / f"rm3{ext}").write_text("\n".join([lines[0], *body]) + "\n")
    ds = load_hdb(stem, wamit={"ulen": 1.0, "gravity": 9.81, "iperout": 1})
    assert list(ds["body"].values) == ["float", "spar"]
    assert ds.attrs["g"] == 9.81 and np.isinf(ds.attrs["water_depth"])
    np.testing.assert_array_equal(ds["reference_point"].values, rm3_wamit["reference_point"].values)
    np.testing.assert_allclose(ds["omega"].values, rm3_wamit["omega"].values)
    for name in ("added_mass", "radiation_damping", "excitation_force", "hydrostatic_stiffness", "added_mass_inf"):
        np.testing.assert_array_equal(ds[name].values, rm3_wamit[name].values, err_msg=name)


def test_wamit_rho_scales_coefficients(reference_data, rm3_wamit):
    ds = load_hdb(reference_data / "rm3_wamit" / "rm3", rho=1025.0)
    ratio = ds["added_mass"].sel(**HEAVE).values / rm3_wamit["added_mass"].sel(**HEAVE).values
    np.testing.assert_allclose(ratio, 1.025)
    assert ds.attrs["rho"] == 1025.0


# ---------------------------------------------------------------- Capytaine (RM3)

def test_capytaine_rm3_agrees_with_wamit(rm3_capytaine, rm3_wamit, reference_data):
    assert list(rm3_capytaine["body"].values) == ["float", "spar"]
    assert rm3_capytaine.attrs["body_names_in_file"] == "rm3_float,rm3_spar"
    for name in ("added_mass", "radiation_damping"):
        c, w = _at(rm3_capytaine, name, W_T8, **HEAVE).real, _at(rm3_wamit, name, W_T8, **HEAVE).real
        assert c == pytest.approx(w, rel=0.02), name
    xc = _at(rm3_capytaine, "excitation_force", W_T8, influenced_dof="float.heave")
    xw = _at(rm3_wamit, "excitation_force", W_T8, influenced_dof="float.heave")
    phase_gap = abs(np.angle(xc / xw, deg=True))
    assert phase_gap < 3.0
    # the conjugation matters: WAMIT's raw exp(+iwt) value is far from Capytaine's phase
    assert abs(np.angle(xc / np.conj(xw), deg=True)) > 3.0 + phase_gap
    assert abs(np.angle(xw, deg=True)) > 10.0  # and the phase is large enough for that test to bite


def test_capytaine_raw_file_is_exp_minus_iwt(reference_data, rm3_capytaine):
    """The reader does not conjugate Capytaine data (it is already exp(-iwt))."""
    raw = xr.open_dataset(reference_data / "rm3_capytaine" / "rm3_hydrodynamics.nc")
    x = raw["excitation_force"].sel(complex="re") + 1j * raw["excitation_force"].sel(complex="im")
    x = x.sel(influenced_dof="rm3_float__Heave").squeeze().values
    np.testing.assert_allclose(rm3_capytaine["excitation_force"].sel(influenced_dof="float.heave").squeeze(), x)


def test_body_name_rule():
    assert short_body_names(["rm3_float", "rm3_spar"]) == ["float", "spar"]
    assert short_body_names(["buoy"]) == ["buoy"]
    assert short_body_names(["float", "floater"]) == ["float", "floater"]  # no shared prefix ending in '_'
    assert short_body_names(["wec_1", "wec_"]) == ["wec_1", "wec_"]  # a name would become empty
    assert short_body_names(["a.stl", "b.stl"]) == ["a_stl", "b_stl"]


def test_capytaine_in_memory_dataset(tmp_path):
    """A fresh Capytaine solve: rotation centre, omega=inf -> A_inf, gravity terms removed, export."""
    cpt = pytest.importorskip("capytaine")
    import logging
    logging.getLogger("capytaine").setLevel(logging.ERROR)
    mesh = cpt.mesh_sphere(radius=1.0, center=(0, 0, 0), resolution=(8, 8)).immersed_part()
    body = cpt.FloatingBody(mesh=mesh, dofs=cpt.rigid_body_dofs(rotation_center=(0, 0, -0.2)),
                            center_of_mass=(0, 0, -0.3), name="buoy")
    matrix = xr.Dataset(coords={"omega": [1.0, 0.5, np.inf], "wave_direction": [0.0],
                                "radiating_dof": list(body.dofs)})
    ds = cpt.BEMSolver().fill_dataset(matrix, body, hydrostatics=True)
    hdb = from_capytaine_dataset(ds, "in-memory")
    assert list(hdb["body"].values) == ["buoy"]
    np.testing.assert_allclose(hdb["omega"].values, [0.5, 1.0])
    np.testing.assert_allclose(hdb["reference_point"].values, [[0, 0, -0.2]])
    # the mass and centre of gravity the file records (Capytaine's inertia_matrix: rho V of the
    # immersed hemisphere, as its rigid-body inertia is computed for a neutrally buoyant body)
    assert float(hdb["mass"].item()) == pytest.approx(ds["inertia_matrix"].sel(influenced_dof="Heave",
                                                                             radiating_dof="Heave").item())
    np.testing.assert_allclose(hdb["center_of_mass"].values, [[0, 0, -0.3]])
    a_inf = ds["added_mass"].sel(omega=np.inf, influenced_dof="Heave", radiating_dof="Heave").item()
    assert hdb["added_mass_inf"].sel(influenced_dof="buoy.heave", radiating_dof="buoy.heave").item() == a_inf
    # buoyancy + waterplane only: the same as Capytaine's stiffness for a centre of mass at the
    # rotation centre (where its gravity terms vanish)
    neutral = cpt.FloatingBody(mesh=mesh, dofs=cpt.rigid_body_dofs(rotation_center=(0, 0, -0.2)),
                               center_of_mass=(0, 0, -0.2))
    np.testing.assert_allclose(hdb["hydrostatic_stiffness"].values,
                               neutral.compute_hydrostatic_stiffness().values, atol=1e-6)
    path = tmp_path / "buoy.nc"
    cpt.export_dataset(path, ds, format="netcdf")
    again = load_hdb(path)
    for name in ("added_mass", "radiation_damping", "excitation_force", "hydrostatic_stiffness"):
        np.testing.assert_allclose(again[name].values, hdb[name].values)


# ---------------------------------------------------------------- BEMIO (Task-10 sphere)

def test_bemio_sphere(sphere):
    rho, g, radius = 1000.0, 9.81, 5.0
    assert list(sphere["body"].values) == ["sphere"]
    k33 = sphere["hydrostatic_stiffness"].sel(influenced_dof="sphere.heave", radiating_dof="sphere.heave").item()
    assert k33 == pytest.approx(rho * g * np.pi * radius**2, rel=0.01)
    # High-frequency heave of a half-immersed sphere: phi = 0 on z = 0 and the heave dipole z/r^3 is
    # odd in z, so the flow is half that of a sphere translating in unbounded fluid (added mass
    # 1/2 rho (4/3) pi R^3): A_inf,33 = 1/2 * 1/2 * rho (4/3) pi R^3 = rho pi R^3 / 3.
    a_inf = sphere["added_mass_inf"].sel(influenced_dof="sphere.heave", radiating_dof="sphere.heave").item()
    assert a_inf == pytest.approx(rho * np.pi * radius**3 / 3, rel=0.01)
    a_last = sphere["added_mass"].sel(influenced_dof="sphere.heave", radiating_dof="sphere.heave").values[-1]
    assert a_inf == pytest.approx(a_last, rel=0.03)
    assert sphere["displaced_volume"].item() == pytest.approx(2 / 3 * np.pi * radius**3, rel=1e-3)
    # centre of buoyancy of a hemisphere below its centre (z = 0): -3R/8
    assert sphere["center_of_buoyancy"].sel(xyz="z").item() == pytest.approx(-3 * radius / 8, rel=1e-3)


def test_bemio_reference_point_is_cg(sphere):
    """A sphere's radiation about its centre has no rotational part, so about a point d below the
    centre A15 = d A11 and A55 = d^2 A11: with cg at z = -2 m, d = 2."""
    np.testing.assert_allclose(sphere["reference_point"].values, [[0, 0, -2.0]])
    a = sphere["added_mass"].isel(omega=-1)
    a11 = a.sel(influenced_dof="sphere.surge", radiating_dof="sphere.surge").item()
    assert a.sel(influenced_dof="sphere.surge", radiating_dof="sphere.pitch").item() == pytest.approx(2 * a11, rel=1e-3)
    assert a.sel(influenced_dof="sphere.pitch", radiating_dof="sphere.pitch").item() == pytest.approx(4 * a11, rel=1e-3)


def test_bemio_excitation_is_conjugated(sphere, reference_data):
    with h5py.File(reference_data / "sphere_task10" / "sphere.h5") as fh:
        im = fh["body1/hydro_coeffs/excitation/im"][2, 0, :]
    x = sphere["excitation_force"].sel(influenced_dof="sphere.heave").squeeze().values
    np.testing.assert_allclose(x.imag, -1000 * 9.81 * im)


# ---------------------------------------------------------------- round trip

def test_roundtrip_hydrolink_netcdf(rm3_wamit, tmp_path):
    path = tmp_path / "rm3_hdb.nc"
    to_netcdf(rm3_wamit, path)
    back = load_hdb(path)
    for name in rm3_wamit.data_vars:
        np.testing.assert_array_equal(back[name].values, rm3_wamit[name].values)
    assert list(back["body"].values) == ["float", "spar"]
    assert back.attrs["rho"] == 1000.0 and np.isinf(back.attrs["water_depth"])


# ---------------------------------------------------------------- bad input

def _error(path, **kw) -> HDBError:
    with pytest.raises(HDBError) as info:
        load_hdb(path, **kw)
    return info.value


def test_missing_files(tmp_path):
    for name in ("nope.h5", "nope.nc", "nope.1", "nope"):
        err = _error(tmp_path / name)
        assert "nope" in str(err) and ("not found" in str(err))
    (tmp_path / "notes.txt").write_text("hello")
    assert _error(tmp_path / "notes.txt").field == "format"


def test_wamit_truncated_line(reference_data, tmp_path):
    stem = _copy_wamit(reference_data, tmp_path)
    lines = (tmp_path / "rm3.1").read_text().splitlines()
    n = next(i for i, line in enumerate(lines) if i > 0 and float(line.split()[0]) > 0)
    lines[n] = " ".join(lines[n].split()[:2])
    (tmp_path / "rm3.1").write_text("\n".join(lines) + "\n")
    err = _error(stem)
    assert str(err).startswith(f"rm3.1: line {n + 1}: expected 'PER I J Abar [Bbar]'")


def test_wamit_missing_damping_column(reference_data, tmp_path):
    stem = _copy_wamit(reference_data, tmp_path)
    lines = (tmp_path / "rm3.1").read_text().splitlines()
    n = next(i for i, line in enumerate(lines) if i > 0 and float(line.split()[0]) > 0)
    lines[n] = " ".join(lines[n].split()[:4])
    (tmp_path / "rm3.1").write_text("\n".join(lines) + "\n")
    assert str(_error(stem)).startswith(f"rm3.1: line {n + 1}:")


def test_wamit_nan(reference_data, tmp_path):
    stem = _copy_wamit(reference_data, tmp_path)
    lines = (tmp_path / "rm3.hst").read_text().splitlines()
    lines[5] = "     1     5   NaN"
    (tmp_path / "rm3.hst").write_text("\n".join(lines) + "\n")
    assert str(_error(stem)).startswith("rm3.hst: line 6: not a finite number")


def test_wamit_missing_excitation_file(reference_data, tmp_path):
    stem = _copy_wamit(reference_data, tmp_path, exts=(".1", ".hst"))
    err = _error(stem)
    assert err.field == "excitation_force" and "rm3.3" in str(err)


def _sphere_copy(reference_data: Path, tmp_path: Path) -> Path:
    path = tmp_path / "sphere.h5"
    shutil.copy(reference_data / "sphere_task10" / "sphere.h5", path)
    return path


def test_bemio_missing_dataset(reference_data, tmp_path):
    path = _sphere_copy(reference_data, tmp_path)
    with h5py.File(path, "a") as fh:
        del fh["body1/hydro_coeffs/excitation/re"]
    err = _error(path)
    assert err.field == "body1/hydro_coeffs/excitation/re" and "sphere.h5" in err.source


def test_bemio_wrong_shape(reference_data, tmp_path):
    path = _sphere_copy(reference_data, tmp_path)
    with h5py.File(path, "a") as fh:
        data = fh["body1/hydro_coeffs/radiation_damping/all"][()]
        del fh["body1/hydro_coeffs/radiation_damping/all"]
        fh["body1/hydro_coeffs/radiation_damping/all"] = data[:, :, :-1]
    err = _error(path)
    assert err.field == "body1/hydro_coeffs/radiation_damping/all" and "shape" in err.why


def test_bemio_nan_and_repeated_frequency(reference_data, tmp_path):
    path = _sphere_copy(reference_data, tmp_path)
    with h5py.File(path, "a") as fh:
        fh["body1/hydro_coeffs/added_mass/all"][2, 2, 7] = np.nan
    err = _error(path)
    assert err.field == "added_mass" and "NaN" in err.why and "sphere.heave" in err.why
    path = _sphere_copy(reference_data, tmp_path)
    with h5py.File(path, "a") as fh:
        fh["simulation_parameters/w"][5, 0] = fh["simulation_parameters/w"][4, 0]
    err = _error(path)
    assert err.field == "omega" and "increasing" in err.why


def test_dimensional_file_refuses_other_rho(sphere, reference_data):
    err = _error(reference_data / "sphere_task10" / "sphere.h5", rho=1025.0)
    assert err.field == "rho"


def test_capytaine_unknown_dof(reference_data, tmp_path):
    raw = xr.open_dataset(reference_data / "rm3_capytaine" / "rm3_hydrodynamics.nc").load()
    labels = [str(v) for v in raw["radiating_dof"].values]
    labels[0] = "rm3_float__Bend.1"      # a mode name that cannot be a label "<body>.<mode>"
    raw = raw.assign_coords(radiating_dof=labels, influenced_dof=labels)
    with pytest.raises(HDBError) as info:
        from_capytaine_dataset(raw, "rm3.nc")
    assert info.value.field == "radiating_dof" and "Bend.1" in info.value.why


def test_read_capytaine_missing_variable(reference_data, tmp_path):
    raw = xr.open_dataset(reference_data / "rm3_capytaine" / "rm3_hydrodynamics.nc").load()
    path = tmp_path / "no_exc.nc"
    raw.drop_vars("excitation_force").to_netcdf(path)
    with pytest.raises(HDBError) as info:
        read_capytaine(path)
    assert info.value.field == "excitation_force" and "no_exc.nc" in info.value.source


# ---------------------------------------------------------------- time convention of Capytaine-layout files

@pytest.fixture(scope="module")
def capytaine_buoy(tmp_path_factory):
    """A small Capytaine solve (heave and pitch of a floating sphere off the origin) exported as
    Capytaine writes it; returns the file."""
    cpt = pytest.importorskip("capytaine")
    import logging
    logging.getLogger("capytaine").setLevel(logging.ERROR)
    mesh = cpt.mesh_sphere(radius=1.0, center=(2.0, 0, 0), resolution=(8, 8)).immersed_part()
    body = cpt.FloatingBody(mesh=mesh, dofs=cpt.rigid_body_dofs(rotation_center=(2.0, 0, 0)),
                            center_of_mass=(2.0, 0, -0.2), name="buoy")
    ds = cpt.BEMSolver().fill_dataset(xr.Dataset(coords={"omega": [0.8, 1.6, 2.4], "wave_direction": [0.0],
                                                         "radiating_dof": ["Heave", "Pitch"]}), body, hydrostatics=True)
    path = tmp_path_factory.mktemp("buoy") / "buoy.nc"
    cpt.export_dataset(path, ds, format="netcdf")
    return path


def _rewrite(src: Path, dst: Path, conj: tuple[str, ...] = (), attrs: dict | None = None, extra: bool = False) -> Path:
    """The file with the named variables conjugated (their 'im' part negated), attributes added and
    optionally a variable Capytaine does not write (WecOptTool's 'friction')."""
    with xr.open_dataset(src) as raw:
        ds = raw.load()
    for name in conj:
        ds[name] = xr.where(ds["complex"] == "im", -ds[name], ds[name]).transpose(*ds[name].dims)
    ds.attrs.update(attrs or {})
    if extra:
        ds["friction"] = xr.zeros_like(ds["hydrostatic_stiffness"])
    ds.to_netcdf(dst)
    return dst


def _heave_force(hdb, period: float = 2 * np.pi / 1.6, **keys) -> np.ndarray:
    """The server's excitation force on the buoy in regular waves (H 1 m), heave and pitch, over one
    period after the ramp: the regular-wave phase check of the convention."""
    from hydrolink.server.model import HydroModel
    from hydrolink.protocol.scene import parse_scene
    from conftest import body, regular_waves, scene_toml
    scene = parse_scene(scene_toml(dt=period / 40, duration=3 * period, water={"density": 1025.0, "depth": "inf"},
                                   waves=regular_waves(1.0, period), hydro={"radiation": "constant", "irf_duration": 3.0},
                                   bodies=[body("buoy", hdb="buoy.nc", mass=2000.0, center_of_mass=[2.0, 0, -0.2],
                                                inertia=[500.0] * 3, dofs=["heave", "pitch"], **keys)]))
    m = HydroModel(scene, {"buoy": hdb})
    pos = m.setup_info().equilibrium_position
    return np.array([m.step(k * period / 40, pos, np.zeros_like(pos))["excitation"][0, [2, 4]] for k in range(40)])


def test_capytaine_file_convention_declared_stated_or_checked(capytaine_buoy, tmp_path):
    """Capytaine's own file: exp(-iwt), checked on its force phases, no note. The same file converted
    to exp(+iwt) (excitation, Froude-Krylov and diffraction conjugated, as WecOptTool holds them),
    with or without a variable Capytaine does not write: an error asking for hdb_convention (read as
    exp(-iwt) it would be wrong); stated (hdb_convention) or declared by an attribute, it is
    conjugated back and the server's force in a regular wave is the original's to round-off; a
    statement that contradicts the file is an error, one that contradicts its phases is noted."""
    with warnings.catch_warnings():
        warnings.simplefilter("error")          # Capytaine's own file: nothing to note
        plain = load_hdb(capytaine_buoy)
    assert hdb_warnings(plain) == ()
    assert plain.attrs["time_convention_in_file"] == "exp(-iwt)"
    assert plain.attrs["time_convention_from"].startswith("Capytaine's, checked: ")
    ref = _heave_force(plain)
    assert np.abs(ref).max() > 1e3
    every = ("excitation_force", "Froude_Krylov_force", "diffraction_force")
    for extra in (True, False):
        wot = _rewrite(capytaine_buoy, tmp_path / f"wot{extra}.nc", conj=every, extra=extra)
        with pytest.raises(HDBError, match=r"hdb_convention: the file does not declare its time convention and its "
                                           r"force phases are exp\(\+iwt\)'s.*\"exp\(\+iwt\)\" for WecOptTool"):
            load_hdb(wot)
    silent = load_hdb(wot, convention="exp(-iwt)")    # the doubt kept with the HDB (setup.warnings)
    assert [re.search(r"read as exp\(-iwt\) \(stated \(hdb_convention\)\), but .* fit exp\(\+iwt\)", n) is not None
            for n in hdb_warnings(silent)] == [True]
    assert np.abs(_heave_force(silent) - ref).max() > 0.1 * np.abs(ref).max()   # what a wrong read costs
    stated = load_hdb(wot, convention="exp(+iwt)")
    np.testing.assert_allclose(_heave_force(stated), ref, rtol=1e-12, atol=1e-9 * np.abs(ref).max())
    declared = _rewrite(capytaine_buoy, tmp_path / "declared.nc", conj=every, attrs={"time_convention": "exp(+iwt)"})
    np.testing.assert_allclose(_heave_force(load_hdb(declared)), ref, rtol=1e-12, atol=1e-9 * np.abs(ref).max())
    with pytest.raises(HDBError, match=r"the file declares exp\(\+iwt\), the scene states exp\(-iwt\)"):
        load_hdb(declared, convention="exp(-iwt)")
    half = _rewrite(capytaine_buoy, tmp_path / "half.nc", conj=("Froude_Krylov_force", "diffraction_force"))
    assert ["are the complex conjugates of its excitation_force" in n for n in hdb_warnings(load_hdb(half))] == [True]
    with pytest.raises(HDBError, match="only for a Capytaine-layout NetCDF"):
        load_hdb(tmp_path / "x.h5", convention="exp(+iwt)")


def test_wecopttool_file_refused_then_read_right(capytaine_buoy, tmp_path):
    """A file WecOptTool 3.3 writes itself (run_bem + write_netcdf, the buoy of capytaine_buoy: the
    same mesh, DOFs and centres): not declared, its force phases are exp(+iwt)'s, so reading it
    stops with an error asking for hdb_convention; stated, the excitation force in a regular wave
    (heave and pitch over one period) is the Capytaine dataset's of the same body, and hdb info
    says which convention was read and why."""
    wot = pytest.importorskip("wecopttool", reason="WecOptTool is not installed (.ci/run installs it)")
    import capytaine as cpt
    import logging
    from hydrolink.server.hdb.info import hdb_summary
    logging.getLogger("capytaine").setLevel(logging.ERROR)
    logging.getLogger("wecopttool").setLevel(logging.ERROR)
    mesh = cpt.mesh_sphere(radius=1.0, center=(2.0, 0, 0), resolution=(8, 8))
    body = cpt.FloatingBody(mesh=mesh, dofs=cpt.rigid_body_dofs(rotation_center=(2.0, 0, 0)),
                            center_of_mass=(2.0, 0, -0.2), name="buoy").with_only_dofs(["Heave", "Pitch"])
    body.mass = 2000.0
    bem = wot.run_bem(body, freq=np.array([0.8, 1.6, 2.4]) / (2 * np.pi), wave_dirs=[0.0])
    # Capytaine >= 2.3.2 keeps the DOF coordinates categorical, which xarray cannot write; WecOptTool 3.3
    # pins Capytaine 2.3.1, where they are strings: make them strings as that version has them
    bem = bem.assign_coords(radiating_dof=bem["radiating_dof"].astype(str),
                            influenced_dof=bem["influenced_dof"].astype(str))
    path = tmp_path / "buoy.nc"
    wot.write_netcdf(path, bem)
    with pytest.raises(HDBError, match=r"hdb_convention: .*force phases are exp\(\+iwt\)'s"):
        load_hdb(path)
    stated = load_hdb(path, convention="exp(+iwt)")
    ref = _heave_force(load_hdb(capytaine_buoy))
    force = _heave_force(stated, hdb_body="copy_of_buoy_immersed")     # run_bem's name for the body
    np.testing.assert_allclose(force, ref, rtol=1e-6, atol=1e-6 * np.abs(ref).max())
    phase = np.angle(np.fft.rfft(force, axis=0)[1] / np.fft.rfft(ref, axis=0)[1], deg=True)
    assert np.all(np.abs(phase) < 0.01)                       # the regular-wave phase, heave and pitch
    info = hdb_summary(stated)
    assert "time convention of the file's complex amplitudes: exp(+iwt) (stated (hdb_convention); 2" in info


# ---------------------------------------------------------------- WAMIT: the run's facts, read or stated (issue 40)

RM3_STATED = {"ulen": 1.0, "gravity": 9.81, "iperout": 1}     # what rm3.pot/.frc/.cfg do not state
COEFFICIENTS = ("added_mass", "radiation_damping", "excitation_force", "hydrostatic_stiffness", "added_mass_inf")


def _same_as(ds: xr.Dataset, ref: xr.Dataset, names=COEFFICIENTS, rtol: float = 0.0) -> None:
    for name in names:
        np.testing.assert_allclose(ds[name].values, ref[name].values, rtol=rtol, atol=0, err_msg=name)


def _mmx(path: Path, ulen: float = 1.0) -> Path:
    """An .mmx as WAMIT writes it, with rm3.out's facts (g 9.81, the bodies' volumes, centres of
    buoyancy and gravity) and ``ulen``."""
    bodies = [("725.833      725.833      725.834", "0.000000     0.000003    -0.572734", "0.000000     0.000003     0.000000"),
              ("886.687      886.687      886.691", "0.000000    -0.000002     5.686012", "0.000000    -0.000002     0.000000")]
    lines = [" WAMIT -- Force Output File -- rm3.mmx", "", f" Gravity:     9.81000                Length scale:        {ulen:.5f}",
             "", " NBODY =     2       IALTFRC = 1", " "]
    for n, (vol, cb, cg) in enumerate(bodies, start=1):
        lines += [f" WAMIT  Ouputs for body N =     {n}    IALTFRCN = 1", f" Volumes (VOLX,VOLY,VOLZ):           {vol}",
                  f" Center of Buoyancy (Xb,Yb,Zb):     {cb}", f" Center of Gravity:  (Xg,Yg,Zg)     {cg}", "",
                  " Normalized mass matrix: ", "     I     J     MASS(I,J)/RHO", "     1     1     7.258330E+02", " "]
    path.write_text("\n".join(lines) + "\n")
    return path


def test_wamit_without_out_names_what_no_file_states(reference_data, tmp_path, rm3_wamit):
    """Before: read with XBODY at the origin, ULEN 1, g 9.80665, infinite depth, silently. Now each
    value no file states is named with its scene key; the .pot/.frc state XBODY, depth and VCG."""
    stem = _copy_wamit(reference_data, tmp_path, exts=(".1", ".3", ".hst"))
    err = _error(stem)
    assert err.field == "wamit" and "the run's ULEN, g, water depth, XBODY, VCG, IPEROUT are" in err.why
    assert "stated by no file: no file beside it (no .out/.mmx/.pot/.frc/.cfg)" in err.why
    assert "[bodies.wamit] table (ulen, gravity, depth, xbody, vcg, iperout)" in err.why
    _copy_wamit(reference_data, tmp_path, exts=(".pot", ".frc", ".cfg"))
    err = _error(stem)
    assert err.field == "wamit" and "(ulen, gravity, iperout)" in err.why
    assert "rm3.pot, rm3.frc, rm3.cfg beside it (no .out/.mmx)" in err.why
    ds = load_hdb(stem, wamit=RM3_STATED)
    np.testing.assert_array_equal(ds["reference_point"].values, rm3_wamit["reference_point"].values)
    assert list(ds["body"].values) == ["float", "spar"] and np.isinf(ds.attrs["water_depth"])
    _same_as(ds, rm3_wamit)
    # all stated, no file but the three numeric ones: the same HDB (generic body names)
    for ext in (".pot", ".frc", ".cfg"):
        (tmp_path / f"rm3{ext}").unlink()
    ds = load_hdb(stem, wamit={**RM3_STATED, "depth": "inf", "xbody": [[0, 0, -0.72], [0, 0, -21.29]], "vcg": [0, 0]})
    assert list(ds["body"].values) == ["body1", "body2"]
    np.testing.assert_array_equal(ds["reference_point"].values, rm3_wamit["reference_point"].values)
    _same_as(ds, rm3_wamit)


def test_wamit_mmx_states_ulen_and_g(reference_data, tmp_path, rm3_wamit):
    """.mmx (g, ULEN, volumes) + .pot + .frc + IPEROUT: no key needed. A run whose ULEN is 2 (before:
    read as 1, added mass x1/8, rotational x1/32, stiffness and excitation x1/4): A = rho L^k Abar,
    B = rho w L^k Bbar, C = rho g L^k Cbar, X = rho g L^m Xbar (WAMIT's definitions) against the
    full set's (ULEN 1) values."""
    stem = _copy_wamit(reference_data, tmp_path, exts=(".1", ".3", ".hst", ".pot", ".frc"))
    (tmp_path / "rm3.cfg").write_text("IPEROUT=1\n")
    _mmx(tmp_path / "rm3.mmx")
    ds = load_hdb(stem)
    _same_as(ds, rm3_wamit)
    np.testing.assert_allclose(ds["displaced_volume"].values, rm3_wamit["displaced_volume"].values)
    _mmx(tmp_path / "rm3.mmx", ulen=2.0)
    scaled = load_hdb(stem)
    pairs = {"added_mass": (8, 16, 32), "radiation_damping": (8, 16, 32), "hydrostatic_stiffness": (4, 8, 16)}
    for name, (tt, tr, rr) in pairs.items():
        for (i, j), factor in (((2, 2), tt), ((0, 4), tr), ((4, 4), rr), ((6, 10), tr), ((3, 9), rr)):
            a, b = rm3_wamit[name].values[..., i, j], scaled[name].values[..., i, j]
            np.testing.assert_allclose(b, factor * a, rtol=1e-12, err_msg=f"{name}[{i},{j}]")
    x, xs = rm3_wamit["excitation_force"].values, scaled["excitation_force"].values
    np.testing.assert_allclose(xs[..., [0, 2, 6, 8]], 4 * x[..., [0, 2, 6, 8]], rtol=1e-12)
    np.testing.assert_allclose(xs[..., [4, 10]], 8 * x[..., [4, 10]], rtol=1e-12)


def test_wamit_stated_value_a_file_contradicts(reference_data, tmp_path):
    """The OSWEC's case: a depth stated that the .pot (HBOT 0: infinite) contradicts is an error
    naming the file, the field and both values; a list of the wrong length names the key."""
    stem = _copy_wamit(reference_data, tmp_path, exts=(".1", ".3", ".hst", ".pot", ".frc"))
    err = _error(stem, wamit={**RM3_STATED, "depth": 10.9})
    assert err.source == "rm3.pot" and err.field == "water depth"
    assert "the file states inf, the scene's wamit.depth 10.9" in err.why
    err = _error(stem, wamit={**RM3_STATED, "vcg": [0.0]})
    assert err.field == "wamit.vcg" and "1 values for the run's 2 bodies" in err.why
    err = _error(reference_data / "sphere_task10" / "sphere.h5", wamit={"ulen": 1.0})
    assert err.field == "wamit"


def test_wamit_symlinked_one_finds_siblings_beside_the_link(reference_data, tmp_path, rm3_wamit):
    """Before: the siblings were looked for beside the link's target. The scene's path keeps the link."""
    from hydrolink.protocol.scene import resolve_path
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    shutil.copy(reference_data / "rm3_wamit" / "rm3.1", elsewhere / "rm3.1")   # alone: no .3, .hst, .out
    here = tmp_path / "here"
    here.mkdir()
    _copy_wamit(reference_data, here, exts=(".3", ".hst", ".out"))
    (here / "rm3.1").symlink_to(elsewhere / "rm3.1")
    path = resolve_path(here / "scene.toml", "rm3.1")
    assert path == here / "rm3.1"
    _same_as(load_hdb(path), rm3_wamit)


def test_wamit_without_excitation_for_still_water(reference_data, tmp_path, rm3_wamit):
    """Before: refused even for a still-water decay. Now read when the scene needs no excitation
    (Scene.wamit_statement), refused with the reason when it does."""
    from conftest import body, regular_waves, scene_toml
    from hydrolink.protocol.scene import parse_scene
    stem = _copy_wamit(reference_data, tmp_path, exts=(".1", ".hst", ".out"))
    bodies = [body("float", hdb="rm3.1", mass=725833.0, center_of_mass=None, inertia=None, dofs=["heave"])]
    still = parse_scene(scene_toml(dt=0.1, duration=1.0, bodies=bodies))
    waves = parse_scene(scene_toml(dt=0.1, duration=1.0, bodies=bodies, waves=regular_waves(1.0, 8.0)))
    assert still.wamit_statement("rm3.1") == {"excitation_needed": False}
    err = _error(stem, wamit=waves.wamit_statement("rm3.1"))
    assert err.field == "excitation_force" and "the scene's waves need the excitation force" in err.why
    ds = load_hdb(stem, wamit=still.wamit_statement("rm3.1"))
    _same_as(ds, rm3_wamit, names=("added_mass", "radiation_damping", "hydrostatic_stiffness", "added_mass_inf"))
    assert not np.any(ds["excitation_force"].values) and "absent" in ds.attrs["excitation_force"]


def _rewrite_first_column(path: Path, to_frequency: bool = True) -> None:
    """The file with each positive period T of its first column written as 2 pi / T (IPEROUT 2);
    the -1 and 0 markers as they are."""
    lines = path.read_text().splitlines()
    out = [lines[0]]
    for line in lines[1:]:
        first, rest = line.split(None, 1)
        t = float(first)
        out.append(f" {2 * np.pi / t if t > 0 and to_frequency else t:.6E} {rest}")
    path.write_text("\n".join(out) + "\n")


def test_wamit_frequency_column_from_iperout_or_the_out(reference_data, tmp_path, rm3_wamit):
    """RM3 written with frequencies (IPEROUT 2). Before: read as periods (omega 1.2...314 rad/s) where
    the .cfg lacks IPEROUT, and with IPEROUT 2 the A_inf rows were dropped. Now: IPEROUT 2 from the
    .cfg keeps A_inf; without it the .out's period list tells; without both, an error naming the key;
    a .cfg the .out contradicts, an error naming both."""
    stem = _copy_wamit(reference_data, tmp_path, exts=(".1", ".3", ".hst", ".pot", ".frc"))
    for ext in (".1", ".3"):
        _rewrite_first_column(tmp_path / f"rm3{ext}")
    (tmp_path / "rm3.cfg").write_text("IPEROUT=2\n")
    ds = load_hdb(stem, wamit={"ulen": 1.0, "gravity": 9.81})
    np.testing.assert_allclose(ds["omega"].values, rm3_wamit["omega"].values, rtol=1e-6)
    _same_as(ds, rm3_wamit, names=("added_mass", "added_mass_inf", "hydrostatic_stiffness"))
    _same_as(ds, rm3_wamit, names=("radiation_damping", "excitation_force"), rtol=1e-6)   # B = rho w L^k Bbar
    (tmp_path / "rm3.cfg").unlink()
    err = _error(stem, wamit={"ulen": 1.0, "gravity": 9.81})
    assert err.field == "wamit.iperout" and "1 if the first column holds periods" in err.why
    shutil.copy(reference_data / "rm3_wamit" / "rm3.out", tmp_path / "rm3.out")
    ds = load_hdb(stem)
    np.testing.assert_allclose(ds["omega"].values, rm3_wamit["omega"].values, rtol=1e-6)
    assert "iperout: rm3.out's period list" in ds.attrs["wamit_facts_from"]
    (tmp_path / "rm3.cfg").write_text("IPEROUT=1\n")
    err = _error(stem)
    assert err.source == "rm3.cfg" and err.field == "IPEROUT"
    assert "matches rm3.out's period list as angular frequencies in rad/s (IPEROUT 2)" in err.why
    err = _error(reference_data / "rm3_wamit" / "rm3", wamit={"iperout": 2})
    assert err.field == "IPEROUT" and "the scene's wamit.iperout 2" in err.why


def test_wamit_out_of_another_run(reference_data, tmp_path):
    """An .out whose period list is not the .1's first column, read any way, is an error."""
    stem = _copy_wamit(reference_data, tmp_path)
    lines = (tmp_path / "rm3.1").read_text().splitlines()
    (tmp_path / "rm3.1").write_text("\n".join(line for line in lines if not line.startswith("  3.141593E+02")) + "\n")
    err = _error(stem)
    assert err.source == "rm3.out" and err.field == "Period" and "is this report of the same run?" in err.why


def test_scene_states_the_run_and_its_density(reference_data, tmp_path, rm3_wamit):
    """Through a scene (hydrolink run's loader): the [bodies.wamit] table states what rm3.pot/.frc do
    not; the nondimensional set takes the scene's 1025 kg/m^3 (A = rho L^k Abar), and the set-up
    has no note that "the HDB's 1000 kg/m^3" differs (before: it had, about the reader's default)."""
    from conftest import rm3_float, scene_toml, write_scene
    from hydrolink.clients.scene_inputs import load_scene_hdbs
    from hydrolink.protocol.scene import load_scene
    from hydrolink.server.model import HydroModel
    _copy_wamit(reference_data, tmp_path, exts=(".1", ".3", ".hst", ".pot", ".frc"))
    text = scene_toml(dt=0.1, duration=1.0, water={"density": 1025.0, "gravity": 9.81},
                      bodies=[rm3_float("rm3.1", dofs=["heave"], wamit=RM3_STATED)])
    path = write_scene(tmp_path, text)
    scene, _ = load_scene(path)
    hdbs = load_scene_hdbs(scene, path, progress=False)
    ds = hdbs["rm3.1"]
    assert ds.attrs["rho"] == 1025.0
    np.testing.assert_allclose(ds["added_mass"].values, 1.025 * rm3_wamit["added_mass"].values, rtol=1e-15)
    np.testing.assert_allclose(ds["hydrostatic_stiffness"].values, 1.025 * rm3_wamit["hydrostatic_stiffness"].values,
                               rtol=1e-15)
    model = HydroModel(scene, {"float": ds})
    assert not [w for w in model.warnings if w.startswith("water:")], model.warnings
    err = _error(tmp_path / "rm3.1", wamit=scene.wamit_statement("nope.1"))
    assert err.field == "wamit" and "(ulen, gravity, iperout)" in err.why


# ---------------------------------------------------------------- WAMIT: VCG, on a hand-built set

R, DRAFT, RHO, G = 3.0, 2.0, 1000.0, 9.81      # a vertical cylinder, XBODY at the waterline


def _cylinder_run(folder: Path, vcg: float, source: str) -> Path:
    """A one-body WAMIT run of a vertical cylinder (radius R, draft DRAFT, ULEN 1) whose .hst holds,
    as WAMIT writes it, the hydrostatics plus the gravity term -V VCG in C44 and C55 (nondimensional,
    m = rho V): C33 = pi R^2, C44 = C55 = pi R^4 / 4 + V z_b - V VCG with z_b = -DRAFT/2. VCG is
    stated by the .frc (``source`` "frc") or by the .out's centre of gravity ("out")."""
    folder.mkdir()
    stem = folder / "cyl"
    volume, zb = np.pi * R**2 * DRAFT, -DRAFT / 2
    c44 = np.pi * R**4 / 4 + volume * zb - volume * vcg
    rows = [f"{p} {i} {i} {1.0 + 0.1 * i} {0.2 * i}" for p in (8.0, 4.0) for i in range(1, 7)]
    (folder / "cyl.1").write_text("\n".join([f"0.0 {i} {i} {0.9 + 0.1 * i}" for i in range(1, 7)] + rows) + "\n")
    (folder / "cyl.3").write_text("\n".join(f"{p} 0.0 {i} 1.0 0.0 {0.3 * i} {0.1 * i}" for p in (8.0, 4.0)
                                            for i in range(1, 7)) + "\n")
    (folder / "cyl.hst").write_text(f"3 3 {np.pi * R**2!r}\n4 4 {c44!r}\n5 5 {c44!r}\n")
    (folder / "cyl.cfg").write_text("IPEROUT=1\n")
    if source == "frc":
        (folder / "cyl.pot").write_text("cyl.pot\n0.0\n1 1\n2\n8.0 4.0\n1\n0.0\n1\ncyl.gdf\n0 0 0 0\n1 1 1 1 1 1\n")
        (folder / "cyl.frc").write_text(f"cyl.frc\n1 0 1 0 0 0 0 0 0\n{vcg!r}\n0 0 0\n0 0 0\n0 0 0\n0\n0\n")
    else:
        (folder / "cyl.out").write_text("\n".join([
            " Input from Geometric Data Files:", "                               N=  1     cyl.gdf", "",
            f" Gravity:     {G:.5f}                Length scale:        1.00000",
            " Water depth:        infinite", "",
            " XBODY =    0.0000 YBODY =    0.0000 ZBODY =    0.0000 PHIBODY =   0.0",
            f" Volumes (VOLX,VOLY,VOLZ):           {volume:.6f}      {volume:.6f}      {volume:.6f}",
            f" Center of Buoyancy (Xb,Yb,Zb):     0.000000     0.000000    {zb:.6f}",
            f" Center of Gravity  (Xg,Yg,Zg):     0.000000     0.000000    {vcg:.6f}", ""]) + "\n")
    return stem


@pytest.mark.parametrize("source", ["frc", "out"])
def test_wamit_hst_gravity_terms_taken_out(tmp_path, source):
    """Before: a VCG = -5 m .hst was read as it is and the scene's gravity terms were added again
    (C44 +98 % here; RM3's spar pitch +46 %). Now the HDB's stiffness is buoyancy and waterplane only,
    rho g (pi R^4/4 + V z_b), the same with VCG 0 and -5; with the scene's gravity (m = rho V, centre
    of gravity at VCG) the total is rho g V GM, GM = KB + BM - KG (BM = R^2 / (4 DRAFT))."""
    from hydrolink.server.hydrostatics import total_stiffness
    volume = np.pi * R**2 * DRAFT
    hydro = RHO * G * (np.pi * R**4 / 4 - volume * DRAFT / 2)
    stated = {"gravity": G, "ulen": 1.0, "volume": [volume]} if source == "frc" else {}
    for vcg in (0.0, -5.0):
        ds = load_hdb(_cylinder_run(tmp_path / f"{source}{vcg}", vcg, source), rho=RHO, wamit=stated)
        k = ds["hydrostatic_stiffness"].values
        assert k[2, 2] == pytest.approx(RHO * G * np.pi * R**2, rel=1e-12)
        assert k[3, 3] == pytest.approx(hydro, rel=1e-6) and k[4, 4] == pytest.approx(hydro, rel=1e-6)
        total = total_stiffness(k, np.array([RHO * volume]), np.array([[0, 0, vcg]]), ds["reference_point"].values, G)
        gm = DRAFT / 2 + R**2 / (4 * DRAFT) - (DRAFT + vcg)
        assert total[3, 3] == pytest.approx(RHO * G * volume * gm, rel=1e-6)
        assert total[4, 4] == pytest.approx(RHO * G * volume * gm, rel=1e-6)


def test_wamit_vcg_without_volume_names_the_key(tmp_path):
    stem = _cylinder_run(tmp_path / "run", -5.0, "frc")
    err = _error(stem, wamit={"gravity": G, "ulen": 1.0})
    assert err.field == "wamit.volume" and "-m g VCG terms" in err.why


# ---------------------------------------------------------------- Capytaine layout: headings' units

def test_capytaine_headings_unit_from_attributes(reference_data, tmp_path, rm3_capytaine):
    """The RM3 file with its heading written as 30 (before: read as 30 rad, listed as 1719 deg):
    units "degrees" -> pi/6 with the same forces; in a radian field (units "rad" or none) 30 is
    more than 2 pi: refused, naming the field and the way out."""
    with xr.open_dataset(reference_data / "rm3_capytaine" / "rm3_hydrodynamics.nc") as raw:
        base = raw.load()

    def variant(name: str, units: str | None) -> Path:
        attrs = {k: v for k, v in base["wave_direction"].attrs.items() if k != "units"}
        if units is not None:
            attrs["units"] = units
        ds = base.assign_coords(wave_direction=xr.DataArray([30.0], dims="wave_direction", attrs=attrs))
        ds.to_netcdf(tmp_path / name)
        return tmp_path / name

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)  # rotation centre not recorded in this file
        ds = load_hdb(variant("deg.nc", "degrees"))
    np.testing.assert_allclose(ds["wave_direction"].values, [np.pi / 6], rtol=1e-15)
    np.testing.assert_array_equal(ds["excitation_force"].values, rm3_capytaine["excitation_force"].values)
    for units, said in (("rad", "units = 'rad'"), (None, "no units attribute")):
        err = _error(variant(f"rad{units}.nc", units))
        assert err.field == "wave_direction" and "30 is more than 2 pi in a field in radians" in err.why
        assert said in err.why and 'units to "degrees"' in err.why
    err = _error(variant("grad.nc", "grad"))
    assert err.field == "wave_direction.units"


def test_wamit_file_set_read_with_the_scene_statement(reference_data, tmp_path, rm3_wamit):
    """Sent by content (run --hdb-files): the .pot/.frc travel in the set, the server reads it with
    the scene's statement (session.py passes Scene.wamit_statement) and the scene's density; the
    same HDB as the full set's at 1025 kg/m^3. Without the statement: the error names the keys."""
    from hydrolink.server.hdb.io import file_set
    from hydrolink.server.hdb.file_set import FileSetReader
    from hydrolink.server.hdb.store import ContentStore
    from hydrolink.protocol.codec import ProtocolError
    stem = _copy_wamit(reference_data, tmp_path, exts=(".1", ".3", ".hst", ".pot", ".frc"))
    files = file_set(stem, rho=1025.0)
    assert [p.name for p in files.paths] == ["rm3.1", "rm3.3", "rm3.hst", "rm3.pot", "rm3.frc"]
    reader = FileSetReader(ContentStore(None))
    ds = reader.read(files.entry(inline=True), 'hdbs["rm3.1"]', None, {**RM3_STATED, "excitation_needed": True})
    assert ds.attrs["rho"] == 1025.0
    np.testing.assert_array_equal(ds["reference_point"].values, rm3_wamit["reference_point"].values)
    np.testing.assert_allclose(ds["added_mass"].values, 1.025 * rm3_wamit["added_mass"].values, rtol=1e-15)
    with pytest.raises(ProtocolError) as info:
        reader.read(files.entry(inline=True), 'hdbs["rm3.1"]', None, {"excitation_needed": True})
    assert info.value.field == 'hdbs["rm3.1"].files["rm3.1"].wamit'
    assert "the run's ULEN, g, IPEROUT are stated by no file" in info.value.message


def test_scene_wamit_table_is_the_runs():
    """bodies[i].wamit: only with hdb; the bodies of one HDB state the same table (or one does);
    keys checked like every scene key."""
    from conftest import body, scene_toml
    from hydrolink.protocol.scene import SceneError, parse_scene

    def scene(*bodies):
        return parse_scene(scene_toml(dt=0.1, duration=1.0, bodies=list(bodies)))

    def wet(name, **keys):
        return body(name, hdb="run.1", mass=1.0, center_of_mass=None, inertia=None, dofs=["heave"], **keys)

    table = {"ulen": 2.0, "depth": "inf", "xbody": [[0, 0, 0], [5, 0, 0]], "iperout": 2}
    ok = scene(wet("a", wamit=table), wet("b", hdb_body="body2"))
    assert ok.wamit_statement("run.1") == {**table, "excitation_needed": False}
    with pytest.raises(SceneError, match=r"bodies\[1\]\.wamit: differs from another body's wamit for the same HDB"):
        scene(wet("a", wamit=table), wet("b", wamit={**table, "ulen": 1.0}))
    with pytest.raises(SceneError, match=r"bodies\[0\]\.wamit: needs hdb"):
        scene(body("a", mass=1.0, center_of_mass=[0, 0, 0], inertia=None, dofs=["heave"], wamit=table))
    with pytest.raises(SceneError, match=r"bodies\[0\]\.wamit\.iperout"):
        scene(wet("a", wamit={"iperout": 4}))
    with pytest.raises(SceneError, match=r"bodies\[0\]\.wamit\.ulen"):
        scene(wet("a", wamit={"ulen": -1.0}))


def test_wamit_file_set_within_the_protocols_16_files(tmp_path):
    """A run with every file the reader may use (.pot/.mmx/.frc now among them), three drift files and
    three QTF levels of each kind: the set holds the QTF level the reader reads (the most complete),
    so it stays within SPEC §5.1's 16 files."""
    from hydrolink.server.hdb.io import file_set
    from hydrolink.server.hdb.file_set import MAX_FILES
    suffixes = (".1", ".3", ".hst", ".out", ".cfg", ".pot", ".mmx", ".frc", ".7", ".8", ".9",
                ".10d", ".11d", ".12d", ".10s", ".11s", ".12s")
    for s in suffixes:
        (tmp_path / f"run{s}").write_text("x\n")
    names = [p.name for p in file_set(tmp_path / "run.1").paths]
    assert len(names) <= MAX_FILES < len(suffixes)
    assert {n for n in names if n[-1] in "ds"} == {"run.12d", "run.12s"}
    (tmp_path / "run.12d").unlink()
    assert {n for n in file_set(tmp_path / "run.1").paths if n.name[-1] in "ds"} == {tmp_path / "run.11d",
                                                                                   tmp_path / "run.12s"}


def test_scene_wamit_table_on_another_format_is_refused(reference_data, tmp_path):
    """A [bodies.wamit] table on a body whose HDB is not a WAMIT run: an error, not ignored."""
    from conftest import SPHERE_WATER, scene_toml, sphere_body, write_scene
    from hydrolink.clients.scene_inputs import load_scene_hdbs
    from hydrolink.protocol.scene import load_scene
    path = write_scene(tmp_path, scene_toml(dt=0.1, duration=1.0, water=SPHERE_WATER, bodies=[sphere_body(
        str(reference_data / "sphere_task10" / "sphere.h5"), mass=261.8e3, wamit={"ulen": 1.0})]))
    with pytest.raises(HDBError, match=r"sphere\.h5: wamit: only for a WAMIT run's files"):
        load_scene_hdbs(load_scene(path)[0], path, progress=False)


def test_wamit_frc_of_another_form(reference_data, tmp_path, rm3_wamit):
    """An .frc of alternative form 2 (RHO, XCG YCG ZCG, IMASS, ...) read as form 1: an error naming the
    file and the way out; IALTFRC = 2 in the .cfg: not read for VCG (the .out states it), the HDB is
    the full set's; IALTFRC = 2 with a VCG != 0 is refused (its .hst's gravity terms use a mass not read)."""
    stem = _copy_wamit(reference_data, tmp_path, exts=(".1", ".3", ".hst", ".pot"))
    (tmp_path / "rm3.frc").write_text("rm3.frc\n1 0 1 0 0 0 0 0 0\n1000.0\n0 0 -5\n1\n" + "1 0 0 0 0 0\n" * 6)
    err = _error(stem, wamit=RM3_STATED)
    assert err.source == "rm3.frc" and err.field == "VCG" and "IALTFRC = 2 or 3" in err.why
    (tmp_path / "rm3.cfg").write_text("IALTFRC=2\n")
    shutil.copy(reference_data / "rm3_wamit" / "rm3.out", tmp_path / "rm3.out")
    _same_as(load_hdb(stem), rm3_wamit)
    err = _error(stem, wamit={"vcg": [0.0, -5.0]})
    assert err.source == "rm3.out" and err.field == "VCG"      # the .out states VCG 0: contradicted
    (tmp_path / "rm3.out").unlink()
    err = _error(stem, wamit={**RM3_STATED, "vcg": [0.0, -5.0], "volume": [725.833, 886.687]})
    assert err.source == "rm3.cfg" and err.field == "IALTFRC" and "only IALTFRC = 1" in err.why


def test_generalized_modes_of_bemio_and_capytaine_files_are_read_after_the_rigid_six(reference_data, tmp_path):
    """Issue 38: a body with more than six DOFs reads as its rigid six then its generalized modes.
    BEMIO: the sphere's file as 6 + 4 DOFs (properties/dof = 10; the modes' added mass, damping,
    stiffness and excitation set to known values, the rigid block the file's), named mode1..mode4;
    Capytaine: RM3's file with two flexible radiating DOFs added to the float (copies of its heave
    row and column), read by the file's names after the float's six, the spar's block where it was."""
    bemio = tmp_path / "sphere10.h5"
    shutil.copy(reference_data / "sphere_task10" / "sphere.h5", bemio)
    rigid = load_hdb(reference_data / "sphere_task10" / "sphere.h5")
    known = np.arange(7.0, 11.0)
    with h5py.File(bemio, "r+") as f:
        f["body1/properties/dof"][...] = 10.0
        n_w = f["simulation_parameters/w"].size
        for name, unit in (("added_mass/all", 1.0), ("radiation_damping/all", 0.1)):
            new = np.zeros((10, 10, n_w))
            new[:6, :6] = f[f"body1/hydro_coeffs/{name}"][()]
            new[range(6, 10), range(6, 10)] = unit * known[:, None]
            del f[f"body1/hydro_coeffs/{name}"]
            f[f"body1/hydro_coeffs/{name}"] = new
        for part, value in (("re", 1.0), ("im", 0.5)):
            old = f[f"body1/hydro_coeffs/excitation/{part}"][()]
            del f[f"body1/hydro_coeffs/excitation/{part}"]
            f[f"body1/hydro_coeffs/excitation/{part}"] = np.concatenate([old, np.full((4, *old.shape[1:]), value)])
        k = f["body1/hydro_coeffs/linear_restoring_stiffness"][()]
        del f["body1/hydro_coeffs/linear_restoring_stiffness"]
        f["body1/hydro_coeffs/linear_restoring_stiffness"] = np.pad(k, (0, 4)) + np.diag(np.r_[np.zeros(6), 10 * known])
        if "body1/hydro_coeffs/added_mass/inf_freq" in f:
            del f["body1/hydro_coeffs/added_mass/inf_freq"]
    ds = load_hdb(bemio)
    rho, g = ds.attrs["rho"], ds.attrs["g"]
    body = str(ds["body"].values[0])
    assert [str(v) for v in ds["influenced_dof"].values][6:] == [f"{body}.mode{k}" for k in range(1, 5)]
    np.testing.assert_array_equal(ds["added_mass"].values[:, :6, :6], rigid["added_mass"].values)
    np.testing.assert_allclose(ds["added_mass"].values[:, range(6, 10), range(6, 10)], rho * np.tile(known, (n_w, 1)))
    np.testing.assert_allclose(ds["radiation_damping"].values[:, range(6, 10), range(6, 10)],
                               rho * ds["omega"].values[:, None] * 0.1 * known)
    np.testing.assert_allclose(np.diag(ds["hydrostatic_stiffness"].values)[6:], rho * g * 10 * known)
    np.testing.assert_allclose(ds["excitation_force"].values[..., 6:], rho * g * (1.0 - 0.5j))   # exp(-iwt)
    with h5py.File(bemio, "r+") as f:
        f["body1/properties/dof"][...] = 9.5
    with pytest.raises(HDBError, match=r"sphere10\.h5: body1/properties/dof: 9\.5 DOFs for this body: must be a whole"):
        load_hdb(bemio)

    with xr.open_dataset(reference_data / "rm3_capytaine" / "rm3_hydrodynamics.nc") as raw:
        ds = raw.load()
    flex = ["rm3_float__Flex1", "rm3_float__Flex2"]
    cols = xr.concat([ds, ds.isel(radiating_dof=[2, 2]).assign_coords(radiating_dof=flex)], dim="radiating_dof",
                     data_vars="minimal", coords="minimal", compat="override")
    both = xr.concat([cols, cols.isel(influenced_dof=[2, 2]).assign_coords(influenced_dof=flex)],
                     dim="influenced_dof", data_vars="minimal", coords="minimal", compat="override")
    names = [str(v) for v in ds["radiating_dof"].values]
    order = [*names[:6], *flex, *names[6:]]
    both.sel(radiating_dof=order, influenced_dof=order).to_netcdf(tmp_path / "rm3_flex.nc")
    out = load_hdb(tmp_path / "rm3_flex.nc")
    plain = load_hdb(reference_data / "rm3_capytaine" / "rm3_hydrodynamics.nc")
    labels = [str(v) for v in out["influenced_dof"].values]
    assert labels[6:8] == ["float.Flex1", "float.Flex2"]
    assert labels[8:] == [str(v) for v in plain["influenced_dof"].values[6:]]
    keep = [*range(6), *range(8, 14)]
    np.testing.assert_array_equal(out["added_mass"].values[:, keep][:, :, keep], plain["added_mass"].values)
    np.testing.assert_array_equal(out["added_mass"].values[:, 6, 7], plain["added_mass"].values[:, 2, 2])
    np.testing.assert_array_equal(out["excitation_force"].values[..., 7], plain["excitation_force"].values[..., 2])
    np.testing.assert_array_equal(out["hydrostatic_stiffness"].values[keep][:, keep], plain["hydrostatic_stiffness"].values)
