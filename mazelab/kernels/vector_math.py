"""Random numbers, exp, cos and sin for the compiled kernels' loops, branch-free so that the compiler
vectorises the loops that call them (numba's own call the C library once per value: 10-15 ns, against
about 1 ns here; benchmarks/vector_math.py).

random_bits: SplitMix64 (Steele, Lea and Flood 2014; it passes BigCrush) as a counter-based generator:
number i of the stream `key` is the mix of key + (i + 1) * golden gamma, so a particle's draw is worked
out on its own, on whichever thread takes its chunk. The keys come from the runs' numpy Generators (one
64-bit number a run and call), so a seed fixes every draw. exp32: float32, Cephes' expf, within one
float32 ulp. cos and sin of a float32 angle: in float64, x = j pi/2 + r with |r| <= pi/4 (pi/2 in two
parts, fdlibm's: r exact to about 1e-20 for |x| < 2^19), the float32 kernels of FreeBSD's libm (k_cosf.c,
k_sinf.c: degree 8 and 9, errors below 2^-34 and 2^-37), the quadrant by selects, then rounded to
float32: within 0.502 ulp of the exact value (tests/test_kernels.py), numpy's float32 cos and sin
(within 1.5) to the bit for about 85% of angles.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from llvmlite import ir
from numba import types
from numba.extending import intrinsic

from mazelab.kernels import inline

_LOWEST = np.float32(-87.0)  # below it exp(x) is subnormal in float32: 0 here
_GAMMA, _MIX1, _MIX2 = np.uint64(0x9E3779B97F4A7C15), np.uint64(0xBF58476D1CE4E5B9), np.uint64(0x94D049BB133111EB)
_S30, _S27, _S31, _ONE = np.uint64(30), np.uint64(27), np.uint64(31), np.uint64(1)
_TO_FLOAT32, _TO_FLOAT64 = np.uint64(40), np.uint64(11)  # the bits a float32 (24) and a float64 (53) take


@inline
def random_bits(key, counter):  # pragma: no cover - compiled
    """Number `counter` of the stream `key` (uint64 both): SplitMix64's output, 64 random bits."""
    z = key + (counter + _ONE) * _GAMMA
    z = (z ^ (z >> _S30)) * _MIX1
    z = (z ^ (z >> _S27)) * _MIX2
    return z ^ (z >> _S31)


@inline
def uniform32(bits):  # pragma: no cover - compiled
    """A float32 uniform on [0, 1) from 64 random bits (their top 24: a multiple of 2^-24)."""
    return np.float32(bits >> _TO_FLOAT32) * np.float32(2.0**-24)


@inline
def uniform64(bits):  # pragma: no cover - compiled
    """A float64 uniform on [0, 1) from 64 random bits (their top 53)."""
    return np.float64(bits >> _TO_FLOAT64) * 2.0**-53


@intrinsic
def _float_from_bits(typingctx, bits):  # pragma: no cover - compiled
    """The float32 of these int32 bits (a bitcast: no instruction)."""

    def codegen(context: Any, builder: Any, sig: Any, args: Any) -> Any:
        return builder.bitcast(args[0], ir.FloatType())

    return types.float32(types.int32), codegen


@inline
def exp32(x):  # pragma: no cover - compiled
    """exp(x) of a float32 x <= 0, float32, branch-free (Cephes' expf: x = n ln 2 + r, |r| <= ln 2 / 2,
    ln 2 in two parts so that r is exact, a degree-6 polynomial, 2^n from its IEEE bits): within one
    float32 ulp of exp (tests/test_kernels.py); 0 below -87 and for -inf, NaN for NaN."""
    clamped = x if x > _LOWEST else _LOWEST  # NaN becomes _LOWEST here; the select at the end gives NaN back
    n = np.floor(clamped * np.float32(1.44269504088896341) + np.float32(0.5))
    r = (clamped - n * np.float32(0.693359375)) + n * np.float32(2.12194440e-4)
    p = np.float32(1.9875691500e-4) * r + np.float32(1.3981999507e-3)
    p = p * r + np.float32(8.3334519073e-3)
    p = p * r + np.float32(4.1665795894e-2)
    p = p * r + np.float32(1.6666665459e-1)
    p = p * r + np.float32(5.0000001201e-1)
    p = (p * r) * r + r + np.float32(1.0)
    value = p * _float_from_bits((np.int32(n) + np.int32(127)) << np.int32(23))
    return value if x >= _LOWEST else (x if x != x else np.float32(0.0))


_TWO_OVER_PI = 0.6366197723675814
_PIO2_HI = 1.57079632673412561417e00  # pi/2 to 33 bits: j * _PIO2_HI is exact for j < 2^20
_PIO2_LO = 6.07710050650619224932e-11  # pi/2 - _PIO2_HI
_S1, _S2, _S3, _S4 = (
    -0.166666666416265235595,
    0.0083333293858894631756,
    -0.000198393348360966317347,
    2.7183114939898219064e-6,
)
_C0, _C1, _C2, _C3 = (
    -0.499999997251031003120,
    0.0416666233237390631894,
    -0.00138867637746099294692,
    2.43904487962774090654e-5,
)


@inline
def cos_sin(x):  # pragma: no cover - compiled
    """(cos x, sin x) of a float32 angle x (radians, |x| < 2^19: the lab's are within 1e4 of zero) as
    float32, branch-free, each within 0.502 ulp of the exact value (see the module's docstring)."""
    angle = np.float64(x)
    j = np.floor(angle * _TWO_OVER_PI + 0.5)
    r = (angle - j * _PIO2_HI) - j * _PIO2_LO
    z = r * r
    w = z * z
    s = z * r
    sin_r = (r + s * (_S1 + z * _S2)) + s * w * (_S3 + z * _S4)
    cos_r = ((1.0 + z * _C0) + w * _C1) + (w * z) * (_C2 + z * _C3)
    quadrant = np.int64(j) & 3
    odd = (quadrant & 1) != 0
    cos_x = sin_r if odd else cos_r  # cos(r + pi/2) = -sin r, cos(r + pi) = -cos r, cos(r + 3 pi/2) = sin r
    sin_x = cos_r if odd else sin_r
    cos_x = -cos_x if (quadrant == 1) | (quadrant == 2) else cos_x
    sin_x = -sin_x if quadrant >= 2 else sin_x
    return np.float32(cos_x), np.float32(sin_x)
