"""MoorDyn v2 moorings (scene ``[[moorings]] type = "moordyn"``): lumped-mass lines with seabed
contact, stepped by MoorDyn's own library (Python package ``moordyn``) once per multibody step.

Layout of a file (:func:`load_moordyn_files`, before anything runs): the file is opened by MoorDyn in
a child process — a malformed file can crash MoorDyn's reader (a segmentation fault, e.g. an OUTPUTS
section not followed by a ``---`` line), and that must be an error naming the file, not the end of the
run. It gives the number of coupled bodies, rods and points, the coupled points' positions and the
number of lines; the counts must match the scene's ``bodies`` / ``points``.

Coupling (:class:`MoorDynSystem`), MoorDyn's conventions (MoorDyn2.cpp ``Step``, Body.cpp):

- the coupled state is 6 values per coupled body (position of the body origin, then roll, pitch,
  yaw in rad with R = Rx(roll) Ry(pitch) Rz(yaw) — Exudyn's ``NodeRigidBodyRxyz`` convention), then
  3 per coupled point; the coupled body's origin is the scene body's reference point;
- ``Step(x, v, t, dt)`` moves each coupled entity from x along x + v τ (τ in [0, dt]) while MoorDyn
  integrates its lines over dt in substeps of its dtM, and returns the forces on the coupled entities
  at t + dt (a body: force and moment about its origin, global axes). The multibody step applies
  loads at its end (implicit integrators), so the step t_k -> t_k+1 is driven from the pose at t_k
  towards the pose the step ends in: x = pose(t_k), v = (pose_end - pose(t_k)) / dt, where pose_end
  is predicted (x + dt v + dt²/2 a: the predictor of the explicit and mass-matrix schemes; the
  fairlead then ends O(dt³) from the body) or, when the implicit scheme redoes the step, the end
  pose of its previous iteration (the fairlead path converges to the body's with the iteration; what
  is left is the last iteration's change of the end pose — a scene without wet bodies has no
  server forces to iterate on, so its implicit steps are not redone and use the prediction);
- a step advances MoorDyn's state (calling it twice is not idempotent): a redo restores it with
  ``Serialize``/``Deserialize`` (:meth:`MoorDynSystem.save` / :meth:`MoorDynSystem.restore`);
- MoorDyn returns a coupled body's force less the inertia of what it carries (the line end nodes
  attached to it: −M a, with a = the change of the velocity passed in over dt), but a coupled
  point's force without it; hydrolink subtracts a coupled point's mass matrix (``GetPointM``: the
  end nodes' mass and added mass) times that same finite-difference acceleration, so a spread
  coupled through points moves as the same spread on a coupled body;
- ``Init`` runs MoorDyn's initial-condition solve (options dtIC, TmaxIC, threshIC in the file) with
  the bodies at their initial pose: the lines start at rest in equilibrium, no jerk.

The scene's ``[current]`` (protocol/current.py) reaches the lines through MoorDyn's own steady
current grid (option ``Currents`` = 1): hydrolink writes a copy of the file with that option and
the grid ``current_profile.txt`` (the profile tabulated in depth, MoorDyn interpolating linearly
between levels and holding the end values beyond them) into a temporary folder, runs MoorDyn on the
copy and moves MoorDyn's output files beside the original file when it closes. MoorDyn sets its
runtime water kinematics after its initial-condition solve: the lines start in their still-water
shape and take the current's drag from t = 0 on (so does the static-offset estimate, which uses
that solve: it leaves the current out). A file that sets its own ``Currents``, ``WaveKin`` or
``WaterKin`` together with a scene ``[current]`` is refused (which one applies would be a guess).

MoorDyn writes to the process's stdout/stderr (banner, per-line report, "t = ..." every step unless
the file says ``1 disableOutTime``): every call is made with both redirected to a scratch file, whose
last lines go into the error message when MoorDyn fails.

Worker processes (``workers`` >= 1, the default 1): :meth:`MoorDynSystem.start` runs the whole file's
initial-condition solve here, in a folder of its own, then hands its state to the workers
(moordyn_workers.py: the whole file in one, or its independent groups, moordyn_split.py) and closes
its instance; the t = 0 outputs are kept from it. :meth:`MoorDynSystem.step_ahead` starts the next
step in the workers before it is asked for (the adapter: while the hydrodynamic forces are
computed); :meth:`MoorDynSystem.close` ends the workers and makes MoorDyn's output files beside the
scene's file from the instances' (moordyn_split.merge_outputs).
"""

from __future__ import annotations

import json
import logging
import math
import os
import shutil
import subprocess
import sys
import tempfile
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from hydrolink.clients.exudyn.moordyn_split import Graph, SplitRefused, merge_outputs, split, split_state
from hydrolink.clients.exudyn.moordyn_workers import complaint
from hydrolink.protocol.current import MAX_DEPTH, Current
from hydrolink.protocol.scene import MoorDynMooring, Scene, SceneError, resolve_path

log = logging.getLogger(__name__)

#: seconds the child process may take to read a MoorDyn file
PROBE_TIMEOUT = 60.0
#: MoorDyn's steady current grid, read beside its input file (option Currents = 1)
CURRENT_FILE = "current_profile.txt"
#: levels of the tabulated power-law and linear profiles (clustered towards the profile's depth)
CURRENT_LEVELS = 201
#: MoorDyn options a scene [current] would contradict
_WATER_OPTIONS = ("currents", "wavekin", "waterkin")


class MoorDynFailure(RuntimeError):
    """MoorDyn failed (an error code, non-finite forces); the message names the file."""


# -- quiet calls ------------------------------------------------------------------------------------
class _Quiet:
    """Redirects fds 1 and 2 to one scratch file around MoorDyn calls (its C++ output)."""

    def __init__(self) -> None:
        self.file = tempfile.TemporaryFile(mode="w+b")
        self.fd = self.file.fileno()

    @contextmanager
    def __call__(self):
        sys.stdout.flush()
        sys.stderr.flush()
        saved = os.dup(1), os.dup(2)
        os.dup2(self.fd, 1)
        os.dup2(self.fd, 2)
        try:
            yield
        finally:
            os.dup2(saved[0], 1)
            os.dup2(saved[1], 2)
            os.close(saved[0])
            os.close(saved[1])

    def said(self) -> str:
        """What MoorDyn complained about since the last :meth:`clear` (its error lines)."""
        self.file.seek(0)
        return complaint(self.file.read())

    def clear(self) -> None:
        self.file.seek(0)
        self.file.truncate()

    def close(self) -> None:
        self.file.close()


# -- the file's layout (child process) -----------------------------------------------------------------
@dataclass(frozen=True)
class MoorDynLayout:
    """What a MoorDyn input file couples, read by MoorDyn itself."""

    path: Path
    coupled_bodies: int
    coupled_rods: int
    coupled_points: np.ndarray      # (n, 3) positions the file gives the coupled points
    lines: int
    graph: Graph                    # its points and lines as MoorDyn read them (for workers: moordyn_split)

    @property
    def coupled_dofs(self) -> int:
        return 6 * self.coupled_bodies + 6 * self.coupled_rods + 3 * len(self.coupled_points)


def _probe_main(path: str, out: str) -> None:
    """Child process: open ``path`` with MoorDyn and write its coupled layout to ``out`` (JSON)."""
    import cmoordyn
    import moordyn
    m = moordyn.Create(path)
    bodies = sum(moordyn.GetBodyType(moordyn.GetBody(m, i)) == moordyn.BODY_TYPE_COUPLED
                 for i in range(1, moordyn.GetNumberBodies(m) + 1))
    rods = sum(moordyn.GetRodType(moordyn.GetRod(m, i)) in (moordyn.ROD_TYPE_COUPLED, moordyn.ROD_TYPE_CPLDPIN)
               for i in range(1, moordyn.GetNumberRods(m) + 1))
    all_points = [moordyn.GetPoint(m, i) for i in range(1, moordyn.GetNumberPoints(m) + 1)]
    points = [list(moordyn.GetPointPos(p)) for p in all_points if moordyn.GetPointType(p) == moordyn.POINT_TYPE_COUPLED]
    lines = [moordyn.GetLine(m, i) for i in range(1, moordyn.GetNumberLines(m) + 1)]
    ends = [[0, 0] for _ in lines]
    for k, p in enumerate(all_points, start=1):
        for j in range(cmoordyn.point_get_nattached(p)):
            line, end = cmoordyn.point_get_attached(p, j)
            ends[cmoordyn.line_get_id(line) - 1][end] = k
    layout = {"bodies": int(bodies), "rods": int(rods), "points": points, "lines": len(lines),
              "dofs": moordyn.NCoupledDOF(m), "all_bodies": moordyn.GetNumberBodies(m),
              "all_rods": moordyn.GetNumberRods(m), "point_types": [moordyn.GetPointType(p) for p in all_points],
              "line_ends": ends, "segments": [moordyn.GetLineN(line) for line in lines]}
    moordyn.Close(m)
    Path(out).write_text(json.dumps(layout))


def read_layout(path: Path) -> MoorDynLayout:
    """The coupled layout of a MoorDyn file (MoorDynFailure naming the file and MoorDyn's complaint)."""
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "layout.json"
        code = ("import numpy, sys; from hydrolink.clients.exudyn.moordyn_mooring import _probe_main; "
                "_probe_main(sys.argv[1], sys.argv[2])")
        try:
            proc = subprocess.run([sys.executable, "-c", code, str(path), str(out)], capture_output=True,
                                  timeout=PROBE_TIMEOUT, cwd=str(path.parent))
        except subprocess.TimeoutExpired:
            raise MoorDynFailure(f"MoorDyn took more than {PROBE_TIMEOUT:g} s to read {path}") from None
        if proc.returncode != 0 or not out.exists():
            raise MoorDynFailure(("MoorDyn crashed reading it (signal {-proc.returncode})" if proc.returncode < 0
                                  else "MoorDyn could not read it") + ": " + complaint(proc.stdout + proc.stderr))
        d = json.loads(out.read_text())
    points = np.asarray(d["points"], float).reshape(-1, 3)
    graph = Graph(tuple(d["point_types"]), tuple(map(tuple, d["line_ends"])), tuple(d["segments"]),
                  d["all_bodies"], d["bodies"], d["all_rods"])
    layout = MoorDynLayout(path, d["bodies"], d["rods"], points, d["lines"], graph)
    if layout.coupled_dofs != d["dofs"]:
        raise MoorDynFailure(f"MoorDyn couples {d['dofs']} DOFs, the bodies, rods and points it lists make "
                             f"{layout.coupled_dofs}")
    return layout


# -- the current ----------------------------------------------------------------------------------------
def _options(text: str) -> dict[str, str] | None:
    """The OPTIONS section of a MoorDyn file's ``text``: option name (lower case) -> value as
    written; None when the file has no such section."""
    out: dict[str, str] | None = None
    inside = False
    for line in text.splitlines():
        if line.lstrip().startswith("---"):
            inside = "OPTIONS" in line.upper()
            out = {} if inside and out is None else out
            continue
        words = line.split()
        if inside and len(words) >= 2:
            out[words[1].lower()] = words[0]
    return out


def current_conflict(path: Path) -> str | None:
    """Why MoorDyn file ``path`` cannot take a scene's current (None: it can): it sets its own water
    kinematics (non-zero ``Currents``, ``WaveKin``, or a ``WaterKin`` file), or it has no OPTIONS
    section to set ``Currents`` in."""
    found = _options(path.read_text(errors="replace"))
    if found is None:
        return f"{path.name} has no OPTIONS section to set the scene's [current] in (Currents = 1)"
    own = [f"{v} {k}" for k, v in found.items() if k in _WATER_OPTIONS and v not in ("0", "0.0")]
    return (f"{path.name} sets its own water kinematics ({', '.join(own)}) and the scene has a [current]: keep "
            "one of them") if own else None


def current_profile(current: Current) -> np.ndarray:
    """(L, 4) rows z, ux, uy, uz of MoorDyn's steady current grid for ``current``: z from the
    profile's depth (or the deepest water for a uniform one) to the still water line."""
    depth = MAX_DEPTH if current.depth is None else current.depth
    s = np.linspace(0.0, 1.0, 2 if current.profile == "uniform" else CURRENT_LEVELS) ** 3
    z = -depth * (1.0 - s)
    return np.column_stack([z, current.velocity(z)])


def with_current(path: Path, current: Current, folder: Path) -> Path:
    """A copy of MoorDyn file ``path`` in ``folder`` with ``Currents`` = 1 and its grid
    ``current_profile.txt`` for ``current`` beside it (a file :func:`current_conflict` passes)."""
    lines = path.read_text(errors="replace").splitlines()
    header = next(i for i, ln in enumerate(lines)
                  if ln.lstrip().startswith("---") and "OPTIONS" in ln.upper())
    lines.insert(header + 1, "1 Currents - steady current grid current_profile.txt (hydrolink, from [current])")
    out = folder / path.name
    out.write_text("\n".join(lines) + "\n")
    rows = "\n".join(" ".join(f"{v:.17g}" for v in row) for row in current_profile(current))
    (folder / CURRENT_FILE).write_text("--- MoorDyn steady currents file written by hydrolink ---\n"
                                       f"{current!r}\nz (m), ux (m/s), uy (m/s), uz (m/s)\n{rows}\n")
    return out


def load_moordyn_files(scene: Scene, scene_path: str | Path) -> dict[int, MoorDynLayout]:
    """The layouts of the scene's MoorDyn files by mooring index, checked against the scene
    (SceneError naming the scene file, the key and why)."""
    out: dict[int, MoorDynLayout] = {}
    for i, m in enumerate(scene.moorings):
        if not isinstance(m, MoorDynMooring):
            continue
        key = f"moorings[{i}]"
        path = resolve_path(scene_path, m.file)
        if not path.is_file():
            raise SceneError(scene_path, f"{key}.file", f"MoorDyn input file not found: {path}")
        try:
            layout = read_layout(path)
        except MoorDynFailure as exc:
            raise SceneError(scene_path, f"{key}.file", f"{path}: {exc}") from None
        if scene.current is not None and (why := current_conflict(path)):
            raise SceneError(scene_path, f"{key}.file", why)
        if layout.coupled_rods:
            raise SceneError(scene_path, f"{key}.file", f"{path}: {layout.coupled_rods} coupled rod(s): hydrolink "
                                                        "couples MoorDyn bodies and points only")
        for what, n, given in (("bodies", layout.coupled_bodies, m.bodies),
                               ("points", len(layout.coupled_points), m.points)):
            if n != len(given):
                raise SceneError(scene_path, f"{key}.{what}",
                                 f"{path.name} has {n} coupled {what[:-1] if n == 1 else what}, {key}.{what} "
                                 f"lists {len(given)} scene bod{'y' if len(given) == 1 else 'ies'} {given}")
        if m.workers > 1:
            try:
                split(path.read_text(errors="replace"), layout.graph, m.workers)
            except SplitRefused as exc:
                raise SceneError(scene_path, f"{key}.workers", f"{path.name} cannot be stepped in {m.workers} worker "
                                                               f"processes: {exc} (workers = 1 steps it whole in one)") from None
        out[i] = layout
    return out


# -- kinematics -------------------------------------------------------------------------------------
def rotation_xyz(angles: np.ndarray) -> np.ndarray:
    """R = Rx(a) Ry(b) Rz(c) for (..., 3) angles: (..., 3, 3)."""
    a, b, c = (np.asarray(angles, float)[..., k] for k in range(3))
    ca, sa, cb, sb, cc, sc = np.cos(a), np.sin(a), np.cos(b), np.sin(b), np.cos(c), np.sin(c)
    return np.stack([
        np.stack([cb * cc, -cb * sc, sb], -1),
        np.stack([sa * sb * cc + ca * sc, -sa * sb * sc + ca * cc, -sa * cb], -1),
        np.stack([-ca * sb * cc + sa * sc, ca * sb * sc + sa * cc, ca * cb], -1)], -2)


# -- the running system -------------------------------------------------------------------------------
class MoorDynSystem:
    """One MoorDyn instance coupled to scene bodies (module docstring).

    ``rows``: each scene body's row in the (B, 6) pose arrays the caller passes; the loads come back
    per coupled scene body (``spec.coupled_bodies`` order), force and moment about its reference
    point, global axes. ``current``: the scene's, on the lines (module docstring)."""

    def __init__(self, spec: MoorDynMooring, layout: MoorDynLayout, key: str, rows: dict[str, int],
                 reference: np.ndarray, current: Current | None = None):
        self.spec, self.layout, self.key = spec, layout, key
        self.label = f"{key} ({layout.path})"
        # the file MoorDyn runs: the scene's, or its copy with the current in a temporary folder
        self._folder = tempfile.TemporaryDirectory(prefix="hydrolink-moordyn-") if current is not None else None
        self.model_path = (layout.path if current is None
                           else with_current(layout.path, current, Path(self._folder.name)))
        self.names = spec.coupled_bodies
        self._row_of = {n: rows[n] for n in self.names}
        self._body_rows = np.array([rows[n] for n in spec.bodies], int)
        self._point_rows = np.array([rows[n] for n in spec.points], int)
        # a coupled point's offset from its body's reference point (body axes = global at zero angles)
        ref = np.asarray(reference, float)
        self._point_local = layout.coupled_points - ref[self._point_rows, :3] if len(spec.points) else np.zeros((0, 3))
        # where each coupled entity's force goes: scene body index in `names`
        self._body_out = np.array([self.names.index(n) for n in spec.bodies], int)
        self._point_out = np.array([self.names.index(n) for n in spec.points], int)
        # each coupled body a different scene body (the usual file): its force is placed, not summed
        self._bodies_distinct = len(set(spec.bodies)) == len(spec.bodies)
        self._nb6 = 6 * len(spec.bodies)
        self.n_lines = layout.lines
        self.loads = np.zeros((len(self.names), 6))
        self.initial_loads = np.zeros((len(self.names), 6))
        self.offset: np.ndarray | None = None          # static offset under the mooring (static_offset)
        self.offset_residual = 0.0
        self.instance = None
        self._quiet = _Quiet()
        self._lines: list = []
        self._fairlead: list[int] = []
        self._nodes: list[int] = []
        self._cpoints: list = []                       # MoorDyn's coupled points, file order
        self._point_velocity = np.zeros((len(spec.points), 3))   # passed at the last step
        self.steps = 0
        self.dtm = 0.0                                   # MoorDyn's own step (from its file)
        # spec.workers >= 1: the groups in worker processes (moordyn_workers), started by start()
        self._groups = None
        self._run_dir: tempfile.TemporaryDirectory | None = None
        self._split = None
        self._at_start: tuple[np.ndarray, np.ndarray, np.ndarray | None] | None = None   # t = 0 outputs
        self._t_last = 0.0                               # end of the last step taken (the outputs' last row)
        self._group_files: list[Path] = []
        self._saved = False                              # a save was asked for: no steps ahead (a redo may come)

    # -- kinematics --------------------------------------------------------------------------------
    def _points(self, pose: np.ndarray) -> np.ndarray:
        """Global positions (P, 3) of the coupled points for body poses (B, 6)."""
        if not len(self._point_rows):
            return np.zeros((0, 3))
        p = pose[self._point_rows]
        return p[:, :3] + np.einsum("pij,pj->pi", rotation_xyz(p[:, 3:]), self._point_local)

    def _coupled(self, pose: np.ndarray, points: np.ndarray | None = None) -> np.ndarray:
        """MoorDyn's coupled state for body poses (B, 6): the coupled bodies' poses, then the coupled
        points' positions (``points``, from :meth:`_points`, when already computed)."""
        bodies = pose[self._body_rows].reshape(-1)
        if not len(self._point_rows):
            return bodies
        return np.concatenate([bodies, (self._points(pose) if points is None else points).reshape(-1)])

    def _to_bodies(self, f: np.ndarray, pose: np.ndarray, point_accel: np.ndarray | None = None,
                   points: np.ndarray | None = None) -> np.ndarray:
        """MoorDyn's coupled forces -> (len(names), 6) loads about the bodies' reference points; a
        coupled point's force less its mass matrix times ``point_accel`` (module docstring).
        ``points``: the coupled points' positions at ``pose`` when already computed."""
        out = np.zeros((len(self.names), 6))
        nb6 = self._nb6
        if nb6:
            if self._bodies_distinct:
                out[self._body_out] = f[:nb6].reshape(-1, 6)
            else:
                np.add.at(out, self._body_out, f[:nb6].reshape(-1, 6))
        if len(self._point_rows):
            fp = f[nb6:].reshape(-1, 3)
            if point_accel is not None:
                fp = fp - np.einsum("pij,pj->pi", self._point_mass(), point_accel)
            r = (self._points(pose) if points is None else points) - pose[self._point_rows, :3]
            np.add.at(out, self._point_out, np.hstack([fp, np.cross(r, fp)]))
        return out

    def _point_mass(self) -> np.ndarray:
        """(P, 3, 3) the coupled points' mass matrices after the last step (``GetPointM``)."""
        if self._groups is not None:
            return self._groups.point_mass
        import cmoordyn
        return np.array([cmoordyn.point_get_m(p) for p in self._cpoints])

    # -- life cycle ----------------------------------------------------------------------------------
    def _fail(self, why: str) -> MoorDynFailure:
        return MoorDynFailure(f"{self.label}: {why} (MoorDyn: {self._quiet.said()})")

    def start(self, pose: np.ndarray) -> np.ndarray:
        """Create the instance and run MoorDyn's initial-condition solve with the bodies held at
        ``pose`` (B, 6); returns the loads at t = 0. (The bodies are passed at rest: MoorDyn moves a
        coupled body along its velocity during the solve. A body that starts moving enters the first
        step's finite-difference inertia of the end nodes, M v0 / dt, once.)"""
        import moordyn
        x = self._coupled(pose)
        v = np.zeros_like(x)
        model = self.model_path
        if self.spec.workers:     # the whole instance in a folder of its own (moordyn_split: outputs)
            self._run_dir = tempfile.TemporaryDirectory(prefix="hydrolink-moordyn-workers-")
            model = self._copy_model(Path(self._run_dir.name) / "whole", self.model_path.read_text(errors="replace"))
        cwd = os.getcwd()
        try:
            with self._quiet():
                os.chdir(model.parent)    # MoorDyn writes its own outputs beside its file
                try:
                    self.instance = moordyn.Create(str(model))
                    err = moordyn.Init(self.instance, x.tolist(), v.tolist())
                    f0 = np.asarray(moordyn.Step(self.instance, x.tolist(), v.tolist(), 0.0, 0.0), float)
                finally:
                    os.chdir(cwd)
        except (RuntimeError, ValueError) as exc:
            raise self._fail(f"MoorDyn failed to start: {exc}") from None
        if err:
            raise self._fail(f"MoorDyn's initial-condition solve failed (error code {err})")
        if not np.isfinite(f0).all():
            raise self._fail("MoorDyn's initial-condition solve gave non-finite forces")
        self._point_velocity = v[6 * len(self._body_rows):].reshape(-1, 3).copy()
        points = (moordyn.GetPoint(self.instance, k) for k in range(1, moordyn.GetNumberPoints(self.instance) + 1))
        self._cpoints = [p for p in points if moordyn.GetPointType(p) == moordyn.POINT_TYPE_COUPLED]
        self._lines = [moordyn.GetLine(self.instance, k) for k in range(1, self.n_lines + 1)]
        self._nodes = [moordyn.GetLineN(line) for line in self._lines]
        # the fairlead end of each line: the end nearer the surface at t = 0
        self._fairlead = [n if moordyn.GetLineNodePos(line, n)[2] >= moordyn.GetLineNodePos(line, 0)[2] else 0
                          for line, n in zip(self._lines, self._nodes)]
        import cmoordyn          # moordyn.GetDt (2.7.2) drops the value it gets from here
        self.dtm = float(cmoordyn.get_dt(self.instance))
        self._quiet.clear()
        self.loads = self.initial_loads = self._to_bodies(f0, pose)
        if self.spec.workers:
            self._start_workers(model, x)
        return self.loads

    def _copy_model(self, folder: Path, text: str) -> Path:
        """``text`` as the model file in ``folder`` (with the current's grid beside it)."""
        folder.mkdir(parents=True)
        out = folder / self.layout.path.name
        out.write_text(text)
        if self._folder is not None:
            shutil.copyfile(Path(self._folder.name) / CURRENT_FILE, folder / CURRENT_FILE)
        return out

    def _start_workers(self, model: Path, x: np.ndarray) -> None:
        """Hand the started whole instance over to ``spec.workers`` worker processes: its state
        after the initial-condition solve cut into the groups' (moordyn_split), the t = 0
        outputs kept, the whole instance closed (its files hold the outputs' heads)."""
        import moordyn

        from hydrolink.clients.exudyn.moordyn_workers import WorkerSpec, start_groups
        run = Path(self._run_dir.name)
        state = run / "whole.state"
        nodes = self.max_nodes if self.spec.record_nodes else 0
        self._at_start = (self.tensions(), self.end_forces(), self.node_positions(nodes) if nodes else None)
        with self._quiet():
            moordyn.SaveState(self.instance, str(state))
            moordyn.Close(self.instance)
        self.instance = None
        self._split = split(model.read_text(errors="replace"), self.layout.graph, self.spec.workers)
        states = split_state(state.read_bytes(), self._split)
        nb6 = self._nb6
        specs, files = [], []
        for k, (g, data) in enumerate(zip(self._split.groups, states), start=1):
            file = self._copy_model(run / f"group{k}", g.text)
            (file.parent / "start.state").write_bytes(data)
            xg = np.concatenate([x[:nb6], x[nb6:].reshape(-1, 3)[list(g.coupled_points)].reshape(-1)])
            specs.append(WorkerSpec(str(file), str(file.parent / "start.state"), tuple(xg.tolist()),
                                    len(g.coupled_points), tuple(self._fairlead[k - 1] for k in g.lines), nodes))
            files.append(file)
        self._group_files = files
        self._groups = start_groups(self.label, specs, [g.coupled_points for g in self._split.groups],
                                    [tuple(k - 1 for k in g.lines) for g in self._split.groups], nb6,
                                    len(self._point_rows), self.n_lines, run)

    def step_note(self, dt: float) -> str | None:
        """Why ``dt`` (the multibody step) does not suit MoorDyn's dtM (None when it does)."""
        n = dt / self.dtm
        if abs(n - round(n)) <= 1e-6 * max(n, 1.0):
            return None
        return (f"{self.key}: simulation.dt = {dt:g} s is not a multiple of dtM = {self.dtm:g} s in {self.layout.path.name}: "
                f"MoorDyn takes {math.ceil(n - 1e-9)} substeps per step, the last one shorter; make dt a multiple of dtM")

    def loads_at(self, pose: np.ndarray) -> np.ndarray:
        """The loads (len(names), 6) after MoorDyn's initial-condition solve with the bodies held at
        ``pose`` (B, 6), from a separate MoorDyn instance (the running one is left alone)."""
        import moordyn
        x = self._coupled(pose)
        zero = [0.0] * x.size
        cwd = os.getcwd()
        try:
            with self._quiet():
                os.chdir(self.layout.path.parent)
                try:
                    m = moordyn.Create(str(self.model_path))
                    moordyn.Init(m, x.tolist(), zero)
                    f = np.asarray(moordyn.Step(m, x.tolist(), zero, 0.0, 0.0), float)
                    moordyn.Close(m)
                finally:
                    os.chdir(cwd)
        except (RuntimeError, ValueError) as exc:
            raise self._fail(f"MoorDyn failed in the static offset estimate: {exc}") from None
        return self._to_bodies(f, pose)

    def static_offset(self, pose: np.ndarray, displacement: np.ndarray, stiffness: np.ndarray,
                      constant: np.ndarray, active: np.ndarray, iterations: int = 6,
                      tolerance: float = 1e-3) -> tuple[np.ndarray, float]:
        """Displacement (len(names), 6) from their reference positions at which the coupled bodies'
        restoring force −C x (``stiffness`` (B, 6, 6) about the reference points; zero for dry
        bodies) and ``constant`` loads (B, 6: a wet body's net buoyancy, a dry body's weight and
        buoyancy) balance the mooring's load, over their ``active`` (B, 6) DOFs, starting from the
        bodies' ``pose`` (B, 6) = reference + ``displacement`` (B, 6) where MoorDyn was started; the
        other bodies are held (joints and PTOs are not part of it). Chord Newton: the mooring's
        stiffness by one-sided finite differences (0.1 m, 0.01 rad) of MoorDyn's initial-condition
        solve, then one solve per iteration until the out-of-balance load is below ``tolerance`` ×
        the mooring's load. Returns the displacement and the out-of-balance load left (N, N m)."""
        rows = [self._row_of[n] for n in self.names]
        dofs = [(j, d) for j, r in enumerate(rows) for d in range(6) if active[r, d]]
        out = displacement[rows].copy()
        if not dofs:
            return out, 0.0

        def vec(a: np.ndarray) -> np.ndarray:
            return np.array([a[j, d] for j, d in dofs])

        def moved(delta: np.ndarray) -> np.ndarray:
            p = pose.copy()
            for (j, d), x in zip(dofs, delta):
                p[rows[j], d] += x
            return p

        c = np.array([[stiffness[rows[j], d, e] if j == k else 0.0 for k, e in dofs] for j, d in dofs])
        q0 = vec(displacement[rows])
        f_const = vec(constant[rows])
        f0 = vec(self.initial_loads) + f_const
        k_moor = np.zeros((len(dofs), len(dofs)))
        for i, (j, d) in enumerate(dofs):
            step = 0.1 if d < 3 else 0.01
            e = np.zeros(len(dofs))
            e[i] = step
            k_moor[:, i] = -(vec(self.loads_at(moved(e))) + f_const - f0) / step
        k = c + k_moor
        delta, f = np.zeros(len(dofs)), f0
        scale = max(float(np.abs(f0).max()), 1e-300)
        for _ in range(iterations):
            r = f - c @ (q0 + delta)
            if float(np.abs(r).max()) <= tolerance * scale:
                break
            delta = delta + np.linalg.lstsq(k, r, rcond=None)[0]
            f = vec(self.loads_at(moved(delta))) + f_const
        r = f - c @ (q0 + delta)
        for (j, d), x in zip(dofs, q0 + delta):
            out[j, d] = x
        return out, float(np.abs(r).max())

    def _motion(self, dt: float, pose0: np.ndarray, pose1: np.ndarray
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        """MoorDyn's coupled state at ``pose0``, its velocity towards ``pose1`` over ``dt``, and the
        coupled points' positions at ``pose1`` (None without coupled points)."""
        x0 = self._coupled(pose0)
        points1 = self._points(pose1) if len(self._point_rows) else None
        return x0, (self._coupled(pose1, points1) - x0) / dt, points1

    def step_ahead(self, t0: float, dt: float, pose0: np.ndarray, pose1: np.ndarray, ahead: bool = True) -> None:
        """Start the step :meth:`step` will be asked for next (same arguments) in the workers, so
        that they integrate while the caller does other work (no-op without workers; ``ahead``
        steps none after a :meth:`save`: a scheme that saves may redo the step). The caller vouches
        that the next call is that step (moordyn_workers: another is an error naming the mooring)."""
        if self._groups is not None and self._groups.pending is None and not (ahead and self._saved):
            x0, v, _ = self._motion(dt, pose0, pose1)
            self._groups.launch(t0, dt, x0, v, ahead=ahead)

    def step(self, t0: float, dt: float, pose0: np.ndarray, pose1: np.ndarray) -> np.ndarray:
        """Advance MoorDyn over [t0, t0 + dt] with the bodies moving linearly from ``pose0`` to
        ``pose1`` (B, 6); returns the loads at t0 + dt (and keeps them in ``loads``)."""
        x0, v, points1 = self._motion(dt, pose0, pose1)
        if self._groups is not None:
            f = self._step_groups(t0, dt, x0, v)
        else:
            import cmoordyn        # moordyn.Step is this call with its lists copied once more
            try:
                with self._quiet():
                    f = cmoordyn.step(self.instance, x0.tolist(), v.tolist(), t0, dt)
            except (RuntimeError, ValueError) as exc:
                raise self._fail(str(exc)) from None
            f = np.array(f, float)
        if not np.isfinite(f).all():
            raise self._fail("MoorDyn returned non-finite forces")
        self.steps += 1
        self._t_last = t0 + dt
        if self.steps % 4096 == 0:
            self._quiet.clear()
        accel = None
        if points1 is not None:
            vp = v[self._nb6:].reshape(-1, 3)
            accel = (vp - self._point_velocity) / dt
            self._point_velocity = vp
        self.loads = self._to_bodies(f, pose1, accel, points1)
        return self.loads

    def _step_groups(self, t0: float, dt: float, x0: np.ndarray, v: np.ndarray) -> np.ndarray:
        """The step in the workers: the one started ahead (checked to be this one; the time is not
        compared: MoorDyn's Step keeps its own clock and only prints the t passed)."""
        g = self._groups
        if g.pending is not None and not g.matches(dt, x0, v):
            g.refuse_ahead("another step")
        if g.pending is None:
            g.launch(t0, dt, x0, v)
        return g.collect().copy()

    def save(self) -> tuple[bytes | int, np.ndarray, np.ndarray, float]:
        if self._groups is not None:
            self._saved = True
            return self._groups.save(), self.loads, self._point_velocity, self._t_last
        import moordyn
        return moordyn.Serialize(self.instance), self.loads, self._point_velocity, self._t_last

    def restore(self, saved: tuple[bytes | int, np.ndarray, np.ndarray, float]) -> None:
        if self._groups is not None:
            self._groups.restore(saved[0])
        else:
            import moordyn
            moordyn.Deserialize(self.instance, saved[0])
        self.loads, self._point_velocity, self._t_last = saved[1], saved[2], saved[3]

    # -- outputs -------------------------------------------------------------------------------------
    def tensions(self) -> np.ndarray:
        """MoorDyn's own tension at each line's fairlead end (N): the tension of the line's end
        segment, the number MoorDyn's ``GetLineFairTen`` and its output channels give (FairTen;
        AnchTen for a line written from its fairlead down)."""
        if self._groups is not None:
            return (self._groups.tensions if self.steps else self._at_start[0]).copy()
        from cmoordyn import line_get_node_ten
        return np.array([math.hypot(*line_get_node_ten(line, k)) for line, k in zip(self._lines, self._fairlead)])

    def end_forces(self) -> np.ndarray:
        """Magnitude of the force each line's fairlead end node passes on to what it is attached to
        (N): the end segment's tension plus the node's own weight, buoyancy, drag and seabed
        contact (half a segment's): the line's pull on its fairlead point."""
        if self._groups is not None:
            return (self._groups.end_forces if self.steps else self._at_start[1]).copy()
        from cmoordyn import line_get_node_force
        return np.array([math.hypot(*line_get_node_force(line, k)) for line, k in zip(self._lines, self._fairlead)])

    def node_positions(self, n_nodes: int) -> np.ndarray:
        """(lines, n_nodes, 3) node positions from the anchor end, NaN past a line's last node."""
        if self._groups is not None:
            return (self._groups.nodes if self.steps else self._at_start[2])[:, :n_nodes].copy()
        import moordyn
        out = np.full((self.n_lines, n_nodes, 3), np.nan)
        for i, (line, n) in enumerate(zip(self._lines, self._nodes)):
            out[i, :n + 1] = [moordyn.GetLineNodePos(line, k) for k in range(n + 1)]
        return out

    @property
    def max_nodes(self) -> int:
        return max(self._nodes, default=0) + 1

    def close(self) -> None:
        if self.instance is not None:
            import moordyn
            with self._quiet():
                moordyn.Close(self.instance)
            self.instance = None
        try:
            if self._groups is not None:
                c = self._groups.counts
                log.info("%s: %d steps in %d worker process(es), %d of them started ahead",
                         self.label, c["steps"], len(self._split.groups), c["ahead"])
                self._groups.close()      # the workers' MoorDyn closes its files
                self._groups = None
                merge_outputs(Path(self._run_dir.name) / "whole" / self.layout.path.name, self._split,
                              self._group_files, self.layout.path, self._t_last)
        finally:
            if self._run_dir is not None:
                self._run_dir.cleanup()
                self._run_dir = None
            self._quiet.close()
        if self._folder is not None:      # MoorDyn's own outputs of the copy go beside the scene's file
            for f in Path(self._folder.name).iterdir():
                if f.name not in (self.model_path.name, CURRENT_FILE):
                    shutil.move(str(f), str(self.layout.path.parent / f.name))
            self._folder.cleanup()
            self._folder = None
