"""Weighted particles: the Weights value, log-domain normalisation, the effective sample size and
weighted summaries. Numpy only (the engine and the exercise's sandbox import it)."""

from __future__ import annotations

import math
from functools import cached_property

import numpy as np

from mazelab.constants import LOG_UNDERFLOW


class Weights:
    """The weights of R runs as a value (nchopin/particles' resampling.Weights, one row per run): the
    normalised log weights, W and the ESS derived when read, every array read-only. The numpy backend's;
    the compiled one's (mazelab.kernels.compiled.CompiledWeights) keeps W in float32 and reads the
    step's mean and confidence in its normalisation's passes.

    Parameters
    ----------
    lw : array (R, N)
        log W_i of each run, normalised (each row's exp sums to 1).
    log_total : array (R,), optional
        log sum_i w_i of the log weights they were normalised from (`from_log`): for `add`, the log of
        the mean increment sum_i W_{k-1}^i G_k^i, the estimate of log p(z_k | z_1:k-1) (particles' loglt).
    """

    def __init__(self, lw: np.ndarray, log_total: np.ndarray | None = None):
        self.lw = read_only(lw)
        self.log_total = read_only(np.zeros(len(lw)) if log_total is None else log_total)

    @classmethod
    def from_log(cls, log_w: np.ndarray, x: np.ndarray | None = None) -> Weights:
        """Each row of log w normalised: log W = log w - log sum exp(log w), in float64 (the sums in log
        w's dtype).

        Parameters
        ----------
        log_w : array (R, N)
        x : array (R, N, 2), optional
            The particles they weigh (the compiled backend's reads; unused here).

        Returns
        -------
        Weights
        """
        totals = np.atleast_1d(log_sum_exp(log_w))
        lw = log_w.astype(float)  # a float64 copy, then in place: no buffered cast against a broadcast row
        with np.errstate(invalid="ignore"):  # a lost run (every log w -inf) gets NaN: the engine restarts it
            lw -= totals[:, None]
        return cls(lw, totals)

    @classmethod
    def uniform(cls, runs: int, count: int) -> Weights:
        """W_i = 1/N in each of R runs, as a filter starts: log W = -log N, one number broadcast (R, N)."""
        return cls(np.broadcast_to(-math.log(count), (runs, count)))

    def add(self, log_g: np.ndarray, x: np.ndarray | None = None) -> Weights:
        """W_i G_i normalised per run (log W + log G): the reweighting of a step that does not resample,
        and the APF's first stage; its `log_total` is log sum_i W_i G_i.

        Parameters
        ----------
        log_g : array (R, N)
        x : array (R, N, 2), optional
            The particles (the compiled backend's reads).

        Returns
        -------
        Weights
        """
        return self.from_log(self.lw + log_g, x)

    def reset(self, rows: np.ndarray, other: Weights, x: np.ndarray | None = None) -> Weights:
        """These weights with the given rows replaced by `other`'s (one row each, in order).

        Parameters
        ----------
        rows : bool array (R,)
        other : Weights of rows.sum() runs
        x : array (R, N, 2), optional
            The particles (the compiled backend's reads).

        Returns
        -------
        Weights
        """
        if not rows.any():
            return self
        lw, totals = self.lw.copy(), self.log_total.copy()
        lw[rows], totals[rows] = other.lw, other.log_total
        return type(self)(lw, totals)

    @cached_property
    def lost(self) -> np.ndarray:
        """The runs whose log total underflows (nothing explains the data): bool (R,)."""
        return ~(self.log_total >= LOG_UNDERFLOW)

    @cached_property
    def W(self) -> np.ndarray:  # noqa: N802 (the paper's W, as particles names it)
        """W_i = exp(log W_i), (R, N)."""
        return read_only(np.exp(self.lw))

    @cached_property
    def ess(self) -> np.ndarray:
        """N_eff = 1 / sum_i W_i^2 per run (eq. 51), (R,)."""
        return read_only(effective_sample_size(self.W))


def read_only(values: np.ndarray) -> np.ndarray:
    """`values` with writing switched off (a value's arrays cannot change under its readers)."""
    if values.flags.writeable:
        values.flags.writeable = False
    return values


# -- weights: each function takes one run's weights (N,) or R runs' (R, N), summing along the last axis
def log_sum_exp(log_w: np.ndarray) -> float | np.ndarray:
    """log(sum(exp(log_w))) along the last axis without overflow or underflow; -inf where every entry
    is -inf.

    Parameters
    ----------
    log_w : array (N,) or (R, N)
        Log weights of one run or of R runs.

    Returns
    -------
    float for one run, float64 array (R,) for R runs
    """
    top = log_w.max(axis=-1, keepdims=True)  # the array methods skip np.max's dispatch: a few us a call
    finite = np.isfinite(top[..., 0])
    if finite.all():
        shifted = np.subtract(log_w, top)
        totals = top[..., 0] + np.log(np.exp(shifted, out=shifted).sum(axis=-1))
    else:
        with np.errstate(invalid="ignore"):  # rows whose top is -inf give NaN here and -inf below
            shifted = np.subtract(log_w, top)
            totals = top[..., 0] + np.log(np.exp(shifted, out=shifted).sum(axis=-1))
        totals = np.where(finite, totals, top[..., 0])
    return float(totals) if log_w.ndim == 1 else totals.astype(float)


def effective_sample_size(weights: np.ndarray) -> float | np.ndarray:
    """N_eff = 1 / sum(W_i^2) for normalised weights W (Arulampalam et al., eq. 51), per run.

    Parameters
    ----------
    weights : array (N,) or (R, N)
        Normalised weights.

    Returns
    -------
    float for one run, array (R,) for R runs
    """
    ess = 1.0 / (weights * weights).sum(axis=-1)
    return float(ess) if weights.ndim == 1 else ess


# -- weighted summaries: numpy's pairwise sums, not BLAS (threaded BLAS stalls on a busy machine) -----
# `points` (R*N, 2) hold R runs' particles in R blocks of N rows (one run: (N, 2)).
def _columns(points: np.ndarray, runs: int) -> tuple[np.ndarray, np.ndarray]:
    """The x and y columns of the points as (R, N) views."""
    return points[:, 0].reshape(runs, -1), points[:, 1].reshape(runs, -1)


def weighted_mean(weights: np.ndarray, points: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
    """sum_i W_i x_i per run, float64 (summed in the points' dtype).

    Parameters
    ----------
    weights : array (N,) or (R, N)
        Normalised weights.
    points : array (N, 2) or (R*N, 2)
        The particles, run r's in the block of rows r*N..(r+1)*N.
    out : array (R, N) of the points' dtype, optional
        Where the products are formed (the grid filter's workspace: no new pages per step); the same numbers.

    Returns
    -------
    float64 array (2,) for one run, (R, 2) for R runs
    """
    W = weights if weights.ndim > 1 else weights[None]
    w = W.astype(points.dtype, copy=False)
    means = np.empty((len(W), 2))
    for column, c in enumerate(_columns(points, len(W))):
        means[:, column] = np.multiply(w, c, out=out).sum(axis=1)  # summed in the points' dtype, then float64
    return means[0] if weights.ndim == 1 else means


def weighted_covariance(weights: np.ndarray, points: np.ndarray) -> np.ndarray:
    """sum_i W_i (x_i - mean)(x_i - mean)^T per run, float64: (2, 2) for one run, (R, 2, 2) for R runs (the
    weights and points as `weighted_mean` takes them)."""
    W = weights if weights.ndim > 1 else weights[None]
    mean = weighted_mean(W, points)
    x, y = _columns(points, len(W))
    dx, dy = x - mean[:, :1], y - mean[:, 1:]  # float64: the spread may be tiny
    xx, xy, yy = ((W * a * b).sum(axis=1) for a, b in ((dx, dx), (dx, dy), (dy, dy)))
    covariance = np.stack([np.stack([xx, xy], -1), np.stack([xy, yy], -1)], -2)
    return covariance[0] if weights.ndim == 1 else covariance


def mass_within(
    weights: np.ndarray, points: np.ndarray, centre: np.ndarray, radius: float, out: tuple | None = None
) -> float | np.ndarray:
    """The total weight of the points at most `radius` (map units) from `centre` ((2,), or (R, 2) per run),
    distances in the points' dtype: a float for one run, (R,) for R runs (the weights and points as
    `weighted_mean` takes them); `out`, two arrays of the points' dtype and a bool one, each (R, N), where
    the distances and the mask are formed (as `weighted_mean`'s)."""
    W = weights if weights.ndim > 1 else weights[None]
    c = (centre if centre.ndim > 1 else centre[None]).astype(points.dtype)
    x, y = _columns(points, len(W))
    dx, dy, inside = (None, None, None) if out is None else out
    dx, dy = np.subtract(x, c[:, :1], out=dx), np.subtract(y, c[:, 1:], out=dy)
    dx *= dx
    dy *= dy
    dx += dy
    mass = np.sum(W, axis=1, where=np.less_equal(dx, radius * radius, out=inside))
    return float(mass[0]) if weights.ndim == 1 else mass


__all__ = [
    "Weights",
    "effective_sample_size",
    "log_sum_exp",
    "mass_within",
    "read_only",
    "weighted_covariance",
    "weighted_mean",
]
