"""numba's own cos, sin and exp against mazelab.kernels.vector_math's float32 polynomials, in loops like
the move's and the normalisation's (CPU microseconds a call, median of 7):

    uv run python benchmarks/vector_math.py
"""

import os
import statistics
import time

import numba
import numpy as np

from mazelab.kernels.vector_math import cos_sin, exp32


@numba.njit(nogil=True, error_model="numpy")
def poly_move(h, out_c, out_s):
    for i in range(len(h)):
        out_c[i], out_s[i] = cos_sin(h[i])


@numba.njit(nogil=True, error_model="numpy")
def own_move(h, out_c, out_s):
    for i in range(len(h)):
        out_c[i] = np.cos(h[i])
        out_s[i] = np.sin(h[i])


@numba.njit(nogil=True, error_model="numpy")
def poly_exp(x, out):
    for i in range(len(x)):
        out[i] = exp32(x[i])


@numba.njit(nogil=True, error_model="numpy")
def own_exp(x, out):
    for i in range(len(x)):
        out[i] = np.exp(x[i])


rng = np.random.default_rng(1)
print(f"load average {os.getloadavg()}")
for n in (1000, 10000, 100000):
    h = rng.uniform(-4, 4, n).astype(np.float32)
    c = np.empty_like(h)
    s = np.empty_like(h)
    x = -rng.exponential(5, n).astype(np.float32)
    o = np.empty_like(x)
    res = {}
    kernels = (("poly cos/sin", poly_move, (h, c, s)), ("numba cos/sin", own_move, (h, c, s)))
    kernels += (("poly exp", poly_exp, (x, o)), ("numba exp", own_exp, (x, o)))
    for name, f, args in kernels:
        f(*args)
        ts = []
        for _ in range(7):
            t = time.process_time()
            for _ in range(max(1, 200000 // n)):
                f(*args)
            ts.append((time.process_time() - t) / max(1, 200000 // n))
        res[name] = statistics.median(ts) * 1e6
    print(n, {k: round(v, 1) for k, v in res.items()}, "us")
