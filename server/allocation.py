"""The size of what a session's set-up allocates, checked before it is allocated.

A scene's values are bounded (protocol/scene_bounds.py), but their products are not: an IRF of
irf_duration / dt samples over n x n DOF pairs, wave components x DOFs, an elevation series over
duration / dt steps. Each object that allocates such an array asks :func:`require_size` first,
which refuses (ModelError naming the scene key) an array over MAX_ARRAY_BYTES instead of letting
numpy fail ("Maximum allowed size exceeded", MemoryError) or the machine swap.
"""

from __future__ import annotations

import math
import types
from typing import Any

import numpy as np
import xarray as xr

from hydrolink.server.errors import ModelError

MAX_ARRAY_BYTES = 2**30   # one set-up array: at most 1 GiB


def _human(nbytes: float) -> str:
    for unit, size in (("TiB", 2**40), ("GiB", 2**30), ("MiB", 2**20), ("KiB", 2**10)):
        if nbytes >= size:
            return f"{nbytes / size:.3g} {unit}"
    return f"{nbytes:.0f} B"


def require_size(key: str, what: str, shape: tuple[float, ...], itemsize: int = 8, hint: str = "") -> int:
    """The bytes of an array of ``shape`` (sizes as floats: they may be astronomical) of ``itemsize``
    bytes; ModelError naming ``key`` when over MAX_ARRAY_BYTES. ``what`` names the array, ``hint``
    says what to change."""
    elements = math.prod(float(n) for n in shape)
    nbytes = elements * itemsize
    if not nbytes <= MAX_ARRAY_BYTES:   # also NaN
        dims = " x ".join(f"{n:.4g}" for n in shape)
        raise ModelError(key, f"{what} would take {dims} values ({_human(nbytes)}), over the "
                              f"{_human(MAX_ARRAY_BYTES)} a set-up array may take" + (f"; {hint}" if hint else ""))
    return int(nbytes)


_OPAQUE = (str, bytes, bytearray, int, float, complex, bool, type(None), type, types.ModuleType, types.FunctionType,
           types.BuiltinFunctionType, types.MethodType)


def _holds_data(cls: type) -> bool:
    """Whether the attributes of an object of ``cls`` are walked by :func:`footprint`: hydrolink's
    own classes, scipy's (interpolators, filters) and any dataclass; not a compiler's or a
    library's internals (numba's dispatchers reach ~10,000 objects of its type system)."""
    module = cls.__module__ or ""
    return module.startswith(("hydrolink.", "scipy.")) or hasattr(cls, "__dataclass_fields__")


def footprint(obj: Any, max_objects: int = 200_000) -> int:
    """The bytes of the numpy arrays and xarray datasets reachable from ``obj`` (its attributes,
    containers, their attributes...), each counted once, views by their base: what a session's
    model holds in memory, to within the Python objects around them. At most ``max_objects``
    objects are visited; the attributes only of the objects :func:`_holds_data` names."""
    seen: set[int] = set()
    counted: set[int] = set()   # the array bases already added
    total = 0
    stack = [obj]
    while stack and len(seen) < max_objects:
        o = stack.pop()
        if id(o) in seen or isinstance(o, _OPAQUE):
            continue
        seen.add(id(o))
        if isinstance(o, np.ndarray):
            base = o
            while isinstance(base.base, np.ndarray):
                base = base.base
            if id(base) not in counted:
                counted.add(id(base))
                total += base.nbytes
            continue
        if isinstance(o, (xr.Dataset, xr.DataArray)):
            total += int(o.nbytes)
            continue
        if isinstance(o, dict):
            stack.extend(o.values())
        elif isinstance(o, (list, tuple, set, frozenset)):
            stack.extend(o)
        elif _holds_data(type(o)):   # an object: its attributes (some wrappers' __dict__ is no dict: skipped)
            attrs = getattr(o, "__dict__", None)
            if isinstance(attrs, dict):
                stack.extend(attrs.values())
            slots = getattr(type(o), "__slots__", ())
            for slot in (slots,) if isinstance(slots, str) else slots:
                try:
                    stack.append(getattr(o, slot))
                except AttributeError:
                    pass
    return total
