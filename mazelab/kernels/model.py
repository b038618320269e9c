"""The model's equations, compiled (mazelab.model is the numpy reference; the paper's numbering):

    (1) the move: th = th0 + Delta (u - 1/2), u ~ U[0, 1), then x_k = x_{k-1} + L (cos th, sin th),
        gathered from the resampled ancestors
    (3) the likelihood: log p(z_k | x_k) = -((d(x_k) - z_k) / sigma)^2 / 2 - log(sigma sqrt(2 pi)),
        plus log 0.5 outside the free area, d the distance to the nearest station (mazelab.lookup's table)
    the RPF's jitter: x^{i*} + h D eps, eps ~ N(0, I_2) (mazelab.regularisation)

R runs' float32 particles come as (2, R, N) planes (x's, then y's), written into new arrays; float
constants are rounded to float32 in a kernel, as numpy's float32 arithmetic rounds them. The draws
are the kernels' own: particle m of run r takes number m of run r's stream (vector_math.random_bits,
its key from the run's Generator). The arithmetic is the numpy path's float32, operation for
operation: the likelihood of given points and the headings of given uniforms are numpy's to the bit;
cos and sin are vector_math's, within 0.502 ulp of the exact values (numpy's float32 ones within 1.5).
"""

from __future__ import annotations

import math

import numpy as np
from numba import prange

from mazelab.kernels import Kernel, chunk_of, chunks, inline, scratch
from mazelab.kernels.vector_math import cos_sin, random_bits, uniform32, uniform64

F32 = np.float32
_FREE, _MORE = 1, 2  # the low bits of a lookup cell's code (mazelab.kernels.compiled.lookup_tables)
_ZERO, _HALF, _MINUS_HALF = F32(0.0), F32(0.5), F32(-0.5)
# unsigned indices (numba checks a signed index for wrap-around at every load)
_X0, _Y0, _X1, _Y1, _X2, _Y2, _X3, _Y3 = (np.uint64(k) for k in range(8))
_NONE, _PAIR, _TWO = np.uint64(0), np.uint64(2), np.uint64(2)


@Kernel
def move(xy, ancestors, keys, moving, angles, delta, speed, out):  # pragma: no cover - compiled
    """Equation (1) for R runs in one call, with its draws: th_i = th0_r + Delta (u_i - 1/2), then
    out[:2, r, m] = xy[:, r, a_m] + L (cos th_i, sin th_i), and out[2, r, m] = th_i (radians), out
    (3, R, M); the headings are mazelab.model.headings_from_uniforms' float32 operations.

    `ancestors` (R, M) uint64 the particle of its own run each moves from ((1, 0): particle m moves
    from particle m); u_m of run r is number m of the stream keys[r] (uint64 (R,)), or 1/2 in a run
    whose `moving` is False (it draws nothing: it restarts after this step; an empty `moving`: every
    run draws); `angles` (R,) the th0 of each run; `delta` and `speed` Delta (radians) and L (map
    units)."""
    delta, speed = F32(delta), F32(speed)
    runs, size = out.shape[1:]
    blocks, jobs = chunks(runs, size)
    gathered = ancestors.shape[1] > 0
    for job in prange(jobs):
        r, start, stop = chunk_of(job, blocks, size)
        key, angle, x, y = keys[r], F32(angles[r]), xy[0, r], xy[1, r]
        drawn = moving[r] if len(moving) else True
        sources = ancestors[r if gathered else 0, start:stop]  # empty when there are none
        moved_x, moved_y, taken = out[0, r, start:stop], out[1, r, start:stop], out[2, r, start:stop]
        for m in range(stop - start):  # the gather alone: in the loop below it cost a third of the pass
            source = sources[m] if gathered else np.uint64(start + m)
            moved_x[m] = x[source]
            moved_y[m] = y[source]
        for m in range(stop - start):  # each loop from 0: numba checks no index of it for wrap-around
            u = uniform32(random_bits(key, np.uint64(start + m))) if drawn else _HALF
            heading = (u - _HALF) * delta + angle
            taken[m] = heading
            cos_h, sin_h = cos_sin(heading)
            moved_x[m] += cos_h * speed
            moved_y[m] += sin_h * speed


@inline
def _residual(best, zr, sigma, term):  # pragma: no cover - compiled
    """-((sqrt(best) - z) / sigma)^2 / 2 + term: numpy's float32 operations, in its order."""
    residual = (np.sqrt(best) - zr) / sigma
    return residual * residual * _MINUS_HALF + term


@inline
def _squared(px, py, sx, sy):  # pragma: no cover - compiled
    """The squared distance from (px, py) to the station (sx, sy), numpy's float32 operations."""
    dx = sx - px
    dy = sy - py
    return dx * dx + dy * dy


@inline
def _nearer(px, py, sx, sy, best):  # pragma: no cover - compiled
    """The smaller of `best` and the squared distance from (px, py) to (sx, sy) (a NaN best stays)."""
    d2 = _squared(px, py, sx, sy)
    return d2 if d2 < best else best


@inline
def _log_likelihood_of_four(px, py, zr, sigma, free_term, outside_term, tables):  # pragma: no cover - compiled
    """(log p(z_r | x) for the point (px, py) from its cell's first four candidates, what is left open):
    numpy's locate and likelihood for one point without a branch, so that the loop calling it
    vectorises (its loads gathers). Left open: 0 when the value is the answer; 1 for a point beyond the
    table (which reads cell 0 instead, by a select); the cell's code for a cell with more than four
    candidates (one in fifty in a large maze; its code names them), whose value is then the squared
    distance to the nearest four. `_close` works both out. `tables` is log_likelihood's typed tables."""
    scale, offset, nxf, nyf, nx, codes, quads, _, _, _ = tables
    fx = np.floor(px * scale) + offset  # float32, exact: the scale is a power of two
    fy = np.floor(py * scale) + offset
    inside = (fx >= _ZERO) & (fy >= _ZERO) & (fx < nxf) & (fy < nyf)  # False for NaN
    cell = np.uint64(fy) * nx + np.uint64(fx) if inside else _NONE  # the conversions' value unused beyond it
    code = codes[cell]
    best = _squared(px, py, quads[cell, _X0], quads[cell, _Y0])
    best = _nearer(px, py, quads[cell, _X1], quads[cell, _Y1], best)
    best = _nearer(px, py, quads[cell, _X2], quads[cell, _Y2], best)
    best = _nearer(px, py, quads[cell, _X3], quads[cell, _Y3], best)
    value = _residual(best, zr, sigma, free_term if code & _FREE else outside_term)
    more = inside & ((code & _MORE) != 0)
    return best if more else value, (code if more else 0) if inside else 1


@inline
def _close(px, py, value, left, zr, sigma, free_term, outside_term, tables):  # pragma: no cover - compiled
    """log p(z_r | x) of a point `_log_likelihood_of_four` left open: beyond the table (outside the free
    area), the nearest of the border cells' candidates by brute force; in a cell with more than four
    candidates (`left` its code, `value` the squared distance to its first four), the nearest of them
    all. The minimum is exact whatever the order, so the distance is numpy's to the bit."""
    _, _, _, _, _, _, _, rows, width, border = tables
    if left == 1:
        best = _squared(px, py, border[0, 0], border[0, 1])
        for b in range(1, border.shape[0]):
            best = _nearer(px, py, border[b, 0], border[b, 1], best)
        return _residual(best, zr, sigma, outside_term)
    best, start = value, np.uint64(left >> _TWO)
    for c in range(start, start + width, _PAIR):
        best = _nearer(px, py, rows[c], rows[c + _Y0], best)
    return _residual(best, zr, sigma, free_term if left & _FREE else outside_term)


@Kernel
def log_likelihood(xy, z, constants, sizes, codes, quads, rows, border, out):  # pragma: no cover - compiled
    """Equation (3) with the outside penalty, in logs, for R runs: out[r, m] = log p(z_r | x_{r, m})
    float32 (R, N), numpy's values to the bit (the same float32 operations, and the nearest of the
    same candidates). Each chunk in two loops: every point from its cell's first four candidates
    (vectorised), then the few left open.

    z (R,) is each run's z_k (map units); `constants` (7,) float32: the noise's standard deviation
    sigma, -log(sigma sqrt(2 pi)), that plus log(the outside penalty), then the tables' grid; sizes,
    codes, quads, rows and border the maze's tables (compiled.lookup_tables)."""
    sigma, free_term, outside_term = constants[0], constants[1], constants[2]
    typed = (constants[3], constants[4], constants[5], constants[6], sizes[0], codes, quads, rows, sizes[1], border)
    runs, size = out.shape
    blocks, jobs = chunks(runs, size)
    left = scratch(runs * size, codes.dtype)  # what each point leaves open
    for job in prange(jobs):
        r, start, stop = chunk_of(job, blocks, size)
        zr, values, open_ = F32(z[r]), out[r, start:stop], left[r * size + start : r * size + stop]
        xs, ys = xy[0, r, start:stop], xy[1, r, start:stop]
        opened = 0  # any point left open in the chunk
        for m in range(stop - start):
            value, code = _log_likelihood_of_four(xs[m], ys[m], zr, sigma, free_term, outside_term, typed)
            values[m], open_[m] = value, code
            opened |= code
        for m in range(stop - start if opened else 0):
            if open_[m]:
                values[m] = _close(xs[m], ys[m], values[m], open_[m], zr, sigma, free_term, outside_term, typed)


@Kernel
def jitter(xy, rows, ancestors, keys, scales, out):  # pragma: no cover - compiled
    """The RPF's kernel K_h for D due runs, with its draws: out[:, d, m] = xy[:, rows[d], a_m] + h D_d
    eps_m (out (2, D, M); `rows` (D,) the due runs, `ancestors` (D, M) uint64), h D_d = [[a, 0], [c,
    d]] from scales[d] = (a, c, d) (D, 3), eps_m ~ N(0, I_2) by Box and Muller's transform of two
    float64 uniforms, numbers 2m and 2m + 1 of the stream keys[d] (uint64 (D,)) (the cos and sin of the
    angle rounded to float32 are vector_math's; the log the C library's: docs/speed.md)."""
    runs, size = ancestors.shape
    blocks, jobs = chunks(runs, size)
    for job in prange(jobs):
        r, start, stop = chunk_of(job, blocks, size)
        a, c, d, key, x, y = scales[r, 0], scales[r, 1], scales[r, 2], keys[r], xy[0, rows[r]], xy[1, rows[r]]
        sources, moved_x, moved_y = ancestors[r, start:stop], out[0, r, start:stop], out[1, r, start:stop]
        for m in range(stop - start):
            counter = np.uint64(start + m) * _TWO
            radius = math.sqrt(-2.0 * math.log(1.0 - uniform64(random_bits(key, counter))))
            cos_a, sin_a = cos_sin(F32(2 * math.pi * uniform64(random_bits(key, counter + np.uint64(1)))))
            e0, e1 = F32(radius * cos_a), F32(radius * sin_a)
            moved_x[m] = x[sources[m]] + a * e0
            moved_y[m] = y[sources[m]] + (c * e0 + d * e1)
