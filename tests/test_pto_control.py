"""clients/exudyn/pto_control.py: controller decisions applied to a real Exudyn PTO (SPEC §5.7).

A dry surge body held by a linear PTO spring to ground and pushed by a constant load P (a linear
mooring's pretension); its static surge is the closed form of whatever is in force: x = (P - F) / k
under an added tension F, P / k' under an impedance command, P / k again after a passive fallback.
The measurements, the results variables and the run summary report the same.
"""

from __future__ import annotations

import json

import exudyn as exu
import numpy as np
import pytest
import xarray as xr

from conftest import body, linear_pto, scene_toml
from hydrolink.clients.exudyn.mechanism import build_mechanism
from hydrolink.clients.exudyn.moorings import build_moorings
from hydrolink.clients.exudyn.pto_control import PTOControl
from hydrolink.clients.exudyn.ptos import build_ptos
from hydrolink.clients.lockstep.results import ResultWriter
from hydrolink.protocol.scene import parse_scene

M, K, C, P, RHO = 50.0, 2.0e3, 30.0, 400.0, 1025.0
DT = 0.01


def build(tmp_path, modal_ptos: int = 0, **controller) -> tuple:
    """(control, mbs, ptos, node, writer, system container) for the body and one controller "ctl"
    driving "pto" (the container keeps the Exudyn system alive); ``modal_ptos``: that many PTOs on
    generalized modes after "pto" in the results' dim ``pto``, declared first as the client does."""
    scene = parse_scene(scene_toml(
        dt=DT, duration=1.0,
        bodies=[body("b", mass=M, center_of_mass=[0, 0, 0], inertia=[1, 1, 1], dofs=["surge"],
                     buoyancy_volume=M / RHO)],
        ptos=[linear_pto("pto", "b", [0, 0, 0], "ground", [-5, 0, 0], stiffness=K, damping=C)],
        moorings=[{"type": "linear", "body": "b", "point": [0, 0, 0], "pretension": [P, 0, 0, 0, 0, 0]}],
        controllers=[{"name": "ctl", "ptos": ["pto"], **controller}]))
    sc = exu.SystemContainer()
    mbs = sc.AddSystem()
    mech = build_mechanism(mbs, scene, {})
    ptos = build_ptos(mbs, scene.ptos, mech.handles)
    build_moorings(mbs, scene.moorings, mech.handles, scene.water)
    mbs.Assemble()
    writer = ResultWriter(tmp_path / "run.nc", scene=scene, bodies=["b"], dt=DT)
    if modal_ptos:
        writer.add_variable("pto_force", ("pto",), {"pto": ["pto"] + [f"b.mode{k + 1}" for k in range(modal_ptos)]})
    return (PTOControl(scene, ptos, mbs, writer, modal_ptos=modal_ptos), mbs, ptos, mech.handles["b"].node, writer,
            sc)


def static_surge(mbs, node) -> float:
    """The body's surge at static equilibrium under what is in force now."""
    ss = exu.SimulationSettings()
    ss.solution.file.write = False
    ss.staticSolver.verboseMode = 0
    mbs.SolveStatic(ss)
    return float(mbs.GetNodeOutput(node, exu.OutputVariableType.Coordinates)[0])


def ok(commands: dict, latency: float = 0.02) -> dict:
    return {"ctl": {"status": "ok", "commands": commands, "latency": latency}}


def test_force_command_adds_tension_and_is_measured(tmp_path):
    control, mbs, ptos, node, writer, _ = build(tmp_path)
    assert static_surge(mbs, node) == pytest.approx(P / K, rel=1e-8)            # scene PTO in force
    f = 150.0
    control.apply(ok({"pto": {"force": f}}))
    x = static_surge(mbs, node)
    assert x == pytest.approx((P - f) / K, rel=1e-8)
    m = control.measurements(3, np.zeros((1, 6)), np.zeros((1, 6)), ptos.sample(mbs))
    assert m["step"] == 3
    assert m["pto_displacement"][0] == pytest.approx(x, rel=1e-9)                # extension = surge here
    assert m["pto_force"][0] == pytest.approx(K * x + f, rel=1e-9)               # tension = the load P
    assert m["pto_force"][0] == pytest.approx(P, rel=1e-8)
    assert (control.force[0], control.damping[0], control.stiffness[0]) == (f, C, K)
    assert (control.status[0], control.latency[0]) == (0, 0.02)
    writer.close()


def test_impedance_command_and_passive_fallback(tmp_path):
    control, mbs, ptos, node, writer, _ = build(tmp_path, command="impedance", fallback="passive",
                                                fallback_damping=5.0)
    control.apply(ok({"pto": {"stiffness": 4 * K}}))                              # damping omitted: kept
    assert static_surge(mbs, node) == pytest.approx(P / (4 * K), rel=1e-8)
    assert (control.force[0], control.damping[0], control.stiffness[0]) == (0.0, C, 4 * K)
    control.apply({"ctl": {"status": "timeout"}})                                 # passive: scene stiffness
    assert static_surge(mbs, node) == pytest.approx(P / K, rel=1e-8)
    assert (control.force[0], control.damping[0], control.stiffness[0]) == (0.0, 5.0, K)
    assert control.status[0] == 1 and np.isnan(control.latency[0]) and control.fallbacks[0] == 1
    control.apply(None)                                                           # no decision due
    assert np.isnan(control.status[0])
    writer.close()


def test_hold_fallback_keeps_the_last_command_and_results_record_it(tmp_path):
    control, mbs, ptos, node, writer, _ = build(tmp_path)
    eq = np.zeros((1, 6))
    rows = [ok({"pto": {"force": 100.0}}, 0.01), {"ctl": {"status": "absent"}}, ok({"pto": {"force": -50.0}}, 0.03),
            {"ctl": {"status": "invalid"}}]
    expected_x = [(P - 100.0) / K, (P - 100.0) / K, (P + 50.0) / K, (P + 50.0) / K]
    for k, (decision, x) in enumerate(zip(rows, expected_x)):
        control.apply(decision)
        assert static_surge(mbs, node) == pytest.approx(x, rel=1e-8)
        control.stage()
        writer.append(k * DT, eq, eq, eq, eq, eq, 0.0)
    summary = control.finish()
    writer.finish("complete")
    writer.close()
    assert summary["ctl"] == {"ok": 2, "timeout": 0, "absent": 1, "invalid": 1,
                              "mean_latency_s": pytest.approx(0.02), "max_latency_s": 0.03}
    ds = xr.load_dataset(tmp_path / "run.nc")
    np.testing.assert_array_equal(ds["pto_command_force"].values[:, 0], [100.0, 100.0, -50.0, -50.0])
    np.testing.assert_array_equal(ds["controller_status"].values[:, 0], [0, 2, 0, 3])
    np.testing.assert_array_equal(ds["controller_fallbacks"].values[:, 0], [0, 1, 1, 2])
    assert json.loads(ds.attrs["controller_events"])["ctl"]["absent"] == 1


def test_ptos_on_modes_after_the_scene_s_are_left_uncommanded(tmp_path):
    """A PTO on a generalized mode comes after the scene's PTOs in the results' dim ``pto``: the
    controlled PTO's command is recorded in its own column, the mode's PTO's is NaN (no control)."""
    control, mbs, ptos, node, writer, _ = build(tmp_path, modal_ptos=1)
    eq = np.zeros((1, 6))
    control.apply(ok({"pto": {"force": 100.0}}))
    assert static_surge(mbs, node) == pytest.approx((P - 100.0) / K, rel=1e-8)
    control.stage()
    writer.append(0.0, eq, eq, eq, eq, eq, 0.0)
    control.finish()
    writer.finish("complete")
    writer.close()
    ds = xr.load_dataset(tmp_path / "run.nc")
    assert list(ds["pto"].values) == ["pto", "b.mode1"]
    assert ds["pto_command_force"].values[0, 0] == 100.0 and np.isnan(ds["pto_command_force"].values[0, 1])
