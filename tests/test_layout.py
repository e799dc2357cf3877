"""The code's layout rules (docs/architecture.md), checked on the source itself: the layers and the
absence of import loops by import-linter (the contracts in pyproject.toml), no function over 100
lines and no folder of more than 12 modules in server/, clients/ or protocol/, and no netCDF file opened
without its xarray engine named."""

from __future__ import annotations

import ast
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from conftest import EXIT_S

REPO = Path(__file__).resolve().parents[1]
PACKAGES = ("server", "clients", "protocol")
API = REPO / "clients" / "api"      # the package `hydrolink` itself (pyproject's package-dir)


def _modules(folder: str) -> list[Path]:
    return sorted(p for p in (REPO / folder).rglob("*.py") if "__pycache__" not in p.parts)


def test_no_function_over_100_lines():
    long = []
    for folder in PACKAGES:
        for path in _modules(folder):
            for node in ast.walk(ast.parse(path.read_text())):
                if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                    n = node.end_lineno - node.lineno + 1
                    if n > 100:
                        long.append(f"{path.relative_to(REPO)}:{node.lineno} {node.name} ({n} lines)")
    assert not long, "functions over 100 lines: " + "; ".join(long)


def test_no_folder_holds_more_than_twelve_modules():
    crowded = {}
    for folder in PACKAGES:
        for pkg in [REPO / folder, *(p.parent for p in (REPO / folder).rglob("__init__.py"))]:
            modules = [p.name for p in pkg.glob("*.py") if p.name != "__init__.py"]
            if len(modules) > 12:
                crowded[str(pkg.relative_to(REPO))] = len(modules)
    assert not crowded, f"folders of more than 12 modules: {crowded}"


def test_every_netcdf_open_names_its_engine():
    """xarray's open_dataset (and load/open_dataarray, open_mfdataset) with no engine loads every
    installed xarray backend to guess one (wavespectra's 20, with scipy.interpolate and scipy.io:
    ~1 s of CPU in each process that opens a file, bench/bench_startup.py); named, xarray takes its
    built-in backend directly."""
    openers = {"open_dataset", "load_dataset", "open_dataarray", "load_dataarray", "open_mfdataset"}
    unnamed = []
    for folder in PACKAGES:
        for path in _modules(folder):
            for node in ast.walk(ast.parse(path.read_text())):
                if (isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute) and node.func.attr in openers
                        and not any(k.arg == "engine" for k in node.keywords)):
                    unnamed.append(f"{path.relative_to(REPO)}:{node.lineno}")
    assert not unnamed, "xarray opens without engine=: " + "; ".join(unnamed)

def _installed_layout(root: Path) -> Path:
    """The three folders copied as the installed package lays them out (root/hydrolink/...): grimp,
    which import-linter builds its graph with, reads a package from one folder."""
    ignore = shutil.ignore_patterns("__pycache__", "*.pyc", "native_c")
    pkg = root / "hydrolink"
    shutil.copytree(API, pkg, ignore=ignore)
    for folder in PACKAGES:
        shutil.copytree(REPO / folder, pkg / folder,
                        ignore=shutil.ignore_patterns("__pycache__", "*.pyc", "native_c", "api", "*.md"))
    return root


def test_import_contracts_hold(tmp_path):
    """import-linter's contracts (pyproject.toml [tool.importlinter]): clients above the server above the
    protocol, the server's service above its physics, and no import loop between any modules."""
    pytest.importorskip("importlinter", reason="import-linter not installed (pip install -e '.[test]')")
    root = _installed_layout(tmp_path)
    env = {"PYTHONPATH": str(root), "PATH": "/usr/bin:/bin", "HOME": str(tmp_path)}
    done = subprocess.run([sys.executable, "-c", "import sys; from importlinter.cli import lint_imports_command; "
                           "sys.exit(lint_imports_command())", "--config", str(REPO / "pyproject.toml"), "--no-cache"],
                          capture_output=True, text=True, cwd=tmp_path, env=env, timeout=EXIT_S)
    out = done.stdout + done.stderr
    assert done.returncode == 0, out
    assert "4 kept, 0 broken" in out, out
    for name in ("clients above the server above the protocol", "no import loop anywhere"):
        assert name in out, out


def test_the_installed_layout_is_the_one_the_contracts_see(tmp_path):
    """The copy import-linter checks holds every module the package has (none left out of the graph)."""
    root = _installed_layout(tmp_path)
    copied = {p.relative_to(root / "hydrolink").as_posix() for p in (root / "hydrolink").rglob("*.py")}
    expected = {f"{folder}/{p.relative_to(REPO / folder).as_posix()}" for folder in PACKAGES
                for p in _modules(folder) if "api" not in p.relative_to(REPO / folder).parts}
    assert expected <= copied


def test_every_subpackage_is_in_the_build_backends_list():
    """pyproject's explicit packages list names every folder with an __init__.py (a folder left out
    is missing from a non-editable install, though the editable one finds it)."""
    import tomllib
    listed = set(tomllib.loads((REPO / "pyproject.toml").read_text())["tool"]["setuptools"]["packages"])
    found = {"hydrolink." + ".".join(p.parent.relative_to(REPO).parts) for folder in PACKAGES
             for p in (REPO / folder).rglob("__init__.py") if "api" not in p.relative_to(REPO / folder).parts}
    assert found - listed == set(), "add these to pyproject's [tool.setuptools] packages"


def test_python_floor_is_stated_once_and_holds_for_the_code():
    """pyproject's requires-python and the README state the same floor, and the code runs there:
    no module imports a standard-library module newer than the floor (tomllib is Python 3.11's),
    and no ``tomli`` fallback or version guard is left for a Python the project does not claim."""
    import re
    import tomllib

    project = tomllib.loads((REPO / "pyproject.toml").read_text())["project"]
    floor = re.fullmatch(r">=\s*3\.(\d+)", project["requires-python"])
    assert floor, f"pyproject.toml requires-python {project['requires-python']!r} is not '>=3.N'"
    minor = int(floor.group(1))
    readme = re.findall(r"Python ≥ 3\.(\d+)", (REPO / "README.md").read_text())
    assert readme and {int(m) for m in readme} == {minor}, f"README states Python ≥ 3.{readme}, pyproject 3.{minor}"
    assert not any("tomli" in d for d in project["dependencies"]), "tomli is a fallback for Python < 3.11"
    since = {"tomllib": 11}                      # standard-library modules newer than 3.10
    offenders = []
    for path in sorted(REPO.rglob("*.py")):
        if {".venv", "__pycache__", ".git"} & set(path.parts) or "egg-info" in str(path) or path == Path(__file__).resolve():
            continue
        text = path.read_text()
        if "sys.version_info" in text or re.search(r"\bimport tomli\b", text):
            offenders.append(f"{path.relative_to(REPO)}: a version guard or tomli fallback")
        for node in ast.walk(ast.parse(text)):
            names = [a.name for a in node.names] if isinstance(node, ast.Import) else \
                [node.module or ""] if isinstance(node, ast.ImportFrom) else []
            offenders += [f"{path.relative_to(REPO)}: imports {n} (3.{since[n]}+)"
                          for n in names if since.get(n, 0) > minor]
    assert not offenders, offenders
    assert sys.version_info[:2] >= (3, minor)
