"""Cosine, sine and exponential of many values at once, written so that the compiler vectorises
them (issue 26): plain code compiled by server/terms/nonlinear/kernels_numba.py, as server/terms/nonlinear/rows.py is.

numba calls the C library's scalar ``sin``, ``cos`` and ``exp`` once per value (measured here: 14,
13 and 6 ns); its vectorised ones (Intel's SVML) need an llvmlite built with them, which the
package index's wheels are not. On the 988-triangle hull of bench/bench_nonlinear.py a step took
about 3,400 such calls (the components' phasors, the recurrences' starting powers): a quarter of
the Froude–Krylov pass. These loops have no calls and no branches the compiler cannot turn into
selects, so it runs them four values at a time.

- :func:`sincos`: x = q pi/2 + r with q the nearest integer to x 2/pi and r in [-pi/4, pi/4]
  (Cody and Waite's reduction: pi/2 in three parts of 27 significant bits, so q times each is
  exact for |q| < 2^26), then the Taylor series of sin r to r^19 and of cos r to r^18 (the first
  term left out below 1e-19: less than a thousandth of an ulp), and the quadrant's swap and signs.
  Beyond |x| = 2^25 pi/2 (5.3e7) and for a value that is not finite, the C library's.
- :func:`exp`: x = q ln 2 + r, |r| <= ln 2 / 2 (ln 2 in two parts of 32 bits), the Taylor series
  of e^r to r^13 (next term below 4e-18), times 2^q as two powers of two made from their exponent
  bits (so that subnormal results round once, as the library's). 0 below -746, inf above 709.78.

Both within 2 ulp of the C library's over the ranges tests/test_vector_math.py sweeps.
"""

from __future__ import annotations

import math
import struct
from decimal import Decimal, localcontext

import numpy as np

__all__ = ["exp", "sincos"]

_PI = Decimal("3.14159265358979323846264338327950288419716939937510582097494459")


def _head(x: Decimal, bits: int) -> float:
    """x rounded to a double, then cut to its first ``bits`` significant bits."""
    (u,) = struct.unpack("<Q", struct.pack("<d", float(x)))
    (f,) = struct.unpack("<d", struct.pack("<Q", u & ~((1 << (53 - bits)) - 1)))
    return f


def _parts(x: Decimal, bits: int, n: int) -> tuple[float, ...]:
    """x as n doubles, all but the last of ``bits`` significant bits (Cody and Waite)."""
    out = []
    for _ in range(n - 1):
        out.append(_head(x, bits))
        x -= Decimal(out[-1])
    return (*out, float(x))


with localcontext() as _context:       # 60 digits for the constants (the caller's context untouched)
    _context.prec = 60
    _PIO2_1, _PIO2_2, _PIO2_3 = _parts(_PI / 2, 27, 3)
    _TWO_OVER_PI = float(2 / _PI)
    _REDUCE_MAX = float(2 ** 25 * _PI / 2)      # beyond: q needs more than 26 bits
    _LN2_1, _LN2_2 = _parts(Decimal(2).ln(), 32, 2)
    _LOG2_E = float(1 / Decimal(2).ln())
    # Taylor coefficients: sin r = r + r^3 (S1 + r^2 (S2 + ...)), cos r = 1 + r^2 (C1 + r^2 (C2 + ...))
    _S1, _S2, _S3, _S4, _S5, _S6, _S7, _S8, _S9 = (float((-1) ** m / Decimal(math.factorial(2 * m + 1)))
                                                   for m in range(1, 10))
    _C1, _C2, _C3, _C4, _C5, _C6, _C7, _C8, _C9 = (float((-1) ** m / Decimal(math.factorial(2 * m)))
                                                   for m in range(1, 10))
    _E = tuple(float(1 / Decimal(math.factorial(m))) for m in range(14))
_EXP_MAX = 709.782712893384                # ln of the largest double: e^x overflows above


def sincos(x: np.ndarray, c: np.ndarray, s: np.ndarray) -> None:
    """c, s = cos x, sin x for arrays of one size (module docstring)."""
    for i in range(x.size):
        v = x[i]
        q = math.floor(v * _TWO_OVER_PI + 0.5)
        r = ((v - q * _PIO2_1) - q * _PIO2_2) - q * _PIO2_3
        r2 = r * r
        sr = r + r * r2 * (_S1 + r2 * (_S2 + r2 * (_S3 + r2 * (_S4 + r2 * (_S5 + r2 * (_S6 + r2 * (_S7 + r2 * (
            _S8 + r2 * _S9))))))))
        cr = 1.0 + r2 * (_C1 + r2 * (_C2 + r2 * (_C3 + r2 * (_C4 + r2 * (_C5 + r2 * (_C6 + r2 * (_C7 + r2 * (
            _C8 + r2 * _C9))))))))
        m = q - 4.0 * math.floor(0.25 * q)      # the quadrant, 0 to 3
        odd = m == 1.0 or m == 3.0
        cv, sv = (sr, cr) if odd else (cr, sr)
        c[i] = -cv if (m == 1.0 or m == 2.0) else cv
        s[i] = -sv if m >= 2.0 else sv
    for i in range(x.size):
        if not abs(x[i]) <= _REDUCE_MAX:
            c[i], s[i] = math.cos(x[i]), math.sin(x[i])


def exp(x: np.ndarray, out: np.ndarray) -> None:
    """out = e^x for arrays of one size (module docstring)."""
    bits = np.empty((2, x.size), np.int64)
    for i in range(x.size):
        v = min(max(x[i], -746.0), 710.0)
        q = math.floor(v * _LOG2_E + 0.5)
        r = (v - q * _LN2_1) - q * _LN2_2
        out[i] = _E[0] + r * (_E[1] + r * (_E[2] + r * (_E[3] + r * (_E[4] + r * (_E[5] + r * (_E[6] + r * (
            _E[7] + r * (_E[8] + r * (_E[9] + r * (_E[10] + r * (_E[11] + r * (_E[12] + r * _E[13]))))))))))))
        a = int(q) >> 1         # 2^q as 2^a 2^(q - a): each a normal number from q = -1076 to 1024
        bits[0, i], bits[1, i] = (a + 1023) << 52, (int(q) - a + 1023) << 52
    scale = bits.view(np.float64)
    for i in range(x.size):
        v = x[i]
        e = out[i] * scale[0, i] * scale[1, i]
        e = math.inf if v > _EXP_MAX else e
        out[i] = v if math.isnan(v) else e
