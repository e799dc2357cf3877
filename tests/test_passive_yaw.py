"""Passive yaw (server/sea/passive_yaw.py, ``bodies[i].passive_yaw``): a body that turns meets each
wave at its direction relative to its yaw.

References: with the yaw held at 0 the forces equal the fixed-heading model's bit for bit (numpy and
compiled paths, excitation and mean drift); with the yaw turning, the excitation and the mean drift
of each step equal the HDB's values at the relative heading, rotated into the global frame,
computed here from the HDB's own tables (its 0-90 deg headings mirrored around the circle by the
barge's two planes of symmetry, linear in heading) to 1 %; the refusals name their key.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from conftest import body, irregular_waves, regular_waves, scene_toml

from hydrolink.protocol.hdb.second_order import MeanDrift
from hydrolink.protocol.hdb.schema import with_second_order
from hydrolink.protocol.scene import SceneError, parse_scene
from hydrolink.server.errors import ModelError
from hydrolink.server.hdb.io import load_hdb
from hydrolink.server.model import HydroModel

HDB = Path(__file__).resolve().parents[1] / "examples" / "data" / "barge_headings" / "barge_headings.nc"
WATER = {"density": 1025.0, "gravity": 9.81, "depth": "inf"}
XZ, YZ = np.array([1, -1, 1, -1, 1, -1.0]), np.array([-1, 1, 1, 1, -1, -1.0])   # DOF signs of the mirrors


@pytest.fixture(scope="module")
def barge():
    """The crossing-sea barge's HDB (headings 0..90 deg) with an analytic mean drift that has its
    symmetries: surge 1e3 w^2 cos b, sway 1e3 w^2 sin b, yaw 4e3 w^2 sin 2b (N/m^2, N m/m^2)."""
    ds = load_hdb(HDB)
    w, b = ds["omega"].values, ds["wave_direction"].values
    values = np.zeros((1, w.size, b.size, 6))
    values[0, :, :, 0] = 1e3 * np.outer(w ** 2, np.cos(b))
    values[0, :, :, 1] = 1e3 * np.outer(w ** 2, np.sin(b))
    values[0, :, :, 5] = 4e3 * np.outer(w ** 2, np.sin(2 * b))
    return with_second_order(ds, mean_drift=MeanDrift(("momentum",), w, b, values))


def _scene(waves: dict, *, passive: bool = True, hydro: dict | None = None, **keys):
    bodies = [body("barge", hdb=str(HDB), mass=328e3, center_of_mass=[0, 0, 0], inertia=[2e6, 1.12e7, 1.27e7],
                   **{"heading_symmetry": "both", "passive_yaw": passive, **keys})]
    return parse_scene(scene_toml(dt=0.1, duration=10.0, water=WATER, waves=waves, bodies=bodies,
                                  hydro={"radiation": "off", **(hydro or {})}))


def _circle(values: np.ndarray, axis: int) -> tuple[np.ndarray, np.ndarray]:
    """The HDB's 0..90 deg headings (along ``axis``) completed around the circle by the barge's
    mirrors: (24 headings in [0, 2 pi), values) with the DOF axis last."""
    v = np.moveaxis(values, axis, -2)                                       # (..., 7, 6)
    heads = np.deg2rad(np.arange(0, 360, 15.0))
    out = np.empty(v.shape[:-2] + (24, 6), v.dtype)
    for n, h in enumerate(np.arange(0, 360, 15)):
        q, sign = h, np.ones(6)
        if h > 180:                                                         # from -h: the xz mirror
            q, sign = 360 - h, XZ
        if q > 90:                                                          # from 180 - q: the yz mirror
            q, sign = 180 - q, sign * YZ
        out[..., n, :] = v[..., q // 15, :] * sign
    return heads, out


def _at(heads: np.ndarray, table: np.ndarray, theta: float) -> np.ndarray:
    """(6,) table (24, 6) linear in heading around the circle at theta."""
    return np.array([np.interp(theta % (2 * np.pi), heads, table[:, d].real, period=2 * np.pi)
                     + 1j * np.interp(theta % (2 * np.pi), heads, table[:, d].imag, period=2 * np.pi)
                     for d in range(6)])


def _rotate(f: np.ndarray, psi: float) -> np.ndarray:
    c, s = np.cos(psi), np.sin(psi)
    out = f.copy()
    for a, b in ((0, 1), (3, 4)):
        out[a], out[b] = c * f[a] - s * f[b], s * f[a] + c * f[b]
    return out


@pytest.mark.parametrize("compiled,mode", [(False, "newman"), (True, "mean-drift")])   # (the drift's path is one)
def test_yaw_held_at_zero_is_the_fixed_heading_bit_for_bit(barge, compiled, mode):
    waves = irregular_waves(1.5, 7.0, direction=30.0, components=16, spreading="cos2s", s=10.0,
                            directions=3, ramp=2.0)
    fixed = HydroModel(_scene(waves, passive=False, second_order=mode), {"barge": barge}, compiled=compiled)
    turning = HydroModel(_scene(waves, second_order=mode), {"barge": barge}, compiled=compiled)
    x0 = fixed.setup_info().equilibrium_position
    for k in range(30):
        x = x0 + [[0.1 * np.sin(k), -0.2, 0.05 * k, 0.01, -0.02, 0.0]]
        v = np.array([[0.3, 0.1, -0.2, 0.01, 0.02, 0.0]])
        a, b = fixed.step(k * 0.1, x, v), turning.step(k * 0.1, x, v)
        for field in ("excitation", "drift", "wave_elevation"):
            np.testing.assert_array_equal(a[field], b[field], err_msg=f"{mode}: {field} at step {k}")


@pytest.mark.parametrize("compiled", [False, True])
def test_turning_excitation_is_the_hdb_at_the_relative_heading(barge, compiled):
    w = barge["omega"].values
    picks = [9, 12, 16]                                      # components at HDB frequencies: no interpolation in w
    comps = {"type": "components", "omega": w[picks].tolist(), "direction": [20.0, -75.0, 160.0],
             "amplitude": [0.6, 0.4, 0.3], "phase": [10.0, 200.0, 300.0]}
    model = HydroModel(_scene(comps), {"barge": barge}, compiled=compiled)
    heads, table = _circle(barge["excitation_force"].values[picks], axis=1)    # (3, 24, 6)
    x0 = model.setup_info().equilibrium_position
    worst = 0.0
    for k in range(60):
        t = k * 0.1
        psi = 3.5 * np.sin(0.11 * k) + 0.004 * k * k      # through every quadrant, past a full turn
        got = model.step(t, x0 + [[0, 0, 0, 0, 0, psi]], np.zeros((1, 6)))["excitation"][0]
        want, scale = np.zeros(6), np.zeros(6)
        for c in range(3):
            x = _rotate(_at(heads, table[c], np.deg2rad(comps["direction"][c]) - psi), psi)
            z = comps["amplitude"][c] * np.exp(1j * (np.deg2rad(comps["phase"][c]) - w[picks[c]] * t))
            want += (x * z).real
            scale += np.abs(x) * comps["amplitude"][c]
        worst = max(worst, float(np.max(np.abs(got - want) / scale)))
    assert worst < 0.01, worst


def test_turning_mean_and_slow_drift_are_the_hdb_at_the_relative_heading(barge):
    w = barge["omega"].values
    model = HydroModel(_scene(regular_waves(1.2, 2 * np.pi / w[14], direction=-40.0), second_order="mean-drift"),
                       {"barge": barge})
    heads, table = _circle(barge["mean_drift"].values[0][14], axis=0)          # (24, 6)
    x0 = model.setup_info().equilibrium_position
    for k, psi in enumerate(np.deg2rad([0.0, 7.3, 44.5, 95.0, -130.2, 181.0, 400.0])):
        got = model.step(k * 0.1, x0 + [[0, 0, 0, 0, 0, psi]], np.zeros((1, 6)))["drift"][0]
        want = 0.6 ** 2 * _rotate(_at(heads, table, np.deg2rad(-40.0) - psi).real, psi)
        np.testing.assert_allclose(got, want, rtol=0, atol=0.01 * np.abs(want).max())
    # Newman's slow drift of two components: Re[(sum_i z_i T_ii) conj(sum_j z_j)], T_ii turned likewise
    picks, heads_deg = [12, 16], [20.0, -75.0]
    comps = {"type": "components", "omega": w[picks].tolist(), "direction": heads_deg, "amplitude": [0.6, 0.4],
             "phase": [10.0, 200.0]}
    model = HydroModel(_scene(comps, second_order="newman"), {"barge": barge})
    tables = [_circle(barge["mean_drift"].values[0][p], axis=0)[1] for p in picks]
    for k, psi in enumerate(np.deg2rad([0.0, 33.3, -101.7, 222.2])):
        got = model.step(k * 0.1, x0 + [[0, 0, 0, 0, 0, psi]], np.zeros((1, 6)))["drift"][0]
        z = np.array(comps["amplitude"]) * np.exp(1j * (np.deg2rad(comps["phase"]) - w[picks] * k * 0.1))
        t_ii = [_rotate(_at(heads, tables[c], np.deg2rad(heads_deg[c]) - psi).real, psi) for c in range(2)]
        want = ((z[0] * t_ii[0] + z[1] * t_ii[1]) * np.conj(z.sum())).real
        np.testing.assert_allclose(got, want, rtol=0, atol=0.01 * np.abs(want).max())


def test_refusals_name_their_key(barge):
    with pytest.raises(SceneError) as err:
        _scene(regular_waves(1.0, 7.0), dofs=["surge", "sway", "heave", "roll", "pitch"])
    assert "bodies[0].passive_yaw" in str(err.value) and "yaw DOF free" in str(err.value)
    cases = [
        ({"waves": regular_waves(1.0, 7.0, excitation="convolution")}, "convolution"),
        ({"waves": regular_waves(1.0, 7.0), "second_order": "newman", "hydro": {"sum_frequency": True}}, "not built"),
        ({"waves": regular_waves(1.0, 7.0), "heading_symmetry": "none"}, "not covered"),
    ]
    for keys, why in cases:
        with pytest.raises(ModelError) as err:
            HydroModel(_scene(keys.pop("waves"), **keys), {"barge": barge})
        assert err.value.key == "bodies[0].passive_yaw" and why in str(err.value), str(err.value)


@pytest.mark.parametrize("compiled", [False, True])
def test_filtered_yaw_reads_the_waves_at_the_low_passed_heading(barge, compiled):
    """passive_yaw_filter = tau: the waves are read at psi_f, psi_f,k = psi_f,k-1 + dt/(tau + dt) (psi_k -
    psi_f,k-1) from psi_f,0 = psi_0 (the recursion written here); the excitation equals the
    unfiltered model's at that heading, and a step recomputed (replace_last) or rolled back repeats it."""
    waves = regular_waves(1.0, 2 * np.pi / barge["omega"].values[14], direction=-40.0)
    filtered = HydroModel(_scene(waves, passive_yaw_filter=2.0, second_order="mean-drift"), {"barge": barge},
                          compiled=compiled)
    plain = HydroModel(_scene(waves, second_order="mean-drift"), {"barge": barge}, compiled=compiled)
    x0 = filtered.setup_info().equilibrium_position
    psi_f, alpha = 0.0, 0.1 / 2.1
    for k in range(25):
        psi = 0.8 * np.sin(1.3 * k) + 0.05 * k
        psi_f = psi if k == 0 else psi_f + alpha * (psi - psi_f)
        if k == 10:                       # a step first sent with another yaw, then recomputed
            filtered.step(k * 0.1, x0 + [[0, 0, 0, 0, 0, psi + 1.0]], np.zeros((1, 6)))
            saved = filtered.state()
            got = tenth = filtered.step(k * 0.1, x0 + [[0, 0, 0, 0, 0, psi]], np.zeros((1, 6)), replace_last=True)
        else:
            got = filtered.step(k * 0.1, x0 + [[0, 0, 0, 0, 0, psi]], np.zeros((1, 6)))
        want = plain.step(k * 0.1, x0 + [[0, 0, 0, 0, 0, psi_f]], np.zeros((1, 6)))
        for field in ("excitation", "drift"):
            np.testing.assert_allclose(got[field], want[field], rtol=1e-12, atol=1e-9 * np.abs(want[field]).max())
    filtered.set_state(saved)             # rolled back to step 10 as first sent: recomputed, the same bits
    again = filtered.step(1.0, x0 + [[0, 0, 0, 0, 0, 0.8 * np.sin(13.0) + 0.5]], np.zeros((1, 6)), replace_last=True)
    for field in ("excitation", "drift"):
        np.testing.assert_array_equal(again[field], tenth[field])


def test_turning_qtf_force_is_the_hdb_at_the_relative_heading(barge):
    """The full difference QTF of a turning body: Re sum_ij z_i conj(z_j) R(psi) T(w_i, w_j, beta - psi),
    T on the QTF's diagonal heading pairs (h, h) (0..90 deg mirrored around the circle) linear in
    heading, written here; the components sit on the QTF's frequencies (no frequency interpolation).
    At yaw 0 the force is the fixed-heading model's bit for bit."""
    from hydrolink.protocol.hdb.second_order import QTF
    grid = barge["omega"].values[10:31:5]                                      # 5 frequencies
    b = barge["wave_direction"].values
    rng = np.random.default_rng(3)
    r = rng.standard_normal((5, 5, b.size, 6)) + 1j * rng.standard_normal((5, 5, b.size, 6))
    diff = 1e3 * 0.5 * (r + np.conj(np.swapaxes(r, 0, 1)))                    # Hermitian in (i, j)
    diff[..., 2:5] = 0.0                                                      # heave, roll, pitch: none
    diff[:, :, [0, 6], 1] = diff[:, :, [0, 6], 5] = 0.0   # sway and yaw vanish at 0 (xz) and 90 deg (yz)
    diff[:, :, 6, 0] = 0.0                                # surge vanishes at 90 deg (yz)
    ds = barge.drop_vars([v for v in barge.data_vars if "drift" in v]).drop_dims(["drift_omega", "drift_direction",
                                                                                  "drift_method"], errors="ignore")
    from hydrolink.protocol.hdb.schema import with_second_order
    ds = with_second_order(ds, qtf=QTF(grid, b, b, diff, None, "test"))
    comps = {"type": "components", "omega": grid[[0, 2, 4]].tolist(), "direction": [-40.0] * 3,
             "amplitude": [0.5, 0.4, 0.3], "phase": [0.0, 70.0, 250.0]}
    fixed = HydroModel(_scene(comps, passive=False, second_order="qtf"), {"barge": ds})
    model = HydroModel(_scene(comps, second_order="qtf"), {"barge": ds})
    heads, table = _circle(diff[np.ix_([0, 2, 4], [0, 2, 4])], axis=2)       # (3, 3, 24, 6)
    x0 = model.setup_info().equilibrium_position
    for k, psi in enumerate(np.deg2rad([0.0, 12.5, -101.7, 222.2, 0.0])):
        t = k * 0.1
        got = model.step(t, x0 + [[0, 0, 0, 0, 0, psi]], np.zeros((1, 6)))["drift"][0]
        if psi == 0.0:
            np.testing.assert_array_equal(got, fixed.step(t, x0, np.zeros((1, 6)))["drift"][0])
            continue
        fixed.step(t, x0, np.zeros((1, 6)))
        theta = (np.deg2rad(-40.0) - psi) % (2 * np.pi)
        hat = np.array([np.interp(theta, heads, np.eye(24)[n], period=2 * np.pi) for n in range(24)])
        t_rel = np.einsum("ijhd,h->ijd", table, hat)
        z = np.array(comps["amplitude"]) * np.exp(1j * (np.deg2rad(comps["phase"]) - grid[[0, 2, 4]] * t))
        want = _rotate(np.einsum("i,j,ijd->d", z, np.conj(z), t_rel).real, psi)
        np.testing.assert_allclose(got, want, rtol=0, atol=1e-7 * np.abs(want).max())   # headings kept to 1e-9 rad
