"""server/allocation.py: what a session's set-up allocates is sized before it is allocated. Scene
values within their bounds whose products are huge (an IRF of irf_duration/dt samples over 36 DOF
pairs, B(w) resampled at 1e-4 rad/s, 100 000 components in 360 directions, an excitation kernel
over +-1 h at 1 µs) are refused at once, naming the key and the size (issue 22: "Maximum allowed
size exceeded" from numpy, a 36 TiB allocation attempt)."""

from __future__ import annotations

import time

import numpy as np
import pytest

import analytic_hdb as an
from conftest import body, irregular_waves, regular_waves, scene_toml
from hydrolink.protocol.scene import parse_scene
from hydrolink.server.allocation import MAX_ARRAY_BYTES, require_size
from hydrolink.server.model import HydroModel, ModelError


def _model(*, dt: float, hydro: dict, waves: dict | None = None, dofs=("surge", "sway", "heave", "roll", "pitch", "yaw"),
           directions=(0.0,)) -> HydroModel:
    scene = parse_scene(scene_toml(dt=dt, duration=1.0, hydro=hydro, waves=waves, bodies=[
        body("float", hdb="x.nc", mass=3e5, center_of_mass=[0, 0, 0], inertia=[1e6, 1e6, 1e6], dofs=list(dofs))]))
    return HydroModel(scene, {"float": an.make_body_hdb(directions=np.asarray(directions))})


@pytest.mark.parametrize("dt,hydro,waves,key,size", [
    # 3.6e9 samples of the IRF's time grid
    (1e-6, {"irf_duration": 3600.0}, None, "hydro.irf_duration", "3.6e+09 values (26.8 GiB)"),
    # irf_duration = 0: Ogilvie's A_inf still needs 40 s of IRF, 4e7 samples x 36 pairs
    (1e-6, {"irf_duration": 0.0}, None, "simulation.dt", "4e+07 x 36 values (10.7 GiB)"),
    # B(w) up to 8 rad/s at 1e-4 rad/s: a cosine table of 2048 rows x 8e4 frequencies
    (0.01, {"irf_duration": 30.0, "irf_domega": 1e-4}, None, "hydro.irf_domega", "2048 x 8e+04 values (1.22 GiB)"),
    # 1e5 components in 360 directions
    (0.05, {"irf_duration": 2.0}, irregular_waves(1.0, 6.0, components=100_000, spreading="cos2s", directions=360),
     "waves.components", "4 x 360 x 1e+05 values (1.07 GiB)"),
    # the excitation IRF over +-1 h at 1 µs
    (1e-6, {"irf_duration": 0.001}, regular_waves(1.0, 6.0, excitation="convolution", excitation_irf_duration=3600.0),
     "waves.excitation_irf_duration", "1 x 7.2e+09 x 6 values (322 GiB)"),
])
def test_oversized_setup_arrays_are_refused_before_allocating(dt, hydro, waves, key, size):
    t0 = time.perf_counter()
    with pytest.raises(ModelError) as info:
        _model(dt=dt, hydro=hydro, waves=waves)
    assert info.value.key == key, info.value
    assert size in info.value.why and "over the 1 GiB a set-up array may take" in info.value.why, info.value.why
    assert time.perf_counter() - t0 < 20.0   # refused, not computed (a 1 GiB array would take longer)


def test_require_size_counts_astronomical_shapes_without_overflow():
    assert require_size("k", "x", (1024, 1024), 8) == 8 * 2**20
    assert require_size("k", "x", (MAX_ARRAY_BYTES // 8,)) == MAX_ARRAY_BYTES
    for shape in ((MAX_ARRAY_BYTES // 8 + 1,), (1e300, 1e300), (float("nan"),), (float("inf"), 0.5)):
        with pytest.raises(ModelError, match=r"^k: x would take .* over the 1 GiB"):
            require_size("k", "x", shape)


def test_footprint_counts_each_array_once_views_by_their_base():
    """footprint: the bytes of the arrays and datasets reachable from an object graph, written out
    here: shared arrays and views of one base count once, datasets by their nbytes, cycles end; the
    attributes of dataclasses (and hydrolink's and scipy's classes) are walked, a library's
    internals are not."""
    from dataclasses import dataclass, field
    from typing import Any

    import numpy as np
    import xarray as xr

    from hydrolink.server.allocation import footprint

    @dataclass(eq=False)
    class Node:
        views: Any = None
        table: Any = None
        ds: Any = None
        nested: Any = None
        deeper: Any = None
        text: str = ""
        parent: Any = None
        wrapper: Any = None
        other: Any = field(default=None)

    big = np.zeros((100, 50))                     # 40,000 bytes
    small = np.ones(10, np.float32)               # 40 bytes
    ds = xr.Dataset({"a": ("x", np.arange(7.0))})   # 56 bytes of data, plus its index coordinate
    root = Node(views=[big[:10], big.T, big], table={"s": small, "again": small}, ds=ds,
                nested=Node(deeper=(big[::2],), text="no array"))
    root.nested.parent = root                      # a cycle

    @dataclass(eq=False)
    class Wrapper:                                 # a compiled-library wrapper whose __dict__ is no dict
        __dict__ = property(lambda self: object())
        __slots__ = "value"

    wrapped = Wrapper()
    wrapped.value = np.zeros(3)                    # 24 bytes, through its slot
    root.wrapper = wrapped

    class Internals:                               # a library's object (numba's dispatchers): not walked
        __module__ = "numba.core.types"

        def __init__(self):
            self.cache = np.zeros(1000)

    root.other = Internals()
    assert footprint(root) == big.nbytes + small.nbytes + ds.nbytes + wrapped.value.nbytes
    assert footprint(Node()) == 0
