"""A directional sea from gauge records (server/sea/gauges.py, ``[waves] type = "gauges"``) against a
known multi-direction sea written here: records synthesized at the gauges, the reconstructed sea's
elevation at points that are no gauge and its excitation force against the known sea's; one gauge
at the origin with one direction against the record itself; bad input names its key and file."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import brentq

from analytic_hdb import make_body_hdb
from conftest import body, scene_toml

from hydrolink.clients.scene_inputs import load_gauge_files
from hydrolink.protocol.scene import SceneError, parse_scene
from hydrolink.server.errors import ModelError
from hydrolink.server.model import HydroModel
from hydrolink.server.sea.probes import WaveProbes

OMEGA = np.linspace(0.05, 4.0, 300)
DEPTH, G = 30.0, 9.81
DT, N, T0 = 0.5, 1024, 100.0            # the records: 512 s from t = 100 s, Fourier step 0.01227 rad/s
GAUGES = [(0.0, 0.0), (15.0, 0.0), (2.0, 14.0), (-13.0, 5.0), (-4.0, -14.0)]
DIRECTIONS = [-40.0, 15.0, 70.0]        # on the HDB's 5-degree headings: no heading interpolation


def x_true(w, beta):
    """The analytic HDB's X(w, beta) (tests/analytic_hdb.py's default), (..., 6)."""
    base = np.array([1e4, 1e4, 3e5, 2e5, 2e5, 1e4])
    rot = np.stack([np.cos(beta), np.sin(beta), np.ones_like(beta), np.sin(beta), np.cos(beta), 0.5 * np.sin(2 * beta)], -1)
    return base * rot * (np.exp(-0.3 * w ** 2) * np.exp(1j * (0.4 + 0.8 * w)))[..., None]


def wave_number(w, g=G, h=DEPTH):
    return brentq(lambda k: g * k * np.tanh(k * h) - w ** 2, 1e-9, 10 * w ** 2 / g + 10)


def known_sea(band=(0.5, 2.0), directions=DIRECTIONS, seed=4):
    """Components (w, beta, a, phase) at the records' Fourier frequencies in ``band``, every one in
    each direction, a JONSWAP-like shape (Tp 8 s) and per-direction weights: eta(x, t_file) =
    sum a cos(k (x cos beta + y sin beta) - w t_file + phase)."""
    rng = np.random.default_rng(seed)
    w = 2 * np.pi * np.arange(N // 2) / (N * DT)
    w = w[(w >= band[0]) & (w <= band[1])]
    shape = w ** -5 * np.exp(-1.25 * (2 * np.pi / 8.0 / w) ** 4)
    weight = np.array([0.5, 0.3, 0.2])[:len(directions)]
    a = np.sqrt(np.outer(weight, shape / shape.max())) * 0.4 * rng.uniform(0.5, 1.0, (len(directions), w.size))
    return (np.tile(w, len(directions)), np.repeat(np.deg2rad(directions), w.size), a.reshape(-1),
            rng.uniform(0, 2 * np.pi, a.size))


def elevation(sea, points, t_file):
    """The known sea's eta at ``points`` (P, 2) and file times (T,): (P, T)."""
    w, beta, a, ph = sea
    k = np.array([wave_number(x) for x in w])
    kx = np.asarray(points, float) @ np.array([k * np.cos(beta), k * np.sin(beta)])          # (P, C)
    return np.einsum("c,ptc->pt", a, np.cos(kx[:, None, :] - np.outer(t_file, w)[None] + ph))


def write_records(folder, sea, gauges=GAUGES, n=N, dt=DT, t0=T0):
    times = t0 + dt * np.arange(n)
    eta = elevation(sea, gauges, times)
    names = []
    for i, e in enumerate(eta):
        names.append(f"gauge{i}.csv")
        np.savetxt(folder / names[-1], np.column_stack([times, e]), delimiter=",", header="time,eta", fmt="%.17g")
    return names


def gauge_scene(folder, names, gauges=GAUGES, duration=100.0, current=None, dt=0.1, **keys):
    waves = dict(type="gauges", directions=keys.pop("directions", DIRECTIONS),
                 omega_range=keys.pop("omega_range", [0.5, 2.0]),
                 gauges=[dict(x=x, y=y, file=f) for (x, y), f in zip(gauges, names)], **keys)
    text = scene_toml(dt=dt, duration=duration, water={"density": 1000.0, "depth": DEPTH, "gravity": G}, waves=waves,
                      current=current,
                      bodies=[body("float", hdb="h", mass=3.0e5, center_of_mass=[0, 0, 0], inertia=[1e6] * 3)])
    (folder / "scene.toml").write_text(text)
    return folder / "scene.toml"


def gauge_model(path) -> HydroModel:
    scene = parse_scene(path.read_text(), path, have_hdbs=["h"])
    scene = scene.with_gauges(load_gauge_files(scene, path))
    ds = make_body_hdb(omega=OMEGA, directions=np.deg2rad(np.arange(-180.0, 180.0, 5.0)), depth=DEPTH)
    return HydroModel(scene, {"float": ds})


def test_three_directions_from_five_gauges_give_the_known_sea(tmp_path):
    """369 components (123 frequencies x 3 directions) recorded at 5 gauges (30 m across, depth
    30 m), run from file time 150 s. The known sea lies on the fit's bins (the records' Fourier
    frequencies, the scene's directions), so the fit is exact up to round-off amplified by at most
    the condition number (<= 100, checked by the fit): elevation at two points that are no gauge,
    at three times, within 1e-9 of the sea's RMS. The excitation force: the HDB's X interpolated
    linearly on its 0.0132 rad/s grid against the analytic X (relative error ~ dw^2 |X''| / 8 / |X|
    ~ 2e-5; measured 1.9e-5): within 1e-4 of each DOF's largest force."""
    sea = known_sea()
    path = gauge_scene(tmp_path, write_records(tmp_path, sea), start=150.0)
    m = gauge_model(path)
    assert m.waves.size == sea[0].size and np.all(m.waves.omega >= 0.5) and m.waves.energy_outside < 1e-20
    assert m.waves.fit_residual < 1e-20 and not [x for x in m.warnings if x.startswith("waves.directions")]
    points = np.array([[7.0, -11.0], [-25.0, 30.0]])
    probes = WaveProbes(m.waves, points, np.zeros(0), G, DEPTH)
    rms = np.sqrt(0.5 * np.sum(sea[2] ** 2))
    times = np.array([0.0, 13.3, 77.7])
    want = elevation(sea, points, 150.0 + times)
    for i, t in enumerate(times):
        np.testing.assert_allclose(probes(t)[:, 0], want[:, i], rtol=0, atol=1e-9 * rms)
    omega, f, _ = m.excitation_phasors()
    w, beta, a, ph = sea
    ref = x_true(w, beta) * (a * np.exp(1j * (ph - w * 150.0)))[:, None]
    t = np.linspace(0.0, 100.0, 201)
    got = np.real(np.exp(-1j * np.outer(t, omega)) @ f)
    expected = np.real(np.exp(-1j * np.outer(t, w)) @ ref)
    scale = np.abs(expected).max(axis=0)
    np.testing.assert_array_less(np.abs(got - expected).max(axis=0), 1e-4 * scale)


def test_one_gauge_at_the_origin_replays_its_record(tmp_path):
    """One gauge at the origin, one direction (today's single series): the fit is the record's
    Fourier series, so the model's elevation at the origin is the record at every sample of the run
    (the band holds all its frequencies but the mean and Nyquist, which the known sea lacks), to
    round-off, 1e-10 of its RMS."""
    sea = known_sea(band=(0.1, 3.0), directions=[25.0])
    names = write_records(tmp_path, sea, gauges=[(0.0, 0.0)])
    path = gauge_scene(tmp_path, names, gauges=[(0.0, 0.0)], directions=[25.0], duration=60.0, omega_range=[0.05, 3.5])
    m = gauge_model(path)
    assert np.all(m.waves.heading_of() == np.deg2rad(25.0))
    record = np.loadtxt(tmp_path / names[0], delimiter=",")
    omega, _, c = m.excitation_phasors()
    got = np.real(np.exp(-1j * np.outer(record[:121, 0] - T0, omega)) @ c)
    np.testing.assert_allclose(got, record[:121, 1], rtol=0, atol=1e-10 * np.sqrt(np.mean(record[:, 1] ** 2)))
    x0 = m.setup_info().equilibrium_position
    assert m.step(0.0, x0, np.zeros_like(x0))["wave_elevation"] == pytest.approx(record[0, 1], abs=1e-10)


def test_bad_gauge_input_names_the_key_and_file(tmp_path):
    sea = known_sea()
    names = write_records(tmp_path, sea)
    # directions the array cannot resolve: more than gauges, and a 1 m array at these wavelengths
    with pytest.raises(ModelError, match=r"waves\.directions: 3 directions from 2 gauges"):
        gauge_model(gauge_scene(tmp_path, names[:2], gauges=GAUGES[:2]))
    small = [(x / 15, y / 15) for x, y in GAUGES]
    with pytest.raises(ModelError, match=r"waves\.directions: the gauges cannot tell .*narrow waves\.omega_range"):
        gauge_model(gauge_scene(tmp_path, write_records(tmp_path, sea, gauges=small), gauges=small))
    # coinciding gauges, a direction twice
    with pytest.raises(SceneError, match=r"gauges\[2\]: .*within 1 mm of gauges\[0\]"):
        gauge_model(gauge_scene(tmp_path, names, gauges=[GAUGES[0], GAUGES[1], GAUGES[0], *GAUGES[3:]]))
    with pytest.raises(SceneError, match=r"directions\[1\]: 320 deg is directions\[0\] again"):
        gauge_model(gauge_scene(tmp_path, names, directions=[-40.0, 320.0]))
    # records of different lengths, time steps, start times
    np.savetxt(tmp_path / "short.csv", np.loadtxt(tmp_path / names[1], delimiter=",")[:-8], delimiter=",")
    with pytest.raises(SceneError, match=r"waves\.gauges\[1\]\.file: short\.csv: 1016 samples where gauge0\.csv"):
        gauge_model(gauge_scene(tmp_path, [names[0], "short.csv", *names[2:]]))
    write_records(tmp_path, sea, gauges=GAUGES[2:3], dt=0.25)
    (tmp_path / "gauge0.csv").rename(tmp_path / "fine.csv")
    write_records(tmp_path, sea)
    with pytest.raises(SceneError, match=r"waves\.gauges\[2\]\.file: fine\.csv: sampled every 0\.25 s"):
        gauge_model(gauge_scene(tmp_path, [*names[:2], "fine.csv", *names[3:]]))
    write_records(tmp_path, sea, gauges=GAUGES[3:4], t0=101.0)
    (tmp_path / "gauge0.csv").rename(tmp_path / "late.csv")
    write_records(tmp_path, sea)
    with pytest.raises(SceneError, match=r"waves\.gauges\[3\]\.file: late\.csv: starts at 101"):
        gauge_model(gauge_scene(tmp_path, [*names[:3], "late.csv", names[4]]))
    # a current's Doppler shift (the records are at the encounter frequencies already)
    with pytest.raises(ModelError, match=r"current\.doppler: not with a sea from gauges"):
        gauge_model(gauge_scene(tmp_path, names, current={"speed": 1.0, "direction": 0.0, "doppler": True}))
    # a run past the records' end, a missing file
    with pytest.raises(SceneError, match=r"simulation\.duration: .*repeats past the records' end"):
        gauge_model(gauge_scene(tmp_path, names, duration=600.0))
    with pytest.raises(SceneError, match=r"waves\.gauges\[4\]\.file.*not found"):
        gauge_model(gauge_scene(tmp_path, [*names[:4], "none.csv"]))
    # a model whose scene lacks the records (a server not sent them)
    with pytest.raises(ModelError, match=r"waves\.gauges\[0\]\.file: the record of 'gauge0\.csv' did not reach"):
        HydroModel(parse_scene((tmp_path / "scene.toml").read_text()), {"float": make_body_hdb(omega=OMEGA)})


def test_records_through_a_server(tmp_path):
    """The client sends the records in hello.gauges (SPEC §5.1): the server's sea is the in-process
    model's (same components); without them, or with one record cut short, it refuses naming the
    gauge's scene key."""
    from hydrolink.clients.lockstep.connection import RemoteError, ServerConnection
    from hydrolink.server.service.force_server import ForceServer
    path = gauge_scene(tmp_path, write_records(tmp_path, known_sea()))
    scene = parse_scene(path.read_text(), path, have_hdbs=["h"])
    records = load_gauge_files(scene, path)
    hdb = make_body_hdb(omega=OMEGA, directions=np.deg2rad(np.arange(-180.0, 180.0, 5.0)), depth=DEPTH)
    with ServerConnection(ForceServer(None)) as conn:
        assert conn.hello(path.read_text(), {"h": hdb}, gauges=records).wave_components == gauge_model(path).waves.size
    short = dict(records, **{"waves.gauges[1].file": tuple(x[:-8] for x in records["waves.gauges[1].file"])})
    for sent, why in ((None, "was not given"), (short, "1016 samples")):
        with ServerConnection(ForceServer(None)) as conn, pytest.raises(RemoteError) as err:
            conn.hello(path.read_text(), {"h": hdb}, gauges=sent)
        assert err.value.field.endswith(f"waves.gauges[{0 if sent is None else 1}].file") and why in str(err.value)


def test_one_gauge_by_convolution_is_the_elevation_series(tmp_path):
    """One gauge at the origin, one direction, ``excitation = "convolution"``, against today's
    ``type = "elevation"`` of the same file (dt the records' step, start 20 s in): the convolution
    of the gauge sea reads the elevation its Fourier series gives at the step grid, which is the
    record to round-off (previous test), so the excitation of every step agrees to 1e-9 of its
    largest value (not bit for bit: the series is summed, not read)."""
    sea = known_sea(band=(0.1, 3.0), directions=[25.0])
    names = write_records(tmp_path, sea, gauges=[(0.0, 0.0)])
    keys = dict(start=T0 + 20.0, excitation="convolution", excitation_irf_duration=20.0)
    gauges = gauge_model(gauge_scene(tmp_path, names, gauges=[(0.0, 0.0)], directions=[25.0], duration=60.0, dt=DT,
                                     omega_range=[0.05, 3.5], **keys))
    text = scene_toml(dt=DT, duration=60.0, water={"density": 1000.0, "depth": DEPTH, "gravity": G},
                      waves=dict(type="elevation", file=names[0], direction=25.0, **keys),
                      bodies=[body("float", hdb="h", mass=3.0e5, center_of_mass=[0, 0, 0], inertia=[1e6] * 3)])
    record = np.loadtxt(tmp_path / names[0], delimiter=",")
    ds = make_body_hdb(omega=OMEGA, directions=np.deg2rad(np.arange(-180.0, 180.0, 5.0)), depth=DEPTH)
    series = HydroModel(parse_scene(text), {"float": ds}, (record[:, 0], record[:, 1]))
    x0 = series.setup_info().equilibrium_position
    got, want = [], []
    for k in range(120):
        got.append(gauges.step(k * DT, x0, np.zeros_like(x0))["excitation"])
        want.append(series.step(k * DT, x0, np.zeros_like(x0))["excitation"])
    got, want = np.array(got), np.array(want)
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-9 * np.abs(want).max())


def test_a_pitch_roll_buoy_gives_three_directions(tmp_path):
    """A directional record at one point: elevation and the surface slopes d eta/dx, d eta/dy of a
    pitch-roll buoy 10 m off the origin (the slopes synthesized here as sum -a k (cos, sin) beta
    sin(...)). Three directions from it at every frequency (its rows do not depend on k): the known
    sea's elevation at two other points within 1e-9 of the RMS (exact fit, round-off times cond);
    the same quantity twice at one point is refused naming the gauge."""
    sea = known_sea()
    w, beta, a, ph = sea
    k = np.array([wave_number(x) for x in w])
    times = T0 + DT * np.arange(N)
    phase = k * (10.0 * np.cos(beta) - 3.0 * np.sin(beta)) - np.outer(times, w) + ph
    names = write_records(tmp_path, sea, gauges=[(10.0, -3.0)])
    for name, direction in (("sx.csv", np.cos(beta)), ("sy.csv", np.sin(beta))):
        np.savetxt(tmp_path / name, np.column_stack([times, -np.sin(phase) @ (a * k * direction)]), delimiter=",")
    buoy = [dict(x=10.0, y=-3.0, file=f, quantity=q) for f, q in zip((names[0], "sx.csv", "sy.csv"),
                                                                      ("elevation", "slope-x", "slope-y"))]
    waves = dict(type="gauges", directions=DIRECTIONS, omega_range=[0.5, 2.0], start=150.0, gauges=buoy)
    text = scene_toml(dt=0.1, duration=100.0, water={"density": 1000.0, "depth": DEPTH, "gravity": G}, waves=waves,
                      bodies=[body("float", hdb="h", mass=3.0e5, center_of_mass=[0, 0, 0], inertia=[1e6] * 3)])
    path = tmp_path / "scene.toml"
    path.write_text(text)
    m = gauge_model(path)
    points = np.array([[0.0, 0.0], [-25.0, 30.0]])
    probes = WaveProbes(m.waves, points, np.zeros(0), G, DEPTH)
    want = elevation(sea, points, 150.0 + np.array([0.0, 41.3]))
    rms = np.sqrt(0.5 * np.sum(a ** 2))
    for i, t in enumerate((0.0, 41.3)):
        np.testing.assert_allclose(probes(t)[:, 0], want[:, i], rtol=0, atol=1e-9 * rms)
    path.write_text(text.replace('"slope-y"', '"slope-x"'))
    with pytest.raises(SceneError, match=r"gauges\[2\]: .*within 1 mm of gauges\[1\] and recording the same slope-x"):
        gauge_model(path)


def test_directions_left_out_are_reported(tmp_path):
    """The known sea fitted with two of its three directions (70 deg, a fifth of its variance, left
    out): the records are not explained — residual above the 5 % warning level and below the left-out
    share (part of those waves projects on the two bins, most where the array barely tells
    directions apart) — and the setup warns naming waves.directions."""
    path = gauge_scene(tmp_path, write_records(tmp_path, known_sea()), directions=[-40.0, 15.0])
    m = gauge_model(path)
    w, _, a, _ = known_sea()
    left_out = np.sum(a[2 * a.size // 3:] ** 2) / np.sum(a ** 2)
    assert 0.05 < m.waves.fit_residual < left_out, (m.waves.fit_residual, left_out)
    warned = [x for x in m.warnings if x.startswith("waves.directions")]
    assert len(warned) == 1 and f"{100 * m.waves.fit_residual:.2g} %" in warned[0]
