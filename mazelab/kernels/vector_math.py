"""exp for the compiled kernels' loops, branch-free so that the compiler vectorises the loops that call
it (numba calls the C library's exp once per value otherwise: 10-15 ns, against about 1 ns here).

x = n ln 2 + r with n = round(x / ln 2) and |r| <= ln 2 / 2 (ln 2 in two parts, fdlibm's, so r is
exact), exp(r) by its Taylor polynomial to degree 12 (the remainder below 2e-16 of the value), and
2^n from its IEEE bits. The value agrees with numpy's exp to a few units in the last place: the
normalised weights to about 1e-15.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from llvmlite import ir
from numba import types
from numba.extending import intrinsic

from mazelab.kernels import jit

_LOG2E = 1.4426950408889634
_LN2_HI = 6.93147180369123816490e-01
_LN2_LO = 1.90821492927058770002e-10
_LOWEST = -708.0  # below it exp(x) is subnormal or 0 in float64: 0 here


@intrinsic
def _double_from_bits(typingctx: Any, bits: Any) -> Any:  # pragma: no cover - compiled
    """The float64 whose IEEE bits are the int64 `bits` (a bitcast: no instruction)."""
    signature = types.float64(types.int64)

    def codegen(context: Any, builder: Any, sig: Any, args: Any) -> Any:
        return builder.bitcast(args[0], ir.DoubleType())

    return signature, codegen


@jit(inline=True)
def exp(x):  # pragma: no cover - compiled
    """exp(x) for float64 x <= 709, branch-free: 0 below -708 and for -inf, NaN for NaN.

    Parameters
    ----------
    x : float64

    Returns
    -------
    float64
    """
    clamped = x if x > _LOWEST else _LOWEST  # NaN becomes _LOWEST here; the select at the end gives NaN back
    n = np.floor(clamped * _LOG2E + 0.5)
    r = (clamped - n * _LN2_HI) - n * _LN2_LO
    p = 1.0 / 479001600.0
    p = p * r + 1.0 / 39916800.0
    p = p * r + 1.0 / 3628800.0
    p = p * r + 1.0 / 362880.0
    p = p * r + 1.0 / 40320.0
    p = p * r + 1.0 / 5040.0
    p = p * r + 1.0 / 720.0
    p = p * r + 1.0 / 120.0
    p = p * r + 1.0 / 24.0
    p = p * r + 1.0 / 6.0
    p = p * r + 0.5
    p = p * r + 1.0
    p = p * r + 1.0
    value = p * _double_from_bits((np.int64(n) + np.int64(1023)) << np.int64(52))
    return value if x >= _LOWEST else (x if x != x else 0.0)


__all__ = ["exp"]
