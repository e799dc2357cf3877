"""`hydrolink linearize`: the device as a linear plant (state-space model about its equilibrium).

The linearised equations are those of ``hydrolink steady`` (:func:`hydrolink.clients.analysis.steady.linearize`:
M, K, D of the Exudyn system the run builds, the constraint Jacobian G, the PTO lines, linear
moorings), with the PTO springs and dampers of the scene added as k g g^T and c g g^T::

    M q'' + D q' + K q + G^T lambda = W^T (F_rad + F_ex) - sum_p g_p u_p       G q = 0

Reduced coordinates: q = N z with z a subset of the coordinates (QR with column pivoting on G picks
the dependent ones; N = [I; -G_d^+ G_i] rearranged), so every position state is a named body DOF
(RM3: float.heave, spar.heave). Radiation: the server model's state-space fits
(server/radiation/state_space.py, ``[hydro] radiation = "state-space"``; a scene with "convolution" is fitted
the same way with its ss_* keys), each complex pole as two real states,
x_r' = A_r x_r + B_r W q', F_rad = C_r x_r + D_r W q'. With ``"constant"`` B(w0) is a damping and
there are no radiation states; with ``"off"`` there is no radiation force.

Plant (continuous, x = [z, z', x_r])::

    x' = A x + B u,   y = C x + D u
    inputs   pto:<name> (the added tension a controller's force command sets, SPEC §5.7; a rotary
             PTO: pto:<name>.<axis>), excitation:<body>.<dof> (every active DOF of a wet body)
    outputs  <body>.<dof>.position, <body>.<dof>.velocity (every active DOF of every body,
             displacements from equilibrium), pto:<name>.displacement, pto:<name>.velocity
             (the PTO's extension from equilibrium and its rate: the measurements' pto_displacement,
             pto_velocity)

The states are deviations from the equilibrium; where the scene's reference configuration is not
in equilibrium (a constant load on a stiff mode), the static offset is reported (``equilibrium``)
and the linear model holds about the reference configuration (the linearisation point), as in
``hydrolink steady``. Nonlinear terms are refused with their key, except a PTO's force or torque
limit: the plant is the unlimited PTO (valid while |force| < limit), and the result carries a
warning naming the key.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from hydrolink.clients.analysis.steady import SteadyError, sampling_time
from hydrolink.protocol.capabilities import refuse_unsupported
from hydrolink.protocol.scene import DOF_NAMES, MoorDynMooring, RopeMooring, Scene

FORMATS = (".npz", ".mat", ".nc")


class PlantError(SteadyError):
    """A scene the plant builder cannot represent; the message names the key and why."""


def check_plant_scene(scene: Scene) -> None:
    """Refuse the terms a linear plant cannot hold (first problem as PlantError naming its key)."""
    if scene.client.type != "exudyn":
        raise PlantError("client.type", "hydrolink linearize builds the mechanism with the Exudyn client, "
                                        "an FMU's equations are not accessible")
    for i, m in enumerate(scene.moorings):
        if isinstance(m, (RopeMooring, MoorDynMooring)):
            raise PlantError(f"moorings[{i}]", f"a {m.type} mooring is nonlinear (catenary, seabed contact) and has "
                                               "no equilibrium linearisation here; use a linear mooring")
    for i, j in enumerate(scene.joints):
        if j.friction is not None:
            raise PlantError(f"joints[{i}].friction", "joint friction is nonlinear (stick-slip): remove it "
                                                      "for the linear plant")
    refuse_unsupported(scene, "linearize", PlantError)   # the force terms: protocol/capabilities.py
    for i, c in enumerate(scene.constraints):
        if c.value != 0.0:
            raise PlantError(f"constraints[{i}].value", "a prescribed velocity is not a linear time-invariant term")
    if not scene.served_bodies:
        raise PlantError("bodies", "no wet body: the plant has no hydrodynamics")


@dataclass(frozen=True)
class Plant:
    """A linear state-space model x' = A x + B u, y = C x + D u (or x[k+1] = A x[k] + B u[k] when
    ``dt`` is set: zero-order hold), with the names of its states, inputs and outputs."""
    A: np.ndarray
    B: np.ndarray
    C: np.ndarray
    D: np.ndarray
    states: tuple[str, ...]
    inputs: tuple[str, ...]
    outputs: tuple[str, ...]
    dt: float | None = None
    equilibrium: np.ndarray | None = None     # static offset of the position states (reference -> equilibrium)
    warnings: tuple[str, ...] = ()
    radiation_fit_error: float = 0.0          # the state-space fits' largest relative error (0: none fitted)

    def discretize(self, dt: float) -> "Plant":
        """The zero-order-hold discretisation at ``dt`` (scipy.signal.cont2discrete)."""
        from scipy.signal import cont2discrete

        if self.dt is not None:
            raise ValueError("the plant is already discrete")
        dt = sampling_time(dt)
        a, b, c, d, _ = cont2discrete((self.A, self.B, self.C, self.D), dt, method="zoh")
        return replace(self, A=a, B=b, C=c, D=d, dt=dt)

    def frequency_response(self, omega: np.ndarray) -> np.ndarray:
        """H(i omega) (n_omega, n_outputs, n_inputs) of the continuous plant, e^{+i omega t} convention
        (a real signal's exp(-i omega t) phasor response is the complex conjugate)."""
        if self.dt is not None:
            raise ValueError("frequency_response is for the continuous plant")
        eye = np.eye(self.A.shape[0])
        return np.stack([self.C @ np.linalg.solve(1j * w * eye - self.A, self.B) + self.D for w in np.atleast_1d(omega)])

    def index(self, names: tuple[str, ...], name: str) -> int:
        """Position of ``name`` in ``names`` (KeyError listing them when absent)."""
        try:
            return names.index(name)
        except ValueError:
            raise KeyError(f"{name!r} is not one of {list(names)}") from None

    def to_control(self):
        """The plant as a python-control StateSpace (the package is optional)."""
        try:
            import control
        except ImportError:
            raise ImportError("python-control is not installed (pip install control); the plant's "
                              "A, B, C, D and names are the Plant's fields") from None
        return control.ss(self.A, self.B, self.C, self.D, *([self.dt] if self.dt else []),
                          inputs=list(self.inputs), outputs=list(self.outputs), states=list(self.states))

    def save(self, path: str | Path) -> Path:
        """Write .npz (A, B, C, D, states, inputs, outputs [, dt]), .mat (the same, scipy.io.savemat)
        or .nc (xarray: A over (state, state_from), B (state, input), C (output, state), D (output, input))."""
        path = Path(path)
        arrays = {"A": self.A, "B": self.B, "C": self.C, "D": self.D, "states": np.array(self.states),
                  "inputs": np.array(self.inputs), "outputs": np.array(self.outputs)}
        if self.dt is not None:
            arrays["dt"] = np.array(self.dt)
        if path.suffix == ".npz":
            np.savez(path, **arrays)
        elif path.suffix == ".mat":
            from scipy.io import savemat
            cells = {k: np.array(v, dtype=object) for k, v in arrays.items() if k in ("states", "inputs", "outputs")}
            savemat(path, {**arrays, **cells}, do_compression=True)
        elif path.suffix == ".nc":
            import xarray as xr
            ds = xr.Dataset(
                {"A": (("state", "state_from"), self.A), "B": (("state", "input"), self.B),
                 "C": (("output", "state_from"), self.C), "D": (("output", "input"), self.D)},
                coords={"state": list(self.states), "state_from": list(self.states), "input": list(self.inputs),
                        "output": list(self.outputs)},
                attrs={"title": "hydrolink linear plant x' = A x + B u, y = C x + D u",
                       "time": "continuous" if self.dt is None else "discrete (zero-order hold)",
                       **({"dt": self.dt} if self.dt is not None else {}),
                       "warnings": "\n".join(self.warnings), "radiation_fit_error": self.radiation_fit_error})
            ds.to_netcdf(path)
        else:
            raise PlantError("-o", f"{path.name}: the plant is written as one of {', '.join(FORMATS)}")
        return path


    def to_wire(self) -> dict:
        """The plant as a message map (SPEC §5.7.2 ``control.plant``)."""
        return {"A": self.A, "B": self.B, "C": self.C, "D": self.D, "states": list(self.states),
                "inputs": list(self.inputs), "outputs": list(self.outputs), "dt": self.dt,
                "warnings": list(self.warnings)}

    @classmethod
    def from_wire(cls, m: dict) -> "Plant":
        """A plant from its message map (arrays already decoded)."""
        return cls(*(np.asarray(m[k], float) for k in "ABCD"), tuple(m["states"]), tuple(m["inputs"]),
                   tuple(m["outputs"]), None if m.get("dt") is None else float(m["dt"]),
                   warnings=tuple(m.get("warnings") or ()))


def load_plant(path: str | Path) -> Plant:
    """A plant written by :meth:`Plant.save` as .npz (what a controller loads)."""
    with np.load(path) as f:
        dt = float(f["dt"]) if "dt" in f else None
        return Plant(f["A"], f["B"], f["C"], f["D"], tuple(map(str, f["states"])), tuple(map(str, f["inputs"])),
                     tuple(map(str, f["outputs"])), dt)


def _independent(G: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    """(indices of the independent coordinates, N (n, k) with q = N z and G N = 0): QR with column
    pivoting puts the coordinates G constrains most strongly first; those are the dependent ones."""
    from scipy.linalg import lstsq, qr

    if not G.shape[0]:
        return np.arange(n), np.eye(n)
    _, r, piv = qr(G, pivoting=True, mode="economic")
    diag = np.abs(np.diag(r))
    rank = int(np.sum(diag > 1e-10 * diag[0]))
    dep, ind = piv[:rank], np.sort(piv[rank:])
    N = np.zeros((n, ind.size))
    N[ind, np.arange(ind.size)] = 1.0
    N[dep] = -lstsq(G[:, dep], G[:, ind])[0]
    return ind, N


@dataclass
class _Names:
    """Coordinate labels: ``<body>.<dof>`` for the scene bodies' coordinates."""
    labels: dict[int, str] = field(default_factory=dict)

    def of(self, k: int) -> str:
        return self.labels.get(int(k), f"q{k}")


def build_plant(scene: Scene, hdbs: dict) -> Plant:
    """The continuous plant of ``scene`` (module docstring); ``hdbs`` keyed like :func:`load_scene_hdbs`."""
    from hydrolink.clients.analysis.steady import linearize
    from hydrolink.server.model import HydroModel

    check_plant_scene(scene)
    warnings: list[str] = []
    hydro = scene.hydro
    if hydro.radiation == "convolution" and hydro.irf_duration > 0:
        hydro = hydro.model_copy(update={"radiation": "state-space"})
        warnings.append("hydro.radiation: the plant realises the radiation memory by the state-space fit of the "
                        f"same IRF (ss_tolerance = {hydro.ss_tolerance:g}); a run with \"convolution\" differs by "
                        "the fit's error")
    fitted = scene.model_copy(update={"hydro": hydro})
    model = HydroModel(fitted, {b.name: hdbs[b.hdb] for b in scene.bodies if b.wet})
    setup = model.setup_info()
    warnings += list(model.warnings)
    sys_ = linearize(fitted, model, setup, check=check_plant_scene)
    n = sys_.M.shape[0]
    nb = len(sys_.body_names)
    names = _Names({int(sys_.body_index[6 * b + d]): f"{sys_.body_names[b]}.{DOF_NAMES[d]}"
                    for b in range(nb) for d in range(6)})

    # the full second-order system with the scene's PTO springs/dampers and linear viscous damping
    K, Dm = sys_.K.copy(), sys_.D.copy()
    for i, p in enumerate(scene.ptos):
        limit = "force_limit" if p.type == "linear" else "torque_limit"
        if getattr(p, limit) is not None:
            warnings.append(f"ptos[{i}].{limit}: the plant is the unlimited PTO {p.name!r}, valid while its "
                            f"{limit.split('_')[0]} stays below {getattr(p, limit):g}")
    for pl in sys_.ptos:
        K += pl.stiffness * np.outer(pl.g, pl.g)
        Dm += pl.damping * np.outer(pl.g, pl.g)
    W = np.zeros((sys_.wet_index.size, n))      # coordinates -> the wet bodies' 6N DOFs
    W[np.arange(sys_.wet_index.size), sys_.wet_index] = 1.0
    eq = setup.equilibrium_position
    for term in model.terms:   # the linear force terms (check_plant_scene refused the others): F = J v
        if term.steady != "jacobian":
            raise PlantError(term.scene_keys[0], f"the {term.name} force term has no linear model")
        Dm -= W.T @ term.velocity_jacobian(0.0, eq, np.zeros_like(eq)) @ W
    rad = model.radiation_realization()
    Dm -= W.T @ rad.d @ W                       # F_rad = C_r x_r + D_r v: a damping -D_r

    ind, N = _independent(sys_.G, n)
    k = ind.size
    Mr, Kr, Dr = N.T @ sys_.M @ N, N.T @ K @ N, N.T @ Dm @ N
    Mi = np.linalg.inv(Mr)
    s = rad.a.shape[0]
    A = np.zeros((2 * k + s, 2 * k + s))
    A[:k, k:2 * k] = np.eye(k)
    A[k:2 * k, :k] = -Mi @ Kr
    A[k:2 * k, k:2 * k] = -Mi @ Dr
    A[k:2 * k, 2 * k:] = Mi @ N.T @ W.T @ rad.c
    A[2 * k:, k:2 * k] = rad.b @ W @ N
    A[2 * k:, 2 * k:] = rad.a

    # inputs: PTO added tension (generalised force -g u), excitation on each active wet DOF
    wet_labels = [names.of(i) for i in sys_.wet_index]
    active_wet = [j for j in range(sys_.wet_index.size) if setup.active.reshape(-1)[j]]
    gen = [-pl.g for pl in sys_.ptos] + [W[j] for j in active_wet]
    inputs = tuple([f"pto:{pl.name}" for pl in sys_.ptos] + [f"excitation:{wet_labels[j]}" for j in active_wet])
    B = np.zeros((A.shape[0], len(gen)))
    B[k:2 * k] = Mi @ N.T @ np.array(gen).T if gen else B[k:2 * k]

    # outputs: position and velocity of every active DOF of every body, PTO extension rates
    active = {f"{b.name}.{d}" for b in scene.bodies for d in b.dofs}
    coords = [(int(sys_.body_index[6 * b + d]), f"{sys_.body_names[b]}.{DOF_NAMES[d]}")
              for b in range(nb) for d in range(6) if f"{sys_.body_names[b]}.{DOF_NAMES[d]}" in active]
    rows, outputs = [], []
    for part, off in (("position", 0), ("velocity", k)):
        for c, label in coords:
            row = np.zeros(A.shape[0])
            row[off:off + k] = N[c]
            rows.append(row)
            outputs.append(f"{label}.{part}")
    for part, off in (("displacement", 0), ("velocity", k)):   # the PTO extension from rest and its rate
        for pl in sys_.ptos:
            row = np.zeros(A.shape[0])
            row[off:off + k] = pl.g @ N
            rows.append(row)
            outputs.append(f"pto:{pl.name}.{part}")
    C = np.array(rows).reshape(len(rows), A.shape[0])

    rad_names = [f"radiation:{wet_labels[r]}<-{wet_labels[c]}:{i // 2}{'re' if i % 2 == 0 else 'im'}"
                 for i, (r, c) in enumerate(zip(rad.rows, rad.cols))]
    states = tuple([f"{names.of(i)}.position" for i in ind] + [f"{names.of(i)}.velocity" for i in ind] + rad_names)

    # the static offset: Kr z0 = N^T (f0 - sum g preload)
    f_static = sys_.f0 - sum((pl.preload * pl.g for pl in sys_.ptos), np.zeros(n))
    z0 = np.linalg.lstsq(Kr, N.T @ f_static, rcond=None)[0]
    if np.abs(z0).max(initial=0.0) > 1e-6:
        warnings.append(f"bodies: the reference configuration is not in equilibrium (static offset "
                        f"{', '.join(f'{states[i]} {z0[i]:+.3g}' for i in range(k) if abs(z0[i]) > 1e-6)}); "
                        "the plant is linearised about the reference configuration")
    report = setup.state_space
    fit_error = float(report.max_fit_error) if report is not None else 0.0
    return Plant(A, B, C, np.zeros((C.shape[0], B.shape[1])), states, inputs, tuple(outputs),
                 equilibrium=z0, warnings=tuple(warnings), radiation_fit_error=fit_error)


def linearize_scene(scene_path: str | Path, *, dt: float | None = None, progress: bool = True,
                    hdbs: dict | None = None) -> Plant:
    """Load the scene and its HDBs and build its plant, discretised at ``dt`` when given."""
    from hydrolink.clients.scene_inputs import load_scene_hdbs
    from hydrolink.protocol.scene import load_scene

    scene_path = Path(scene_path)
    scene, _ = load_scene(scene_path)
    check_plant_scene(scene)
    if dt is not None:
        sampling_time(dt)     # before the HDBs are loaded and the plant built
    if hdbs is None:
        hdbs = load_scene_hdbs(scene, scene_path, progress=progress)
    plant = build_plant(scene, hdbs)
    return plant if dt is None else plant.discretize(dt)


def linearize_scene_file(scene_path: str | Path, output: str | Path, *, dt: float | None = None,
                         progress: bool = True, hdbs: dict | None = None) -> Plant:
    """``hydrolink linearize``: :func:`linearize_scene`, written to ``output`` (.npz, .mat or .nc);
    returns the plant written."""
    output = Path(output)
    if output.suffix not in FORMATS:
        raise PlantError("-o", f"{output.name}: the plant is written as one of {', '.join(FORMATS)}")
    plant = linearize_scene(scene_path, dt=dt, progress=progress, hdbs=hdbs)
    plant.save(output)
    return plant
