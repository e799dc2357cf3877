"""A MoorDyn file's lines in independent groups (scene ``[[moorings]] workers``), each group a MoorDyn
file of its own that a worker process steps (clients/exudyn/moordyn_workers.py).

Independence: given the coupled bodies' and points' motion (which the multibody step prescribes),
two lines interact only through a point or a body they share whose motion MoorDyn integrates. The
lines are joined into components through every point that is not fixed to the ground (a free point
couples its lines' dynamics; a coupled or body-mounted point keeps a fairlead's lines together, so
that its own load and mass count once); ground-fixed points (anchors) are copied into each group
that uses them. Components go to ``n`` groups, largest first, onto the group with the fewest
segments. Every group file keeps the file's text: the same options, line types and bodies (every
coupled body in each group, so each group's coupled state is the bodies' poses and its own coupled
points), its points and lines renumbered in their file order, its output channels renamed.

Refused, with the reason (:class:`SplitRefused`): rods, free or fixed bodies, a coupled body with
its own mass, volume or drag area (each group would count it), FAILURE or SYROPE IC sections,
body or rod output channels, a layout the text and MoorDyn read differently, a single component.

The split is exact: the initial-condition solve is the whole file's (its stationary solve stops on
the whole system's residual), whose state (MoorDyn's ``SaveState``: per object, bodies, rods,
points, lines in file order, its state matrix) is cut into the groups' states (:func:`split_state`);
MoorDyn's time integration of one object reads only the objects it is attached to. What differs
is the coupled bodies' load: MoorDyn sums its points' forces and subtracts the inertia of their
summed mass (F - M a); the groups each do that for their own points and hydrolink sums the
groups' loads, so a body's load is the same sum in another order (round-off, ~1e-16 relative).

Outputs (:func:`merge_outputs`): every MoorDyn instance runs in a folder of its own; when the run
closes, the whole file's output files are made beside it from the whole instance's header and t = 0
row (after its initial-condition solve) and the groups' later rows: the main file's channels
column by column from the group that holds them, a line's file from its group, a body's from the
first group, the log the whole instance's followed by the groups'.
"""

from __future__ import annotations

import re
import struct
from dataclasses import dataclass
from pathlib import Path

import numpy as np

#: MoorDyn's section names (MoorDyn2.cpp readFile), by what hydrolink does with them in a group file
_SECTIONS = {
    "bodies": ("BODIES", "BODY LIST", "BODY PROPERTIES"),
    "rods": ("RODS", "ROD LIST", "ROD PROPERTIES"),
    "points": ("POINTS", "POINT LIST", "POINT PROPERTIES", "CONNECTION PROPERTIES", "NODE PROPERTIES"),
    "lines": ("LINES", "LINE LIST", "LINE PROPERTIES"),
    "line types": ("LINE DICTIONARY", "LINE TYPES"),
    "rod types": ("ROD DICTIONARY", "ROD TYPES"),
    "options": ("OPTIONS",),
    "outputs": ("OUTPUT",),
    "refused": ("FAILURE", "SYROPE IC"),
}
_GROUND = ("ANCHOR", "FIXED", "FIX")
_COUPLED = ("FAIRLEAD", "VESSEL", "VES", "COUPLED", "CPLD")
_FREE = ("POINT", "CONNECT", "CON", "FREE")
#: MoorDyn's point types (moordyn.POINT_TYPE_*)
POINT_COUPLED, POINT_FREE, POINT_FIXED = -1, 0, 1


class SplitRefused(ValueError):
    """The file's lines cannot be stepped in independent groups; the message says why."""


def _word(text: str) -> tuple[str, str, str]:
    """MoorDyn's decomposition of a word: leading letters (upper case), their number, the rest."""
    m = re.match(r"([A-Za-z]*)(\d*)(.*)", text)
    return m.group(1).upper(), m.group(2), m.group(3)


@dataclass(frozen=True)
class Section:
    """A ``---`` header line of a MoorDyn file, its kind and the lines under it."""
    header: str
    kind: str | None
    labels: tuple[str, ...]       # a table's label and unit lines
    rows: tuple[str, ...]         # its entries (blank lines dropped)


def sections(text: str) -> tuple[tuple[str, ...], tuple[Section, ...]]:
    """The lines before the first header, and the file's sections in order."""
    lines = text.splitlines()
    heads = [i for i, ln in enumerate(lines) if "---" in ln]
    out = []
    for k, i in enumerate(heads):
        body = lines[i + 1:heads[k + 1] if k + 1 < len(heads) else len(lines)]
        upper = lines[i].upper()
        kind = next((name for name, keys in _SECTIONS.items() if any(key in upper for key in keys)), None)
        table = kind not in (None, "options", "outputs", "refused")
        labels, rows = (body[:2], body[2:]) if table else ([], body)
        out.append(Section(lines[i], kind, tuple(labels), tuple(r for r in rows if r.strip())))
    return tuple(lines[:heads[0]] if heads else lines), tuple(out)


@dataclass(frozen=True)
class Graph:
    """What MoorDyn's own reading says of a file's points and lines (moordyn_mooring's probe)."""
    point_types: tuple[int, ...]                    # MoorDyn's type of each point, file order
    line_ends: tuple[tuple[int, int], ...]          # the points (1-based) at each line's ends A, B
    segments: tuple[int, ...]
    bodies: int
    coupled_bodies: int
    rods: int


@dataclass(frozen=True)
class Group:
    """One group's lines and points (1-based numbers in the whole file) and its file's text."""
    lines: tuple[int, ...]
    points: tuple[int, ...]
    coupled_points: tuple[int, ...]       # indices into the whole file's coupled points
    channels: tuple[int, ...]             # indices into the whole file's output channels
    text: str


@dataclass(frozen=True)
class Split:
    """A file's groups (their lines cover the file's, each once) and its object counts."""
    groups: tuple[Group, ...]
    bodies: int
    rods: int
    points: int
    channels: tuple[str, ...]             # the whole file's output channel names


def _zero(value: str) -> bool:
    try:
        return all(float(v) == 0.0 for v in value.split("|"))
    except ValueError:
        return False


def whole(text: str, graph: Graph) -> Split:
    """``text`` as one group (one worker): the file as it is."""
    _, secs = sections(text)
    out = next((s for s in secs if s.kind == "outputs"), None)
    channels = output_channels(out.rows if out is not None else ())
    kinds = graph.point_types
    coupled = tuple(range(sum(t == POINT_COUPLED for t in kinds)))
    group = Group(tuple(range(1, len(graph.line_ends) + 1)), tuple(range(1, len(kinds) + 1)), coupled,
                  tuple(range(len(channels))), text)
    return Split((group,), graph.bodies, graph.rods, len(kinds), channels)


def split(text: str, graph: Graph, n: int) -> Split:
    """``text`` (a MoorDyn file MoorDyn read as ``graph``) in at most ``n`` groups (module docstring);
    one group (:func:`whole`) for ``n`` = 1."""
    if n == 1:
        return whole(text, graph)
    preamble, secs = sections(text)
    by_kind = {s.kind: s for s in reversed(secs)}       # MoorDyn reads the first of each
    if "refused" in by_kind:
        raise SplitRefused(f"its {by_kind['refused'].header.strip('- ')} section refers to lines across the file")
    if graph.rods or by_kind.get("rods") and by_kind["rods"].rows:
        raise SplitRefused("it has rods")
    if graph.bodies != graph.coupled_bodies:
        raise SplitRefused(f"{graph.bodies - graph.coupled_bodies} of its bodies are not coupled (a free or fixed "
                           "body joins the lines on it)")
    for row in by_kind["bodies"].rows if "bodies" in by_kind else ():
        w = row.split()
        if len(w) < 13 or not all(_zero(w[k]) for k in (8, 11, 12)):
            raise SplitRefused(f"body {w[0]} has its own mass, volume or drag area (each group would count it): "
                               f"{row.strip()!r}")
    # points: where each is attached, by the text, checked against MoorDyn's types
    kinds = []
    for k, row in enumerate(by_kind["points"].rows if "points" in by_kind else (), start=1):
        w = row.split()
        let, num, _ = _word(w[1])
        kind = ("ground" if let in _GROUND else "body" if let == "BODY" else "coupled" if let in _COUPLED
                else "free" if let in _FREE else None)
        expected = {"ground": POINT_FIXED, "body": POINT_FIXED, "coupled": POINT_COUPLED, "free": POINT_FREE}.get(kind)
        if int(w[0]) != k or k > len(graph.point_types) or expected != graph.point_types[k - 1]:
            raise SplitRefused(f"its point {w[0]} ({w[1]}) is not what MoorDyn read")
        kinds.append(kind)
    if len(kinds) != len(graph.point_types):
        raise SplitRefused(f"MoorDyn read {len(graph.point_types)} points, the text lists {len(kinds)}")
    line_rows = by_kind["lines"].rows if "lines" in by_kind else ()
    ends = []
    for k, row in enumerate(line_rows, start=1):
        w = row.split()
        pts = []
        for word in w[2:4]:
            let, num, rest = _word(word)
            if let not in ("", "C", "CON", "P", "POINT") or not num or rest:
                raise SplitRefused(f"its line {w[0]} ends on {word} (a rod)")
            pts.append(int(num))
        ends.append(tuple(pts))
    if int(len(ends)) != len(graph.line_ends) or tuple(ends) != graph.line_ends:
        raise SplitRefused("its lines' end points are not what MoorDyn read")
    # components: lines joined through every point not fixed to the ground (union-find)
    parent = list(range(len(ends)))

    def root(i: int) -> int:
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i
    owner: dict[int, int] = {}
    for i, pair in enumerate(ends):
        for p in pair:
            if kinds[p - 1] == "ground":
                continue
            if p in owner:
                parent[root(i)] = root(owner[p])
            else:
                owner[p] = i
    comps: dict[int, list[int]] = {}
    for i in range(len(ends)):
        comps.setdefault(root(i), []).append(i)
    if len(comps) < 2:
        raise SplitRefused("its lines are all joined (through free, coupled or body-mounted points)")
    n = min(n, len(comps))
    bins: list[list[int]] = [[] for _ in range(n)]
    load = [0] * n
    for comp in sorted(comps.values(), key=lambda c: (-sum(graph.segments[i] for i in c), c[0])):
        b = load.index(min(load))
        bins[b].extend(comp)
        load[b] += sum(graph.segments[i] for i in comp)
    bins = sorted((sorted(b) for b in bins), key=lambda b: b[0])
    channels = output_channels(by_kind["outputs"].rows if "outputs" in by_kind else ())
    if refused := [c for c in channels if _word(c)[0] in ("B", "BODY", "R", "ROD")]:
        raise SplitRefused(f"its output channels {refused} are a body's or a rod's (each group holds part of its load)")
    coupled = [p for p, kind in enumerate(kinds, start=1) if kind == "coupled"]
    groups = tuple(_group(preamble, secs, by_kind, [i + 1 for i in b], ends, coupled, channels) for b in bins)
    return Split(groups, graph.bodies, graph.rods, len(kinds), channels)


def output_channels(rows) -> tuple[str, ...]:
    """The words of an OUTPUTS section MoorDyn takes for channels (it skips others with a warning)."""
    kinds = ("FAIRTEN", "ANCHTEN", "L", "LINE", "P", "POINT", "R", "ROD", "B", "BODY")
    return tuple(w for w in " ".join(rows).split() if _word(w)[0] in kinds)


def _group(preamble, secs, by_kind, lines: list[int], ends, coupled: list[int], channels) -> Group:
    points = sorted({p for k in lines for p in ends[k - 1]})
    new_point = {p: j for j, p in enumerate(points, start=1)}
    new_line = {k: j for j, k in enumerate(lines, start=1)}
    mine = []
    renamed = []
    for c, name in enumerate(channels):
        let, num, rest = _word(name)
        table = new_point if let in ("P", "POINT") else new_line
        if num and int(num) in table:
            mine.append(c)
            renamed.append(name[:len(let)] + str(table[int(num)]) + rest)
    out = list(preamble)
    for s in secs:
        if s.kind == "points":
            rows = [_renumber(s.rows[p - 1], new_point[p]) for p in points]
        elif s.kind == "lines":
            rows = []
            for k in lines:
                w = s.rows[k - 1].split()
                a, b = (new_point[p] for p in ends[k - 1])
                rows.append(" ".join([str(new_line[k]), w[1], str(a), str(b), *w[4:]]))
        elif s.kind == "outputs":
            rows = [" ".join(renamed)] if renamed else []
        else:
            rows = list(s.rows)
        if s.kind == "outputs" and not rows:
            continue
        out += [s.header, *s.labels, *rows]
    return Group(tuple(lines), tuple(points), tuple(coupled.index(p) for p in points if p in coupled),
                 tuple(mine), "\n".join(out) + "\n")


def _renumber(row: str, number: int) -> str:
    w = row.split()
    return " ".join([str(number), *w[1:]])


# -- the initial state --------------------------------------------------------------------------------
#: a MoorDyn binary file's magic: "MoorDyn", its major and minor version (IO.cpp MakeFile)
_MAGIC = 9


def _instances(data: bytes) -> list[bytes]:
    """The per-object chunks of a MoorDyn state file (``SaveState``: the magic, the words that
    follow, the object count, then per object its state matrix: rows, columns, values)."""
    if data[:7] != b"MoorDyn":
        raise ValueError("not a MoorDyn state file")
    words = np.frombuffer(data[_MAGIC:], "<u8")
    size, count = int(words[0]), int(words[1])
    if size != words.size - 1:
        raise ValueError(f"a MoorDyn state of {size} words in {words.size - 1}")
    out, i = [], 2
    for _ in range(count):
        rows, cols = int(words[i]), int(words[i + 1])
        end = i + 2 + rows * cols
        out.append(words[i:end].tobytes())
        i = end
    if i != words.size:
        raise ValueError("a MoorDyn state with words after its last object")
    return out


def split_state(data: bytes, whole: Split) -> list[bytes]:
    """The whole file's state (``SaveState``'s file) cut into its groups' (module docstring)."""
    chunks = _instances(data)
    n_lines = sum(len(g.lines) for g in whole.groups)
    if len(chunks) != whole.bodies + whole.rods + whole.points + n_lines:
        raise ValueError(f"a MoorDyn state of {len(chunks)} objects for {whole.bodies} bodies, {whole.points} "
                         f"points and {n_lines} lines")
    nbr = whole.bodies + whole.rods
    bodies_rods, points, lines = chunks[:nbr], chunks[nbr:nbr + whole.points], chunks[nbr + whole.points:]
    out = []
    for g in whole.groups:
        mine = bodies_rods + [points[p - 1] for p in g.points] + [lines[k - 1] for k in g.lines]
        body = struct.pack("<Q", len(mine)) + b"".join(mine)
        out.append(data[:_MAGIC] + struct.pack("<Q", len(body) // 8) + body)
    return out


# -- the outputs ----------------------------------------------------------------------------------------
def _is_row(line: str) -> bool:
    try:
        float(line.split()[0])
        return True
    except (ValueError, IndexError):
        return False


def _head_and_rows(path: Path) -> tuple[list[str], list[str]]:
    """A MoorDyn output file's header lines and t = 0 row, and its later rows."""
    lines = path.read_text(errors="replace").splitlines() if path.exists() else []
    first = next((i for i, ln in enumerate(lines) if _is_row(ln)), len(lines))
    return lines[:first + 1], [ln for ln in lines[first + 1:] if ln.strip()]


def _until(rows: list[str], t_last: float) -> list[str]:
    """Rows up to time ``t_last`` (a step stepped ahead and not taken is dropped)."""
    return [r for r in rows if float(r.split()[0]) <= t_last + 1e-9]


def merge_outputs(whole: Path, whole_split: Split, groups: list[Path], target: Path, t_last: float) -> None:
    """Make the whole file's outputs (``target``: the input file's path; ``whole``: the file the
    whole instance ran, ``groups``: the files the groups ran) from the instances' (module docstring)."""
    stem, folder = target.stem, target.parent
    head, _ = _head_and_rows(whole.with_suffix(".out"))
    if head:
        parts = [_until(_head_and_rows(g.with_suffix(".out"))[1], t_last) for g in groups]
        rows = []
        for k in range(min(map(len, parts), default=0)):
            cols: dict[int, str] = {}
            time = ""
            for g, row in zip(whole_split.groups, (p[k] for p in parts)):
                n = len(g.channels)
                if not n:
                    continue
                width = (len(row) - 10) // n
                time = row[:10]
                for j, c in enumerate(g.channels):
                    cols[c] = row[10 + j * width:10 + (j + 1) * width]
            rows.append(time + "".join(cols[c] for c in range(len(whole_split.channels))))
        (folder / f"{stem}.out").write_text("\n".join(head + rows) + "\n")
    for g, file in zip(whole_split.groups, groups):
        for j, k in enumerate(g.lines, start=1):
            _splice(whole.parent / f"{whole.stem}_Line{k}.out", file.parent / f"{file.stem}_Line{j}.out",
                    folder / f"{stem}_Line{k}.out", t_last)
    for body in sorted(whole.parent.glob(f"{whole.stem}_Body*.out")):
        _splice(body, groups[0].parent / body.name.replace(whole.stem, groups[0].stem, 1),
                folder / body.name.replace(whole.stem, stem, 1), t_last)
    logs = [whole.with_suffix(".log"), *(g.with_suffix(".log") for g in groups)]
    if logs[0].exists():
        text = logs[0].read_text(errors="replace")
        for k, (log, g) in enumerate(zip(logs[1:], whole_split.groups)):
            if log.exists():
                text += (f"\n--- hydrolink: group {k + 1} of {len(groups)} (lines {', '.join(map(str, g.lines))}), "
                         "stepped in a worker process from the state above ---\n" + log.read_text(errors="replace"))
        (folder / f"{stem}.log").write_text(text)


def _splice(head_from: Path, rows_from: Path, target: Path, t_last: float) -> None:
    head, _ = _head_and_rows(head_from)
    if head:
        target.write_text("\n".join(head + _until(_head_and_rows(rows_from)[1], t_last)) + "\n")
