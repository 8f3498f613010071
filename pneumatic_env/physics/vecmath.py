"""Elementary functions the compiler can vectorise across environments.

Numba calls the scalar C library for ``math.exp``, ``math.log`` and ``math.acos`` (the
pip build of llvmlite has no vector math library), which stops LLVM from vectorising a
loop over environments. These versions use only IEEE arithmetic, ``sqrt``, ``floor`` and
bit casts, so a loop of them compiles to SIMD code. Each is a classical reduction plus a
truncated series whose coefficients are exact rationals; ``tests/test_physics.py``
checks them against the C library (a few units in the last place over the ranges the
sub-models use).

- ``exp_``: x = n ln2 + r, |r| <= ln2/2, e^r by its Taylor series to r^13, times 2^n
  built in the exponent bits. Arguments are clamped to [EXP_MIN_ARG, EXP_MAX_ARG], the
  range of normal doubles.
- ``log_``: x = 2^e m with m in [sqrt(1/2), sqrt(2)), ln m = 2 atanh(s), s = (m-1)/(m+1),
  by its series to s^25. For positive normal x.
- ``acos_``: acos(z) = 2 atan(sqrt((1-z)/(1+z))); atan reduced to |w| <= tan(pi/12)
  (atan(w) = pi/6 + atan((sqrt3 w - 1)/(sqrt3 + w)), atan(w) = pi/2 - atan(1/w)), then
  its series to w^29.
"""

import math

import numpy as np
from llvmlite import ir
from numba import njit, types
from numba.extending import intrinsic

LN2_HI = 6.93147180369123816490e-01  # ln 2 split so that n * LN2_HI is exact (fdlibm)
LN2_LO = 1.90821492927058770002e-10
LOG2_E = 1.0 / math.log(2.0)
EXP_MAX_ARG = 709.0
EXP_MIN_ARG = -708.0  # exp(-708) ~ 3e-308, the smallest normal double's neighbourhood
SQRT_HALF = math.sqrt(0.5)
SQRT3 = math.sqrt(3.0)
TAN_PI_12 = 2.0 - SQRT3
EXPONENT_BIAS = 1023
MANTISSA_BITS = 52
MANTISSA_MASK = (1 << MANTISSA_BITS) - 1
ONE_BITS = EXPONENT_BIAS << MANTISSA_BITS  # bit pattern of 1.0


@intrinsic
def _bits_to_float(typingctx, bits):
    """Reinterpret an int64's bits as a float64 (an LLVM bitcast; vectorises)."""
    sig = types.float64(types.int64)

    def codegen(context, builder, signature, args):
        return builder.bitcast(args[0], ir.DoubleType())

    return sig, codegen


@intrinsic
def float_to_bits(typingctx, value):
    """Reinterpret a float64's bits as an int64 (an LLVM bitcast; vectorises)."""
    sig = types.int64(types.float64)

    def codegen(context, builder, signature, args):
        return builder.bitcast(args[0], ir.IntType(64))

    return sig, codegen


@njit(cache=True, forceinline=True, error_model="numpy")
def exp_(x):
    """e^x for any finite x (clamped to the normal range, see the module docstring)."""
    x = min(max(x, EXP_MIN_ARG), EXP_MAX_ARG)
    n = np.floor(x * LOG2_E + 0.5)
    r = (x - n * LN2_HI) - n * LN2_LO
    # Taylor series of e^r to r^13 (|r| <= 0.347: remainder below 2e-17), in Estrin's
    # scheme: a short dependency chain, so the pipelines stay full
    r2 = r * r
    r4 = r2 * r2
    r8 = r4 * r4
    p = (
        ((1.0 + r) + (0.5 + r * (1.0 / 6.0)) * r2)
        + ((1.0 / 24.0 + r * (1.0 / 120.0)) + (1.0 / 720.0 + r * (1.0 / 5040.0)) * r2) * r4
        + (
            (
                (1.0 / 40320.0 + r * (1.0 / 362880.0))
                + (1.0 / 3628800.0 + r * (1.0 / 39916800.0)) * r2
            )
            + (1.0 / 479001600.0 + r * (1.0 / 6227020800.0)) * r4
        )
        * r8
    )
    # int32 conversions: AVX2 converts doubles to and from int32 lanes, not int64
    return p * _bits_to_float(np.int64(np.int32(n) + EXPONENT_BIAS) << MANTISSA_BITS)


@njit(cache=True, forceinline=True, error_model="numpy")
def log_(x):
    """ln x for a positive normal double."""
    bits = float_to_bits(x)
    e = np.int32((bits >> MANTISSA_BITS) - EXPONENT_BIAS)
    m = _bits_to_float((bits & MANTISSA_MASK) | ONE_BITS)  # in [1, 2)
    big = m > 2.0 * SQRT_HALF
    m = 0.5 * m if big else m
    exponent = np.float64(e + np.int32(1) if big else e)
    s = (m - 1.0) / (m + 1.0)  # |s| <= 0.1716
    z = s * s
    # 2 atanh(s) = 2 s (1 + z/3 + z^2/5 + ...) to z^12 (remainder below 1e-19), Estrin
    z2 = z * z
    z4 = z2 * z2
    z8 = z4 * z4
    q = (
        ((1.0 + z * (1.0 / 3.0)) + (1.0 / 5.0 + z * (1.0 / 7.0)) * z2)
        + ((1.0 / 9.0 + z * (1.0 / 11.0)) + (1.0 / 13.0 + z * (1.0 / 15.0)) * z2) * z4
        + (
            ((1.0 / 17.0 + z * (1.0 / 19.0)) + (1.0 / 21.0 + z * (1.0 / 23.0)) * z2)
            + z4 * (1.0 / 25.0)
        )
        * z8
    )
    return exponent * LN2_HI + (exponent * LN2_LO + 2.0 * s * q)


@njit(cache=True, forceinline=True, error_model="numpy")
def _atan_unit(w):
    """atan(w) for 0 <= w <= 1."""
    reduce = w > TAN_PI_12
    w = (SQRT3 * w - 1.0) / (SQRT3 + w) if reduce else w  # now |w| <= tan(pi/12)
    z = w * w
    # atan(w) = w (1 - z/3 + z^2/5 - ...) to z^14 (z <= 0.0718: remainder below 1e-18),
    # Estrin
    z2 = z * z
    z4 = z2 * z2
    z8 = z4 * z4
    q = (
        ((1.0 - z * (1.0 / 3.0)) + (1.0 / 5.0 - z * (1.0 / 7.0)) * z2)
        + ((1.0 / 9.0 - z * (1.0 / 11.0)) + (1.0 / 13.0 - z * (1.0 / 15.0)) * z2) * z4
        + (
            ((1.0 / 17.0 - z * (1.0 / 19.0)) + (1.0 / 21.0 - z * (1.0 / 23.0)) * z2)
            + ((1.0 / 25.0 - z * (1.0 / 27.0)) + z2 * (1.0 / 29.0)) * z4
        )
        * z8
    )
    return (math.pi / 6.0 if reduce else 0.0) + w * q


@njit(cache=True, forceinline=True, error_model="numpy")
def acos_(z):
    """acos(z) for -1 <= z <= 1 (arguments outside are clamped)."""
    z = min(max(z, -1.0), 1.0)
    lo = 1.0 - z
    hi = 1.0 + z
    # acos z = 2 atan(sqrt(lo/hi)); with lo > hi use atan(w) = pi/2 - atan(1/w)
    flip = lo > hi
    w = math.sqrt(min(lo, hi) / max(lo, hi))
    half = _atan_unit(w)
    return 2.0 * (0.5 * math.pi - half if flip else half)
