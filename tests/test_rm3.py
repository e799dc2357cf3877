"""RM3 reference device (examples/rm3): float heave + spar heave coupled by a linear damper PTO, in a
regular wave H = 2.5 m, T = 8 s, dt = T/100, against a two-body frequency-domain solution written here.

Frequency domain (exp(-iwt)), unknowns the complex heave amplitudes x = (X_f, X_s):

    [-w^2 (M + A(w)) - i w (B(w) + B_pto) + C] x = X(w) H/2,    B_pto = c [[1, -1], [-1, 1]]

with M = diag(m_f, m_s), C the heave hydrostatic stiffness (the gravity terms have no heave part),
A, B the 2x2 heave blocks (float, spar) — the off-diagonal ones only for interaction "full" — and X
the heave excitation, all from the same WAMIT HDB. Mean PTO power P = 1/2 c w^2 |X_f - X_s|^2.

Two versions of A(w), B(w) enter the reference:
- "HDB": A(w), B(w) interpolated in the HDB at w;
- "effective": what the truncated, sampled convolution realises, A_eff = A_inf - (1/w) sum_j
  w_j K(t_j) sin(w t_j) dt and B_eff = sum_j w_j K(t_j) cos(w t_j) dt with K(t) = (2/pi) int B cos(wt)
  dw integrated here from the HDB's B(w) (grid 0.02-5.2 rad/s, B(0) = 0) — as tests/test_coupled_dofs.py.
The assertions use the effective reference: it is what the co-simulation (convolution + coupling +
integration) should reproduce, so the comparison measures the co-simulation and not the BEM grid's
truncation. For RM3 at T = 8 s both references agree to < 0.05 % (the IRF truncation is negligible
here); both comparisons are printed (pytest -s).

Time domain: the steady state fitted over the last five periods (a0 + a cos wt + b sin wt) and the
mean of c (v_f - v_s)^2 over them. Two time-domain runs: (1) the force model driven by a two-DOF
trapezoidal integrator written here with the PTO damper (isolates the server), (2) ``hydrolink run``
of the example scenes (Exudyn client with its PTO, embedded server).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from conftest import rm3_example_text
from hydrolink.protocol.scene import load_scene, parse_scene
from hydrolink.server.model import HydroModel

REPO = Path(__file__).resolve().parents[1]
EXAMPLE = REPO / "examples" / "rm3"
H, PERIOD, C_PTO = 2.5, 8.0, 1.2e6
W = 2 * np.pi / PERIOD
DT = PERIOD / 100
MASS = np.array([725833.0, 886687.0])      # rho V, rho = 1000
HEAVE = [2, 8]                             # float heave, spar heave in the 12-DOF HDB
DURATION = 200.0                           # s: steady to < 1e-5 by 160 s with the scenes' 40 s ramp


@pytest.fixture(scope="module")
def rm3(reference_data):
    from hydrolink.server.hdb.io import load_hdb
    return load_hdb(reference_data / "rm3_wamit" / "rm3.1")


def _at_w(rm3, values: np.ndarray) -> np.ndarray:
    """Linear interpolation in w of an (n_w, ...) array (complex: re and im separately)."""
    om = rm3["omega"].values
    flat = values.reshape(om.size, -1)
    out = [np.interp(W, om, flat[:, k].real) + 1j * np.interp(W, om, flat[:, k].imag) for k in range(flat.shape[1])]
    return np.array(out).reshape(values.shape[1:])


def hdb_radiation(rm3) -> tuple[np.ndarray, np.ndarray]:
    hv = np.ix_(range(rm3.sizes["omega"]), HEAVE, HEAVE)
    return (_at_w(rm3, rm3["added_mass"].values[hv]).real,
            _at_w(rm3, rm3["radiation_damping"].values[hv]).real)


def effective_radiation(rm3, irf: float) -> tuple[np.ndarray, np.ndarray]:
    """A_eff, B_eff (2x2 heave) of the trapezoid convolution over [0, irf] with step DT."""
    om = np.r_[0.0, rm3["omega"].values]
    b = rm3["radiation_damping"].values[:, HEAVE][:, :, HEAVE]
    b = np.concatenate([np.zeros((1, 2, 2)), b])
    t = np.arange(int(round(irf / DT)) + 1) * DT
    k = np.array([2 / np.pi * np.trapezoid(b * np.cos(om * ti)[:, None, None], om, axis=0) for ti in t])
    wt = np.full(t.size, DT)
    wt[[0, -1]] *= 0.5
    a_inf = rm3["added_mass_inf"].values[np.ix_(HEAVE, HEAVE)]
    return (a_inf - np.tensordot(wt * np.sin(W * t), k, axes=(0, 0)) / W,
            np.tensordot(wt * np.cos(W * t), k, axes=(0, 0)))


def frequency_domain(rm3, a: np.ndarray, b: np.ndarray, interaction: str) -> tuple[np.ndarray, float]:
    """Complex heave amplitudes (float, spar) and the mean PTO power."""
    if interaction == "none":
        a, b = np.diag(np.diag(a)), np.diag(np.diag(b))
    c_hs = rm3["hydrostatic_stiffness"].values[np.ix_(HEAVE, HEAVE)]
    x_ex = _at_w(rm3, rm3["excitation_force"].values[:, 0, HEAVE])
    b_pto = C_PTO * np.array([[1.0, -1.0], [-1.0, 1.0]])
    z = -W ** 2 * (np.diag(MASS) + a) - 1j * W * (b + b_pto) + c_hs
    x = np.linalg.solve(z, x_ex * H / 2)
    return x, 0.5 * C_PTO * W ** 2 * abs(x[0] - x[1]) ** 2


def steady_state(t: np.ndarray, z: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, float]:
    """Heave amplitudes (2,) fitted over the last five periods and the mean c (v_f - v_s)^2 there."""
    sel = t > t[-1] - 5 * PERIOD + 1e-9
    basis = np.c_[np.ones(sel.sum()), np.cos(W * t[sel]), np.sin(W * t[sel])]
    fit = np.linalg.lstsq(basis, z[sel], rcond=None)[0]
    return np.hypot(fit[1], fit[2]), float(np.mean(C_PTO * (v[sel, 0] - v[sel, 1]) ** 2))


def compare(label: str, amps: np.ndarray, power: float, rm3, interaction: str, irf: float) -> dict:
    """Print TD vs both FD references; return the relative errors against the effective one."""
    out = {}
    for name, (a, b) in (("HDB", hdb_radiation(rm3)), ("effective", effective_radiation(rm3, irf))):
        x, p = frequency_domain(rm3, a, b, interaction)
        err = np.r_[amps / np.abs(x) - 1, power / p - 1]
        print(f"{label} {interaction:>4} vs FD({name:>9}): float {amps[0]:.5f}/{abs(x[0]):.5f} m, spar "
              f"{amps[1]:.5f}/{abs(x[1]):.5f} m, P {power / 1e3:.2f}/{p / 1e3:.2f} kW; errors "
              f"{err[0]:+.2e} {err[1]:+.2e} {err[2]:+.2e}")
        out[name] = err
    return out


def scene_text(interaction: str, hdb: Path, duration: float = DURATION) -> str:
    """The example scene with the HDB at ``hdb`` and a shorter duration."""
    name = "rm3.toml" if interaction == "full" else "rm3_none.toml"
    text = rm3_example_text(name)
    text = text.replace('"../data/rm3_wamit/rm3.1"', f'"{hdb.as_posix()}"')
    return text.replace("duration = 400.0", f"duration = {duration}")


def test_example_scenes_are_the_device():
    """The example files: their HDB is the repository's RM3 WAMIT data (examples/data), the 2-DOF device."""
    for name, interaction in (("rm3.toml", "full"), ("rm3_none.toml", "none")):
        scene, _ = load_scene(EXAMPLE / name)
        assert scene.hydro.interaction == interaction
        assert scene.simulation.dt == pytest.approx(PERIOD / 100)
        assert (scene.waves.height, scene.waves.period) == (H, PERIOD)
        assert [b.dofs for b in scene.bodies] == [["heave"], ["heave"]]
        assert [b.mass for b in scene.bodies] == list(MASS) and scene.water.density == 1000.0
        assert [(p.type, p.damping, p.body1, p.body2) for p in scene.ptos] == [("linear", C_PTO, "float", "spar")]
        assert (EXAMPLE / scene.bodies[0].hdb).resolve() == (REPO / "examples/data/rm3_wamit/rm3.1").resolve()


def lockstep(model: HydroModel, n_steps: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Trapezoidal rule on (M + A_inf) z'' = F_ex + F_rad + F_hs - B_pto z' in the two heave DOFs,
    each step iterated three times with replace_last. Returns t, heave displacements, velocities."""
    info = model.setup_info()
    m_inv = np.linalg.inv(np.diag(MASS) + info.added_mass_inf[np.ix_(HEAVE, HEAVE)])
    b_pto = C_PTO * np.array([[1.0, -1.0], [-1.0, 1.0]])
    pos, vel = info.equilibrium_position.copy(), np.zeros((2, 6))
    z_eq = pos[:, 2].copy()

    def acceleration(k: int, z: np.ndarray, v: np.ndarray, replace: bool) -> np.ndarray:
        pos[:, 2], vel[:, 2] = z_eq + z, v
        out = model.step(k * DT, pos, vel, replace_last=replace)
        return m_inv @ ((out["excitation"] + out["radiation"] + out["hydrostatic"])[:, 2] - b_pto @ v)

    z, v = np.zeros(2), np.zeros(2)
    a = acceleration(0, z, v, False)
    zs, vs = np.zeros((n_steps + 1, 2)), np.zeros((n_steps + 1, 2))
    for k in range(1, n_steps + 1):
        z1, v1, a1 = z + DT * v + 0.5 * DT * DT * a, v + DT * a, a
        for it in range(3):
            a1 = acceleration(k, z1, v1, it > 0)
            v1 = v + 0.5 * DT * (a + a1)
            z1 = z + 0.5 * DT * (v + v1)
        z, v, a = z1, v1, a1
        zs[k], vs[k] = z, v
    return np.arange(n_steps + 1) * DT, zs, vs


@pytest.mark.parametrize("interaction", ["full", "none"])
def test_force_model_lockstep_matches_frequency_domain(rm3, interaction):
    """The server's model alone (no Exudyn): isolates the multi-body hydrodynamics."""
    scene = parse_scene(scene_text(interaction, Path("rm3.1")))
    model = HydroModel(scene, {"float": rm3, "spar": rm3})
    assert model.setup_info().coupled_blocks == (2 if interaction == "full" else 0)
    t, z, v = lockstep(model, scene.simulation.n_steps)
    amps, power = steady_state(t, z, v)
    err = compare("model", amps, power, rm3, interaction, scene.hydro.irf_duration)["effective"]
    assert np.all(np.abs(err[:2]) < 0.01) and abs(err[2]) < 0.02
    assert np.all(np.abs(err) < 2e-3)  # actually much closer; the bounds above are the brief's


def test_interaction_matters_for_rm3(rm3):
    """The float-spar blocks change the spar's response by ~30 %: "none" is not a small correction."""
    a, b = hdb_radiation(rm3)
    x_full, p_full = frequency_domain(rm3, a, b, "full")
    x_none, p_none = frequency_domain(rm3, a, b, "none")
    assert abs(x_full[1]) / abs(x_none[1]) > 1.2 and p_full > p_none


@pytest.mark.parametrize("interaction", ["full", "none"])
def test_hydrolink_run_matches_frequency_domain(rm3, reference_data, tmp_path, interaction):
    """The example scenes through ``hydrolink run`` (Exudyn client, its linear PTO, embedded server)."""
    import xarray as xr

    from hydrolink.clients.run import run_scene_file

    scene = tmp_path / "rm3.toml"
    scene.write_text(scene_text(interaction, reference_data / "rm3_wamit" / "rm3.1"))
    run_scene_file(scene, tmp_path / "rm3.nc", progress=False)
    ds = xr.load_dataset(tmp_path / "rm3.nc")
    assert ds.attrs["status"] == "complete"
    t = ds["time"].values
    heave = (ds["position"] - ds["equilibrium_position"]).sel(body=["float", "spar"], dof="heave").values
    vel = ds["velocity"].sel(body=["float", "spar"], dof="heave").values
    amps, power = steady_state(t, heave, vel)
    sel = t > t[-1] - 5 * PERIOD + 1e-9  # the client's own PTO output: the damper's c v_rel^2
    assert float(ds["pto_power"].sel(pto="pto").values[sel].mean()) == pytest.approx(power, rel=1e-3)
    err = compare("run", amps, power, rm3, interaction, load_scene(scene)[0].hydro.irf_duration)["effective"]
    assert np.all(np.abs(err[:2]) < 0.01) and abs(err[2]) < 0.02
    if interaction == "full":  # the example's plot script on a real results file, as its __main__ in this
        # process (runpy, its own argv): a child would spend seconds of CPU importing what this one has loaded
        import runpy

        import matplotlib.pyplot as plt

        with pytest.MonkeyPatch.context() as mp:
            mp.setattr("sys.argv", [str(EXAMPLE / "plot.py"), str(tmp_path / "rm3.nc"), "-o", str(tmp_path / "rm3.png")])
            try:
                runpy.run_path(str(EXAMPLE / "plot.py"), run_name="__main__")
            finally:
                plt.close("all")
        assert (tmp_path / "rm3.png").stat().st_size > 10_000
