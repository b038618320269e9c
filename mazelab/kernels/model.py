"""The model's equations, compiled (mazelab.model is the numpy reference; the paper's numbering):

    (1) the move: th = th0 + Delta (u - 1/2), u ~ U[0, 1), then x_k = x_{k-1} + L (cos th, sin th),
        gathered from the resampled ancestors
    (3) the likelihood: log p(z_k | x_k) = -((d(x_k) - z_k) / sigma)^2 / 2 - log(sigma sqrt(2 pi)),
        plus log 0.5 outside the free area, d the distance to the nearest station (mazelab.lookup's table)
    the RPF's jitter: x^{i*} + h D eps, eps ~ N(0, I_2) (mazelab.regularisation)

Positions are (R*N, 2) float32 order F (run r's particles the rows r*N..(r+1)*N), written into new
arrays. Each kernel is one body over chunks (mazelab.kernels.Kernel). The draws are the kernels' own:
particle m of run r takes number m of the stream of run r's key (mazelab.kernels.vector_math), so the
moved particles do not depend on the threads. The arithmetic is float32 as in the numpy path,
operation for operation: the likelihood of given points and the headings of given uniforms are the
numpy path's to the bit; cos and sin are vector_math's, within two ulps of numpy's (which are within
1.5 of the exact value, these within 0.502).
"""

from __future__ import annotations

import math

import numpy as np
from numba import prange

from mazelab.kernels import Kernel, chunk_of, chunks, inline
from mazelab.kernels.vector_math import cos_sin, random_bits, uniform32, uniform64

F32 = np.float32
_FREE, _MORE = 1, 2  # the low bits of a lookup cell's code (mazelab.kernels.compiled.lookup_tables)
_ZERO, _HALF, _MINUS_HALF = F32(0.0), F32(0.5), F32(-0.5)
# unsigned indices (numba checks a signed index for wrap-around at every load)
_X0, _Y0, _X1, _Y1, _X2, _Y2, _X3, _Y3 = (np.uint64(k) for k in range(8))
_NONE, _PAIR, _TWO = np.uint64(0), np.uint64(2), np.uint64(2)


@Kernel
def move(x, y, ancestors, keys, moving, angles, delta, speed, out_x, out_y, headings):  # pragma: no cover - compiled
    """Equation (1) for R runs in one call, with its draws: th_i = th0_r + Delta (u_i - 1/2), then
    (out_x, out_y)[i] = (x, y)[a_i] + speed (cos th_i, sin th_i).

    The headings are mazelab.model.headings_from_uniforms' float32 operations; cos and sin are
    vector_math's, within 0.502 ulp of the exact value (numpy's float32 ones within 1.5).

    Parameters
    ----------
    x, y : float32 arrays (P,)
        The coordinates of the particles moved from.
    ancestors : uint64 array (R*M,)
        The particle each particle moves from (into x and y); empty: particle i moves from particle i.
    keys : uint64 array (R,)
        Each run's stream: u_m of run r is number m of keys[r]'s (vector_math.random_bits).
    moving : bool array (R,)
        False for a run that draws nothing (it restarts after this step): u = 1/2, th = th0.
    angles : float32 array (R,)
        th0 of each run (radians).
    delta, speed : float
        Delta (radians) and the step length L (map units), rounded to float32 here (as numpy's float32
        arithmetic rounds them).
    out_x, out_y : float32 arrays (R*M,)
        The moved particles' coordinates.
    headings : float32 array (R, M)
        th of each particle (radians), written.
    """
    delta, speed = F32(delta), F32(speed)
    runs, size = headings.shape
    blocks, jobs = chunks(runs, size)
    for job in prange(jobs):
        r, start, stop = chunk_of(job, blocks, size)
        first, key, angle, drawn = r * size + start, keys[r], angles[r], moving[r]
        sources = ancestors[first : first + stop - start] if len(ancestors) else ancestors
        moved_x, moved_y, taken = (
            out_x[first : first + stop - start],
            out_y[first : first + stop - start],
            headings[r, start:stop],
        )
        for m in range(stop - start):  # each loop from 0: numba checks no index of it for wrap-around
            u = uniform32(random_bits(key, np.uint64(start + m))) if drawn else _HALF
            heading = (u - _HALF) * delta + angle
            taken[m] = heading
            cos_h, sin_h = cos_sin(heading)
            source = sources[m] if len(ancestors) else np.uint64(first + m)
            moved_x[m] = x[source] + cos_h * speed
            moved_y[m] = y[source] + sin_h * speed


@inline
def _typed(tables):  # pragma: no cover - compiled
    """lookup_tables' tuple with its numbers in the kernels' types: (scale, offset, nx, ny) float32, nx
    and the row width uint64 (plain Python numbers cross into a kernel faster than numpy scalars)."""
    scale, offset, nx, ny, codes, quads, rows, width, border = tables
    return F32(scale), F32(offset), F32(nx), F32(ny), np.uint64(nx), codes, quads, rows, np.uint64(width), border


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
    distance to the nearest four. `_close` works both out. `tables` is _typed's."""
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
def log_likelihood(positions, z, sigma, free_term, outside_term, tables, out, left):  # pragma: no cover - compiled
    """Equation (3) with the outside penalty, in logs, for R runs: out[r, m] = log p(z_r | x_i) (i = r N
    + m), float32, numpy's values to the bit (the same float32 operations, and the nearest of the same
    candidates). Each chunk in two loops: every point from its cell's first four candidates (vectorised),
    then the few left open. The numbers come as plain floats (a numpy scalar costs some 0.25 us to
    pass) and are rounded to float32 here, as numpy's float32 arithmetic rounds them.

    Parameters
    ----------
    positions : float32 array (R*N, 2), order F
    z : float array (R,)
        z_k of each run (map units).
    sigma : float
        The measurement noise's standard deviation.
    free_term, outside_term : float
        -log(sigma sqrt(2 pi)), and that plus log(outside penalty): the constant of a free and of an
        outside point.
    tables : tuple
        The maze's lookup tables (mazelab.kernels.compiled.lookup_tables).
    out : float32 array (R, N)
    left : array (R*N,) of the tables' codes' dtype
        Scratch: what the first loop left open.
    """
    sigma, free_term, outside_term, typed = F32(sigma), F32(free_term), F32(outside_term), _typed(tables)
    runs, size = out.shape
    blocks, jobs = chunks(runs, size)
    for job in prange(jobs):
        r, start, stop = chunk_of(job, blocks, size)
        zr, first, values = F32(z[r]), r * size + start, out[r, start:stop]
        xs, ys, open_ = (
            positions[first : first + stop - start, 0],
            positions[first : first + stop - start, 1],
            left[first : first + stop - start],
        )
        for m in range(stop - start):
            values[m], open_[m] = _log_likelihood_of_four(xs[m], ys[m], zr, sigma, free_term, outside_term, typed)
        for m in range(stop - start):
            if open_[m]:
                values[m] = _close(xs[m], ys[m], values[m], open_[m], zr, sigma, free_term, outside_term, typed)


@Kernel
def jitter(positions, ancestors, keys, scales, out):  # pragma: no cover - compiled
    """The RPF's kernel K_h for D due runs, with its draws: out[i] = positions[a_i] + h D_d eps_i, D_d
    lower triangular, eps_i ~ N(0, I_2) by Box and Muller's transform of two float64 uniforms, numbers
    2m and 2m + 1 of the stream keys[d] (so the points do not depend on the threads).

    Parameters
    ----------
    positions : float32 array (P, 2), order F
    ancestors : uint64 array (D*M,)
        The resampled rows of `positions`.
    keys : uint64 array (D,)
        Each due run's stream.
    scales : float32 array (D, 3)
        (a, c, d) of each run's h D = [[a, 0], [c, d]].
    out : float32 array (D*M, 2), order F
    """
    runs = scales.shape[0]
    size = len(ancestors) // runs
    blocks, jobs = chunks(runs, size)
    for job in prange(jobs):
        r, start, stop = chunk_of(job, blocks, size)
        a, c, d, key, first = scales[r, 0], scales[r, 1], scales[r, 2], keys[r], r * size + start
        sources, moved = ancestors[first : first + stop - start], out[first : first + stop - start]
        for m in range(stop - start):
            counter = np.uint64(start + m) * _TWO
            radius = math.sqrt(-2.0 * math.log(1.0 - uniform64(random_bits(key, counter))))
            angle = 2 * math.pi * uniform64(random_bits(key, counter + np.uint64(1)))
            e0, e1 = F32(radius * math.cos(angle)), F32(radius * math.sin(angle))
            source = sources[m]
            moved[m, 0] = positions[source, 0] + a * e0
            moved[m, 1] = positions[source, 1] + (c * e0 + d * e1)


__all__ = ["jitter", "log_likelihood", "move"]
