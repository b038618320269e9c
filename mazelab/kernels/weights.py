"""The weights and the weighted reads, compiled (mazelab.weights is the numpy reference).

`normalise` turns R runs' log weights into their log totals and normalised weights W (float32: every
sum over them runs in float64), and reads what a step reports, in three passes over each run: the top
(max log w), then w = exp(log w - top) and the sums of the weights, their squares and the weighted
positions (the total, the ESS, the mean), then W = w / total and the weight within the green circle
around the mean. log W = log w - log total is left to the Weights value, which derives it when read.
`first_stage` is the APF's: W proportional to exp(log a - shift + log b) and the log of their sum;
`reweighted` makes log W_{k-1} + log p(z | x) of a step that does not resample, `second_stage` the APF's
second-stage log weights, both float32 as the likelihood (log W_{k-1} worked out from log w and its
total per particle, never stored). float32 W and log w hold a million particles' weights in the
memory the fused kernel takes (benchmarks/peak_memory.py); they round a weight by at most 6e-8 of it.

The exponential is float32 (vector_math.exp32, branch-free, so that the passes vectorise): one ulp,
and x = log w - top rounded to float32 (half an ulp of x), so w within 1.2e-7 + 6e-8 |x| of numpy's
float64 exp relative to its value (6e-7 for the weights above exp(-8) of the top), 0 below exp(-87) of
the top (a weight under 1e-38 of the heaviest one, never drawn); the sums and the totals are float64.
Sums run in LANES partial sums in
an order this code fixes, not the compiler (numpy's are pairwise, so the two paths agree to rounding,
not to the bit); an order the compiler chose by the arrays' addresses made a run's sums, and so R runs
against R single runs, differ in the last bit from process to process. LANES is 16 because numba's
loop vectoriser takes a loop of 16 and more (one of 8 it unrolls, and numba leaves the SLP vectoriser
off): the lanes are one vector of float64 partial sums each.

A run whose log weights are all -inf (no particle explains z) or hold a NaN gets the total -inf or NaN
and NaN weights, as in the numpy path; the filter then restarts it.
"""

from __future__ import annotations

import math

import numpy as np

from mazelab.kernels import jit
from mazelab.kernels.vector_math import exp32

LANES = 16  # partial sums each sum keeps: their order is this code's, not the compiler's
CHUNK = 1024  # exponentials worked out at a time (a float32 array the passes' loops read)
_F32 = np.float32


@jit(inline=True)
def _lane_total(lanes, k):  # pragma: no cover - compiled
    """The LANES partial sums of row k, added in a fixed order (pairwise)."""
    width = LANES
    while width > 1:
        width //= 2
        for j in range(width):
            lanes[k, j] += lanes[k, j + width]
    return lanes[k, 0]


@jit(inline=True)
def _top(values):  # pragma: no cover - compiled
    """max of the 1-D `values` in their dtype (-inf for none) from LANES running maxima; a NaN is
    passed over here (its exponential makes the run's total NaN: `normalise` checks the total)."""
    maxima = np.full(LANES, -np.inf, dtype=values.dtype)
    size = len(values)
    full = size // LANES * LANES
    for chunk in range(0, full, LANES):
        for j in range(LANES):
            maxima[j] = max(values[chunk + j], maxima[j])
    top = maxima[0]
    for j in range(1, LANES):
        top = max(maxima[j], top)
    for i in range(full, size):
        top = max(values[i], top)
    return top


@jit(inline=True)
def _exponentials(log_w, top, out):  # pragma: no cover - compiled
    """out[i] = exp32(log w_i - top) for the 1-D `log_w` (the difference in log w's dtype, then float32)."""
    for i in range(len(log_w)):
        out[i] = exp32(np.float32(log_w[i] - top))


@jit(inline=True)
def _add_moments(w, xs, ys, lanes):  # pragma: no cover - compiled
    """lanes[:4, i % LANES] += w_i, w_i^2, w_i x_i, w_i y_i for each i, in order (float64)."""
    full = len(w) // LANES * LANES
    for block in range(0, full, LANES):
        for j in range(LANES):
            weight = np.float64(w[block + j])
            lanes[0, j] += weight
            lanes[1, j] += weight * weight
            lanes[2, j] += weight * xs[block + j]
            lanes[3, j] += weight * ys[block + j]
    for i in range(full, len(w)):
        weight = np.float64(w[i])
        lanes[0, i - full] += weight
        lanes[1, i - full] += weight * weight
        lanes[2, i - full] += weight * xs[i]
        lanes[3, i - full] += weight * ys[i]


@jit(inline=True)
def _add_sum(w, lanes):  # pragma: no cover - compiled
    """lanes[0, i % LANES] += w_i for each i, in order (float64)."""
    full = len(w) // LANES * LANES
    for block in range(0, full, LANES):
        for j in range(LANES):
            lanes[0, j] += np.float64(w[block + j])
    for i in range(full, len(w)):
        lanes[0, i - full] += np.float64(w[i])


@jit(inline=True)
def _scale_and_keep_within(w, inverse, out, xs, ys, centre, r2):  # pragma: no cover - compiled
    """out[i] = w_i * inverse (float64), then w_i kept where particle i lies within sqrt(r2) of the
    centre (float32 distances) and 0 elsewhere (a select the loop vectorises: no branch, no sum)."""
    for i in range(len(w)):
        weight = w[i]
        out[i] = np.float64(weight) * inverse
        dx = xs[i] - centre[0]
        dy = ys[i] - centre[1]
        w[i] = weight if dx * dx + dy * dy <= r2 else np.float32(0.0)


@jit(inline=True)
def _first_pass(log_w, top, xs, ys, lanes, chunk):  # pragma: no cover - compiled
    """(sum w, sum w^2, sum w x, sum w y) over the 1-D log weights `log_w` and their particles' xs and
    ys, w_i = exp(log w_i - top), in LANES partial sums each: particle i goes to lane i % LANES, so the
    sums' order is fixed by this code and not by how the compiler vectorises the loop (or by the
    addresses). The exponentials go through `chunk` (float32, a multiple of LANES long) and each loop
    indexes from 0, so that it vectorises."""
    lanes[:4, :] = 0.0
    size, step = len(log_w), len(chunk)
    for first in range(0, size, step):
        stop = min(first + step, size)
        part = chunk[: stop - first]
        _exponentials(log_w[first:stop], top, part)
        _add_moments(part, xs[first:stop], ys[first:stop], lanes)
    return _lane_total(lanes, 0), _lane_total(lanes, 1), _lane_total(lanes, 2), _lane_total(lanes, 3)


@jit(inline=True)
def _second_pass(log_w, top, inverse, xs, ys, centre, r2, w, lanes, chunk):  # pragma: no cover - compiled
    """W_i = exp(log w_i - top) / total (inverse = 1 / total) of the 1-D `log_w`, written into `w`, and
    the weight within sqrt(r2) of the centre (float32 distances): the sum of those w_i in LANES partial
    sums, over the total."""
    lanes[0, :] = 0.0
    size, step = len(log_w), len(chunk)
    for first in range(0, size, step):
        stop = min(first + step, size)
        part, out = chunk[: stop - first], w[first:stop]
        _exponentials(log_w[first:stop], top, part)
        _scale_and_keep_within(part, inverse, out, xs[first:stop], ys[first:stop], centre, r2)
        _add_sum(part, lanes)
    return _lane_total(lanes, 0) * inverse


@jit(inline=True)
def _failed_total(values, top):  # pragma: no cover - compiled
    """The log total of a run that cannot be normalised (top -inf or +inf, or a NaN among the values):
    NaN where a value is NaN, else the top (numpy's log_sum_exp)."""
    return np.nan if np.isnan(values).any() else top


@jit(inline=True)
def _unnormalisable(r, row, top, w, reads):  # pragma: no cover - compiled
    """NaN weights and reads for run r, whose weights are all 0 or hold a NaN (the filter
    restarts it); its total is -inf where every log weight is -inf, else NaN (as numpy's)."""
    reads[0, r] = _failed_total(row, top)
    reads[1, r] = reads[2, r] = reads[3, r] = reads[4, r] = np.nan
    w[r, :] = np.nan


@jit
def normalise(log_w, positions, radius, w, reads):  # pragma: no cover
    """Normalise R runs' log weights and read each run's mean, ESS and confidence share, in three passes.

    Parameters
    ----------
    log_w : float32 or float64 array (R, N)
        Unnormalised log weights.
    positions : float32 array (R*N, 2)
        The particles (run r's the block r*N..(r+1)*N).
    radius : float
        The green circle's radius (map units).
    w : float64 array (R, N)
        W = w / sum(w), written.
    reads : float64 array (5, R)
        Written, one row each: log sum_j w_j; the mean sum_i W_i x_i (two rows, x and y); the ESS
        1 / sum_i W_i^2; the weight of the particles at most `radius` from the run's mean (float32
        distances, as mazelab.weights.mass_within). A run that cannot be normalised (top -inf or NaN)
        gets its top as total and NaN reads.
    """
    runs, size = log_w.shape
    r2 = np.float32(radius * radius)
    lanes, chunk = np.empty((4, LANES)), np.empty(CHUNK, dtype=np.float32)
    for r in range(runs):
        row, xs, ys = log_w[r], positions[r * size : (r + 1) * size, 0], positions[r * size : (r + 1) * size, 1]
        top = _top(row)
        sums = _first_pass(row, top, xs, ys, lanes, chunk) if abs(top) < np.inf else (np.nan, np.nan, np.nan, np.nan)
        total, squares, sum_x, sum_y = sums
        if total != total:  # every weight is 0, or a NaN: no normalisation (the filter restarts it)
            _unnormalisable(r, row, top, w, reads)
            continue
        log_total = top + math.log(total)
        mean_x, mean_y = sum_x / total, sum_y / total
        reads[0, r], reads[1, r], reads[2, r], reads[3, r] = log_total, mean_x, mean_y, total * total / squares
        centre = np.float32(mean_x), np.float32(mean_y)
        reads[4, r] = _second_pass(row, top, 1.0 / total, xs, ys, centre, r2, w[r], lanes, chunk)


@jit
def second_stage(log_lik, log_mu, ancestors, out):  # pragma: no cover - compiled
    """The APF's second-stage log weights of R runs: out[r, m] = log p(z_k | x_m) - log p(z_k | mu_{a_m}),
    the first stage's values gathered by run r's ancestors in the same pass (numpy's take_along_axis and
    subtract: the same float32 values).

    Parameters
    ----------
    log_lik : float32 array (R, M)
    log_mu : float32 array (R, N)
    ancestors : int array (R, M)
        Indices into each run's own particles.
    out : float32 array (R, M)
    """
    runs, size = log_lik.shape
    for r in range(runs):
        for m in range(size):
            out[r, m] = log_lik[r, m] - log_mu[r, ancestors[r, m]]


@jit
def reweighted(log_a, shifts, log_lik, out):  # pragma: no cover - compiled
    """log w_k = log W_{k-1} + log p(z_k | x_k) of R runs that do not resample, float32 as the likelihood:
    out[r, i] = (log_a[r, i] - shifts[r]) + log_lik[r, i], the sum in float64, then rounded (log W_{k-1}
    = log a - shift, the Weights value's derivation, never stored); `out` may be `log_lik` itself.

    Parameters
    ----------
    log_a : float array (R, N)
    shifts : float64 array (R,)
    log_lik : float32 array (R, N)
    out : float32 array (R, N)
    """
    runs, size = log_lik.shape
    for r in range(runs):
        shift = shifts[r]
        for i in range(size):
            out[r, i] = np.float32((np.float64(log_a[r, i]) - shift) + np.float64(log_lik[r, i]))


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


__all__ = [
    "covariance",
    "mass_within",
    "normalise",
    "reweighted",
    "second_stage",
]
