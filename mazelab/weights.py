"""Weighted particles: log-domain normalisation, the effective sample size and weighted summaries."""

from __future__ import annotations

import numpy as np


# -- weights ---------------------------------------------------------------------------------------
def log_sum_exp(log_w: np.ndarray) -> float:
    """log(sum(exp(log_w))) without overflow or underflow; -inf when every entry is -inf."""
    top = log_w.max()  # the array methods skip np.max's dispatch: a few us a call, which counts at small N
    if not np.isfinite(top):
        return float(top)
    shifted = np.subtract(log_w, top)
    return float(top + np.log(np.exp(shifted, out=shifted).sum()))


def exp_in_place(values: np.ndarray) -> np.ndarray:
    """exp(values), written over `values` (a temporary of the caller's): no second array."""
    return np.exp(values, out=values)


def normalise_log_weights(log_w: np.ndarray) -> np.ndarray:
    """Log weights shifted so that their exponentials sum to one."""
    return log_w - log_sum_exp(log_w)


def effective_sample_size(weights: np.ndarray) -> float:
    """N_eff = 1 / sum(W_i^2) for normalised weights W (Arulampalam et al., eq. 51)."""
    return float(1.0 / (weights * weights).sum())


# -- weighted summaries: numpy's pairwise sums, not BLAS (threaded BLAS stalls on a busy machine) -----
def weighted_mean(weights: np.ndarray, points: np.ndarray) -> np.ndarray:
    """sum_i W_i x_i for normalised weights (N,) and points (N, 2), as float64 (2,)."""
    w = weights.astype(points.dtype, copy=False)
    return np.array([(w * points[:, 0]).sum(), (w * points[:, 1]).sum()], dtype=float)


def weighted_covariance(weights: np.ndarray, points: np.ndarray) -> np.ndarray:
    """sum_i W_i (x_i - mean)(x_i - mean)^T, float64 (2, 2)."""
    mean = weighted_mean(weights, points)
    dx, dy = points[:, 0] - mean[0], points[:, 1] - mean[1]  # float64: the spread may be tiny
    xx, xy, yy = np.sum(weights * dx * dx), np.sum(weights * dx * dy), np.sum(weights * dy * dy)
    return np.array([[xx, xy], [xy, yy]])


def mass_within(weights: np.ndarray, points: np.ndarray, centre: np.ndarray, radius: float) -> float:
    """The total weight of the points (N, 2) at most `radius` from `centre`."""
    dx = points[:, 0] - points.dtype.type(centre[0])
    dy = points[:, 1] - points.dtype.type(centre[1])
    dx *= dx
    dy *= dy
    dx += dy
    return float(weights.sum(where=dx <= radius * radius))


__all__ = [
    "effective_sample_size",
    "exp_in_place",
    "log_sum_exp",
    "mass_within",
    "normalise_log_weights",
    "weighted_covariance",
    "weighted_mean",
]
