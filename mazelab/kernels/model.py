"""The model's equations, compiled (mazelab.model is the numpy reference; the paper's numbering):

    (1) the move: th = th0 + Delta (u - 1/2), then x_k = x_{k-1} + L (cos th, sin th), gathered from
        the resampled ancestors
    (3) the likelihood: log p(z_k | x_k) = -((d(x_k) - z_k) / sigma)^2 / 2 - log(sigma sqrt(2 pi)),
        plus log 0.5 outside the free area, d the distance to the nearest station (mazelab.lookup's table)
    the RPF's jitter: x^{i*} + h D eps, eps ~ N(0, I_2) (mazelab.regularisation)

Positions are (R*N, 2) float32 (run r's particles the rows r*N..(r+1)*N), written into buffers the
caller owns. The arithmetic is float32 as in the numpy path, operation for operation, so the
likelihood of given points, the jitter and the move's headings are the numpy path's to the bit. The
move's cos and sin are mazelab.kernels.vector_math's, within two ulps of numpy's (which are within
1.5 of the exact value, these within 0.502): the moved particles are the numpy path's or a float32
rounding from them, the price of a move in one vectorised call instead of numpy's cos and sin and
two kernels.
"""

from __future__ import annotations

import numpy as np

from mazelab.kernels import jit
from mazelab.kernels.vector_math import cos_sin

F32 = np.float32
_FREE, _MORE = 1, 2  # the low bits of a lookup cell's code (mazelab.kernels.compiled.lookup_tables)
_ZERO, _HALF, _MINUS_HALF = F32(0.0), F32(0.5), F32(-0.5)
# unsigned indices (numba checks a signed index for wrap-around at every load)
_X0, _Y0, _X1, _Y1 = np.uint64(0), np.uint64(1), np.uint64(2), np.uint64(3)
_NONE, _PAIR = np.uint64(0), np.uint64(2)


@jit
def _headings_cos_sin(uniforms, angle, delta, cos_h, sin_h):  # pragma: no cover - compiled
    """th = th0 + Delta (u - 1/2) in place of the uniforms (1-D), and cos th, sin th into cos_h, sin_h: a
    loop of its own, which the compiler vectorises (no gather in it, three arrays to check for overlap)."""
    for m in range(len(uniforms)):
        heading = (uniforms[m] - _HALF) * delta + angle
        uniforms[m] = heading
        cos_h[m], sin_h[m] = cos_sin(heading)


@jit
def move(positions, ancestors, uniforms, angles, delta, speed, out):  # pragma: no cover - compiled
    """Equation (1) for R runs in one call: th_i = th0_r + Delta (u_i - 1/2), then out[i] =
    positions[a_i] + speed (cos th_i, sin th_i).

    The headings are mazelab.model.headings_from_uniforms' float32 operations (its values to the
    bit); cos and sin are vector_math's, within 0.502 ulp of the exact value (numpy's float32 ones
    within 1.5; the two agree for about 85% of angles), so a moved particle is the numpy path's or a
    float32 rounding away from it. cos and sin go into `out` first, in a vectorised loop; the gather and
    the step follow.

    Parameters
    ----------
    positions : float32 array (P, 2), order F
        The particles moved from.
    ancestors : int array (R*M,)
        Row of `positions` each particle moves from; empty: particle i moves from row i.
    uniforms : float32 array (R, M)
        u ~ U[0, 1), overwritten by the headings (radians).
    angles : float32 array (R,)
        th0 of each run (radians).
    delta, speed : float
        Delta (radians) and the step length L (map units), rounded to float32 here (as numpy's float32
        arithmetic rounds them).
    out : float32 array (R*M, 2), order F
        The moved particles.
    """
    delta, speed = F32(delta), F32(speed)
    runs, size = uniforms.shape
    x, y = positions.T[0], positions.T[1]
    out_x, out_y = out.T[0], out.T[1]
    for r in range(runs):
        block = slice(r * size, (r + 1) * size)
        _headings_cos_sin(uniforms[r], angles[r], delta, out_x[block], out_y[block])
    if len(ancestors):
        for i in range(len(out_x)):
            source = ancestors[i]
            out_x[i] = x[source] + out_x[i] * speed
            out_y[i] = y[source] + out_y[i] * speed
    else:
        for i in range(len(out_x)):
            out_x[i] = x[i] + out_x[i] * speed
            out_y[i] = y[i] + out_y[i] * speed


@jit(inline=True)
def _typed(tables):  # pragma: no cover - compiled
    """lookup_tables' tuple with its numbers in the kernels' types: (scale, offset, nx, ny) float32, nx
    and the row width uint64 (plain Python numbers cross into a kernel faster than numpy scalars)."""
    scale, offset, nx, ny, codes, pairs, rows, width, border = tables
    return F32(scale), F32(offset), F32(nx), F32(ny), np.uint64(nx), codes, pairs, rows, np.uint64(width), border


@jit(inline=True)
def _log_likelihood_at(px, py, zr, sigma, free_term, outside_term, tables):  # pragma: no cover - compiled
    """(log p(z_r | x) for the point (px, py) from its lookup cell, whether the point is inside the
    table): numpy's locate and likelihood for one point, with no branch but a loop that runs for few.

    A point beyond the table reads cell 0 instead, by a select (it gets a wrong value and False: the
    caller redoes it; clamping its cell into the table measured 0.6 ns a particle slower). Every cell
    has two candidates (the second a repeat of the first in a cell with one), read in one load, and
    the nearer kept by a select; the cells with more than two (a few in a hundred) loop over the rest
    of their row, which their code names. The minimum is exact whatever the order, so the distance is
    numpy's to the bit. `tables` is _typed's."""
    scale, offset, nxf, nyf, nx, codes, pairs, rows, width, _ = tables
    fx = np.floor(px * scale) + offset  # float32, exact: the scale is a power of two
    fy = np.floor(py * scale) + offset
    inside = (fx >= _ZERO) & (fy >= _ZERO) & (fx < nxf) & (fy < nyf)  # False for NaN
    cell = np.uint64(fy) * nx + np.uint64(fx) if inside else _NONE  # the conversions' value unused beyond it
    code = codes[cell]
    dx = pairs[cell, _X0] - px
    dy = pairs[cell, _Y0] - py
    best = dx * dx + dy * dy
    dx = pairs[cell, _X1] - px
    dy = pairs[cell, _Y1] - py
    d2 = dx * dx + dy * dy
    best = d2 if d2 < best else best
    start = np.uint64(code >> 2)
    for c in range(start, start + (width if code & _MORE else _NONE), _PAIR):
        dx = rows[c] - px
        dy = rows[c + _Y0] - py
        d2 = dx * dx + dy * dy
        best = d2 if d2 < best else best
    residual = (np.sqrt(best) - zr) / sigma
    return residual * residual * _MINUS_HALF + (free_term if code & _FREE else outside_term), inside


@jit
def _beyond_the_table(positions, z, sigma, outside_term, tables, out):  # pragma: no cover - compiled
    """out[r, m] = log p(z_r | x_i) again for the points beyond the table (outside the free area), the
    distance to the nearest of the border cells' candidates by brute force: the rare particle that
    drifted off the map (a pass of its own, so that the common one has no branch on it). The numbers
    are log_likelihood's, typed."""
    scale, offset, nxf, nyf, _, _, _, _, _, border = tables
    runs, size = out.shape
    for r in range(runs):
        zr = F32(z[r])
        for m in range(size):
            px, py = positions[r * size + m, 0], positions[r * size + m, 1]
            fx = np.floor(px * scale) + offset
            fy = np.floor(py * scale) + offset
            if not ((fx >= _ZERO) & (fy >= _ZERO) & (fx < nxf) & (fy < nyf)):
                dx = border[0, 0] - px
                dy = border[0, 1] - py
                best = dx * dx + dy * dy
                for b in range(1, border.shape[0]):
                    dx = border[b, 0] - px
                    dy = border[b, 1] - py
                    d2 = dx * dx + dy * dy
                    best = d2 if d2 < best else best
                residual = (np.sqrt(best) - zr) / sigma
                out[r, m] = residual * residual * _MINUS_HALF + outside_term


@jit
def log_likelihood(positions, z, sigma, free_term, outside_term, tables, out):  # pragma: no cover - compiled
    """Equation (3) with the outside penalty, in logs, for R runs: out[r, m] = log p(z_r | x_i) (i = r N
    + m), float32, numpy's values to the bit (the same float32 operations, and the nearest of the same
    candidates). The numbers come as plain floats (a numpy scalar costs some 0.25 us to pass) and are
    rounded to float32 here, as numpy's float32 arithmetic rounds them.

    Parameters
    ----------
    positions : float32 array (R*N, 2)
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
    """
    sigma, free_term, outside_term, typed = F32(sigma), F32(free_term), F32(outside_term), _typed(tables)
    runs, size = out.shape
    beyond = 0
    for r in range(runs):
        zr = F32(z[r])
        for m in range(size):
            i = r * size + m
            value, inside = _log_likelihood_at(
                positions[i, 0], positions[i, 1], zr, sigma, free_term, outside_term, typed
            )
            out[r, m] = value
            beyond += 0 if inside else 1
    if beyond:
        _beyond_the_table(positions, z, sigma, outside_term, typed, out)


@jit
def jitter(positions, ancestors, eps, scales, out):  # pragma: no cover - compiled
    """The RPF's kernel K_h for R runs: out[i] = positions[a_i] + h D_r eps_i, D_r lower triangular.

    Parameters
    ----------
    positions : float32 array (P, 2)
    ancestors : int array (R*M,)
        The resampled rows of `positions`.
    eps : float32 array (R*M, 2)
        Standard normal draws, block r run r's.
    scales : float32 array (R, 3)
        (a, c, d) of each run's h D = [[a, 0], [c, d]].
    out : float32 array (R*M, 2)
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


__all__ = ["jitter", "log_likelihood", "move"]
