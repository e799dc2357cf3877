"""Multi-body hydrodynamics on the server, on the RM3 WAMIT HDB (float + spar in one file):
interaction "full" vs "none", one file per body, dry bodies, a scene without wet bodies, the wire."""

from __future__ import annotations

import numpy as np
import pytest

from conftest import REPLY_S, body, regular_waves, rm3_float, rm3_spar, scene_toml

from hydrolink.clients.lockstep.connection import RemoteError, ServerConnection
from hydrolink.protocol.scene import parse_scene
from hydrolink.protocol.hdb.schema import select_bodies
from hydrolink.server.model import HydroModel, ModelError

DT, IRF = 0.1, 20.0


def dry(name: str) -> dict:
    """A dry 1 t body 5 m above the origin."""
    return body(name, mass=1000.0, center_of_mass=[0, 0, 5.0], inertia=[10, 10, 10])


def scene_text(interaction: str = "full", *, float_hdb="rm3.1", spar_hdb="rm3.1", dry_between=False,
               dry_first=False, waves: dict | None = None, spar_keys: dict | None = None,
               bodies: list[dict] | None = None) -> str:
    """RM3's float and spar (``spar_keys`` add to the spar's keys), with dry bodies between or first;
    or ``bodies`` instead."""
    if bodies is None:
        bodies = [rm3_float(float_hdb), rm3_spar(spar_hdb, **(spar_keys or {}))]
        if dry_between:
            bodies.insert(1, dry("frame"))
        if dry_first:
            bodies.insert(0, dry("crane"))
    return scene_toml(dt=DT, duration=10, water={"density": 1000.0},
                      hydro={"irf_duration": IRF, "interaction": interaction}, waves=waves, bodies=bodies)


@pytest.fixture(scope="module")
def rm3(reference_data):
    from hydrolink.server.hdb.io import load_hdb
    return load_hdb(reference_data / "rm3_wamit" / "rm3.1")


def model(rm3, interaction="full", **kw) -> HydroModel:
    return HydroModel(parse_scene(scene_text(interaction, **kw)), {"float": rm3, "spar": rm3})


def block(m: np.ndarray, i: int, j: int) -> np.ndarray:
    return m[6 * i:6 * i + 6, 6 * j:6 * j + 6]


def test_full_keeps_and_none_drops_the_body_to_body_blocks(rm3):
    full, none = model(rm3, "full").setup_info(), model(rm3, "none").setup_info()
    a_hdb = rm3["added_mass_inf"].values  # rho = 1000 in both
    assert full.interaction == "full" and none.interaction == "none"
    assert full.coupled_blocks == 2 and none.coupled_blocks == 0
    assert full.hydro_groups == (("float", "spar"),) and none.hydro_groups == (("float",), ("spar",))
    assert full.radiation_kernel_entries == 144 and none.radiation_kernel_entries == 72
    np.testing.assert_allclose(full.added_mass_inf, a_hdb, rtol=1e-12)
    assert abs(block(a_hdb, 0, 1)[2, 2]) > 1e5  # float-spar heave coupling is real in this HDB
    for key in ("added_mass_inf", "hydrostatic_stiffness"):
        for i, j in ((0, 1), (1, 0)):
            assert np.all(block(getattr(none, key), i, j) == 0.0), key
        for i in (0, 1):
            np.testing.assert_array_equal(block(getattr(none, key), i, i), block(getattr(full, key), i, i))


def independent_irf(rm3, rows: slice, cols: slice, t: np.ndarray) -> np.ndarray:
    """K(t) = (2/pi) int_0^inf B(w) cos(w t) dw over the HDB grid with B(0) = 0 (trapezoid)."""
    om = np.r_[0.0, rm3["omega"].values]
    b = rm3["radiation_damping"].values[:, rows, cols]
    b = np.concatenate([np.zeros((1, *b.shape[1:])), b])
    return np.array([2 / np.pi * np.trapezoid(b * np.cos(om * ti)[:, None, None], om, axis=0) for ti in t])


def test_float_motion_radiates_on_the_spar_only_with_full_interaction(rm3):
    """Only the float moves (heave and surge); the spar's radiation force equals
    -dt sum_j w_j K_spar,float(j dt) v_float(t - j dt) from B(w) with "full", and is zero with "none"."""
    n = 120
    t = np.arange(n) * DT
    v_float = np.zeros((n, 6))
    v_float[:, 2] = 0.8 * np.sin(0.9 * t) * (1 - np.exp(-t))
    v_float[:, 0] = 0.3 * np.sin(0.5 * t + 0.2)
    runs = {}
    for interaction in ("full", "none"):
        m = model(rm3, interaction)
        pos = m.setup_info().equilibrium_position
        runs[interaction] = np.array([m.step(k * DT, pos, np.vstack([v_float[k], np.zeros(6)]))["radiation"]
                                      for k in range(n)])
    m_irf = int(round(IRF / DT))
    k_sf = independent_irf(rm3, slice(6, 12), slice(0, 6), np.arange(m_irf + 1) * DT)  # (M+1, 6, 6)
    k_ff = independent_irf(rm3, slice(0, 6), slice(0, 6), np.arange(m_irf + 1) * DT)
    w = np.ones(m_irf + 1)
    w[[0, -1]] = 0.5
    for k in (10, 60, n - 1):
        j = np.arange(min(k, m_irf) + 1)
        hist = v_float[k - j]  # newest first
        expect_spar = -DT * np.einsum("j,jab,jb->a", w[j], k_sf[j], hist)
        expect_float = -DT * np.einsum("j,jab,jb->a", w[j], k_ff[j], hist)
        scale = np.abs(expect_spar).max()
        np.testing.assert_allclose(runs["full"][k, 1], expect_spar, rtol=1e-6, atol=1e-7 * scale)
        np.testing.assert_allclose(runs["full"][k, 0], expect_float, rtol=1e-6,
                                   atol=1e-7 * np.abs(expect_float).max())
        assert np.all(runs["none"][k, 1] == 0.0)
        np.testing.assert_allclose(runs["none"][k, 0], runs["full"][k, 0], rtol=1e-12, atol=1e-9)
    assert np.abs(runs["full"][:, 1, 2]).max() > 1e3  # N: a real force, not round-off


def test_one_file_per_body_equals_none_on_the_shared_file(rm3):
    """Separate single-body datasets never interact: "full" on them equals "none" on the RM3 file."""
    waves = regular_waves(2.5, 8.0, ramp=4.0)
    split = HydroModel(parse_scene(scene_text("full", float_hdb="f.nc", spar_hdb="s.nc", waves=waves)),
                       {"float": select_bodies(rm3, ["float"]), "spar": select_bodies(rm3, ["spar"])})
    none = model(rm3, "none", waves=waves)
    assert split.setup_info().coupled_blocks == 0
    np.testing.assert_array_equal(split.setup_info().added_mass_inf, none.setup_info().added_mass_inf)
    rng = np.random.default_rng(1)
    pos = none.setup_info().equilibrium_position
    for k in range(40):
        x, v = pos + 0.1 * rng.standard_normal((2, 6)), rng.standard_normal((2, 6))
        a, b = split.step(k * DT, x, v), none.step(k * DT, x, v)
        for key in ("excitation", "radiation", "hydrostatic"):
            np.testing.assert_allclose(a[key], b[key], rtol=1e-12, atol=1e-9)
    assert np.abs(a["excitation"][:, 2]).min() > 1e4


def test_dry_bodies_are_absent_from_the_arrays(rm3):
    ref = model(rm3, "full")
    with_dry = HydroModel(parse_scene(scene_text("full", dry_between=True, dry_first=True)),
                          {"float": rm3, "spar": rm3})
    info = with_dry.setup_info()
    assert info.bodies == ("float", "spar")
    assert info.active.shape == (2, 6) and info.added_mass_inf.shape == (12, 12)
    np.testing.assert_array_equal(info.added_mass_inf, ref.setup_info().added_mass_inf)
    np.testing.assert_array_equal(info.hydrostatic_stiffness, ref.setup_info().hydrostatic_stiffness)
    assert info.net_buoyancy == pytest.approx([0.0, 0.0], abs=1e-6 * 9.81 * 886687)  # m = rho V
    pos, v = info.equilibrium_position + 0.05, np.ones((2, 6))
    out, out_ref = with_dry.step(0.0, pos, v), ref.step(0.0, pos, v)
    for key in ("excitation", "radiation", "hydrostatic"):
        assert out[key].shape == (2, 6)
        np.testing.assert_array_equal(out[key], out_ref[key])
    with pytest.raises(ModelError, match=r"\(2, 6\)"):
        with_dry.step(DT, np.zeros((4, 6)), np.zeros((4, 6)))


def test_error_keys_use_scene_indices_with_dry_bodies(rm3):
    text = scene_text(dry_first=True, spar_keys={"hdb_body": "plate"})
    with pytest.raises(ModelError) as err:
        HydroModel(parse_scene(text), {"float": rm3, "spar": rm3})
    assert err.value.key == "bodies[2].hdb_body"


def test_scene_without_wet_bodies_is_refused(rm3):
    text = scene_text(bodies=[dry("a"), dry("b")])
    with pytest.raises(ModelError) as err:
        HydroModel(parse_scene(text), {})
    assert err.value.key == "bodies" and "without a server" in str(err.value)


def test_rm3_over_the_wire_with_a_dry_body(server, rm3):
    """The real server: a dry body needs no HDB, arrays are (N_wet, 6), forces equal the model's."""
    text = scene_text("full", dry_between=True)
    local = model(rm3, "full")
    with ServerConnection(server, timeout=REPLY_S) as conn:
        setup = conn.hello(text, {"rm3.1": rm3})
        assert setup.bodies == ("float", "spar") and setup.coupled_blocks == 2
        np.testing.assert_array_equal(setup.added_mass_inf, local.setup_info().added_mass_inf)
        rng = np.random.default_rng(3)
        pos = local.setup_info().equilibrium_position
        for k in range(5):
            x, v = pos + 0.1 * rng.standard_normal((2, 6)), rng.standard_normal((2, 6))
            reply = conn.step(k, k * DT, x, v)
            expect = local.step(k * DT, x, v)
            for key in ("excitation", "radiation", "hydrostatic"):
                np.testing.assert_allclose(reply[key], expect[key], rtol=1e-12, atol=1e-9)
        with pytest.raises(RemoteError) as err:
            conn.step(5, 5 * DT, np.zeros((3, 6)), np.zeros((3, 6)))
        assert err.value.code == 5 and err.value.field == "position"
        conn.bye()
    dry_only = scene_text(bodies=[dry("a")])
    with ServerConnection(server, timeout=REPLY_S) as conn:
        with pytest.raises(RemoteError) as err:
            conn.hello(dry_only, {})
        assert err.value.code == 8 and err.value.field == "scene.bodies"
