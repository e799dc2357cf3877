"""A WAMIT run read from its ``.out`` report alone (server/hdb/wamit/out_tables.py) against the same
run read from its numeric files (.1, .3, .hst): RM3's run, which ships both. Each quantity agrees
within what the report prints: A, B and A_inf to its 7 significant digits, the hydrostatic
coefficients to its 5, the excitation's modulus to 7 digits and its phase to the whole degree."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from hydrolink.protocol.hdb.layout import HDBError
from hydrolink.server.hdb.io import file_set, load_hdb

RM3 = Path(__file__).resolve().parents[1] / "examples" / "data" / "rm3_wamit"
RHO = 1025.0


@pytest.fixture(scope="module")
def both(tmp_path_factory):
    alone = tmp_path_factory.mktemp("report") / "rm3.out"
    alone.symlink_to(RM3 / "rm3.out")
    return load_hdb(RM3 / "rm3.1", rho=RHO), load_hdb(alone, rho=RHO), alone


def test_report_alone_equals_numeric_files(both):
    files, report, _ = both
    assert report.attrs["source"].endswith("rm3.out")
    np.testing.assert_array_equal(report.omega, files.omega)
    for name in ("added_mass", "radiation_damping", "added_mass_inf"):
        np.testing.assert_allclose(report[name], files[name], rtol=1e-6, atol=0.0, err_msg=name)
    g = files.attrs["g"]
    # 5 significant digits (285.52, 7347.0), and 0.0000 printed for (4,6) and (5,6): 5e-5 nondimensional
    np.testing.assert_allclose(report.hydrostatic_stiffness, files.hydrostatic_stiffness, rtol=5e-5,
                               atol=RHO * g * 5e-5)
    x, y = files.excitation_force.values, report.excitation_force.values
    chord = 2.0 * math.sin(math.radians(0.25))   # |e^(i a) - 1| for half a degree
    assert np.all(np.abs(y - x) <= np.abs(x) * (chord + 1e-6) + 1e-12)
    worst = np.max(np.abs(y - x) / np.abs(x))
    assert worst > 1e-3, "the report's whole-degree phases should show (else .3 was read)"
    for name in ("reference_point", "displaced_volume", "center_of_buoyancy"):
        np.testing.assert_allclose(report[name], files[name], err_msg=name)


def test_report_alone_is_a_file_set(both):
    _, _, alone = both
    files = file_set(alone, rho=RHO)
    assert [p.name for p in files.paths] == ["rm3.out"]


def test_report_without_radiation_tables_is_refused(tmp_path):
    head = (RM3 / "rm3.out").read_text().split("Output from  WAMIT")[0]
    (tmp_path / "cut.out").write_text(head)
    with pytest.raises(HDBError) as info:
        load_hdb(tmp_path / "cut.out")
    assert "cut.out" in str(info.value) and "ADDED-MASS" in str(info.value)
