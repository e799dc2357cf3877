"""A WAMIT run's structure of its generalized modes: the external force matrices the ``.mmx``
reports (IALTFRC = 2 or 3: the ``.frc``'s mass, damping and stiffness, every mode of every body),
as the ``[bodies.modes]`` table of a scene (issue 38: the scene gives the modes' structure; this is
how a WAMIT user gets it from the run's files instead of typing it). ``hydrolink hdb modes``."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from hydrolink.protocol.hdb.layout import BodyDofs, HDBError
from hydrolink.server.hdb.wamit.run import _FLOAT, _floats

_ROW = re.compile(rf"^\s*(\d+)\s+(\d+)\s+({_FLOAT})\s+({_FLOAT})\s+({_FLOAT})\s*$", re.M)


def external_force_matrices(mmx: Path, size: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The ``.mmx``'s external mass, damping and stiffness (``size`` × ``size``, WAMIT's mode
    numbering, as the run gave them); HDBError naming the file when it has none or other modes."""
    if not mmx.is_file():
        raise HDBError(mmx.name, "External force matrices", "no .mmx beside the run's .1: the structure of the "
                                                            "modes is in its external force matrices (IALTFRC = 2 or 3)")
    out = np.zeros((3, size, size))
    rows = _ROW.findall(mmx.read_text(errors="replace"))
    if not rows:
        raise HDBError(mmx.name, "External force matrices", "none in the file (the run had no IALTFRC = 2 or 3 "
                                                            "external mass, damping and stiffness)")
    for i, j, *values in rows:
        i, j = int(i) - 1, int(j) - 1
        if not (0 <= i < size and 0 <= j < size):
            raise HDBError(mmx.name, "External force matrices", f"mode ({i + 1}, {j + 1}) past the run's {size} "
                                                                "modes")
        out[:, i, j] = _floats(" ".join(values))
    return out[0], out[1], out[2]


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
        raise HDBError(mmx.name, "External force matrices", f"body {body!r} has no generalized modes")
    mass, damping, stiffness = external_force_matrices(mmx, dofs.size)
    start = dofs.index(body, 0)
    modal, rigid = np.arange(start + 6, start + 6 + len(names)), np.arange(start, start + 6)
    coupled = [k for k, m in (("mass", mass), ("damping", damping), ("stiffness", stiffness))
               if np.abs(m[np.ix_(rigid, modal)]).max() > 0 or np.abs(m[np.ix_(modal, rigid)]).max() > 0]
    note = (f"\n# {mmx.name} couples the rigid DOFs and the modes in {', '.join(coupled)}: left out (a scene's "
            "[bodies.modes] holds the modes' block)") if coupled else ""
    block = np.ix_(modal, modal)
    quoted = ", ".join(f'"{n}"' for n in names)
    return (f"# body {body!r}: the modes' external force matrices of {mmx.name}{note}\n[bodies.modes]\n"
            f"names = [{quoted}]\nmass = {_toml_values(mass[block])}\nstiffness = {_toml_values(stiffness[block])}\n"
            f"damping = {_toml_values(damping[block])}\n")
