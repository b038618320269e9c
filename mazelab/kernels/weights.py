"""The weights and the weighted reads, compiled (mazelab.weights is the numpy reference).

`normalise` turns R runs' log weights into their log totals and normalised weights, and reads what a
step reports, in two passes over each run: the first takes w = exp(log w - max)
(mazelab.kernels.vector_math: vectorised, about 1e-15 from numpy's) and sums the weights, their squares
and the weighted positions (the total, the ESS, the mean); the second writes W (and log W = log w - log
total for a filter that reads it) and sums the weight within the green circle around the mean.
`first_stage` is the APF's: W proportional to exp(log a + log b) and the log of their sum. Sums are
float64 in LANES partial sums in an order this code fixes, not the compiler (numpy's are pairwise, so
the two paths agree to rounding, not to the bit); an order the compiler chose by the arrays' addresses
made a run's sums, and so R runs against R single runs, differ in the last bit from process to process.
A run whose log weights are all -inf (no particle explains z) or hold a NaN gets the total -inf or NaN
and NaN weights, as in the numpy path; the filter then restarts it.
"""

from __future__ import annotations

import math

import numpy as np
from numba import prange

from mazelab.kernels import jit
from mazelab.kernels.vector_math import exp

LANES = 8  # partial sums each sum keeps: their order is this code's, not the compiler's


@jit(inline=True)
def _lane_total(lanes, k):  # pragma: no cover - compiled
    """The LANES partial sums of row k, added in a fixed order (pairwise)."""
    return ((lanes[k, 0] + lanes[k, 1]) + (lanes[k, 2] + lanes[k, 3])) + (
        (lanes[k, 4] + lanes[k, 5]) + (lanes[k, 6] + lanes[k, 7])
    )


@jit(inline=True)
def _first_pass(log_w, r, top, positions, block, start, stop, w, lanes):  # pragma: no cover - compiled
    """w_i = exp(log w_i - top) for i in [start, stop) of run r, written, and (sum w, sum w^2, sum w x,
    sum w y) in LANES partial sums each: particle i goes to lane (i - start) % LANES, so the sums'
    order is fixed by this code and not by how the compiler vectorises the loop (or by the addresses)."""
    for i in range(start, stop):
        w[r, i] = exp(log_w[r, i] - top)
    lanes[:] = 0.0
    full = start + (stop - start) // LANES * LANES
    for chunk in range(start, full, LANES):
        for j in range(LANES):
            weight = w[r, chunk + j]
            lanes[0, j] += weight
            lanes[1, j] += weight * weight
            lanes[2, j] += weight * positions[block + chunk + j, 0]
            lanes[3, j] += weight * positions[block + chunk + j, 1]
    for i in range(full, stop):
        weight = w[r, i]
        lanes[0, i - full] += weight
        lanes[1, i - full] += weight * weight
        lanes[2, i - full] += weight * positions[block + i, 0]
        lanes[3, i - full] += weight * positions[block + i, 1]
    return _lane_total(lanes, 0), _lane_total(lanes, 1), _lane_total(lanes, 2), _lane_total(lanes, 3)


@jit(inline=True)
def _second_pass(
    log_w, r, log_total, inverse, positions, block, span, centre, r2, w, log_out, lanes
):  # pragma: no cover
    """W_i = w_i / total (and log W_i when log_out is an array) for i in span = (start, stop) of run r,
    written, then the weight within sqrt(r2) of the centre (float32 distances) in LANES partial sums."""
    start, stop = span
    for i in range(start, stop):
        if log_out is not None:
            log_out[r, i] = log_w[r, i] - log_total
        w[r, i] *= inverse
    lanes[0, :] = 0.0
    full = start + (stop - start) // LANES * LANES
    for chunk in range(start, full, LANES):
        for j in range(LANES):
            dx = positions[block + chunk + j, 0] - centre[0]
            dy = positions[block + chunk + j, 1] - centre[1]
            lanes[0, j] += w[r, chunk + j] if dx * dx + dy * dy <= r2 else 0.0
    for i in range(full, stop):
        dx = positions[block + i, 0] - centre[0]
        dy = positions[block + i, 1] - centre[1]
        lanes[0, i - full] += w[r, i] if dx * dx + dy * dy <= r2 else 0.0
    return _lane_total(lanes, 0)


@jit
def normalise(log_w, tops, positions, radius, w, log_out, totals, means, ess, shares):  # pragma: no cover
    """Normalise R runs' log weights and read each run's mean, ESS and confidence share, in two passes.

    Parameters
    ----------
    log_w : float array (R, N)
        Unnormalised log weights.
    tops : float array (R,)
        max_i log_w of each run; -inf or NaN for a run that cannot be normalised (its rows become NaN).
    positions : float32 array (R*N, 2)
        The particles (run r's the block r*N..(r+1)*N).
    radius : float
        The green circle's radius (map units).
    w : float64 array (R, N)
        W = w / sum(w), written.
    log_out : float64 array (R, N), or None
        log W_i = log w_i - log sum_j w_j, written; None: not written (a filter that reads W only; numba
        compiles each case apart, so the array's case is the kernel it always was).
    totals : float64 array (R,)
        log sum_j w_j of each run.
    means : float64 array (R, 2)
        sum_i W_i x_i.
    ess : float64 array (R,)
        1 / sum_i W_i^2.
    shares : float64 array (R,)
        The weight of the particles at most `radius` from the run's mean (float32 distances, as
        mazelab.weights.mass_within).
    """
    runs, size = log_w.shape
    r2 = np.float32(radius * radius)
    lanes = np.empty((4, LANES))
    for r in range(runs):
        top = np.float64(tops[r])
        block = r * size
        if not (top > -np.inf):  # every weight is 0, or a NaN: no normalisation (the filter restarts it)
            totals[r] = top
            for i in range(size):
                w[r, i] = np.nan
                if log_out is not None:
                    log_out[r, i] = np.nan
            means[r, 0] = means[r, 1] = ess[r] = shares[r] = np.nan
            continue
        sums = _first_pass(log_w, r, top, positions, block, 0, size, w, lanes)
        total, squares, sum_x, sum_y = sums[0], sums[1], sums[2], sums[3]
        log_total = top + math.log(total)
        totals[r] = log_total
        mean_x, mean_y = sum_x / total, sum_y / total
        means[r, 0], means[r, 1] = mean_x, mean_y
        ess[r] = total * total / squares
        centre = np.float32(mean_x), np.float32(mean_y)
        span, inverse = (0, size), 1.0 / total
        shares[r] = _second_pass(log_w, r, log_total, inverse, positions, block, span, centre, r2, w, log_out, lanes)


BLOCK = 1 << 15  # particles per block of normalise_threads' sums: their order depends on it alone


@jit(threads=True)
def normalise_threads(log_w, tops, positions, radius, w, log_out, totals, means, ess, shares):  # pragma: no cover
    """normalise's results (its arguments) with the particles in blocks of BLOCK spread over numba's
    threads: each block's sums, then the runs' in block order, so the numbers depend on BLOCK, not on
    the thread count (they agree with normalise's to rounding)."""
    runs, size = log_w.shape
    blocks = (size + BLOCK - 1) // BLOCK
    partial = np.zeros((runs * blocks, 5))
    for job in prange(runs * blocks):
        r, b = job // blocks, job % blocks
        top = np.float64(tops[r])
        start, stop = b * BLOCK, min(size, (b + 1) * BLOCK)
        if not (top > -np.inf):  # the run cannot be normalised: NaN weights (the filter restarts it)
            for i in range(start, stop):
                w[r, i] = np.nan
                if log_out is not None:
                    log_out[r, i] = np.nan
            continue
        block_sums = _first_pass(log_w, r, top, positions, r * size, start, stop, w, np.empty((4, LANES)))
        partial[job, 0], partial[job, 1], partial[job, 2], partial[job, 3] = block_sums
    sums = np.zeros((runs, 4))
    for r in range(runs):
        for b in range(blocks):
            for k in range(4):
                sums[r, k] += partial[r * blocks + b, k]
        top = np.float64(tops[r])
        if not (top > -np.inf):
            totals[r] = top
            means[r, 0] = means[r, 1] = ess[r] = shares[r] = np.nan
            continue
        totals[r] = top + math.log(sums[r, 0])
        means[r, 0], means[r, 1] = sums[r, 2] / sums[r, 0], sums[r, 3] / sums[r, 0]
        ess[r] = sums[r, 0] * sums[r, 0] / sums[r, 1]
    r2 = np.float32(radius * radius)
    for job in prange(runs * blocks):
        r, b = job // blocks, job % blocks
        if not (tops[r] > -np.inf):
            continue
        log_total, inverse = totals[r], 1.0 / sums[r, 0]
        centre = np.float32(means[r, 0]), np.float32(means[r, 1])
        span, lanes, first = (b * BLOCK, min(size, (b + 1) * BLOCK)), np.empty((4, LANES)), r * size
        partial[job, 4] = _second_pass(
            log_w, r, log_total, inverse, positions, first, span, centre, r2, w, log_out, lanes
        )
    for r in range(runs):
        if tops[r] > -np.inf:
            shares[r] = 0.0
            for b in range(blocks):
                shares[r] += partial[r * blocks + b, 4]


@jit
def first_stage(log_a, log_b, w, totals):  # pragma: no cover - compiled
    """The APF's first-stage weights of R runs: W proportional to exp(log a + log b), and log sum exp(log a
    + log b) (mazelab.weights' log_sum_exp and weights_from_logs, one exponential per particle; the total
    in LANES partial sums).

    Parameters
    ----------
    log_a, log_b : float arrays (R, N)
        A run whose sums are all -inf, or hold a NaN, gets NaN weights and the total -inf or NaN.
    w : float64 array (R, N)
        Written: the normalised weights.
    totals : float64 array (R,)
        Written: the log totals.
    """
    runs, size = log_a.shape
    lanes = np.empty((1, LANES))
    for r in range(runs):
        top = -np.inf
        invalid = False
        for i in range(size):
            value = log_a[r, i] + log_b[r, i]
            invalid |= value != value
            top = value if value > top else top
        if invalid:
            top = np.nan
        if not (top > -np.inf):
            totals[r] = top
            for i in range(size):
                w[r, i] = np.nan
            continue
        for i in range(size):
            w[r, i] = exp(log_a[r, i] + log_b[r, i] - top)
        lanes[0, :] = 0.0
        full = size // LANES * LANES
        for chunk in range(0, full, LANES):
            for j in range(LANES):
                lanes[0, j] += w[r, chunk + j]
        for i in range(full, size):
            lanes[0, i - full] += w[r, i]
        total = _lane_total(lanes, 0)
        inverse = 1.0 / total
        for i in range(size):
            w[r, i] *= inverse
        totals[r] = top + math.log(total)


@jit
def mass_within(weights, positions, centres, radius, shares):  # pragma: no cover - compiled
    """The weight within `radius` of each run's centre (mazelab.weights.mass_within, float32 distances).

    Parameters
    ----------
    weights : float array (R, N)
    positions : float32 array (R*N, 2)
    centres : float64 array (R, 2)
    radius : float
    shares : float64 array (R,)
        Written: each run's weight within the circle.
    """
    runs, size = weights.shape
    r2 = np.float32(radius * radius)
    for r in range(runs):
        block = r * size
        centre_x, centre_y = np.float32(centres[r, 0]), np.float32(centres[r, 1])
        inside = 0.0
        for i in range(size):
            dx = positions[block + i, 0] - centre_x
            dy = positions[block + i, 1] - centre_y
            if dx * dx + dy * dy <= r2:
                inside += weights[r, i]
        shares[r] = inside


@jit
def covariance(weights, positions, out):  # pragma: no cover - compiled
    """sum_i W_i (x_i - mean)(x_i - mean)^T of R runs (mazelab.weights.weighted_covariance), the mean
    first (float64 deviations: the spread may be tiny).

    Parameters
    ----------
    weights : float array (R, N)
    positions : float32 array (R*N, 2)
    out : float64 array (R, 2, 2)
        Written: each run's covariance.
    """
    runs, size = weights.shape
    for r in range(runs):
        block = r * size
        sum_x = sum_y = 0.0
        for i in range(size):
            sum_x += weights[r, i] * positions[block + i, 0]
            sum_y += weights[r, i] * positions[block + i, 1]
        xx = xy = yy = 0.0
        for i in range(size):
            w = weights[r, i]
            dx = positions[block + i, 0] - sum_x
            dy = positions[block + i, 1] - sum_y
            xx += w * dx * dx
            xy += w * dx * dy
            yy += w * dy * dy
        out[r, 0, 0], out[r, 0, 1], out[r, 1, 0], out[r, 1, 1] = xx, xy, xy, yy


__all__ = ["BLOCK", "covariance", "first_stage", "mass_within", "normalise", "normalise_threads"]
