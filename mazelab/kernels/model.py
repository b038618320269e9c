"""The model's equations, compiled (mazelab.model is the numpy reference; the paper's numbering):

    (1) the move: th = th0 + Delta (u - 1/2), then x_k = x_{k-1} + L (cos th, sin th), gathered from
        the resampled ancestors
    (3) the likelihood: log p(z_k | x_k) = -((d(x_k) - z_k) / sigma)^2 / 2 - log(sigma sqrt(2 pi)),
        plus log 0.5 outside the free area, d the distance to the nearest station (mazelab.lookup's table)
    the RPF's jitter: x^{i*} + h D eps, eps ~ N(0, I_2) (mazelab.regularisation)

Positions are (R*N, 2) float32 (run r's particles the rows r*N..(r+1)*N), written into buffers the
caller owns. The arithmetic is float32 as in the numpy path, operation for operation, so the moved
particles and the likelihood of given points are the numpy path's to the bit. The headings' cos and
sin are numpy's (mazelab.kernels.compiled calls them): its vectorised float32 cos and sin, exact to
rounding over the whole float32 range, cost a tenth of the C library's scalar ones in a compiled loop.
"""

from __future__ import annotations

import numpy as np
from numba import prange

from mazelab.kernels import jit

F32 = np.float32
_FREE, _AMBIGUOUS = 1, 2  # the bits of a lookup cell's kind (mazelab.lookup)


@jit
def headings(uniforms, angles, delta):  # pragma: no cover - compiled
    """th = th0_r + Delta (u - 1/2) in place, float32 operation for operation as
    mazelab.model.headings_from_uniforms (the same values to the bit).

    Parameters
    ----------
    uniforms : float32 array (R, M)
        u ~ U[0, 1), overwritten by the headings (radians).
    angles : float32 array (R,)
        th0 of each run (radians).
    delta : float32
        Delta (radians).
    """
    runs, size = uniforms.shape
    half = F32(0.5)
    for r in range(runs):
        for m in range(size):
            uniforms[r, m] = (uniforms[r, m] - half) * delta + angles[r]


@jit
def step(positions, ancestors, cos_h, sin_h, speed, out):  # pragma: no cover - compiled
    """Equation (1)'s step for R runs, gathered: out[i] = positions[a_i] + speed (cos th_i, sin th_i).

    Parameters
    ----------
    positions : float32 array (P, 2)
        The particles moved from.
    ancestors : int array (M,)
        Row of `positions` each particle moves from; empty: particle i moves from row i.
    cos_h, sin_h : float32 arrays (M,)
        cos th_i and sin th_i of the headings (they may be the columns of `out`: each is read before
        its place is written).
    speed : float32
        The step length L (map units).
    out : float32 array (M, 2)
        The moved particles.
    """
    gather = len(ancestors) > 0
    for i in range(len(cos_h)):
        source = ancestors[i] if gather else i
        out[i, 0] = positions[source, 0] + cos_h[i] * speed
        out[i, 1] = positions[source, 1] + sin_h[i] * speed


@jit(inline=True)
def _nearest_squared(px, py, scale, offset, nx, ny, kind, row, first, all_x, all_y):  # pragma: no cover
    """(squared distance from (px, py) to its nearest station, whether it is free): the point's lookup
    cell, its first candidate, or all its candidates in an ambiguous cell (mazelab.lookup's
    NearestStationLookup.locate, per point); (-1, False) for a point beyond the table."""
    ix = np.floor(px * scale) + offset  # float32, exact: the scale is a power of two
    iy = np.floor(py * scale) + offset
    if not (ix >= 0 and iy >= 0 and ix < nx and iy < ny):
        return F32(-1.0), False
    cell = int(iy) * nx + int(ix)
    k = kind[cell]
    if k & _AMBIGUOUS:
        r = row[cell]
        dx = all_x[0, r] - px
        dy = all_y[0, r] - py
        best = dx * dx + dy * dy
        for c in range(1, all_x.shape[0]):
            dx = all_x[c, r] - px
            dy = all_y[c, r] - py
            d2 = dx * dx + dy * dy
            if d2 < best:
                best = d2
    else:
        dx = first[cell, 0] - px
        dy = first[cell, 1] - py
        best = dx * dx + dy * dy
    return best, (k & _FREE) != 0


@jit
def _beyond_squared(px, py, border):  # pragma: no cover - compiled
    """Squared distance from a point beyond the table to the nearest of the border cells' candidates
    (b, 2): brute force, for the rare particle that drifted off the map (a call of its own, from the
    caller's loop: inlined into _nearest_squared, it slowed the common path five times)."""
    dx = border[0, 0] - px
    dy = border[0, 1] - py
    best = dx * dx + dy * dy
    for b in range(1, border.shape[0]):
        dx = border[b, 0] - px
        dy = border[b, 1] - py
        d2 = dx * dx + dy * dy
        if d2 < best:
            best = d2
    return best


@jit
def log_likelihood(positions, z, sigma, free_term, outside_term, tables, out):  # pragma: no cover - compiled
    """Equation (3) with the outside penalty, in logs, for R runs: out[i] = log p(z_r | x_i), float32.

    Parameters
    ----------
    positions : float32 array (R*N, 2)
    z : float32 array (R,)
        z_k of each run (map units).
    sigma : float32
        The measurement noise's standard deviation.
    free_term, outside_term : float32
        -log(sigma sqrt(2 pi)), and that plus log(outside penalty): the constant of a free and of an
        outside point.
    tables : tuple
        The maze's lookup tables (mazelab.kernels.compiled.lookup_tables).
    out : float32 array (R*N,)
    """
    scale, offset, nx, ny, kind, row, first, all_x, all_y, border = tables
    runs = len(z)
    size = positions.shape[0] // runs
    minus_half = F32(-0.5)
    for r in range(runs):
        zr = z[r]
        for m in range(size):
            i = r * size + m
            px, py = positions[i, 0], positions[i, 1]
            d2, free = _nearest_squared(px, py, scale, offset, nx, ny, kind, row, first, all_x, all_y)
            if d2 < 0:  # beyond the table
                d2 = _beyond_squared(px, py, border)
            residual = (np.sqrt(d2) - zr) / sigma
            log_p = residual * residual * minus_half
            out[i] = log_p + (free_term if free else outside_term)


@jit(threads=True)
def log_likelihood_threads(positions, z, sigma, free_term, outside_term, tables, out):  # pragma: no cover
    """log_likelihood's values to the bit (its arguments), the particles spread over numba's threads."""
    scale, offset, nx, ny, kind, row, first, all_x, all_y, border = tables
    runs = len(z)
    size = positions.shape[0] // runs
    minus_half = F32(-0.5)
    for r in range(runs):
        zr = z[r]
        for m in prange(size):
            i = r * size + m
            px, py = positions[i, 0], positions[i, 1]
            d2, free = _nearest_squared(px, py, scale, offset, nx, ny, kind, row, first, all_x, all_y)
            if d2 < 0:  # beyond the table
                d2 = _beyond_squared(px, py, border)
            residual = (np.sqrt(d2) - zr) / sigma
            log_p = residual * residual * minus_half
            out[i] = log_p + (free_term if free else outside_term)


@jit
def jitter(positions, headings, ancestors, eps, scales, out, out_headings):  # pragma: no cover - compiled
    """The RPF's kernel K_h for R runs: out[i] = positions[a_i] + h D_r eps_i, D_r lower triangular.

    Parameters
    ----------
    positions : float32 array (P, 2)
    headings : float32 array (P,)
    ancestors : int array (R*M,)
        The resampled rows of `positions`.
    eps : float32 array (R*M, 2)
        Standard normal draws, block r run r's.
    scales : float32 array (R, 3)
        (a, c, d) of each run's h D = [[a, 0], [c, d]].
    out : float32 array (R*M, 2)
    out_headings : float32 array (R*M,)
        The ancestors' headings.
    """
    runs = scales.shape[0]
    size = len(ancestors) // runs
    for r in range(runs):
        a, c, d = scales[r, 0], scales[r, 1], scales[r, 2]
        for m in range(size):
            i = r * size + m
            source = ancestors[i]
            e0 = eps[i, 0]
            out[i, 0] = positions[source, 0] + a * e0
            out[i, 1] = positions[source, 1] + (c * e0 + d * eps[i, 1])
            out_headings[i] = headings[source]


__all__ = ["jitter", "log_likelihood", "log_likelihood_threads", "step"]
