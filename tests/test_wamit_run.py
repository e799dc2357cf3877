"""server/hdb/wamit/run.py: a WAMIT run's number of bodies is what its files (or the scene) say,
never the .1's mode count divided by 6 — a run with generalized modes (NEWMDS) is refused by name,
not read as extra rigid bodies (issue 38: a barge of 6 rigid + 4 flexible modes was read as two
bodies, modes 7-10 as the second body's surge..roll).

The data are written here by hand: one body ("barge"), 2 periods, modes 1-10 with known values
(Abar_ii = i, Bbar_ii = 0.1 i, Cbar_ii = 10 i, excitation 1 + 0.5 i per mode), and the same run
with its six rigid modes only, which reads with those values in SI."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from hydrolink.protocol.hdb.layout import HDBError
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
def test_newmds_in_the_cfg_is_refused_naming_it_and_the_count(tmp_path, newmds):
    path = write_run(tmp_path, 10, cfg=f"IPEROUT=1\nGRAV=9.80665\nULEN=1.0\n{newmds}\n")
    with pytest.raises(HDBError, match=r"barge\.cfg: NEWMDS: NEWMDS(\(1\))? = 4: the run has 4 generalized mode\(s\) "
                                       r"beyond the rigid 6 per body \(barge\.1 holds modes 1-10\); hydrolink reads "
                                       r"rigid bodies of 6 DOFs each"):
        load_hdb(path, rho=RHO, wamit=FACTS)


def test_modes_beyond_the_listed_bodies_are_refused_not_read_as_another_body(tmp_path):
    """No NEWMDS in the .cfg: the .pot lists one body, the .1 holds 10 modes: 4 generalized modes,
    refused naming the .1 (before: read as bodies 'body1', 'body2' with modes 7-10 as the second's)."""
    path = write_run(tmp_path, 10)
    with pytest.raises(HDBError, match=r"barge\.1: modes: modes 1-10 for the run's 1 bodies \(barge\.pot\): 4 "
                                       r"generalized mode\(s\) \(NEWMDS\)"):
        load_hdb(path, rho=RHO, wamit=FACTS)


def test_without_a_file_listing_the_bodies_the_scene_or_the_count_decides(tmp_path):
    """No .pot (nor .out, .mmx): the scene's wamit.xbody gives the body count (one: the 4 extra modes
    are refused), and without it 10 modes are not 6 per body: refused, not rounded up to 2 bodies."""
    path = write_run(tmp_path, 10, pot=False)
    with pytest.raises(HDBError, match=r"modes 1-10 for the run's 1 bodies \(the scene's wamit\.xbody\): 4"):
        load_hdb(path, rho=RHO, wamit={**FACTS, "xbody": [[0.0, 0.0, 0.0]], "depth": "inf"})
    with pytest.raises(HDBError, match=r"barge\.1: modes: 10 modes, not 6 per body, and no file \(\.out, \.pot, "
                                       r"\.mmx\) lists the run's bodies"):
        load_hdb(path, rho=RHO, wamit={"depth": "inf"})
