"""The RPF's jitter kernel (mazelab.kernels.model.jitter's loop, on numba's noalias pipeline) with the C
library's log, as it now is, against a branch-free float64 log from the IEEE bits (the polynomial the
package carried until it was measured here), at 30 runs x 1,500 particles, the paper's study's shape
(CPU milliseconds a call, 500 calls a round, alternating rounds):

    uv run python benchmarks/jitter_log.py
"""

import math
import os
import time

import numba
import numpy as np
from llvmlite import ir
from numba import prange, types
from numba.extending import intrinsic

from mazelab.kernels import _NoAliasCompiler, chunk_of, chunks, inline
from mazelab.kernels.vector_math import cos_sin, random_bits, uniform64

F32, TWO = np.float32, np.uint64(2)
MANTISSA, ONE_BITS, S52, BIAS = np.int64(2**52 - 1), np.int64(1023 << 52), np.int64(52), np.int64(1023)
SQRT2, LN2 = 1.4142135623730951, 0.6931471805599453


def bitcast(source, target, llvm_type):
    @intrinsic
    def cast(typingctx, value):
        return target(source), lambda context, builder, sig, args: builder.bitcast(args[0], llvm_type)

    return cast


bits_of_double = bitcast(types.float64, types.int64, ir.IntType(64))
double_from_bits = bitcast(types.int64, types.float64, ir.DoubleType())


@inline
def log64(x):
    """log x of a normal float64 x > 0, branch-free: x = 2^e m, log m = 2 atanh((m - 1) / (m + 1)) by its
    series to s^15 (within about 1e-14 of log x)."""
    bits = bits_of_double(x)
    m = double_from_bits((bits & MANTISSA) | ONE_BITS)
    big = m > SQRT2
    m = m * 0.5 if big else m
    e = np.float64((bits >> S52) - (BIAS - 1 if big else BIAS))
    s = (m - 1.0) / (m + 1.0)
    z = s * s
    p = ((z * (1 / 15) + 1 / 13) * z + 1 / 11) * z + 1 / 9
    p = ((p * z + 1 / 7) * z + 1 / 5) * z + 1 / 3
    return e * LN2 + 2.0 * s * (p * z + 1.0)


def jitter_with(polynomial):
    @numba.njit(nogil=True, error_model="numpy", pipeline_class=_NoAliasCompiler)
    def jitter(xy, rows, ancestors, keys, scales, out):
        runs, size = ancestors.shape
        blocks, jobs = chunks(runs, size)
        for job in prange(jobs):
            r, start, stop = chunk_of(job, blocks, size)
            a, c, d, key, x, y = scales[r, 0], scales[r, 1], scales[r, 2], keys[r], xy[0, rows[r]], xy[1, rows[r]]
            sources, moved_x, moved_y = ancestors[r, start:stop], out[0, r, start:stop], out[1, r, start:stop]
            for m in range(stop - start):
                counter = np.uint64(start + m) * TWO
                u = 1.0 - uniform64(random_bits(key, counter))
                radius = math.sqrt(-2.0 * (log64(u) if polynomial else math.log(u)))
                cos_a, sin_a = cos_sin(F32(2 * math.pi * uniform64(random_bits(key, counter + np.uint64(1)))))
                e0, e1 = F32(radius * cos_a), F32(radius * sin_a)
                moved_x[m] = x[sources[m]] + a * e0
                moved_y[m] = y[sources[m]] + (c * e0 + d * e1)

    return jitter


R, N = 30, 1500
rng = np.random.default_rng(0)
ancestors, keys = rng.integers(0, N, (R, N)).astype(np.uint64), rng.integers(0, 2**63, R).astype(np.uint64)
arguments = (rng.random((2, R, N)).astype(np.float32), np.arange(R), ancestors, keys)
arguments += (np.ones((R, 3), np.float32), np.empty((2, R, N), np.float32))
kernels = {"C library's log": jitter_with(False), "branch-free log": jitter_with(True)}
for kernel in kernels.values():
    kernel(*arguments)
print(f"load average {os.getloadavg()}")
for _ in range(3):
    for name, kernel in kernels.items():
        started = time.process_time()
        for _ in range(500):
            kernel(*arguments)
        print(f"{name}: {(time.process_time() - started) / 500 * 1e3:.3f} ms a call")
