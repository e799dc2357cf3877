"""HDB readers (WAMIT, BEMIO, Capytaine, hydrolink NetCDF) against independent reference numbers."""

from __future__ import annotations

import shutil
import warnings
from pathlib import Path

import h5py
import numpy as np
import pytest
import xarray as xr

from hydrolink.server.hdb.capytaine_io import from_capytaine_dataset, read_capytaine, short_body_names
from hydrolink.server.hdb.io import load_hdb
from hydrolink.protocol.hdb_schema import HDBError, to_netcdf
from hydrolink.server.hdb.wamit import read_wamit

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
    labels[0] = "rm3_float__Bending"
    raw = raw.assign_coords(radiating_dof=labels, influenced_dof=labels)
    with pytest.raises(HDBError) as info:
        from_capytaine_dataset(raw, "rm3.nc")
    assert info.value.field in ("influenced_dof", "radiating_dof") and "Bending" in info.value.why


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
    with pytest.warns(UserWarning, match=r"read as exp\(-iwt\) \(stated \(hdb_convention\)\), but .* fit exp\(\+iwt\)"):
        silent = load_hdb(wot, convention="exp(-iwt)")
    assert np.abs(_heave_force(silent) - ref).max() > 0.1 * np.abs(ref).max()   # what a wrong read costs
    stated = load_hdb(wot, convention="exp(+iwt)")
    np.testing.assert_allclose(_heave_force(stated), ref, rtol=1e-12, atol=1e-9 * np.abs(ref).max())
    declared = _rewrite(capytaine_buoy, tmp_path / "declared.nc", conj=every, attrs={"time_convention": "exp(+iwt)"})
    np.testing.assert_allclose(_heave_force(load_hdb(declared)), ref, rtol=1e-12, atol=1e-9 * np.abs(ref).max())
    with pytest.raises(HDBError, match=r"the file declares exp\(\+iwt\), the scene states exp\(-iwt\)"):
        load_hdb(declared, convention="exp(-iwt)")
    half = _rewrite(capytaine_buoy, tmp_path / "half.nc", conj=("Froude_Krylov_force", "diffraction_force"))
    with pytest.warns(UserWarning, match="are the complex conjugates of its excitation_force"):
        load_hdb(half)
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
