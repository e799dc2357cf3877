"""A WAMIT run's structure of its generalized modes: the external force matrices the ``.mmx``
reports (IALTFRC = 2 or 3: the ``.frc``'s mass, damping and stiffness, every mode of every body).
Read for the scene's ``bodies[i].modes.mmx`` (the client sends a body's block in
``hello.modal_structure``, SPEC §5.1) and printed as a ``[bodies.modes]`` table by ``hydrolink hdb
modes`` (issue 38: the scene gives the modes' structure; this is how a WAMIT user takes it from the
run's files instead of typing it)."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from hydrolink.protocol.hdb.external_matrices import ExternalMatrices
from hydrolink.protocol.hdb.layout import BodyDofs, HDBError
from hydrolink.server.hdb.wamit.run import _FLOAT, _floats

_ROW = re.compile(rf"^\s*(\d+)\s+(\d+)\s+({_FLOAT})\s+({_FLOAT})\s+({_FLOAT})\s*$", re.M)
# a body's section of a multi-body run (WAMIT spells it "Ouputs")
_BODY = re.compile(r"Ou?tputs\s+for\s+body\s+N\s*=\s*(\d+)", re.I)
_WHERE = "External force matrices"


def _rows(mmx: Path, dofs: BodyDofs, body: str) -> tuple[list[tuple], int, int]:
    """The matrix rows of ``body`` in the file, the first DOF number they use and how many DOFs
    the file numbers there: a file of one run-wide table (one body, or no body sections) is
    numbered over the run's DOFs; a file with a section per body, within each body."""
    text = mmx.read_text(errors="replace")
    marks = list(_BODY.finditer(text))
    if len(marks) <= 1:
        return _ROW.findall(text), dofs.index(body, 0), dofs.size
    k = dofs.bodies.index(body)
    if len(marks) != len(dofs.bodies):
        raise HDBError(mmx.name, _WHERE, f"{len(marks)} body sections for the HDB's {len(dofs.bodies)} bodies")
    start = marks[k].end()
    end = marks[k + 1].start() if k + 1 < len(marks) else len(text)
    return _ROW.findall(text[start:end]), 0, 6 + len(dofs.modes[k])


def body_external_matrices(mmx: Path, dofs: BodyDofs, body: str) -> ExternalMatrices:
    """Body ``body``'s block of the ``.mmx``'s external mass, damping and stiffness (its six, then its
    modes; ``dofs`` the HDB's, whose numbering the file uses); HDBError naming the file when it has
    no matrices or numbers another count of DOFs than the HDB has (the run's modes differ)."""
    if not mmx.is_file():
        raise HDBError(mmx.name, _WHERE, "file not found: the structure of the modes is in a WAMIT run's .mmx "
                                         "external force matrices (IALTFRC = 2 or 3)")
    rows, start, size = _rows(mmx, dofs, body)
    if not rows:
        raise HDBError(mmx.name, _WHERE, "none in the file (the run had no IALTFRC = 2 or 3 external mass, "
                                         "damping and stiffness)")
    numbered = max(max(int(i), int(j)) for i, j, *_ in rows)
    if numbered != size:
        raise HDBError(mmx.name, _WHERE, f"the file numbers {numbered} DOFs ({numbered - 6} mode(s) beyond six) where "
                                         f"the HDB has {size} ({size - 6} mode(s) beyond six)")
    full = np.zeros((3, size, size))
    for i, j, *values in rows:
        full[:, int(i) - 1, int(j) - 1] = _floats(" ".join(values))
    block = np.ix_(*[np.arange(start, start + 6 + len(dofs.of(body)))] * 2)
    mass, damping, stiffness = (m[block] for m in full)
    return ExternalMatrices(tuple(dofs.of(body)), mass, damping, stiffness)


def _toml_values(m: np.ndarray) -> str:
    """A diagonal matrix as its list, any other as its table."""
    if np.array_equal(m, np.diag(np.diag(m))):
        return "[" + ", ".join(f"{v:.7g}" for v in np.diag(m)) + "]"
    return "[" + ", ".join("[" + ", ".join(f"{v:.7g}" for v in row) + "]" for row in m) + "]"


def modes_table(mmx: Path, dofs: BodyDofs, body: str) -> str:
    """Body ``body``'s ``[bodies.modes]`` table (names, mass, stiffness, damping from the ``.mmx``;
    ``dofs`` the whole run's, whose numbering the file uses) after a comment line; a rigid–mode
    coupling in the external matrices, which a scene's modal structure cannot hold, is said in it."""
    names = dofs.of(body)
    if not names:
        raise HDBError(mmx.name, _WHERE, f"body {body!r} has no generalized modes")
    block = body_external_matrices(mmx, dofs, body)
    coupled = block.coupled()
    note = (f"\n# {mmx.name} couples the rigid DOFs and the modes in {', '.join(coupled)}: left out (a scene's "
            "[bodies.modes] holds the modes' block)") if coupled else ""
    quoted = ", ".join(f'"{n}"' for n in names)
    return (f"# body {body!r}: the modes' external force matrices of {mmx.name}{note}\n[bodies.modes]\n"
            f"names = [{quoted}]\nmass = {_toml_values(block.modal('mass', names))}\n"
            f"stiffness = {_toml_values(block.modal('stiffness', names))}\n"
            f"damping = {_toml_values(block.modal('damping', names))}\n")
