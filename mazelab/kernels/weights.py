"""The weights and the weighted reads, compiled (mazelab.weights is the numpy reference).

`normalise` turns R runs' weights exp(log w - max) (numpy's vectorised exp makes them) into normalised
log weights and weights, and reads what a step reports, in two passes: the first sums the weights,
their squares and the weighted positions (the total, the ESS, the mean); the second writes
log W = log w - log total and W, and sums the weight within the green circle around the mean. Sums
are float64, in order (numpy's are pairwise, so the two paths agree to rounding, not to the bit). A run
whose log weights are all -inf (no particle explains z) or hold a NaN gets the total -inf or NaN and
NaN weights, as in the numpy path; the filter then restarts it.
"""

from __future__ import annotations

import math

import numpy as np

from mazelab.kernels import jit


@jit
def normalise(log_w, w, tops, positions, radius, log_out, totals, means, ess, shares):  # pragma: no cover
    """Normalise R runs' log weights and read each run's mean, ESS and confidence share, in two passes.

    Parameters
    ----------
    log_w : float array (R, N)
        Unnormalised log weights.
    w : float64 array (R, N)
        exp(log_w - top) on entry (numpy's vectorised exp), W = w / sum(w) on return.
    tops : float64 array (R,)
        max_i log_w of each run; -inf or NaN for a run that cannot be normalised (its rows become NaN).
    positions : float32 array (R*N, 2)
        The particles (run r's the block r*N..(r+1)*N).
    radius : float
        The green circle's radius (map units).
    log_out : float64 array (R, N)
        log W_i = log w_i - log sum_j w_j.
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
    for r in range(runs):
        top = tops[r]
        block = r * size
        if not (top > -np.inf):  # every weight is 0, or a NaN: no normalisation (the filter restarts it)
            totals[r] = top
            for i in range(size):
                log_out[r, i] = w[r, i] = np.nan
            means[r, 0] = means[r, 1] = ess[r] = shares[r] = np.nan
            continue
        total = squares = sum_x = sum_y = 0.0
        for i in range(size):
            weight = w[r, i]
            total += weight
            squares += weight * weight
            sum_x += weight * positions[block + i, 0]
            sum_y += weight * positions[block + i, 1]
        log_total = top + math.log(total)
        totals[r] = log_total
        mean_x, mean_y = sum_x / total, sum_y / total
        means[r, 0], means[r, 1] = mean_x, mean_y
        ess[r] = total * total / squares
        centre_x, centre_y = np.float32(mean_x), np.float32(mean_y)
        inverse = 1.0 / total
        inside = 0.0
        for i in range(size):
            log_out[r, i] = log_w[r, i] - log_total
            weight = w[r, i] * inverse
            w[r, i] = weight
            dx = positions[block + i, 0] - centre_x
            dy = positions[block + i, 1] - centre_y
            if dx * dx + dy * dy <= r2:
                inside += weight
        shares[r] = inside


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


__all__ = ["covariance", "mass_within", "normalise"]
