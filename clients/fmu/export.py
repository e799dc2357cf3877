"""``hydrolink fmu export --python``: hydrolink's forces as an FMI 2.0 co-simulation FMU (built with
pythonfmu; the default is the native FMU of :mod:`hydrolink.clients.fmu.native`).

The FMU carries the scene text and its HDBs (as hydrolink NetCDF) in ``resources/``; its model
class is :mod:`hydrolink.clients.fmu.slave`. At run time it needs a Python with hydrolink installed
(pythonfmu FMUs run their Python code in the importing process or in the Python that pythonfmu's
binary finds) and connects to the server named by its ``server_address`` parameter — or starts an
embedded one when that is empty.
"""

from __future__ import annotations

import json
import shutil
import tempfile
from pathlib import Path

import numpy as np

from hydrolink.protocol.capabilities import refuse_unsupported
from hydrolink.protocol.scene import SceneError, load_scene

MECHANISM_KEYS = ("point_masses", "joints", "constraints", "ptos", "moorings")


def export_fmu(scene_path: str | Path, output: str | Path, *, progress: bool = True) -> tuple[Path, list[str]]:
    """Write the FMU; returns its path and notes (e.g. scene parts the FMU does not contain)."""
    try:
        from pythonfmu import FmuBuilder
    except ImportError:  # pragma: no cover - an install without the extra
        raise RuntimeError("hydrolink fmu export needs pythonfmu: pip install 'hydrolink[fmu]'") from None
    from hydrolink.clients.lockstep.connection import ServerConnection
    from hydrolink.clients.scene_inputs import load_scene_hdbs
    from hydrolink.protocol.hdb.schema import to_netcdf
    from hydrolink.server.service.force_server import serve_in_thread

    scene_path, output = Path(scene_path), Path(output)
    scene, text = load_scene(scene_path)
    refuse_unsupported(scene, "python_fmu", lambda key, why: SceneError(scene_path, key, why))
    hdbs = load_scene_hdbs(scene, scene_path, progress=progress)
    srv, thread = serve_in_thread("tcp://127.0.0.1:*")
    try:
        with ServerConnection(srv.address) as conn:    # validates scene + HDBs, gives the setup
            setup = conn.hello(text, hdbs)
            conn.bye()
    finally:
        srv.stop()
        thread.join(5.0)
    names, dofs, n = setup.bodies, setup.dofs, setup.n
    active = np.flatnonzero(setup.active.reshape(6 * n))
    # what the importer puts in its mass matrix: A∞, or A(ω0) with [hydro] radiation = "constant"
    added_mass = setup.added_mass[np.ix_(active, active)]
    notes = [f"[{k}] is not in the FMU: the importer models the mechanism" for k in MECHANISM_KEYS
             if getattr(scene, k)]
    notes += [f"the server warns (the FMU logs it when it starts): {w}" for w in setup.warnings]
    with tempfile.TemporaryDirectory(prefix="hydrolink-export-") as tmp:
        work = Path(tmp)
        files = {}
        for i, (key, ds) in enumerate(hdbs.items()):
            files[key] = f"hdb_{i}.nc"
            to_netcdf(ds, work / files[key])
        config = {
            "model_name": "hydrolink_forces", "scene": text, "hdbs": files, "dt": setup.dt,
            "n_bodies": n, "labels": [f"{names[k // 6]}.{dofs[k % 6]}" for k in active],
            "flat": active.tolist(), "equilibrium": setup.equilibrium_position.tolist(),
            "added_mass": added_mass.tolist(),
            "net_buoyancy": [float(setup.net_buoyancy[k // 6]) if k % 6 == 2 else 0.0 for k in active],
        }
        (work / "hydrolink_fmu.json").write_text(json.dumps(config))
        script = work / "hydrolink_forces.py"
        shutil.copy2(Path(__file__).with_name("slave.py"), script)
        output.parent.mkdir(parents=True, exist_ok=True)
        built = FmuBuilder.build_FMU(script, dest=output, project_files=[work / "hydrolink_fmu.json",
                                                                          *(work / f for f in files.values())],
                                     canHandleVariableCommunicationStepSize=False)   # only the scene's dt
    return Path(built), notes
