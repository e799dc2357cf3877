"""Build the test FMUs from the sources in tests/fmu_src (never downloaded): the FMI 2.0 C FMU with
the machine's C compiler (FMI headers from the installed fmpy), the Python FMUs with pythonfmu
(FMI 2.0) and pythonfmu3 (FMI 3.0)."""

from __future__ import annotations

import os
import shutil
import subprocess
import zipfile
from pathlib import Path

import fmpy

FMU_SRC = Path(__file__).resolve().parent / "fmu_src"


def build_c_fmu(dest: Path) -> Path:
    """Compile heave_body.c into dest/heave_body.fmu (binary for this platform + the sources)."""
    dest.mkdir(parents=True, exist_ok=True)
    lib = dest / "heave_body.so"
    include = Path(fmpy.__file__).resolve().parent / "c-code"
    cmd = [os.environ.get("CC", "cc"), "-shared", "-fPIC", "-O2", "-std=c99", "-Wall", "-Wextra", "-Werror",
           f"-I{include}", str(FMU_SRC / "heave_body.c"), "-o", str(lib), "-lm"]
    done = subprocess.run(cmd, capture_output=True, text=True)
    if done.returncode:
        raise RuntimeError(f"compiling the test FMU failed: {' '.join(cmd)}\n{done.stderr}")
    fmu = dest / "heave_body.fmu"
    with zipfile.ZipFile(fmu, "w", zipfile.ZIP_DEFLATED) as z:
        z.write(FMU_SRC / "modelDescription.xml", "modelDescription.xml")
        z.write(lib, f"binaries/{fmpy.platform}/heave_body.so")
        z.write(FMU_SRC / "heave_body.c", "sources/heave_body.c")
    return fmu


def build_python_fmu(dest: Path, *, handle_state: bool = True) -> Path:
    """pythonfmu build of pyheave.py (``handle_state``: canGetAndSetFMUstate, pythonfmu's --handle-state)."""
    from pythonfmu import FmuBuilder

    dest.mkdir(parents=True, exist_ok=True)
    work = dest / ("py_state" if handle_state else "py_nostate")
    work.mkdir(exist_ok=True)
    script = work / "pyheave.py"
    shutil.copy2(FMU_SRC / "pyheave.py", script)
    return Path(FmuBuilder.build_FMU(script, dest=work / "PyHeave.fmu", canGetAndSetFMUstate=handle_state))


def build_python3_fmu(dest: Path) -> Path:
    """pythonfmu3 build of pyheave3.py (FMI 3.0, canGetAndSetFMUState)."""
    from pythonfmu3 import FmuBuilder

    work = dest / "py3_state"
    work.mkdir(parents=True, exist_ok=True)
    script = work / "pyheave3.py"
    shutil.copy2(FMU_SRC / "pyheave3.py", script)
    return Path(FmuBuilder.build_FMU(script, dest=work, canGetAndSetFMUState=True))
