"""The SPEC alone gives a third party the right physics: tests/spec_client.py (written from
protocol/SPEC.md, no hydrolink import) co-simulates a heave buoy against `hydrolink serve` with both
lockstep recipes of SPEC §8.3, and its response in regular waves equals the frequency-domain RAO
X / (C - w^2 (m + A(w)) - i w B(w)) of the same analytic coefficients, in amplitude and phase."""

from __future__ import annotations

import ast
from pathlib import Path

import numpy as np
import pytest
from scipy.special import dawsn

import spec_client
from conftest import body, regular_waves, scene_toml, serve_process

# One pytest-xdist worker runs this whole module (pyproject: --dist loadgroup): its module fixture (a server
# process) costs ~3 s, paid once per worker otherwise.
pytestmark = pytest.mark.xdist_group("spec_client")

RHO, G = 1000.0, 9.81
MASS, A_INF, B0, W0 = 3.0e5, 3.0e5, 4.0e5, 1.0     # heave: B(w) = B0 x^2 exp(-x^2), x = w/W0
C33 = RHO * G * 78.5                                 # waterplane of a 5 m radius buoy
COG = np.array([0.0, 0.0, -1.0])
INERTIA = np.array([2.0e6, 2.0e6, 3.0e6])            # about the centre of mass
OMEGA = np.linspace(0.02, 8.0, 400)


def damping(w):
    x = np.asarray(w) / W0
    return B0 * x ** 2 * np.exp(-x ** 2)


def added_mass(w):
    """Kramers-Kronig partner of damping(): A(w) = A_inf + (B0/W0)(1 - 2x F(x))/sqrt(pi), F Dawson's."""
    x = np.asarray(w) / W0
    return A_INF + (B0 / W0) * (1 - 2 * x * dawsn(x)) / np.sqrt(np.pi)


def excitation(w):
    """Heave excitation per metre of amplitude, exp(-iwt) convention (SPEC §5.1 HDB map)."""
    w = np.asarray(w)
    return C33 * np.exp(-(w / 2.0) ** 2) * np.exp(0.4j * w)


def arr(a) -> dict:
    return spec_client.pack_array(np.asarray(a))


def hdb_map() -> dict:
    """One body, all six DOFs, as SPEC §5.1's HDB map table lists it (heave carries the physics;
    the other DOFs get small diagonal coefficients and no excitation)."""
    nw = OMEGA.size
    a, b = np.zeros((nw, 6, 6)), np.zeros((nw, 6, 6))
    a_inf = np.diag([2e5, 2e5, A_INF, 4e6, 4e6, 1e6])
    for i in range(6):
        a[:, i, i] = a_inf[i, i] + (added_mass(OMEGA) - A_INF) * (1.0 if i == 2 else 0.1)
        b[:, i, i] = damping(OMEGA) * (1.0 if i == 2 else 0.1)
    x = np.zeros((nw, 1, 6), complex)
    x[:, 0, 2] = excitation(OMEGA)
    return {"bodies": ["buoy"], "omega": arr(OMEGA), "wave_direction": arr([0.0]),
            "attrs": {"rho": RHO, "g": G, "water_depth": float("inf"), "source": "analytic buoy"},
            "added_mass": arr(a), "radiation_damping": arr(b), "excitation_force": arr(x),
            "hydrostatic_stiffness": arr(np.diag([0.0, 0.0, C33, 5e6, 5e6, 0.0])),
            "reference_point": arr([[0.0, 0.0, 0.0]]), "added_mass_inf": arr(a_inf),
            "displaced_volume": arr([MASS / RHO]), "center_of_buoyancy": arr([[0.0, 0.0, -1.5]])}


def rigid_mass() -> np.ndarray:
    """The body's 6x6 mass matrix about its reference point (origin), centre of mass at COG."""
    s = np.array([[0, -COG[2], COG[1]], [COG[2], 0, -COG[0]], [-COG[1], COG[0], 0]])
    m = np.zeros((6, 6))
    m[:3, :3] = MASS * np.eye(3)
    m[:3, 3:], m[3:, :3] = -MASS * s, MASS * s
    m[3:, 3:] = np.diag(INERTIA) - MASS * s @ s
    return m


def scene(period: float) -> str:
    return scene_toml(dt=0.02, duration=80.0, water={"density": RHO, "gravity": G},
                      waves=regular_waves(2.0, period, ramp=10.0), hydro={"irf_duration": 15.0},
                      bodies=[body("buoy", hdb="buoy.nc", mass=MASS, center_of_mass=COG, inertia=INERTIA,
                                   dofs=["heave"])])


def complex_amplitude(t: np.ndarray, y: np.ndarray, w: float) -> complex:
    """c with y = Re{c exp(-iwt)} = Re c cos wt + Im c sin wt, least squares."""
    basis = np.column_stack([np.cos(w * t), np.sin(w * t), np.ones_like(t)])
    coef = np.linalg.lstsq(basis, y, rcond=None)[0]
    return complex(coef[0], coef[1])


@pytest.fixture(scope="module")
def server():
    with serve_process() as address:
        yield address


def test_the_client_imports_nothing_of_hydrolink():
    tree = ast.parse(Path(spec_client.__file__).read_text())
    names = {a.name.split(".")[0] for n in ast.walk(tree) if isinstance(n, ast.Import) for a in n.names}
    names |= {n.module.split(".")[0] for n in ast.walk(tree) if isinstance(n, ast.ImportFrom) and n.module}
    assert names <= {"__future__", "itertools", "dataclasses", "numpy", "msgpack", "zmq"}, names


@pytest.mark.parametrize("recipe", ["predictor", "iterated"])
@pytest.mark.parametrize("period", [5.0, 8.0])
def test_heave_rao_equals_the_frequency_domain(server, recipe, period):
    rec = spec_client.run(server, scene(period), {"buoy.nc": hdb_map()}, rigid_mass(), recipe)
    t = np.array(rec.time)
    assert t[-1] == pytest.approx(80.0)
    w = 2 * np.pi / period
    late = t >= 50.0
    z = complex_amplitude(t[late], np.array(rec.displacement)[late, 0], w)
    eta = complex_amplitude(t[late], np.array(rec.elevation)[late], w)
    rao = z / eta
    ref = excitation(w) / (C33 - w * w * (MASS + added_mass(w)) - 1j * w * damping(w))
    assert abs(abs(rao) / abs(ref) - 1) <= 0.005, (abs(rao), abs(ref))
    assert abs(np.angle(rao / ref, deg=True)) <= 0.5
    if recipe == "iterated":
        # the published feedthrough predicts the replaced step's force exactly (linear in v)
        assert max(rec.corrections) <= 1e-8 * C33


def test_a_step_past_the_end_is_refused_by_name(server):
    conn = spec_client.Connection(server)
    try:
        welcome = conn.request("hello", role="multibody", scene=scene(5.0), hdbs={"buoy.nc": hdb_map()})
        conn.session = welcome["session"]
        last, h = welcome["setup"]["last_seq"], welcome["setup"]["dt"]
        assert last == 4000
        zero = spec_client.pack_array(np.zeros((1, 6)))
        with pytest.raises(spec_client.ServerError) as err:
            conn.request("step", seq=last + 1, time=(last + 1) * h, position=zero, velocity=zero)
        assert (err.value.code, err.value.field) == (5, "seq")
        conn.request("bye")
    finally:
        conn.close()
