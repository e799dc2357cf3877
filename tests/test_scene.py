"""Scene files: valid ones parse with their defaults; every error names the file, the key and why."""

from __future__ import annotations

import math

import numpy as np
import pytest

from conftest import body, joint, regular_waves, scene_toml, write_scene

from hydrolink.protocol.scene import SceneError, load_scene, parse_scene, resolve_path

FLOAT = body("float", hdb="float.nc", mass=1000.0, center_of_mass=[0, 0, -1], inertia=[1, 1, 1], dofs=["heave"])
# the error cases below edit this text: each edit must hit (they assert the text changed)
BASE = scene_toml(dt=0.01, duration=10.0, waves=regular_waves(0.2, 4.0), bodies=[FLOAT])


def test_valid_scene_and_defaults():
    s = parse_scene(BASE)
    assert s.simulation.n_steps == 1000
    assert s.water.density == 1025.0 and math.isinf(s.water.depth_m)
    assert s.hydro.irf_duration == 40.0
    b = s.bodies[0]
    assert b.active_mask == [False, False, True, False, False, False]
    assert b.hdb_body_name == "float"
    assert b.initial_displacement == [0.0] * 6


def test_full_inertia_matrix_accepted():
    s = parse_scene(BASE.replace("inertia = [1, 1, 1]", "inertia = [[2, 0.1, 0], [0.1, 2, 0], [0, 0, 3]]"))
    assert s.bodies[0].inertia_matrix[0, 1] == 0.1


@pytest.mark.parametrize("old,new,key,why", [
    ("dt = 0.01", "dt = -1.0", "simulation.dt", "greater than 0"),
    ("duration = 10.0", "duration = nan", "simulation.duration", "finite"),
    ("period = 4.0", "period = 4.0\ncolour = 1", "waves.colour", "unknown key"),
    ('type = "regular"', 'type = "tsunami"', "waves.type", "one of"),
    ("mass = 1000.0\n", "", "bodies[0].mass", "required key is missing"),
    ('dofs = ["heave"]', 'dofs = ["heav"]', "bodies[0].dofs[0]", "heave"),
    ('dofs = ["heave"]', 'dofs = ["heave", "heave"]', "bodies[0].dofs", "repeated"),
    ("inertia = [1, 1, 1]", "inertia = [[1, 2, 0], [0, 1, 0], [0, 0, 1]]", "bodies[0].inertia", "symmetric"),
    ("inertia = [1, 1, 1]", "inertia = [1, -1, 1]", "bodies[0].inertia", "positive definite"),
    ("center_of_mass = [0, 0, -1]", "center_of_mass = [0, 0]", "bodies[0].center_of_mass", "at least 3"),
    ('name = "float"', 'name = "my float"', "bodies[0].name", "pattern"),
])
def test_errors_name_key(old, new, key, why):
    text = BASE.replace(old, new)
    assert text != BASE
    with pytest.raises(SceneError) as info:
        parse_scene(text, "s.toml")
    msg = str(info.value)
    assert msg.startswith(f"s.toml: {key}:"), msg
    assert why in msg, msg


def test_duplicate_body_names():
    extra = scene_toml(dt=0.01, duration=10.0, waves=regular_waves(0.2, 4.0),
                       bodies=[FLOAT, body("float", hdb="x.nc", mass=1.0, center_of_mass=[0, 0, 0], inertia=[1, 1, 1])])
    with pytest.raises(SceneError, match=r"s.toml: bodies\[1\]\.name: duplicate body name 'float'"):
        parse_scene(extra, "s.toml")


def test_bad_toml_and_missing_file(tmp_path):
    with pytest.raises(SceneError, match="s.toml: not valid TOML"):
        parse_scene("dt = ", "s.toml")
    with pytest.raises(SceneError, match="cannot read the scene file"):
        load_scene(tmp_path / "nope.toml")


def test_missing_files_are_listed_with_the_schema_errors(tmp_path):
    """One SceneError lists the schema's problems and every input file the scene names that is not
    there (HDB, hull mesh, NEMOH QTF, elevation series, MoorDyn file, FMU), each by its key and its
    path; a WAMIT HDB named by its stem is there when its .1 is, and an HDB the caller already holds
    is not looked for."""
    (tmp_path / "here.nc").touch()
    (tmp_path / "wamit.1").touch()
    (tmp_path / "here.gdf").touch()
    wet = dict(mass=1.0, center_of_mass=[0, 0, 0], inertia=[1, 1, 1])
    bodies = [body("a", hdb="gone.nc", **wet, mesh="gone.gdf", qtf={"difference": "OUT_QTFM_N.dat", "frequency_unit": "rad/s",
                                                                     "convention": "exp(-iwt)"}),
              body("b", hdb="here.nc", **wet, mesh="here.gdf"),
              body("c", hdb="gone.nc", **wet),        # the same missing HDB: listed once
              body("d", hdb="wamit", **wet)]
    text = scene_toml(dt=-0.1, duration=1.0, bodies=bodies, waves={"type": "elevation", "file": "eta.csv", "colour": 1},
                      moorings=[{"name": "m", "type": "moordyn", "file": "lines.dat", "bodies": ["b"]}])
    path = write_scene(tmp_path, text)
    with pytest.raises(SceneError) as info:
        load_scene(path)
    lines = str(info.value).splitlines()
    schema = [f"{path}: simulation.dt:", f"{path}: waves.colour: unknown key"]
    files = [f"{path}: bodies[0].hdb: file not found: {tmp_path / 'gone.nc'}",
             f"{path}: bodies[0].mesh: file not found: {tmp_path / 'gone.gdf'}",
             f"{path}: bodies[0].qtf.difference: file not found: {tmp_path / 'OUT_QTFM_N.dat'}",
             f"{path}: waves.file: elevation file not found: {tmp_path / 'eta.csv'}",
             f"{path}: moorings[0].file: MoorDyn input file not found: {tmp_path / 'lines.dat'}"]
    for expected in schema + files:
        assert sum(line.startswith(expected) for line in lines) == 1, (expected, lines)
    assert len(lines) == len(schema + files), "\n".join(lines)   # nothing else: here.nc, here.gdf, wamit(.1) are there
    # the schema fixed: the files alone, the same list
    fixed = text.replace("dt = -0.1", "dt = 0.1").replace("colour = 1\n", "")
    assert fixed.count("dt = 0.1") == 1 and "colour" not in fixed
    path.write_text(fixed)
    with pytest.raises(SceneError) as info:
        load_scene(path)
    assert str(info.value).splitlines() == files
    # the HDB in hand (hydrolink run's hdbs=) is not looked for; without check_files nothing is
    with pytest.raises(SceneError) as info:
        load_scene(path, have_hdbs=["gone.nc"])
    assert str(info.value).splitlines() == files[1:]
    scene, _ = load_scene(path, check_files=False)
    assert [b.hdb for b in scene.bodies] == ["gone.nc", "here.nc", "gone.nc", "wamit"]
    # an FMU client's FMU, in a folder of the scene's
    fmu = write_scene(tmp_path, fmu_scene({**FMU_CLIENT, "fmu": "sub/wec.fmu"}), "fmu.toml")
    with pytest.raises(SceneError) as info:
        load_scene(fmu)
    assert str(info.value).splitlines() == [f"{fmu}: bodies[0].hdb: file not found: {tmp_path / 'f.nc'}",
                                            f"{fmu}: client.fmu: FMU not found: {tmp_path / 'sub' / 'wec.fmu'}"]


def test_relative_paths_resolve_against_scene(tmp_path):
    scene = tmp_path / "sub" / "scene.toml"
    assert resolve_path(scene, "float.nc") == (tmp_path / "sub" / "float.nc").resolve()
    assert resolve_path(scene, "/abs/x.nc").as_posix() == "/abs/x.nc"


FMU_CLIENT = {"type": "fmu", "fmu": "wec.fmu",
              "bodies": {"float": {"position": {"heave": "z"}, "velocity": {"heave": "v"}, "force": {"heave": "F"}}}}


def fmu_scene(client: dict, **sections) -> str:
    return scene_toml(dt=0.1, duration=1.0, client=client, **sections,
                      bodies=[body("float", hdb="f.nc", mass=1.0, center_of_mass=[0, 0, 0], inertia=[1, 1, 1],
                                   dofs=["heave"])])


@pytest.mark.parametrize("mode, scheme", [("auto", "auto"), ("parameters", "mass-matrix"),
                                          ("iterative", "implicit"), ("explicit", "explicit-predictor")])
def test_deprecated_fmu_coupling_is_read_as_the_one_vocabulary(mode, scheme, tmp_path, caplog):
    """[client.coupling] mode (FMU only, deprecated) becomes [coupling] scheme with its own values
    (its defaults too: tolerance 1e-6, explicit_limit 0.5), and loading the file says so."""
    client = {**FMU_CLIENT, "coupling": {"mode": mode, "max_iterations": 7}}
    path = tmp_path / "fmu.toml"
    path.write_text(fmu_scene(client))
    for name in ("f.nc", "wec.fmu"):   # the files the scene names (load_scene looks for them)
        (tmp_path / name).touch()
    scene, _ = load_scene(path)
    c = scene.coupling
    assert (c.scheme, c.tolerance, c.max_iterations, c.explicit_limit) == (scheme, 1e-6, 7, 0.5)
    assert f'client.coupling is deprecated: write [coupling] scheme = "{scheme}"' in caplog.text
    assert str(path) in caplog.text


def test_one_coupling_table_for_every_client():
    both = fmu_scene({**FMU_CLIENT, "coupling": {"mode": "iterative"}}, coupling={"scheme": "implicit"})
    with pytest.raises(SceneError, match=r"client.coupling: deprecated, and \[coupling\] is given too"):
        parse_scene(both)
    scene = parse_scene(fmu_scene(FMU_CLIENT, coupling={"scheme": "implicit", "tolerance": 1e-7}))
    assert scene.coupling.scheme == "implicit" and scene.coupling.tolerance == 1e-7 and not scene.notes
    with pytest.raises(SceneError, match="coupling.exchange_every: an FMU client exchanges every simulation.dt"):
        parse_scene(fmu_scene(FMU_CLIENT, coupling={"exchange_every": 2}))
    assert parse_scene(fmu_scene(FMU_CLIENT)).coupling.scheme == "auto"


def test_inertia_is_needed_only_by_a_body_that_rotates():
    """A heave-only body needs no inertia (its rotations are locked); one with a rotational DOF
    must give it, and the error names the key and the DOFs."""
    heave = parse_scene(scene_toml(dt=0.01, duration=1.0, bodies=[body("b", hdb="h.nc", mass=874.0,
                                                                      center_of_mass=[0, 0, 0], inertia=None,
                                                                      dofs=["heave"])]))
    assert heave.bodies[0].inertia is None
    with pytest.raises(SceneError, match=r"bodies\[0\]\.inertia: required: the body's rotational DOFs \['pitch'\]"):
        parse_scene(scene_toml(dt=0.01, duration=1.0, bodies=[body("b", hdb="h.nc", mass=874.0, center_of_mass=[0, 0, 0],
                                                                    inertia=None, dofs=["heave", "pitch"])]))


def test_centre_of_mass_is_needed_by_a_body_that_rotates_or_is_dry():
    ok = parse_scene(scene_toml(dt=0.01, duration=1.0, bodies=[body("b", hdb="h.nc", mass=874.0, center_of_mass=None,
                                                                   inertia=None, dofs=["heave"])]))
    assert ok.bodies[0].center_of_mass is None and list(ok.bodies[0].com_or([0, 0, -0.1])) == [0, 0, -0.1]
    with pytest.raises(SceneError, match=r"bodies\[0\]\.center_of_mass: required: the body's rotational DOFs \['roll'\]"):
        parse_scene(scene_toml(dt=0.01, duration=1.0, bodies=[body("b", hdb="h.nc", mass=874.0, center_of_mass=None,
                                                                    inertia=[1, 1, 1], dofs=["heave", "roll"])]))
    with pytest.raises(SceneError, match=r"bodies\[0\]\.center_of_mass: required for a dry body"):
        parse_scene(scene_toml(dt=0.01, duration=1.0, bodies=[body("b", mass=874.0, center_of_mass=None,
                                                                    inertia=None, dofs=["heave"])]))


def test_hdb_convention_is_for_wet_bodies_and_one_per_hdb():
    def scene(*bodies) -> str:
        return scene_toml(dt=0.01, duration=1.0, bodies=list(bodies))
    ok = parse_scene(scene(body("a", hdb="w.nc", mass=1.0, center_of_mass=[0, 0, 0], inertia=[1, 1, 1],
                                hdb_convention="exp(+iwt)")))
    assert ok.bodies[0].hdb_convention == "exp(+iwt)"
    with pytest.raises(SceneError, match=r"bodies\[0\]\.hdb_convention: Input should be 'exp\(-iwt\)' or 'exp\(\+iwt\)'"):
        parse_scene(scene(body("a", hdb="w.nc", mass=1.0, center_of_mass=[0, 0, 0], inertia=[1, 1, 1],
                               hdb_convention="+iwt")))
    with pytest.raises(SceneError, match=r"bodies\[0\]\.hdb_convention: needs hdb"):
        parse_scene(scene(body("a", mass=1.0, center_of_mass=[0, 0, 0], inertia=[1, 1, 1], hdb_convention="exp(+iwt)")))
    with pytest.raises(SceneError, match=r"bodies\[1\]\.hdb_convention: exp\(-iwt\) but another body states exp\(\+iwt\)"):
        parse_scene(scene(body("a", hdb="w.nc", mass=1.0, center_of_mass=[0, 0, 0], inertia=[1, 1, 1],
                               hdb_convention="exp(+iwt)"),
                          body("b", hdb="w.nc", mass=1.0, center_of_mass=[0, 0, 0], inertia=[1, 1, 1],
                               hdb_convention="exp(-iwt)")))


@pytest.mark.parametrize("kind,axis", [("revolute", [1, 0, 0]), ("revolute", [0, -1, 0]), ("revolute", [0, 0, 1]),
                                       ("prismatic", [0, 1, 0]), ("prismatic", [0, 0, -1]),
                                       ("revolute", [0.6, 0.8, 0]), ("prismatic", [0, 0.6, 0.8]), ("spherical", None)])
def test_the_dofs_a_joint_frees_are_the_nonzero_rigid_velocities(kind, axis):
    """Joint.freed_dofs against kinematics: a body turning about the hinge (axis e through p) moves
    its reference point r at w e x (r - p) and turns at w e; sliding, at v e. The freed DOFs are those
    a generic offset r - p makes nonzero; None where the joint frees a mix (oblique axis) or is not
    a one-axis joint. Scene.fixed_to_ground: the fixed joints to ground, either body order."""
    bodies = [body(n, mass=1.0, center_of_mass=[0, 0, 0], inertia=[1, 1, 1]) for n in ("a", "b", "c")]
    one = joint(kind, "ground", "a", [0.0, 0.0, 0.0], **({} if axis is None else {"axis": axis}))
    scene = parse_scene(scene_toml(dt=0.1, duration=1.0, waves={"type": "still"}, bodies=bodies, joints=[
        one, joint("fixed", "b", "ground", [0.0, 0.0, 0.0]), joint("fixed", "b", "c", [0.0, 0.0, 0.0]),
        joint("fixed", "ground", "c", [1.0, 0.0, 0.0])]))
    assert scene.fixed_to_ground() == {"b": [1], "c": [3]}
    freed = scene.joints[0].freed_dofs()
    if axis is None or np.count_nonzero(axis) > 1:
        assert freed is None
        return
    e, offset = np.asarray(axis, float), np.array([0.3, -0.7, 1.1])
    velocity = np.r_[np.cross(e, offset), e] if kind == "revolute" else np.r_[e, 0, 0, 0]
    assert freed == tuple(int(d) for d in np.flatnonzero(np.abs(velocity) > 1e-12))
