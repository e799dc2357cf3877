"""``hydrolink view`` (clients/cli.py over clients/view/series.py): the command writes one VTKHDF file
per part and a GIF, says where and how to open them, and reports bad options in one line naming
the option and the limit."""

from __future__ import annotations

import numpy as np
from click.testing import CliRunner

from test_view_placement import results_file

from hydrolink.clients.cli import cli


def test_command_writes_the_series_and_a_gif(tmp_path):
    run = results_file(tmp_path, np.arange(0.0, 2.0, 0.1))
    out = tmp_path / "view"
    res = CliRunner().invoke(cli, ["view", str(run), "-o", str(out), "--parts", "bodies,markers", "--stride", "2",
                                   "--gif", "--frames", "4", "--no-progress"])
    assert res.exit_code == 0, res.output
    assert sorted(p.name for p in out.iterdir()) == ["a.vtkhdf", "b.vtkhdf", "markers.vtkhdf", "view.gif"]
    assert "wrote 10 frames to" in res.output and "open in ParaView: paraview" in res.output
    from PIL import Image
    with Image.open(out / "view.gif") as im:
        assert im.n_frames == 4


def test_bad_options_name_themselves(tmp_path):
    run = results_file(tmp_path, np.arange(0.0, 1.0, 0.1))
    runner = CliRunner()
    res = runner.invoke(cli, ["view", str(run), "-o", str(tmp_path / "v"), "--parts", "bodies,sky"])
    assert res.exit_code == 1 and "--parts: unknown part(s) ['sky']" in res.output
    res = runner.invoke(cli, ["view", str(run), "-o", str(tmp_path / "v"), "--grid-cells", "40000", "25000",
                              "--no-progress"])
    assert res.exit_code == 1 and "--grid-cells: the free-surface grid's" in res.output and "a set-up array may take" in res.output
    res = runner.invoke(cli, ["view", str(run), "-o", str(tmp_path / "v"), "--start", "5", "--no-progress"])
    assert res.exit_code == 1 and "--start/--end: no row of the file lies in [5, inf] s" in res.output
