"""server/compiler.py: numba told to use 512-bit vectors only where the CPU has them, only when it
imports numba first, and never over the user's own setting (each case in a fresh interpreter)."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest
from hydrolink.server import compiler

pytestmark = pytest.mark.skipif(not compiler.AVAILABLE, reason="numba not installed")

_PRINT = "import os; print(os.environ.get('NUMBA_CPU_FEATURES', ''))"


def _features_after(code: str, **env: str) -> str:
    clean = {k: v for k, v in os.environ.items() if k not in ("NUMBA_CPU_FEATURES", "NUMBA_CPU_NAME")}
    done = subprocess.run([sys.executable, "-c", code + "; " + _PRINT], env={**clean, **env}, capture_output=True,
                          text=True, timeout=120, check=True)
    return done.stdout.strip()


def test_wide_vectors_where_the_cpu_has_them():
    from llvmlite import binding
    features = _features_after("from hydrolink.server import compiler; compiler.load()")
    if binding.get_host_cpu_features().get("avx512f"):
        assert features.endswith(",-prefer-256-bit") and "+avx512f" in features
    else:
        assert features == ""


def test_the_users_setting_and_an_earlier_numba_are_left_alone():
    load = "from hydrolink.server import compiler; compiler.load()"
    assert _features_after(load, NUMBA_CPU_NAME="generic") == ""
    assert _features_after(load, NUMBA_CPU_FEATURES="+sse2") == "+sse2"
    assert _features_after("import numba; " + load) == ""
