"""Per-case summaries (clients/studies/sweep_case_file.py): a results file written row by row as the clients
write it, summarised over a window, against the same numbers computed from the arrays in the test."""

from __future__ import annotations

import numpy as np
import pytest


def test_summary_of_a_results_file(tmp_path):
    """A results file written row by row (ResultWriter, as the clients write them) with PTOs, joints
    and moorings: the summary's means, standard deviations and maxima over the window against the
    same numbers from the arrays."""
    from hydrolink.clients.lockstep.results import ResultWriter
    from hydrolink.clients.studies.sweep_case_file import summarise
    rng = np.random.default_rng(5)
    n, dt = 400, 0.1
    t = np.arange(n) * dt
    eq = np.array([[0, 0, -1.0, 0, 0, 0], [1.0, 0, -5.0, 0, 0, 0]])
    pos = eq[None] + rng.normal(size=(n, 2, 6))
    pto_f, pto_v = rng.normal(size=(n, 2)), rng.normal(size=(n, 2))
    joint = rng.normal(size=(n, 1, 6))
    moor = rng.normal(size=(n, 3, 6))
    path = tmp_path / "case.nc"
    with ResultWriter(path, scene_text="", bodies=["a", "b"], equilibrium_position=eq, dt=dt) as w:
        w.add_variable("joint_force", ("joint", "joint_component"),
                       {"joint": ["hinge"], "joint_component": ["fx", "fy", "fz", "mx", "my", "mz"]})
        w.add_variable("pto_force", ("pto",), {"pto": ["p1", "p2"]})
        w.add_variable("pto_velocity", ("pto",))
        w.add_variable("pto_power", ("pto",))
        w.add_variable("total_pto_power", ())
        w.add_variable("mooring_force", ("mooring", "mooring_component"),
                       {"mooring": ["m1", "m2", "m3"], "mooring_component": ["fx", "fy", "fz", "mx", "my", "mz"]})
        z = np.zeros((2, 6))
        for i in range(n):
            w.stage_extra({"joint_force": joint[i], "pto_force": pto_f[i], "pto_velocity": pto_v[i],
                           "pto_power": pto_f[i] * pto_v[i], "total_pto_power": (pto_f[i] * pto_v[i]).sum(),
                           "mooring_force": moor[i]})
            w.append(t[i], pos[i], z, z, z, z, 0.0)
        w.finish("complete")
    s = summarise(path, (10.0, 35.0), steady=False)
    sel = (t > 10.0) & (t <= 35.0)
    p = pto_f * pto_v
    assert s.mean_total_pto_power == pytest.approx(p[sel].sum(axis=1).mean(), rel=1e-12)
    assert s.mean_pto_power == pytest.approx({"p1": p[sel, 0].mean(), "p2": p[sel, 1].mean()}, rel=1e-12)
    assert s.max_pto_force == pytest.approx({"p1": np.abs(pto_f[sel, 0]).max(), "p2": np.abs(pto_f[sel, 1]).max()})
    assert s.bodies == ["a", "b"]
    np.testing.assert_allclose(s.motion_std, (pos - eq)[sel].std(axis=0), rtol=1e-12)
    np.testing.assert_allclose(s.motion_max, np.abs(pos - eq)[sel].max(axis=0), rtol=1e-12)
    assert s.joint_force[0] == ["hinge"] and s.mooring_force[0] == ["m1", "m2", "m3"]
    np.testing.assert_allclose(s.joint_force[2], np.abs(joint[sel]).max(axis=0))
    np.testing.assert_allclose(s.mooring_force[2], np.abs(moor[sel]).max(axis=0))
