"""hydrolink view's pictures (clients/view/animation.py): one frame rendered to PNG shows the body
where it is (its orange pixels around the projection of its moved centre, and they follow its
heave between two frames); a GIF holds the frames asked for."""

from __future__ import annotations

import numpy as np
import pytest

from test_view_placement import poses, results_file

from hydrolink.clients.view.animation import BODY_COLOR, animate, render_png
from hydrolink.clients.view.frames import ViewOptions, make_stage
from hydrolink.clients.view.results import open_run


def _orange(png) -> np.ndarray:
    """(row, col) of the pixels close to the body colour."""
    from matplotlib.image import imread
    img = imread(png)[:, :, :3]
    near = np.linalg.norm(img - np.array(BODY_COLOR), axis=2) < 0.25
    return np.argwhere(near)


def test_a_frame_shows_the_body_where_it_is(tmp_path):
    t = np.arange(0.0, 3.0, 0.1)
    run = open_run(results_file(tmp_path, t))
    stage = make_stage(run, ViewOptions(parts=("bodies",)))
    centre = {}
    for k in (0, 20):
        fig = render_png(stage, np.array([k]), tmp_path / f"frame{k}.png")
        pixels = _orange(tmp_path / f"frame{k}.png")
        assert pixels.shape[0] > 200                                   # the bodies are drawn
        pos = poses(t)[k]
        col, row = fig.pixel_of(pos[0, :3])          # body a's cube is centred on its reference point
        near = pixels[np.hypot(pixels[:, 0] - row, pixels[:, 1] - col) < 60]   # body a alone (b is 150 px away)
        assert near.shape[0] > 100, f"frame {k}: no body pixels around its projected centre ({col:.0f}, {row:.0f})"
        centre[k] = (near[:, 1].mean(), near[:, 0].mean(), col, row)
        assert np.hypot(centre[k][0] - col, centre[k][1] - row) < 12   # its silhouette centres on it (to perspective)
    moved = np.hypot(centre[20][2] - centre[0][2], centre[20][3] - centre[0][3])
    assert moved > 4                                                    # it moved on the picture, and they followed


def test_gif_holds_the_frames(tmp_path):
    from PIL import Image
    t = np.arange(0.0, 1.0, 0.1)
    run = open_run(results_file(tmp_path, t))
    stage = make_stage(run, ViewOptions(parts=("bodies", "markers")))
    path = animate(stage, np.arange(0, 10, 2), tmp_path / "view.gif", progress=False)
    with Image.open(path) as im:
        assert im.n_frames == 5
