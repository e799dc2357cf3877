"""The code's layout rules (docs/architecture.md), checked on the source itself: the layers and the
absence of import loops by import-linter (the contracts in pyproject.toml), no function over 100
lines and no folder of more than 12 modules in server/, clients/ or protocol/."""

from __future__ import annotations

import ast
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

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
                          capture_output=True, text=True, cwd=tmp_path, env=env, timeout=240)
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
