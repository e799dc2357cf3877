"""``hydrolink fmu export --native``: hydrolink's forces as a native FMU (FMI 2.0 or 3.0
co-simulation) whose binary is C: no Python where it is imported.

The binary (``clients/fmu/native_c/``: the core, ``fmi2.c`` or ``fmi3.c``) is compiled here with the
machine's C compiler against the FMI headers fmpy ships, and depends on the C library alone (its
ZeroMQ transport and msgpack codec are its own). It talks to a ``hydrolink serve`` at its
``server_address`` parameter and sends the scene and the HDB files it carries in ``resources/``
by SHA-256, uploading them once (SPEC §5.1, §5.8). ``GetFMUState``/``SetFMUState`` save and
restore the server's session (SPEC §5.9), so iterating masters can redo a step.

The model description says what the FMU does: a fixed communication step (the scene's dt; any
other is an error with a logged message), ``dependencies`` of every output on the inputs it
depends on (from the setup's hydrostatic stiffness and radiation feedthrough, plus every DOF of a
body with viscous or Morison terms), units and descriptions on every variable, and as constant
outputs (which masters can connect) the added mass for the importer's mass matrix (A∞, or A(ω0)
named ``A_omega0.*`` with radiation = "constant"), the hydrostatic stiffness ``K_hs.*`` and the net
buoyancy ``<body>.heave.net_buoyancy`` that a model using the ``dynamic`` output applies itself.
"""

from __future__ import annotations

import hashlib
import platform
import shutil
import subprocess
import tempfile
import zipfile
from pathlib import Path
from xml.sax.saxutils import quoteattr

import numpy as np

from hydrolink.protocol.capabilities import refuse_unsupported
from hydrolink.protocol.scene import SceneError, load_scene
from hydrolink.server.disk_cache import env_dir, user_cache_dir, write_atomic

SOURCES = Path(__file__).with_name("native_c")
MODEL_IDENTIFIER = "hydrolink_forces"
VR_TIME, VR_SERVER, VR_TIMEOUT, VR_ETA, VR_DOF, VR_AINF, VR_KHS = 0, 1, 2, 3, 1000, 1000000, 2000000
VR_NET = 7            # VR_DOF + 8 i + VR_NET: the DOF's net buoyancy
QUANTITIES = ("displacement", "velocity", "force", "excitation", "radiation", "hydrostatic", "dynamic")
UNITS = {  # name: base-unit exponents (kg, m, s, rad)
    "m": {"m": 1}, "rad": {"rad": 1}, "m/s": {"m": 1, "s": -1}, "rad/s": {"rad": 1, "s": -1},
    "N": {"kg": 1, "m": 1, "s": -2}, "N.m": {"kg": 1, "m": 2, "s": -2}, "kg": {"kg": 1},
    "kg.m": {"kg": 1, "m": 1}, "kg.m2": {"kg": 1, "m": 2}, "s": {"s": 1}, "N/m": {"kg": 1, "s": -2},
    "N/rad": {"kg": 1, "m": 1, "s": -2, "rad": -1}, "N.m/m": {"kg": 1, "m": 1, "s": -2},
    "N.m/rad": {"kg": 1, "m": 2, "s": -2, "rad": -1}}
TRANSLATIONS = ("surge", "sway", "heave")


class NativeFMUError(RuntimeError):
    """The native FMU cannot be built here (no C compiler, no FMI headers, a failed compile)."""


def _platform(fmi: int) -> str:
    machine = platform.machine().lower()
    if platform.system() != "Linux" or machine not in ("x86_64", "amd64", "aarch64", "arm64"):
        raise NativeFMUError(f"the native FMU is built on Linux x86-64/aarch64 (this is {platform.system()} {machine})")
    arch = "x86_64" if machine in ("x86_64", "amd64") else "aarch64"
    if fmi == 2:
        return "linux64" if arch == "x86_64" else "aarch64-linux"
    return f"{arch}-linux"


def _headers() -> Path:
    import fmpy
    folder = Path(fmpy.__file__).with_name("c-code")
    if not (folder / "fmi2Functions.h").is_file() or not (folder / "fmi3Functions.h").is_file():
        raise NativeFMUError(f"the FMI headers are not in {folder} (fmpy's c-code folder)")
    return folder


def binary_cache() -> Path:
    """Where compiled FMU binaries are kept: ``$HYDROLINK_FMU_BINARIES``, else
    ``$HYDROLINK_CACHE/fmu_binaries``, else the user cache's ``fmu_binaries``."""
    shared = env_dir("HYDROLINK_CACHE")
    return env_dir("HYDROLINK_FMU_BINARIES") or (shared / "fmu_binaries" if shared else user_cache_dir("fmu_binaries"))


def compile_binary(fmi: int, out: Path) -> None:
    """Compile the core and the FMI ``fmi`` wrapper into the shared library ``out``; a binary compiled
    before from the same sources, headers, command and compiler is copied from :func:`binary_cache`
    instead (the binary does not depend on the scene: the scene and HDBs are the FMU's resources)."""
    cc = shutil.which("cc") or shutil.which("gcc")
    if cc is None:
        raise NativeFMUError("building the native FMU needs a C compiler (Debian package gcc); "
                             "or export the pythonfmu FMU with --python")
    sources = [SOURCES / "hydro_core.c", SOURCES / f"fmi{fmi}.c"]
    flags = ["-std=c99", "-O2", "-shared", "-fPIC", "-fvisibility=hidden", "-Wall", "-Wextra", "-Wno-unused-parameter",
             f"-I{_headers()}"]
    version = subprocess.run([cc, "--version"], capture_output=True, text=True).stdout
    digest = hashlib.sha256("\0".join([cc, version, *flags, "-lm", "-static-libgcc"]).encode())
    for path in sorted([*SOURCES.glob("*.[ch]"), *_headers().glob(f"fmi{fmi}*.h")]):
        digest.update(path.name.encode() + b"\0" + path.read_bytes())
    cached = binary_cache() / f"fmi{fmi}-{digest.hexdigest()[:32]}.so"
    if not cached.is_file():
        def build(tmp: str) -> None:
            cmd = [cc, *flags, "-o", tmp, *map(str, sources), "-lm", "-static-libgcc"]
            done = subprocess.run(cmd, capture_output=True, text=True)
            if done.returncode:
                raise NativeFMUError(f"compiling the native FMU failed:\n{' '.join(cmd)}\n{done.stderr}")
        write_atomic(cached, build)
    shutil.copyfile(cached, out)


def _hdb_sources(scene, scene_path: Path, progress: bool) -> tuple[dict, dict]:
    """Per HDB key: (format, [paths]) of the files the FMU carries, and the loaded datasets."""
    from hydrolink.clients.scene_inputs import load_scene_hdbs
    from hydrolink.server.hdb.io import file_set
    from hydrolink.protocol.scene import resolve_path
    from hydrolink.protocol.hdb.schema import to_netcdf

    datasets = load_scene_hdbs(scene, scene_path, progress=progress)
    sources = {}
    for key, ds in datasets.items():
        path = resolve_path(scene_path, key)
        if path.suffix == ".toml":   # a build spec: the FMU carries the built HDB as hydrolink NetCDF
            built = Path(tempfile.mkdtemp(prefix="hydrolink-native-")) / f"{path.stem}.nc"
            to_netcdf(ds, built)
            sources[key] = ("netcdf", [built])
        else:
            files = file_set(path)
            sources[key] = (files.format, list(files.paths))
    return sources, datasets


def _setup(text: str, datasets: dict):
    from hydrolink.clients.lockstep.connection import ServerConnection
    from hydrolink.server.service.force_server import ForceServer

    server = ForceServer(None)
    try:
        with ServerConnection(server) as conn:     # validates scene + HDBs, gives the setup
            return conn.hello(text, datasets)
    finally:
        server.close()


def _unit(dof: str, quantity: str) -> str:
    lin = dof in TRANSLATIONS
    return {"displacement": "m" if lin else "rad", "velocity": "m/s" if lin else "rad/s"}.get(
        quantity, "N" if lin else "N.m")


def _a_inf_unit(a: str, b: str) -> str:
    n = (a in TRANSLATIONS) + (b in TRANSLATIONS)
    return {2: "kg", 1: "kg.m", 0: "kg.m2"}[n]


def _stiffness_unit(a: str, b: str) -> str:
    """Force (moment) on DOF a per displacement (rotation) of DOF b."""
    return ("N" if a in TRANSLATIONS else "N.m") + ("/m" if b in TRANSLATIONS else "/rad")


def export_native_fmu(scene_path: str | Path, output: str | Path, *, fmi: int = 3,
                      progress: bool = True) -> tuple[Path, list[str]]:
    """Write the native FMU (``fmi`` 2 or 3); returns its path and notes."""
    from hydrolink.clients.fmu.export import MECHANISM_KEYS

    if fmi not in (2, 3):
        raise NativeFMUError(f"--fmi must be 2 or 3, got {fmi}")
    scene_path, output = Path(scene_path), Path(output)
    scene, text = load_scene(scene_path)
    refuse_unsupported(scene, "native_fmu", lambda key, why: SceneError(scene_path, key, why))
    sources, datasets = _hdb_sources(scene, scene_path, progress)
    setup = _setup(text, datasets)
    names, n = setup.bodies, setup.n
    flat = np.flatnonzero(setup.active.reshape(6 * n))
    labels = [f"{names[k // 6]}.{setup.dofs[k % 6]}" for k in flat]
    added = setup.added_mass[np.ix_(flat, flat)]
    stiffness = setup.hydrostatic_stiffness[np.ix_(flat, flat)]
    net = [float(setup.net_buoyancy[k // 6]) if k % 6 == 2 else 0.0 for k in flat]
    notes = [f"[{k}] is not in the FMU: the importer models the mechanism" for k in MECHANISM_KEYS
             if getattr(scene, k)]
    notes += [f"the server warns (the FMU logs it when it starts): {w}" for w in setup.warnings]
    with tempfile.TemporaryDirectory(prefix="hydrolink-native-") as tmp:
        root = Path(tmp)
        res = root / "resources"
        (res / "hdb").mkdir(parents=True)
        (res / "scene.toml").write_text(text)
        cfg = [f"dt {setup.dt!r}", f"n_bodies {n}", f"active {len(flat)} " + " ".join(map(str, flat)),
               "equilibrium " + " ".join(repr(float(x)) for x in setup.equilibrium_position.reshape(-1)),
               "net_buoyancy " + " ".join(repr(x) for x in net),
               "added_mass " + " ".join(repr(float(x)) for x in added.reshape(-1)),
               "hydrostatic_stiffness " + " ".join(repr(float(x)) for x in stiffness.reshape(-1)), "scene scene.toml"]
        for i, (key, (fmt, paths)) in enumerate(sources.items()):
            folder = res / "hdb" / str(i)
            folder.mkdir()
            cfg += [f"hdb_key {key}", f"hdb_format {fmt}"]
            for p in paths:
                shutil.copy2(p, folder / Path(p).name)
                cfg.append(f"hdb_file hdb/{i}/{Path(p).name}")
        config = "\n".join(cfg) + "\n"
        (res / "hydrolink_native.cfg").write_text(config)
        token = "{" + hashlib.sha256(config.encode() + text.encode()).hexdigest()[:32] + "}"
        description = _model_description(fmi, scene, setup, flat, labels, token)
        (root / "modelDescription.xml").write_text(description)
        binaries = root / "binaries" / _platform(fmi)
        binaries.mkdir(parents=True)
        compile_binary(fmi, binaries / f"{MODEL_IDENTIFIER}.so")
        output.parent.mkdir(parents=True, exist_ok=True)
        with zipfile.ZipFile(output, "w", zipfile.ZIP_DEFLATED) as z:
            for path in sorted(root.rglob("*")):
                if path.is_file():
                    z.write(path, path.relative_to(root).as_posix())
    for fmt, paths in sources.values():
        for p in paths:
            if p.parent.name.startswith("hydrolink-native-"):
                shutil.rmtree(p.parent, ignore_errors=True)
    return output, notes


# ------------------------------------------------------------------ the model description

def _dependencies(scene, setup, flat: np.ndarray) -> dict[tuple[int, str], list[tuple[int, str]]]:
    """(active DOF, output quantity) -> the (active DOF, input quantity) it depends on."""
    k = setup.hydrostatic_stiffness[np.ix_(flat, flat)]
    d = (setup.radiation_feedthrough if setup.radiation_feedthrough is not None
         else np.ones((6 * setup.n, 6 * setup.n)))[np.ix_(flat, flat)]
    pointwise = {b.name for b in scene.bodies if b.viscous} | {m.body for m in scene.morison}
    body_of = [setup.bodies[f // 6] for f in flat]
    deps = {}
    for i in range(flat.size):
        hyd = [(j, "displacement") for j in range(flat.size) if k[i, j] != 0]
        rad = [(j, "velocity") for j in range(flat.size) if d[i, j] != 0]
        deps[i, "excitation"] = []
        deps[i, "hydrostatic"] = hyd
        deps[i, "radiation"] = rad
        extra = ([(j, q) for j in range(flat.size) if body_of[j] == body_of[i] for q in ("displacement", "velocity")]
                 if body_of[i] in pointwise else [])
        order = lambda t: (t[1] != "displacement", t[0])  # noqa: E731
        deps[i, "force"] = sorted(set(hyd) | set(rad) | set(extra), key=order)
        deps[i, "dynamic"] = sorted(set(rad) | set(extra), key=order)
    return deps


def _constants(setup, flat: np.ndarray, labels: list[str]) -> list[tuple]:
    """The constant outputs a master wires into its body model: the added mass of its mass matrix
    (A_inf; A(omega0) with radiation = "constant", named so), the hydrostatic stiffness and the net
    buoyancy (what the ``dynamic`` output leaves to the model). Outputs, not calculated parameters:
    masters connect outputs (libcosim refuses a calculated parameter as a connection's source)."""
    added = setup.added_mass[np.ix_(flat, flat)]
    stiffness = setup.hydrostatic_stiffness[np.ix_(flat, flat)]
    w0 = setup.radiation_frequency
    if w0 is None:
        prefix, what = "A_inf", ("infinite-frequency added mass A_inf, force {a} per acceleration {b}: add it to the "
                                 "mass matrix (the force excludes -A_inf a)")
    else:
        prefix, what = "A_omega0", (f"added mass A(omega0) at the radiation frequency omega0 = {w0:.6g} rad/s "
                                    "(radiation = \"constant\"), force {a} per acceleration {b}: add it to the mass "
                                    "matrix (the force holds B(omega0) v, no memory)")
    out = []
    for i, a in enumerate(labels):
        for j, b in enumerate(labels):
            da, db = a.rsplit(".", 1)[1], b.rsplit(".", 1)[1]
            out.append((f"{prefix}.{a}.{b}", VR_AINF + flat.size * i + j, "real", "output", "constant",
                        float(added[i, j]), _a_inf_unit(da, db), what.format(a=a, b=b), "exact"))
    for i, a in enumerate(labels):
        for j, b in enumerate(labels):
            da, db = a.rsplit(".", 1)[1], b.rsplit(".", 1)[1]
            out.append((f"K_hs.{a}.{b}", VR_KHS + flat.size * i + j, "real", "output", "constant",
                        float(stiffness[i, j]), _stiffness_unit(da, db),
                        f"linear hydrostatic stiffness, force {a} per displacement {b} (buoyancy and waterplane): "
                        "with the dynamic output, the model applies -K_hs x itself", "exact"))
    for i, (k, a) in enumerate(zip(flat, labels)):
        if k % 6 == 2:
            out.append((f"{a}.net_buoyancy", VR_DOF + 8 * i + VR_NET, "real", "output", "constant",
                        float(setup.net_buoyancy[k // 6]), "N",
                        f"{a}: net buoyancy rho g V - m g, a constant force: with the dynamic output, the model "
                        "applies it itself", "exact"))
    return out


def _model_description(fmi: int, scene, setup, flat, labels, token) -> str:
    deps = _dependencies(scene, setup, flat)
    na = flat.size
    stop = scene.simulation.duration
    variables = [  # (name, vr, kind, causality, variability, start, unit, description, initial)
        ("server_address", VR_SERVER, "string", "parameter", "fixed", "",
         None, "the hydrolink server, tcp://HOST:PORT (hydrolink serve --bind ...)", "exact"),
        ("timeout", VR_TIMEOUT, "real", "parameter", "fixed", 30.0, "s",
         "seconds to wait for the server's connection and each reply", "exact"),
        ("wave_elevation", VR_ETA, "real", "output", "continuous", None, "m",
         "undisturbed wave elevation at the origin", "calculated")]
    text = {"displacement": "displacement from equilibrium", "velocity": "velocity",
            "force": "total hydrodynamic force: excitation + radiation memory + hydrostatic + net buoyancy "
                     "(+ viscous and Morison terms where the scene has them); apply it, with the added mass "
                     "output in the mass matrix",
            "excitation": "wave excitation force", "radiation": "radiation force (without the added mass term)",
            "hydrostatic": "linear hydrostatic restoring force plus the net buoyancy",
            "dynamic": "force minus hydrostatic: for an importer whose model holds the hydrostatic stiffness and "
                       "net buoyancy itself (K_hs.* and net_buoyancy outputs; better with an explicit master: no "
                       "stiffness lagged a step)"}
    for i, label in enumerate(labels):
        dof = label.rsplit(".", 1)[1]
        for q, quantity in enumerate(QUANTITIES):
            is_input = q < 2
            variables.append((f"{label}.{quantity}", VR_DOF + 8 * i + q, "real", "input" if is_input else "output",
                              "continuous", 0.0 if is_input else None, _unit(dof, quantity),
                              f"{label}: {text[quantity]}", None if is_input else "calculated"))
    constants = _constants(setup, flat, labels)
    variables += constants
    index = {v[1]: k + 1 for k, v in enumerate(variables)}
    vr_of = lambda i, q: VR_DOF + 8 * i + QUANTITIES.index(q)  # noqa: E731
    outputs = [(VR_ETA, [])] + [(vr_of(i, q), [vr_of(j, p) for j, p in deps[i, q]])
                                for i in range(na) for q in QUANTITIES[2:]] + [(c[1], []) for c in constants]
    units = "\n".join(f'    <Unit name="{u}"><BaseUnit {" ".join(f"{k}={chr(34)}{v}{chr(34)}" for k, v in e.items())}/></Unit>'
                      for u, e in UNITS.items())
    if fmi == 2:
        return _fmi2(variables, outputs, index, units, token, setup.dt, stop)
    time = ("time", VR_TIME, "real", "independent", "continuous", None, "s", "simulation time", None)
    return _fmi3([time, *variables], outputs, units, token, setup.dt, stop)


def _fmi2(variables, outputs, index, units, token, dt, stop) -> str:
    rows = []
    for name, vr, kind, causality, variability, start, unit, desc, initial in variables:
        attrs = f'name={quoteattr(name)} valueReference="{vr}" causality="{causality}" variability="{variability}"'
        if initial and causality != "input" and not (causality == "parameter"):
            attrs += f' initial="{initial}"'
        attrs += f" description={quoteattr(desc)}"
        if kind == "string":
            body = f'<String start={quoteattr(start)}/>'
        else:
            u = f' unit="{unit}"' if unit else ""
            body = f'<Real{u}{"" if start is None else f" start={chr(34)}{start!r}{chr(34)}"}/>'
        rows.append(f"    <ScalarVariable {attrs}>{body}</ScalarVariable>")
    out_rows = [f'      <Unknown index="{index[vr]}" dependencies="{" ".join(str(index[d]) for d in ds)}"'
                f' dependenciesKind="{" ".join("dependent" for _ in ds)}"/>' for vr, ds in outputs]
    exact = {index[v[1]] for v in variables if v[4] == "constant"}
    init_rows = [r for r in out_rows if int(r.split('"')[1]) not in exact]      # constants are not unknowns
    return f"""<?xml version="1.0" encoding="UTF-8"?>
<fmiModelDescription fmiVersion="2.0" modelName="{MODEL_IDENTIFIER}" guid="{token}"
  description="hydrolink linear potential-flow forces from a hydrolink server (native C FMU)"
  generationTool="hydrolink" variableNamingConvention="structured" numberOfEventIndicators="0">
  <CoSimulation modelIdentifier="{MODEL_IDENTIFIER}" canHandleVariableCommunicationStepSize="false"
    canGetAndSetFMUstate="true" canSerializeFMUstate="false" providesDirectionalDerivative="false"
    canInterpolateInputs="false" maxOutputDerivativeOrder="0" canRunAsynchronuously="false"
    canBeInstantiatedOnlyOncePerProcess="false" canNotUseMemoryManagementFunctions="true" needsExecutionTool="false"/>
  <UnitDefinitions>
{units}
  </UnitDefinitions>
  <DefaultExperiment startTime="0" stopTime="{stop!r}" stepSize="{dt!r}"/>
  <ModelVariables>
{chr(10).join(rows)}
  </ModelVariables>
  <ModelStructure>
    <Outputs>
{chr(10).join(out_rows)}
    </Outputs>
    <InitialUnknowns>
{chr(10).join(init_rows)}
    </InitialUnknowns>
  </ModelStructure>
</fmiModelDescription>
"""


def _fmi3(variables, outputs, units, token, dt, stop) -> str:
    rows = []
    for name, vr, kind, causality, variability, start, unit, desc, initial in variables:
        attrs = f'name={quoteattr(name)} valueReference="{vr}" causality="{causality}" variability="{variability}"'
        if initial and causality not in ("input", "parameter"):
            attrs += f' initial="{initial}"'
        attrs += f" description={quoteattr(desc)}"
        if kind == "string":
            rows.append(f"    <String {attrs}><Start value={quoteattr(start)}/></String>")
        else:
            u = f' unit="{unit}"' if unit else ""
            s = "" if start is None else f' start="{start!r}"'
            rows.append(f"    <Float64 {attrs}{u}{s}/>")
    out_rows = [f'    <Output valueReference="{vr}" dependencies="{" ".join(map(str, ds))}"'
                f' dependenciesKind="{" ".join("dependent" for _ in ds)}"/>' if ds else
                f'    <Output valueReference="{vr}" dependencies=""/>' for vr, ds in outputs]
    exact = {v[1] for v in variables if v[4] == "constant"}
    init_rows = [r.replace("<Output ", "<InitialUnknown ") for r in out_rows
                 if int(r.split('"')[1]) not in exact]                       # constants are not unknowns
    return f"""<?xml version="1.0" encoding="UTF-8"?>
<fmiModelDescription fmiVersion="3.0" modelName="{MODEL_IDENTIFIER}" instantiationToken="{token}"
  description="hydrolink linear potential-flow forces from a hydrolink server (native C FMU)"
  generationTool="hydrolink" variableNamingConvention="structured">
  <CoSimulation modelIdentifier="{MODEL_IDENTIFIER}" canHandleVariableCommunicationStepSize="false"
    fixedInternalStepSize="{dt!r}" canGetAndSetFMUState="true" canSerializeFMUState="false"
    providesDirectionalDerivatives="false" providesAdjointDerivatives="false" providesIntermediateUpdate="false"
    canReturnEarlyAfterIntermediateUpdate="false" hasEventMode="false" needsExecutionTool="false"/>
  <UnitDefinitions>
{units}
  </UnitDefinitions>
  <DefaultExperiment startTime="0" stopTime="{stop!r}" stepSize="{dt!r}"/>
  <ModelVariables>
{chr(10).join(rows)}
  </ModelVariables>
  <ModelStructure>
{chr(10).join(out_rows)}
{chr(10).join(init_rows)}
  </ModelStructure>
</fmiModelDescription>
"""
