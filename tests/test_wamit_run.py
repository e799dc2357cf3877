"""server/hdb/wamit/run.py: a WAMIT run's number of bodies is what its files (or the scene) say,
never the .1's mode count divided by 6 — a run with generalized modes (NEWMDS) reads them as the
body's modes beyond its six, never as extra rigid bodies (issue 38: a barge of 6 rigid + 4
flexible modes was read as two bodies, modes 7-10 as the second body's surge..roll).

The data are written here by hand: one body ("barge"), 2 periods, modes 1-10 with known values
(Abar_ii = i, Bbar_ii = 0.1 i, Cbar_ii = 10 i, excitation 1 + 0.5 i per mode), and the same run
with its six rigid modes only, which reads with those values in SI."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from hydrolink.protocol.hdb.layout import HDBError, hdb_warnings
from hydrolink.server.hdb.io import load_hdb

RHO, PERIODS = 1000.0, (5.0, 10.0)
FACTS = {"vcg": [0.0]}     # what no file of this set states (no .frc)


def write_run(folder: Path, modes: int, *, cfg: str = "IPEROUT=1\nGRAV=9.80665\nULEN=1.0\n",
              pot: bool = True) -> Path:
    """barge.1/.3/.hst (modes 1..``modes``), .cfg, and a .pot listing one body."""
    rows1 = [f"{p} {i} {i} {float(i):.6e} {0.1 * i:.6e}" for p in PERIODS for i in range(1, modes + 1)]
    (folder / "barge.1").write_text("\n".join(rows1) + "\n")
    rows3 = [f"{p} 0.0 {i} 1.118034 26.565051 1.0 0.5" for p in PERIODS for i in range(1, modes + 1)]
    (folder / "barge.3").write_text("\n".join(rows3) + "\n")
    (folder / "barge.hst").write_text("\n".join(f"{i} {i} {10.0 * i:.6e}" for i in range(1, modes + 1)) + "\n")
    (folder / "barge.cfg").write_text(cfg)
    if pot:
        (folder / "barge.pot").write_text("barge.pot\n-1.\t HBOT\n1 1\t IRAD, IDIFF\n2\t NPER\n5.0 10.0\n1\t NBETA\n"
                                          "0.0\n1\t NBODY\nbarge.gdf\n0.0 0.0 0.0 0.0\t XBODY\n1 1 1 1 1 1\n")
    return folder / "barge.1"


def test_rigid_modes_read_with_their_known_values(tmp_path):
    ds = load_hdb(write_run(tmp_path, 6), rho=RHO, wamit=FACTS)
    assert [str(b) for b in ds["body"].values] == ["barge"]
    k = int(np.argmin(np.abs(ds["omega"].values - 2 * np.pi / 10.0)))
    assert ds["added_mass"].values[k, 2, 2] == pytest.approx(RHO * 3.0, rel=1e-6)                  # rho Abar
    assert ds["radiation_damping"].values[k, 2, 2] == pytest.approx(RHO * 2 * np.pi / 10.0 * 0.3, rel=1e-6)
    assert ds["hydrostatic_stiffness"].values[2, 2] == pytest.approx(RHO * 9.80665 * 30.0, rel=1e-6)
    assert ds["excitation_force"].values[k, 0, 2] == pytest.approx(RHO * 9.80665 * (1.0 - 0.5j), rel=1e-6)


@pytest.mark.parametrize("newmds", ["NEWMDS=4", "NEWMDS(1)=4"])
def test_newmds_modes_read_as_the_body_s_generalized_modes_with_their_known_values(tmp_path, newmds):
    """Issue 38: the .cfg's NEWMDS sizes the body as 6 + 4 DOFs: modes 7-10 are its mode1..mode4
    (never a second body), every column in SI by its known value."""
    path = write_run(tmp_path, 10, cfg=f"IPEROUT=1\nGRAV=9.80665\nULEN=1.0\n{newmds}\n")
    ds = load_hdb(path, rho=RHO, wamit=FACTS)
    assert [str(b) for b in ds["body"].values] == ["barge"]
    assert [str(v) for v in ds["influenced_dof"].values][6:] == [f"barge.mode{k}" for k in range(1, 5)]
    k = int(np.argmin(np.abs(ds["omega"].values - 2 * np.pi / 10.0)))
    i = np.arange(1, 11)
    np.testing.assert_allclose(np.diag(ds["added_mass"].values[k]), RHO * i, rtol=1e-6)
    np.testing.assert_allclose(np.diag(ds["radiation_damping"].values[k]), RHO * 2 * np.pi / 10.0 * 0.1 * i,
                               rtol=1e-6)
    np.testing.assert_allclose(np.diag(ds["hydrostatic_stiffness"].values), RHO * 9.80665 * 10.0 * i, rtol=1e-6)
    np.testing.assert_allclose(ds["excitation_force"].values[k, 0], RHO * 9.80665 * (1.0 - 0.5j), rtol=1e-6)


def test_generalized_modes_scale_like_translations_and_another_ulen_is_warned(tmp_path):
    """ULEN = 2: roll (mode 4) scales A by L^5, a generalized mode (7) like a translation, L^3;
    the warning names ULEN (the modes' own scaling is the run's)."""
    path = write_run(tmp_path, 10, cfg="IPEROUT=1\nGRAV=9.80665\nULEN=2.0\nNEWMDS=4\n")
    ds = load_hdb(path, rho=RHO, wamit=FACTS)
    assert any(re.match(r"barge\.cfg: ULEN = 2\.0 with generalized modes", w) for w in hdb_warnings(ds))
    a = np.diag(ds["added_mass"].values[0])
    assert a[3] == pytest.approx(RHO * 2.0 ** 5 * 4, rel=1e-6) and a[6] == pytest.approx(RHO * 2.0 ** 3 * 7, rel=1e-6)


def test_mode_counts_that_do_not_agree_are_an_error_naming_the_file(tmp_path):
    """NEWMDS = 3 in the .cfg but modes 1-10 in the .1: refused naming the .1 and both counts."""
    path = write_run(tmp_path, 10, cfg="IPEROUT=1\nGRAV=9.80665\nULEN=1.0\nNEWMDS=3\n")
    with pytest.raises(HDBError, match=r"barge\.1: modes: modes 1-10 for the run's 1 bodies \(barge\.pot\) and "
                                       r"the \.cfg's NEWMDS \[3\]: 9 expected .* do not agree"):
        load_hdb(path, rho=RHO, wamit=FACTS)


def test_a_lone_listed_body_owns_the_modes_beyond_its_six(tmp_path):
    """No NEWMDS in the .cfg: the .pot lists one body, the .1 holds 10 modes: its 4 generalized
    modes (before issue 38: read as bodies 'body1', 'body2' with modes 7-10 as the second's)."""
    ds = load_hdb(write_run(tmp_path, 10), rho=RHO, wamit=FACTS)
    assert ds.sizes["body"] == 1 and ds.sizes["influenced_dof"] == 10


def test_without_a_file_listing_the_bodies_the_scene_or_the_count_decides(tmp_path):
    """No .pot (nor .out, .mmx): the scene's wamit.xbody gives the body count (one: it owns the 4
    extra modes), and without it 10 modes are not 6 per body: refused, not rounded up to 2 bodies."""
    path = write_run(tmp_path, 10, pot=False)
    ds = load_hdb(path, rho=RHO, wamit={**FACTS, "xbody": [[0.0, 0.0, 0.0]], "depth": "inf"})
    assert ds.sizes["influenced_dof"] == 10
    with pytest.raises(HDBError, match=r"barge\.1: modes: 10 modes, not 6 per body plus the \.cfg's NEWMDS \(0\), "
                                       r"and no file \(\.out, \.pot, \.mmx\) lists the run's bodies"):
        load_hdb(path, rho=RHO, wamit={"depth": "inf"})


def test_one_newmds_for_several_bodies_is_refused_naming_it(tmp_path):
    path = write_run(tmp_path, 16, pot=False, cfg="IPEROUT=1\nGRAV=9.80665\nULEN=1.0\nNEWMDS=2\n")
    with pytest.raises(HDBError, match=r"barge\.cfg: NEWMDS: one count for the run's 2 bodies"):
        load_hdb(path, rho=RHO, wamit={**FACTS, "vcg": [0.0, 0.0], "xbody": [[0.0, 0.0, 0.0], [5.0, 0.0, 0.0]],
                                      "depth": "inf"})


GBM = Path(__file__).resolve().parents[1] / "examples" / "data" / "wamit_gbm_barge"


def _rows(path: Path, ncols: int) -> np.ndarray:
    """The numeric rows of a WAMIT file (its header line left out), read here."""
    return np.array([[float(v) for v in line.split()] for line in path.read_text().splitlines()
                     if len(line.split()) == ncols and not line.lstrip()[0].isalpha()])


def test_wec_sim_s_flexible_barge_reads_its_four_generalized_modes_with_the_file_s_figures(tmp_path):
    """WEC-Sim's WAMIT GBM barge (NEWMDS = 4, examples/data/wamit_gbm_barge): one body of 6 + 4
    DOFs; every mode-7..10 entry of the .1, .hst and .3 equals the file's line in SI (rho Abar,
    rho w Bbar, rho g Cbar, rho g (Re - i Im)); the .mmx's ten modes agree with the .1's."""
    ds = load_hdb(GBM / "barge.1", rho=RHO, wamit={"iperout": 1})
    assert [str(v) for v in ds["influenced_dof"].values][6:] == [f"barge.mode{k}" for k in range(1, 5)]
    g = 9.81
    omega = ds["omega"].values
    rad = _rows(GBM / "barge.1", 5)
    for per, i, j, a, b in rad[(rad[:, 1] > 6) | (rad[:, 2] > 6)]:
        w = int(np.argmin(np.abs(omega - 2 * np.pi / per)))
        assert ds["added_mass"].values[w, int(i) - 1, int(j) - 1] == pytest.approx(RHO * a, rel=1e-6, abs=1e-6)
        assert ds["radiation_damping"].values[w, int(i) - 1, int(j) - 1] == pytest.approx(
            RHO * omega[w] * b, rel=1e-6, abs=1e-6)
    hst = _rows(GBM / "barge.hst", 3)
    for i, j, c in hst[(hst[:, 0] > 6) | (hst[:, 1] > 6)]:
        assert ds["hydrostatic_stiffness"].values[int(i) - 1, int(j) - 1] == pytest.approx(RHO * g * c, rel=1e-6)
    exc = _rows(GBM / "barge.3", 7)
    for per, _, i, _, _, re_, im_ in exc[(exc[:, 2] > 6) & (exc[:, 0] > 0)]:
        w = int(np.argmin(np.abs(omega - 2 * np.pi / per)))
        assert ds["excitation_force"].values[w, 0, int(i) - 1] == pytest.approx(RHO * g * (re_ - 1j * im_), rel=1e-6)


def test_mode_counts_of_the_mmx_and_the_1_must_agree(tmp_path):
    """The GBM barge's .1 cut to modes 1-9 (no .cfg NEWMDS: the lone body would own 3 modes) while
    its .mmx lists ten: refused naming the .mmx."""
    for name in ("barge.3", "barge.hst", "barge.pot", "barge.mmx", "barge.frc"):
        (tmp_path / name).write_text((GBM / name).read_text())
    (tmp_path / "barge.cfg").write_text("IPEROUT=1\nIALTFRC=2\n")
    kept = [line for line in (GBM / "barge.1").read_text().splitlines()
            if line.lstrip()[:1].isalpha() or (int(line.split()[1]) < 10 and int(line.split()[2]) < 10)]
    (tmp_path / "barge.1").write_text("\n".join(kept) + "\n")
    with pytest.raises(HDBError, match=r"barge\.mmx: External force matrices: modes 1-10, but barge\.1 holds modes "
                                       r"1-9: the mode counts of the files do not agree"):
        load_hdb(tmp_path / "barge.1", rho=RHO)
