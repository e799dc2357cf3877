"""One co-simulation session: hello → model, the step sequencing rules, the cached last reply.

State machine and rules: SPEC.md §4.2 and §5.3. A rejected request leaves the session unchanged.
"""

from __future__ import annotations

import time as _time
from collections import OrderedDict
from dataclasses import dataclass, field
from typing import Any, Callable, Protocol

import numpy as np
import xarray as xr

from hydrolink.protocol import codec
from hydrolink.protocol.codec import Code, ProtocolError
from hydrolink.protocol.errors import KeyedError
from hydrolink.protocol.hdb.external_matrices import MATRICES, ExternalMatrices
from hydrolink.protocol.scene import Scene, SceneError, parse_scene
from hydrolink.protocol.scene_bounds import MAX_COORDINATE, MAX_SPEED
from hydrolink.protocol.hdb.wire import from_wire
from hydrolink.protocol.hdb.layout import HDBError
from hydrolink.protocol.pacing import Pacer
from hydrolink.server.hdb.file_set import FileSetReader, MissingContent, is_file_set
from hydrolink.server.hydro_states import hydro_model, state_datasets
from hydrolink.server.model import HydroModel, ModelError
from hydrolink.server.sea.probes import PreviewGrid, WaveProbes
from hydrolink.server.terms.hulls import MeshError, closed_hull


def _scene_field(key: str) -> str:
    return f"scene.{key}" if key else "scene"


@dataclass(frozen=True)
class ModelInputs:
    """What a ``hello`` builds its model from, read and checked: the scene, the wet bodies' HDBs by
    body name, the wave elevation series (time, eta) and the nonlinear bodies' hulls. Plain data
    (it pickles): a worker process builds the same model from it (server/service/step_worker.py)."""
    scene: Scene
    hdbs: dict[str, xr.Dataset]
    series: tuple[np.ndarray, np.ndarray] | None
    hulls: dict
    # the switching body's other hydrodynamic states' HDBs: body name -> state name -> dataset
    state_hdbs: dict[str, dict[str, xr.Dataset]] = field(default_factory=dict)


def build_model(msg: dict, files: FileSetReader | None = None) -> HydroModel:
    """Validate a ``hello``'s scene and HDBs and build the model over the scene's wet bodies (dry
    bodies need no HDB); ProtocolError 8/9 naming the field (13 for file contents ``files``, the
    server's store reader, lacks; 5 for a file set when there is no store)."""
    return model_from(read_hello(msg, files))


def model_from(inputs: ModelInputs) -> HydroModel:
    """The model of a hello's :class:`ModelInputs`; ProtocolError 8/9 naming the field."""
    try:
        return hydro_model(inputs.scene, inputs.hdbs, inputs.state_hdbs, inputs.series, hulls=inputs.hulls)
    except ModelError as exc:
        raise ProtocolError(Code.BAD_SCENE, _scene_field(exc.key), str(exc)) from None
    except HDBError as exc:
        raise ProtocolError(Code.BAD_HDB, f"{codec.key_path('hdbs', exc.source)}.{exc.field}", str(exc)) from None


def read_hello(msg: dict, files: FileSetReader | None = None) -> ModelInputs:
    """A ``hello``'s scene, HDBs, elevation series and hulls, read and checked (see build_model)."""
    text = codec.require_str(msg, "scene")
    hdb_maps = codec.require_map(msg, "hdbs")
    try:
        scene: Scene = parse_scene(text, "scene")
    except SceneError as exc:
        raise ProtocolError(Code.BAD_SCENE, _scene_field(exc.key), str(exc)) from None
    datasets: dict[str, xr.Dataset] = {}
    missing: tuple[str, list[str]] | None = None   # the first file set's field and every missing digest
    for i, body, key, scene_key in scene.hdb_keys():
        if key in datasets:
            continue
        where = codec.key_path("hdbs", key)
        if key not in hdb_maps:
            raise ProtocolError(Code.BAD_HDB, where,
                                f"scene body {body.name!r} ({scene_key}) uses HDB {key!r} but hello.hdbs "
                                f"holds {sorted(hdb_maps)}")
        if is_file_set(hdb_maps[key]):
            if files is None:
                raise ProtocolError(Code.BAD_VALUE, where, "this server keeps no HDB store: send the HDB as a map")
            stated = next((b.hdb_convention for b in scene.bodies if b.hdb == key and b.hdb_convention), None)
            try:
                datasets[key] = files.read(hdb_maps[key], where, stated, scene.wamit_statement(key))
            except MissingContent as exc:    # every file set's missing contents in one error: one upload round
                missing = (missing[0], missing[1] + [d for d in exc.extra["missing"] if d not in missing[1]]) \
                    if missing else (exc.field, list(exc.extra["missing"]))
            continue
        try:
            data = codec.decode_tree(hdb_maps[key], where)
        except ProtocolError as exc:
            raise ProtocolError(Code.BAD_HDB, exc.field or where, exc.message) from None
        try:
            datasets[key] = from_wire(data, key)
        except HDBError as exc:
            raise ProtocolError(Code.BAD_HDB, f"{where}.{exc.field}" if exc.field else where, str(exc)) from None
    if missing:
        raise MissingContent(*missing)
    scene = _with_gauges(_with_spectra(scene, msg.get("spectra")), msg.get("gauges"))
    scene = _with_modal_structure(scene, msg.get("modal_structure"))
    series = None
    if msg.get("wave_elevation") is not None:  # [waves] type = "elevation": the client read the file
        we = codec.require_map(msg, "wave_elevation")
        series = (codec.require_array(we, "time", (None,), finite=False, path="wave_elevation.time"),
                  codec.require_array(we, "eta", (None,), finite=False, path="wave_elevation.eta"))
    hulls = {}
    if msg.get("meshes") is not None:   # the closed hulls of nonlinear bodies (SPEC §5.1)
        for name, mesh in codec.require_map(msg, "meshes").items():
            where = codec.key_path("meshes", str(name))
            if not isinstance(mesh, dict):
                raise ProtocolError(Code.BAD_VALUE, where, "must be a map with vertices and faces")
            vertices = codec.decode_array(codec.require(mesh, "vertices", f"{where}.vertices"), f"{where}.vertices", "f")
            faces = codec.decode_array(codec.require(mesh, "faces", f"{where}.faces"), f"{where}.faces", "i")
            try:
                hulls[str(name)] = closed_hull(vertices, faces)
            except MeshError as exc:
                raise ProtocolError(Code.BAD_VALUE, where, f"body {name!r}'s hull: {exc.why}") from None
    return ModelInputs(scene, {b.name: datasets[b.hdb] for b in scene.wet_bodies}, series, hulls,
                       state_datasets(scene, datasets))


def _with_gauges(scene: Scene, gauges: Any) -> Scene:
    """The scene with its gauges' records from ``hello.gauges`` (SPEC §5.1); error 5 naming
    ``gauges.<key>`` when malformed, 8 naming ``scene.waves.gauges[i].file`` when one is missing or
    the run reaches past it."""
    def record(entry: dict, where: str) -> tuple:
        time = codec.require_array(entry, "time", (None,), path=f"{where}.time")
        return time, codec.require_array(entry, "eta", time.shape, path=f"{where}.eta")

    if not scene.gauge_files():
        return scene
    return _scene_with(scene.with_gauges, _file_tables(gauges, "gauges", "{time, eta}", record))


def _with_modal_structure(scene: Scene, blocks: Any) -> Scene:
    """The scene with its bodies' modes' structure files from ``hello.modal_structure`` (SPEC §5.1,
    revision 1.17); error 5 naming ``modal_structure.<key>`` when malformed, 8 naming
    ``scene.bodies[i].modes.mmx`` when one is missing or is not the modes' structure."""
    def block(entry: dict, where: str) -> ExternalMatrices:
        modes = codec.require(entry, "modes", f"{where}.modes")
        if not isinstance(modes, list) or not all(isinstance(m, str) for m in modes):
            raise ProtocolError(Code.BAD_VALUE, f"{where}.modes", "must be a list of the body's mode names")
        size = (6 + len(modes),) * 2
        return ExternalMatrices(tuple(modes), *(codec.require_array(entry, k, size, path=f"{where}.{k}")
                                                for k in MATRICES))

    if not scene.modal_files():
        return scene
    return _scene_with(scene.with_modal_structure,
                       _file_tables(blocks, "modal_structure", "{modes, mass, damping, stiffness}", block))


def _with_spectra(scene: Scene, spectra: Any) -> Scene:
    """The scene with its spectrum files' tables from ``hello.spectra`` (SPEC §5.1); error 5 naming
    ``spectra`` when malformed, 8 naming ``scene.waves.systems[i].file`` when a table is missing or
    is not a spectrum."""
    def table(entry: dict, where: str) -> tuple:
        omega = codec.require_array(entry, "omega", (None,), path=f"{where}.omega")
        theta = None if entry.get("theta") is None else codec.require_array(entry, "theta", (None,),
                                                                               path=f"{where}.theta")
        shape = (omega.size,) if theta is None else (omega.size, theta.size)
        density = codec.require_array(entry, "density", shape, path=f"{where}.density")
        return omega.tolist(), None if theta is None else theta.tolist(), density.tolist()

    if not scene.spectrum_files():
        return scene
    return _scene_with(scene.with_spectra, _file_tables(spectra, "spectra", "{omega, theta, density}", table))


def _file_tables(value: Any, field: str, what: str, decode: Callable[[dict, str], tuple]) -> dict[str, tuple]:
    """A ``hello`` map {scene key: ``what``} of the scene's input files as the client read them,
    each entry decoded by ``decode(entry, path)``; error 5 naming ``field`` or ``field.<key>`` when
    malformed (absent: an empty map, which the scene then refuses naming the file's key)."""
    if value is None:
        return {}
    if not isinstance(value, dict):
        raise ProtocolError(Code.BAD_VALUE, field, f"must be a map {{scene key: {what}}}")
    out = {}
    for key, entry in value.items():
        where = codec.key_path(field, str(key))
        if not isinstance(entry, dict):
            raise ProtocolError(Code.BAD_VALUE, where, f"must be a map {what}")
        out[str(key)] = decode(entry, where)
    return out


def _scene_with(put: Callable[[dict], Scene], tables: dict[str, tuple]) -> Scene:
    """``put(tables)`` (Scene.with_spectra, Scene.with_gauges, Scene.with_modal_structure), its ValueError "key: why" as error 8
    naming ``scene.<key>``."""
    try:
        return put(tables)
    except ValueError as exc:
        key, _, why = str(exc).partition(": ")
        raise ProtocolError(Code.BAD_SCENE, _scene_field(key), why) from None


MAX_SAVED_BYTES = 256 * 2**20   # per session: saved states kept (SPEC §5.9)


def _nbytes(obj: Any) -> int:
    """Bytes of the arrays in a nested tuple/list/dict (what a saved state costs)."""
    if isinstance(obj, np.ndarray):
        return obj.nbytes
    if isinstance(obj, (tuple, list)):
        return sum(_nbytes(o) for o in obj)
    if isinstance(obj, dict):
        return sum(_nbytes(o) for o in obj.values())
    return 8


class LinearPlant(Protocol):
    """The device as a linear plant, as a session hands it to controllers (SPEC §5.7.2)."""

    def discretize(self, dt: float) -> "LinearPlant":
        """The plant under a zero-order hold at ``dt``."""

    def to_wire(self) -> dict:
        """The plant as the welcome's ``control.plant`` map."""


# Builds a scene's linear plant from its HDBs (by the scene's hdb names): the server is handed one
# (clients/analysis/plant.py's build_plant, which needs the multibody model the clients own);
# KeyedError or ModelError naming the scene key it cannot represent.
PlantBuilder = Callable[[Scene, dict[str, xr.Dataset]], LinearPlant]


class SessionInfo:
    """What the service's loop keeps of a multibody session wherever its model steps (here:
    :class:`Session`; in a worker process: server/service/step_worker.py): its id and client, the
    pacing of its replies, its linear plant for controllers, the sequence counters it answers by."""

    def __init__(self, session_id: str, scene: Scene, hdbs: dict[str, xr.Dataset], dt: float,
                 client: dict | None = None, realtime: float | None = None,
                 plant_builder: PlantBuilder | None = None):
        """``realtime``: the hello's pace factor (SPEC §5.1): each ``forces`` reply of step seq is
        held until t0 + seq·dt/realtime, t0 the arrival of seq 0 (:attr:`pacer`). ``plant_builder``:
        what builds the linear plant a controller may ask for (None: such a hello is refused).
        ``hdbs``: the wet bodies' HDBs by body name (what the plant is built from)."""
        self.id = session_id
        self.scene, self._hdbs = scene, hdbs
        self._plant_builder = plant_builder
        self.footprint = 0   # bytes its model's arrays hold (server/allocation.py footprint), set when it opens
        self.pacer = None if realtime is None else Pacer(dt, realtime)
        self._paced_seq = -1
        self._plants: dict = {}   # dt (None: continuous) -> Plant, for controllers that ask (SPEC §5.7.2)
        self.client = client or {}
        self.dt = dt
        self.opened = self.last_seen = _time.monotonic()
        self.last_seq = -1
        self.last_iteration = -1
        self.steps = 0
        self.compute_s = 0.0

    @property
    def state(self) -> str:
        return "ready" if self.last_seq < 0 else "running"

    def touch(self) -> None:
        self.last_seen = _time.monotonic()

    def plant(self, dt: float | None):
        """The session's device as a linear plant (by the server's plant builder), continuous or at
        ``dt``; built once per dt. ProtocolError 8 naming the scene key it cannot represent."""
        if self._plant_builder is None:
            raise ProtocolError(Code.BAD_VALUE, "plant", "this server builds no linear plants (it was started "
                                "without a plant builder: use hydrolink serve or hydrolink run)")
        if dt not in self._plants:
            scene = self.scene
            try:
                plant = self._plant_builder(scene, {b.hdb: self._hdbs[b.name] for b in scene.bodies if b.wet})
                self._plants[dt] = plant if dt is None else plant.discretize(dt)
            except (KeyedError, ModelError) as exc:
                raise ProtocolError(Code.BAD_SCENE, _scene_field(exc.key), f"no linear plant: {exc}") from None
            except (ValueError, ArithmeticError, np.linalg.LinAlgError, RuntimeError) as exc:   # e.g. a singular
                raise ProtocolError(Code.BAD_SCENE, "scene", f"no linear plant: {type(exc).__name__}: {exc}") from None
        return self._plants[dt]

    def release_time(self, seq: int, arrived: float) -> float | None:
        """When the reply to step ``seq`` may leave (``time.perf_counter`` clock; None: unpaced).
        The first request of a new step is counted: an overrun when its reply is ready after its
        release (the client or the link took longer than the step's wall-clock budget)."""
        if self.pacer is None:
            return None
        due = self.pacer.release_time(seq)
        if seq > self._paced_seq:      # a new step (not a retry or an iteration of the last)
            self._paced_seq = seq
            if seq:
                self.pacer.done(seq - 1, started=arrived)
        return due


class Session(SessionInfo):
    """A multibody session whose model steps here: the model plus the sequencing state of SPEC §5.3."""

    def __init__(self, session_id: str, model: HydroModel, client: dict | None = None, realtime: float | None = None,
                 plant_builder: PlantBuilder | None = None):
        super().__init__(session_id, model.scene, model.hdbs, model.dt, client, realtime, plant_builder)
        self.model = model
        self.n_bodies = len(model.bodies)
        self._last_state: tuple[np.ndarray, np.ndarray] | None = None
        self._cached: dict[str, Any] | None = None
        self._saved: OrderedDict[int, tuple] = OrderedDict()   # SPEC §5.9, oldest first
        self._saved_bytes = 0
        self._next_state = 1
        self._probes: dict[str, WaveProbes] = {}   # a joined controller's probes, made on first use

    def previews(self, grids: dict[str, PreviewGrid], step: int) -> dict[str, np.ndarray]:
        """The wave probes' elevations (now and the preview) of the controllers ``grids`` names, at
        ``step``: each controller's probes made the first time it is asked for (never when no
        controller joined), their window computed along the run (server/sea/probes.py)."""
        out = {}
        water = self.scene.water
        for name, grid in grids.items():
            probes = self._probes.get(name)
            if probes is None or probes.grid != grid:
                probes = self._probes[name] = WaveProbes.on_grid(self.model.waves, grid, water.gravity,
                                                                 water.depth_m)
            out[name] = probes.at_step(step)
        return out

    # ------------------------------------------------------------ rollback (SPEC §5.9)

    def save(self) -> dict:
        """Keep the session's state now; ``saved`` fields. Older saved states leave first once
        the session's kept states pass MAX_SAVED_BYTES (the newest always stays)."""
        # the last state and the cached reply are replaced by each step, never written to: kept as they are
        saved = (self.model.state(), self.last_seq, self.last_iteration, self._last_state, self._cached)
        size = _nbytes(saved)
        sid = self._next_state
        self._next_state += 1
        self._saved[sid] = (saved, size)
        self._saved_bytes += size
        while self._saved_bytes > MAX_SAVED_BYTES and len(self._saved) > 1:
            _, (_, old) = self._saved.popitem(last=False)
            self._saved_bytes -= old
        return {"state": sid, "seq": self.last_seq, "iteration": self.last_iteration, "bytes": size}

    def restore(self, msg: dict) -> dict:
        """Back to a saved state (it stays saved: a master may restore it again); ``restored`` fields."""
        sid = codec.require_int(msg, "state", minimum=1)
        if sid not in self._saved:
            oldest = next(iter(self._saved), None)
            raise ProtocolError(Code.BAD_VALUE, "state", f"no saved state {sid} in this session (saved: "
                                + (f"{oldest}..{self._next_state - 1}, older ones released or dropped past "
                                   f"{MAX_SAVED_BYTES // 2**20} MiB)" if oldest else "none)"))
        model_state, self.last_seq, self.last_iteration, self._last_state, self._cached = self._saved[sid][0]
        self.model.set_state(model_state)
        return {"state": sid, "seq": self.last_seq, "iteration": self.last_iteration}

    def release(self, msg: dict) -> dict:
        """Forget a saved state; ``released`` fields (releasing an unknown state is no error)."""
        sid = codec.require_int(msg, "state", minimum=1)
        entry = self._saved.pop(sid, None)
        if entry is not None:
            self._saved_bytes -= entry[1]
        return {"state": sid, "kept": len(self._saved)}

    def modal_state(self, msg: dict) -> tuple:
        """A session with generalized modes: the step's ``modal_position`` and ``modal_velocity``
        (M,) (SPEC §5.2, revision 1.15); without modes: ()."""
        m = self.model.modes.size
        if not m:
            return ()
        return (codec.require_array(msg, "modal_position", (m,), bound=MAX_COORDINATE),
                codec.require_array(msg, "modal_velocity", (m,), bound=MAX_SPEED))

    def step(self, msg: dict, hydro_command: dict[str, str] | None = None) -> dict:
        """Reply fields for a ``step`` request (SPEC §5.2–5.3); ProtocolError leaves state unchanged.
        ``hydro_command``: the hydro states the session's controllers commanded for this new step
        ({body: state}, SPEC §5.7.4; only for a model with hydro_states, server/hydro_states.py)."""
        return self.advance(*self.step_input(msg), hydro_command)

    def step_input(self, msg: dict) -> tuple[int, int, np.ndarray, np.ndarray, tuple]:
        """A ``step`` request's fields checked (:meth:`advance`'s ``seq, iteration, pos, vel,
        modal``), nothing stepped: a controlled step's measurements are relayed between the two
        (server/service/force_server.py ``_step``); ProtocolError naming the field."""
        seq = self.within_run(codec.require_int(msg, "seq", minimum=0))
        iteration = codec.require_int(msg, "iteration", default=0, minimum=0)
        t_req = codec.require_float(msg, "time")
        t = seq * self.dt
        if abs(t_req - t) > 1e-9 * max(1.0, abs(t)):
            raise ProtocolError(Code.BAD_VALUE, "time",
                                f"time {t_req!r} does not match seq {seq} * dt {self.dt!r} = {t!r}")
        shape = (self.n_bodies, 6)
        pos = codec.require_array(msg, "position", shape, bound=MAX_COORDINATE)
        vel = codec.require_array(msg, "velocity", shape, bound=MAX_SPEED)
        return seq, iteration, pos, vel, self.modal_state(msg)

    def within_run(self, seq: int) -> int:
        """``seq`` if the run has a step seq (setup.last_seq); else error 5 naming ``seq``."""
        if seq > self.model.last_seq:
            raise ProtocolError(Code.BAD_VALUE, "seq", f"seq {seq} is past the run's end: the last step is "
                                f"{self.model.last_seq} (setup.last_seq; simulation.duration / dt)")
        return seq

    def advanced(self, seq: int, seconds: float) -> None:
        """Step ``seq`` (the next, iteration 0) was taken in process by the model's compiled kernel
        (server/service/local_step.py ``LocalStep.compiled``) in ``seconds``: the sequencing state
        and counters as :meth:`advance` leaves them, no reply cached (a retry is refused)."""
        self.model.count_step(seq)
        self.last_seq, self.last_iteration = seq, 0
        self.steps += 1
        self.compute_s += seconds
        self._last_state = self._cached = None

    def advance(self, seq: int, iteration: int, pos: np.ndarray, vel: np.ndarray, modal: tuple = (),
                hydro_command: dict[str, str] | None = None) -> dict:
        """The reply fields of step ``seq`` ``iteration`` (>= 0, within the run) for a checked state
        (``pos``, ``vel`` (N, 6), ``modal`` :meth:`modal_state`'s): the sequencing rules of SPEC
        §5.3 (a new step, a replacing iteration, a retry answered from the cache), then the
        model's step; ProtocolError leaves the state unchanged."""
        if seq == self.last_seq + 1:
            replace = False
        elif seq == self.last_seq and iteration > self.last_iteration:
            replace = True
        elif seq == self.last_seq and iteration == self.last_iteration:
            if self._last_state is None:   # the step was taken by LocalStep.compiled's caller: nothing kept
                raise ProtocolError(Code.OUT_OF_ORDER, "iteration",
                                    f"seq {seq} iteration {iteration} was computed in process, without a "
                                    f"state kept for a retry; send iteration {iteration + 1} to replace it")
            old_pos, old_vel, *old_modal = self._last_state
            if not (np.array_equal(old_pos, pos) and np.array_equal(old_vel, vel)
                    and all(np.array_equal(a, b) for a, b in zip(old_modal, modal))):
                raise ProtocolError(Code.OUT_OF_ORDER, "iteration",
                                    f"seq {seq} iteration {iteration} was already computed with another state; "
                                    f"send iteration {iteration + 1} to replace it")
            return dict(self._cached, compute_us=0.0)  # the retry: the cached reply, no compute
        else:
            expect = f"expected seq {self.last_seq + 1} (new step)"
            if self.last_seq >= 0:
                expect += (f", or seq {self.last_seq} with iteration > {self.last_iteration} (replace) "
                           f"or = {self.last_iteration} (retry)")
            field = "seq" if seq != self.last_seq else "iteration"
            raise ProtocolError(Code.OUT_OF_ORDER, field, f"{expect}; got seq {seq} iteration {iteration}")
        t = seq * self.dt
        t0 = _time.perf_counter()
        try:
            extra = {"modal_position": modal[0], "modal_velocity": modal[1]} if modal else {}
            if hydro_command is not None:   # only a switching model takes it (never beside modes: protocol/scene.py)
                extra["commanded"] = hydro_command
            out = self.model.step(t, pos, vel, replace_last=replace, **extra)
        except ModelError as exc:
            raise ProtocolError(Code.BAD_VALUE, exc.key, str(exc)) from None
        elapsed = _time.perf_counter() - t0
        self.steps += 1
        self.compute_s += elapsed
        self.last_seq, self.last_iteration = seq, iteration
        self._last_state = (pos.copy(), vel.copy(), *(a.copy() for a in modal))
        # one map: the reply now and, cached (its arrays are read-only), the reply to a retry
        self._cached = reply = {"seq": seq, "iteration": iteration, "time": t, **out, "compute_us": elapsed * 1e6}
        return reply
