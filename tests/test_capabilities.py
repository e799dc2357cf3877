"""Capabilities declared once (protocol/capabilities.py): every (feature, tool) pair either runs —
the tool takes the feature's forces — or is refused by the tool's own entry point before anything
runs, naming the feature's key and the tool. Nothing is dropped silently."""

from __future__ import annotations

import itertools
import re
from pathlib import Path

import numpy as np
import pytest
import xarray as xr

from conftest import SPHERE_WATER, regular_waves, scene_toml, sphere_body, write_gdf, write_scene

from hydrolink.protocol.capabilities import FEATURES, TOOLS, reply_fields
from hydrolink.protocol.reply import OPTIONAL_FORCES, reply_field
from hydrolink.protocol.scene import SceneError, parse_scene
from hydrolink.server.hydro_states import hydro_model, state_datasets
from hydrolink.server.model import HydroModel
from hydrolink.server.terms.hulls import closed_hull

cpt = pytest.importorskip("capytaine")

MASS = 261.8e3
MEMBER = {"body": "sphere", "point_a": [0.0, 0.0, -20.0], "point_b": [0.0, 0.0, -6.0], "diameter": 2.0,
          "cd": 1.0, "ca": 1.0, "segments": 4}
#: feature -> (body keys, scene sections) that turn it on, and the key a refusal must name
USES: dict[str, tuple[dict, dict, str]] = {
    "linear_damping": ({"linear_damping": [0, 0, 2e4, 0, 0, 0]}, {}, "bodies[0].linear_damping"),
    "quadratic_damping": ({"quadratic_damping": [0, 0, 8e4, 0, 0, 0]}, {}, "bodies[0].quadratic_damping"),
    "drag": ({"drag": {"cd": [0, 0, 1.0, 0, 0, 0], "area": [0, 0, 78.5, 0, 0, 0], "relative": True}}, {},
             "bodies[0].drag"),
    "morison": ({}, {"morison": [MEMBER]}, "morison[0]"),
    "nonlinear_hydrostatics": ({"nonlinear": "hydrostatic", "mesh": "sphere.gdf"}, {}, "bodies[0].nonlinear"),
    "nonlinear_froude_krylov": ({"nonlinear": "froude-krylov", "mesh": "sphere.gdf"}, {}, "bodies[0].nonlinear"),
    "second_order": ({}, {"hydro": {"second_order": "mean-drift"}}, "hydro.second_order"),   # on sphere_drift
    "passive_yaw": ({"passive_yaw": True}, {}, "bodies[0].passive_yaw"),                       # on sphere_headings
    "generalized_modes": ({"modes": {"names": ["breathe"], "mass": [2e4], "stiffness": [5e5]}}, {},
                          "bodies[0].modes"),                                                     # on sphere_modes
    # a second state with the sphere's own HDB (its path filled in by scene_text), entered at 0.2 s
    "hydro_states": ({"hydro_state": "first", "hydro_states": [{"name": "second"}]},
                     {"hydro_switches": [{"body": "sphere", "state": "second", "time": 0.2}]}, "bodies[0].hydro_states"),
    # the panel set of a coarse sphere build (its path filled in by scene_text)
    "sectional_loads": ({"sections": {"stations": [0.0], "mass_stations": [-5.0, 5.0], "mass_per_length": [MASS / 10]}},
                        {}, "bodies[0].sections"),
    "panel_pressures": ({"pressure_output": True}, {}, "bodies[0].pressure_output"),
}
PANELS = """
panel_pressures = true
[body]
name = "sphere"
shape = "sphere"
radius = 5.0
panel_size = 2.0
[frequencies]
values = [0.6, 1.2]
[water]
density = 1000.0
depth = 200.0
"""
FMU_CLIENT = {"type": "fmu", "fmu": "heave.fmu", "bodies": {"sphere": {
    "position": {"heave": "z"}, "velocity": {"heave": "v"}, "force": {"heave": "F"}}}}


def scene_text(sphere_path: Path, feature: str, *, fmu: bool = False, panels: Path | None = None) -> str:
    body_keys, sections, _ = USES[feature]
    if panels is not None and feature in ("sectional_loads", "panel_pressures"):
        body_keys = {**body_keys, "panel_pressures": str(panels)}
    if feature == "hydro_states":
        body_keys = {**body_keys, "hydro_states": [{**s, "hdb": str(sphere_path)} for s in body_keys["hydro_states"]]}
    client, dofs = FMU_CLIENT, ["heave"]
    if feature == "passive_yaw":   # the FMU's body turns too (a passive-yaw body needs its yaw DOF)
        dofs = ["heave", "yaw"]
        client = {**FMU_CLIENT, "bodies": {"sphere": {key: {**ports, "yaw": f"{ports['heave']}_yaw"} for key, ports
                                                      in FMU_CLIENT["bodies"]["sphere"].items()}}}
    return scene_toml(dt=0.1, duration=0.5, water=SPHERE_WATER, waves=regular_waves(0.5, 7.0),
                      bodies=[sphere_body(str(sphere_path), mass=MASS, **({"dofs": dofs} if fmu else {}),
                                          **body_keys)],
                      client=client if fmu else None, **sections)


@pytest.fixture(scope="module")
def hull(tmp_path_factory) -> tuple[Path, np.ndarray, np.ndarray]:
    """The sphere's closed hull as a GDF file (for the nonlinear features)."""
    mesh = cpt.mesh_sphere(radius=5.0, resolution=(10, 20))
    mesh = mesh.merged() if hasattr(mesh, "merged") else mesh
    folder = tmp_path_factory.mktemp("hull")
    return write_gdf(folder / "sphere.gdf", mesh.vertices, mesh.faces), mesh.vertices, mesh.faces


def test_every_feature_is_reported_with_its_key(sphere_path):
    assert set(USES) == set(FEATURES)
    for feature, (_, _, key) in USES.items():
        scene = parse_scene(scene_text(sphere_path, feature))
        assert scene.features()[feature] == key
        assert set(FEATURES[feature].reply_fields) <= set(reply_fields(scene)) <= set(OPTIONAL_FORCES)
    assert parse_scene(scene_toml(dt=0.1, duration=0.5, bodies=[sphere_body(str(sphere_path), mass=MASS)])
                       ).features() == {}


def test_each_tool_names_a_known_feature():
    for tool in TOOLS.values():
        assert tool.supports <= set(FEATURES) and tool.name
        assert tool.supports == set(FEATURES) or "{tool}" in tool.refusal


@pytest.fixture(scope="module")
def sphere_drift(sphere, tmp_path_factory) -> tuple[xr.Dataset, Path]:
    """The sphere's HDB with a momentum mean drift T(w) = 1e3 (w / 1 rad/s)^2 N/m^2 in surge
    (the second_order feature needs drift data)."""
    from hydrolink.protocol.hdb.schema import to_netcdf
    from hydrolink.protocol.hdb.second_order import MeanDrift
    from hydrolink.protocol.hdb.schema import with_second_order
    w = sphere["omega"].values
    values = np.zeros((1, w.size, 1, 6))
    values[0, :, 0, 0] = 1e3 * w ** 2
    ds = with_second_order(sphere, mean_drift=MeanDrift(("momentum",), w, np.zeros(1), values))
    path = tmp_path_factory.mktemp("drift") / "sphere_drift.nc"
    to_netcdf(ds, path)
    return ds, path


@pytest.fixture(scope="module")
def sphere_modes(sphere, tmp_path_factory) -> tuple[xr.Dataset, Path]:
    """The sphere's HDB with one generalized mode "breathe" after its six DOFs (the generalized_modes
    feature needs one): its own added mass, damping, stiffness and excitation, uncoupled."""
    from hydrolink.protocol.hdb.schema import make_hdb, to_netcdf

    def grow(a: np.ndarray, diagonal: float) -> np.ndarray:
        out = np.zeros(a.shape[:-2] + (7, 7))
        out[..., :6, :6], out[..., 6, 6] = a, diagonal
        return out
    x = sphere["excitation_force"].values
    ds = make_hdb(bodies=["sphere"], omega=sphere["omega"].values, wave_direction=sphere["wave_direction"].values,
                  added_mass=grow(sphere["added_mass"].values, 1e4),
                  radiation_damping=grow(sphere["radiation_damping"].values, 2e3),
                  excitation_force=np.concatenate((x, 0.1 * x[..., 2:3]), axis=-1),
                  hydrostatic_stiffness=grow(sphere["hydrostatic_stiffness"].values, 1e5),
                  reference_point=sphere["reference_point"].values, rho=float(sphere.attrs["rho"]),
                  g=float(sphere.attrs["g"]), water_depth=float(sphere.attrs["water_depth"]),
                  source="the Task-10 sphere with a breathing mode", modes={"sphere": ["breathe"]})
    path = tmp_path_factory.mktemp("modes") / "sphere_modes.nc"
    to_netcdf(ds, path)
    return ds, path


@pytest.fixture(scope="module")
def sphere_panels(tmp_path_factory) -> Path:
    """A coarse Capytaine build of the sphere with its panel pressures (the loads' features need one)."""
    from hydrolink.server.hdb.build.builder import build_hdb
    folder = tmp_path_factory.mktemp("panels")
    (folder / "sphere_panels.toml").write_text(PANELS)
    return Path(build_hdb(folder / "sphere_panels.toml", cache_dir=folder / "cache", progress=False).attrs[
        "panel_pressure_file"])


@pytest.fixture(scope="module")
def sphere_headings(sphere, tmp_path_factory) -> tuple[xr.Dataset, Path]:
    """The sphere's HDB at 12 headings around the circle (the passive_yaw feature needs them): the
    sphere is symmetric about its vertical axis through its reference point, the origin, so the wave
    from beta gives the force of 0 turned by beta."""
    from hydrolink.protocol.hdb.schema import to_netcdf
    b = np.deg2rad(np.arange(0.0, 360.0, 30.0))
    x0 = sphere["excitation_force"].isel(wave_direction=0).values          # (n_w, 6)
    x = np.repeat(x0[:, None, :], b.size, axis=1)
    for a, c in ((0, 1), (3, 4)):
        x[:, :, a] = np.cos(b) * x0[:, None, a] - np.sin(b) * x0[:, None, c]
        x[:, :, c] = np.sin(b) * x0[:, None, a] + np.cos(b) * x0[:, None, c]
    ds = sphere.drop_dims("wave_direction").assign_coords(wave_direction=b)
    ds = ds.assign(excitation_force=(("omega", "wave_direction", "influenced_dof"), x))
    path = tmp_path_factory.mktemp("headings") / "sphere_headings.nc"
    to_netcdf(ds, path)
    return ds, path


def _model(sphere, sphere_path: Path, feature: str, hull) -> HydroModel:
    _, vertices, faces = hull
    scene = parse_scene(scene_text(sphere_path, feature))
    return hydro_model(scene, {"sphere": sphere}, state_datasets(scene, {str(sphere_path): sphere}),
                       hulls={"sphere": closed_hull(vertices, faces)})


def _refusal(tool: str, scene_path: Path, text: str, tmp_path: Path) -> Exception:
    """Call the tool's own entry point on the scene and return what it raised."""
    scene = parse_scene(text)
    with pytest.raises(Exception) as err:
        if tool == "fmu_master":                # refused by the shared preflight: nothing stepped
            from hydrolink.clients.fmu.master import run
            from hydrolink.clients.lockstep.results import ResultWriter
            with ResultWriter(tmp_path / "refused.nc", scene=scene, scene_text=text) as writer:
                run(scene, text, None, None, writer)
        elif tool == "steady":
            from hydrolink.clients.analysis.steady import check_scene
            check_scene(scene)
        elif tool == "linearize":
            from hydrolink.clients.analysis.plant import check_plant_scene
            check_plant_scene(scene)
        elif tool == "native_fmu":
            from hydrolink.clients.fmu.native import export_native_fmu
            export_native_fmu(scene_path, tmp_path / "x.fmu")
        elif tool == "python_fmu":
            from hydrolink.clients.fmu.export import export_fmu
            export_fmu(scene_path, tmp_path / "x.fmu")
        else:
            raise AssertionError(f"no entry point for {tool} in this test")
    return err.value


def _runs(tool: str, feature: str, sphere, sphere_path: Path, hull, tmp_path: Path, panels: Path | None = None) -> None:
    """The tool takes the feature's forces (what each tool does with them, checked on the tool)."""
    fields = FEATURES[feature].reply_fields
    if tool == "exudyn":                     # a short run: the forces' results variables are written
        from hydrolink.clients.run import run_scene_file
        path = write_scene(hull[0].parent, scene_text(sphere_path, feature, panels=panels), f"{feature}.toml")
        run_scene_file(path, tmp_path / "out.nc", progress=False)
        ds = xr.load_dataset(tmp_path / "out.nc")
        if feature == "sectional_loads":
            assert np.isfinite(ds["section_moment"].values).all() and ds["section_moment"].shape[1:] == (1, 3)
        if feature == "panel_pressures":
            assert np.isfinite(xr.load_dataset(tmp_path / "out.pressures.nc")["pressure"].values).all()
        for f in fields:
            for v in reply_field(f).variables:
                assert ds[v.name].dims[1:] == v.dims and np.isfinite(ds[v.name].values).all(), v.name
        if fields:
            assert np.abs(ds[reply_field(fields[-1]).variables[0].name].values[1:]).max() > 0
    elif tool == "steady":                   # the server's terms of the scene are evaluated pointwise
        from hydrolink.clients.analysis.steady import check_scene
        check_scene(parse_scene(scene_text(sphere_path, feature)))
        model = _model(sphere, sphere_path, feature, hull)
        assert model.terms and all(t.steady is not None for t in model.terms)
    elif tool == "linearize":                # the plant is built, its term in it
        from hydrolink.clients.analysis.plant import build_plant, check_plant_scene
        scene = parse_scene(scene_text(sphere_path, feature))
        check_plant_scene(scene)
        plant = build_plant(scene, {b.hdb: sphere for b in scene.bodies if b.wet})
        assert np.isfinite(plant.A).all() and np.isfinite(plant.B).all()
    elif tool == "native_fmu":               # the C core adds these reply fields to its force output
        from hydrolink.clients.fmu.native import SOURCES
        source = (SOURCES / "hydro_core.c").read_text()
        listed = re.search(r"more\[\d+\] = \{([^}]*)\}", source).group(1)
        assert set(fields) <= set(re.findall(r'"(\w+)"', listed))
    elif tool == "python_fmu":               # the slave adds every optional force to its force output
        from hydrolink.clients.fmu import slave
        assert "self._optional" in Path(slave.__file__).read_text() and set(fields) <= set(OPTIONAL_FORCES)
    elif tool == "save_restore":             # a rollback repeats the steps bit for bit, these fields included
        model = _model(sphere, sphere_path, feature, hull)
        eq = model.setup_info().equilibrium_position
        x, v = eq + [[0, 0, 0.3, 0, 0, 0]], np.array([[0, 0, 0.2, 0, 0, 0]])
        m = model.modes.size    # generalized modes: their state too
        modal = lambda k: {"modal_position": np.full(m, 0.1), "modal_velocity": np.full(m, 0.1 * k)} if m else {}  # noqa: E731
        model.step(0.0, x, v, **modal(0))
        saved = model.state()
        first = [model.step(k * model.dt, x, v * k, **modal(k)) for k in (1, 2)]
        model.set_state(saved)
        again = [model.step(k * model.dt, x, v * k, **modal(k)) for k in (1, 2)]
        for a, b in zip(first, again):
            for f in fields + (("modal_radiation",) if m else ()):
                np.testing.assert_array_equal(a[f], b[f])
    else:
        raise AssertionError(f"no check for {tool} in this test")


@pytest.mark.parametrize("feature,tool", list(itertools.product(FEATURES, TOOLS)))
def test_every_feature_tool_pair_runs_or_is_refused_with_its_key(feature, tool, sphere, sphere_path, sphere_drift,
                                                                 sphere_headings, sphere_modes, hull, tmp_path, request):
    if feature == "second_order":    # its data: the sphere's HDB with mean drift coefficients
        sphere, sphere_path = sphere_drift
    if feature == "passive_yaw":     # its data: the sphere's HDB at headings around the circle
        sphere, sphere_path = sphere_headings
    if feature == "generalized_modes":   # its data: the sphere's HDB with a mode
        sphere, sphere_path = sphere_modes
    t = TOOLS[tool]
    if feature in t.supports:
        panels = request.getfixturevalue("sphere_panels") if feature in ("sectional_loads", "panel_pressures") \
            and tool == "exudyn" else None
        _runs(tool, feature, sphere, sphere_path, hull, tmp_path, panels)
        return
    text = scene_text(sphere_path, feature, fmu=tool == "fmu_master")
    scene_path = write_scene(hull[0].parent, text, f"{tool}-{feature}.toml")
    err = _refusal(tool, scene_path, text, tmp_path)
    key = USES[feature][2]
    assert getattr(err, "key", None) == key, err
    assert t.name in str(err) and key in str(err)
    if tool == "fmu_master":
        assert xr.open_dataset(tmp_path / "refused.nc").attrs["status"].startswith("refused: ")
