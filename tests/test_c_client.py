"""The C multibody client (examples/clients/c/heave.c, written from protocol/SPEC.md with libzmq and
msgpack-c): the Task-10 sphere in heave against `hydrolink serve`, its HDB sent as the raw BEMIO
file by SHA-256. Its heave RAO equals the frequency-domain one of the same HDB, and the forces it
received equal, bit for bit, those a Python client gets for the same states."""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest
from conftest import EXIT_S
from conftest import (SPHERE_WATER, build_zmq_msgpack_program, regular_waves, scene_toml, serve_process,
                      sphere_body, write_scene)

from hydrolink.clients.lockstep.connection import ServerConnection
from hydrolink.server.hdb.io import load_hdb

SOURCE = Path(__file__).resolve().parents[1] / "examples" / "clients" / "c" / "heave.c"
DT, DURATION, FIT_FROM = 0.02, 80.0, 50.0


@pytest.fixture(scope="module")
def heave_exe(tmp_path_factory) -> Path:
    return build_zmq_msgpack_program(SOURCE, tmp_path_factory.mktemp("cclient") / "heave",
                                     "-O2", "-Wall", "-Wextra", "-Werror")


@pytest.fixture(scope="module")
def server(tmp_path_factory):
    with serve_process("--store", str(tmp_path_factory.mktemp("store"))) as address:
        yield address


def complex_amplitude(t: np.ndarray, y: np.ndarray, w: float) -> complex:
    """c with y = Re{c exp(-iwt)} + const, least squares."""
    basis = np.column_stack([np.cos(w * t), np.sin(w * t), np.ones_like(t)])
    coef = np.linalg.lstsq(basis, y, rcond=None)[0]
    return complex(coef[0], coef[1])


def test_c_client_heave_rao_and_forces(heave_exe, server, sphere_path, sphere, tmp_path):
    shutil.copy(sphere_path, tmp_path / "sphere.h5")
    mass = 1000.0 * float(sphere["displaced_volume"].values[0])     # floating freely: rho V
    omega = sphere["omega"].values
    for n, w in enumerate(omega[[15, 23, 35]]):                      # 0.8, 1.2, 1.8 rad/s (HDB frequencies)
        text = scene_toml(dt=DT, duration=DURATION, water=SPHERE_WATER,
                          waves=regular_waves(1.0, 2 * np.pi / w, ramp=10.0), hydro={"irf_duration": 15.0},
                          bodies=[sphere_body("sphere.h5", mass=mass, dofs=["heave"])])
        scene = write_scene(tmp_path, text, f"scene{n}.toml")
        csv = tmp_path / f"out{n}.csv"
        run = subprocess.run([str(heave_exe), server, str(scene), repr(mass), str(csv), "sphere.h5", "bemio",
                              str(tmp_path / "sphere.h5")], capture_output=True, text=True, timeout=EXIT_S)
        assert run.returncode == 0, run.stderr
        assert ("uploaded 1 HDB file(s)" in run.stderr) == (n == 0), run.stderr   # by hash after the first
        rows = np.loadtxt(csv, delimiter=",")
        assert rows.shape == (round(DURATION / DT) + 1, 28)
        t, eta, z = rows[:, 1], rows[:, 26], rows[:, 27]
        late = t >= FIT_FROM
        rao = complex_amplitude(t[late], z[late], w) / complex_amplitude(t[late], eta[late], w)
        k = int(np.flatnonzero(omega == w)[0])
        a, b = sphere["added_mass"].values[k, 2, 2], sphere["radiation_damping"].values[k, 2, 2]
        x = sphere["excitation_force"].values[k, 0, 2]
        c = sphere["hydrostatic_stiffness"].values[2, 2]
        ref = x / (c - w * w * (mass + a) - 1j * w * b)
        print(f"w = {w:.2f} rad/s: |RAO| C {abs(rao):.5f}, frequency domain {abs(ref):.5f} "
              f"({abs(rao) / abs(ref) - 1:+.2e}), phase {np.angle(rao / ref, deg=True):+.3f} deg")
        assert abs(abs(rao) / abs(ref) - 1) <= 0.005
        assert abs(np.angle(rao / ref, deg=True)) <= 0.5
    # the forces of the last run, for the same states, from the Python client with the HDB map
    with ServerConnection(server) as conn:
        conn.hello(text, {"sphere.h5": load_hdb(tmp_path / "sphere.h5")})
        for seq, row in enumerate(rows):
            r = conn.step(seq, row[1], row[2:8].reshape(1, 6), row[8:14].reshape(1, 6))
            assert np.array_equal(r["excitation"][0], row[14:20]), seq
            assert np.array_equal(r["radiation"][0], row[20:26]), seq
