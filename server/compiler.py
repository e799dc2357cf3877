"""numba, as hydrolink's compiled kernels import it (server/terms/nonlinear/kernels_numba.py, server/terms/morison_kernel.py):
on a CPU with 512-bit vector instructions (AVX-512), told to use them.

LLVM, which numba compiles with, prefers 256-bit vectors on Intel's server CPUs even where they
have 512-bit ones (the wider instructions lower the clock on some of them). The Froude–Krylov
kernels are arithmetic-bound loops over blocks of points; measured on this 2-vCPU VM (Cascade Lake,
bench/bench_nonlinear.py, the Task-10 sphere of 988 triangles in 300 components, the linear step
and the rest of the server included): a server step 187 µs with 256-bit vectors, 161 µs with
512-bit ones. So, where the CPU has AVX-512 and neither ``NUMBA_CPU_FEATURES`` nor
``NUMBA_CPU_NAME`` is set, :func:`load` sets ``NUMBA_CPU_FEATURES`` to the host's features without
that preference before numba is first imported (numba reads it then; numba's cache keeps the
kernels compiled for each set of features apart). Where numba was imported before (by the user's
own code), it is left as it is: the kernels then run as numba was set up, with the same results.
Set ``NUMBA_CPU_FEATURES`` (or ``NUMBA_CPU_NAME``) yourself to choose otherwise.
"""

from __future__ import annotations

import functools
import importlib.util
import os
import sys
from types import ModuleType

__all__ = ["AVAILABLE", "imports", "load"]

AVAILABLE = importlib.util.find_spec("numba") is not None   # numba itself imported on first use (load)


def _wide_vector_features() -> str | None:
    """The host's CPU features for LLVM with 512-bit vectors preferred, or None where the CPU has
    no AVX-512 (or LLVM cannot tell)."""
    from llvmlite import binding

    try:
        features = binding.get_host_cpu_features()
    except RuntimeError:
        return None
    return features.flatten() + ",-prefer-256-bit" if features.get("avx512f") else None


def load() -> ModuleType:
    """numba, imported (on the first call) as the module docstring says."""
    if "numba" not in sys.modules and not (os.environ.get("NUMBA_CPU_FEATURES") or os.environ.get("NUMBA_CPU_NAME")):
        features = _wide_vector_features()
        if features:
            os.environ["NUMBA_CPU_FEATURES"] = features
    import numba
    return numba


@functools.cache
def imports() -> bool:
    """Whether numba, installed, also imports here (a numba built for another numpy raises): the
    set-ups ask this before choosing the compiled paths, so such a machine runs the numpy ones."""
    try:
        load()
    except Exception:  # noqa: BLE001 - any failure to import means: no compiled paths
        return False
    return True
