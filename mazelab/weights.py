"""Weighted particles: the Weights value, log-domain normalisation, the effective sample size and
weighted summaries. Numpy only (the engine and the exercise's sandbox import it)."""

from __future__ import annotations

import math
from functools import cached_property

import numpy as np


class Weights:
    """The weights of R runs as a value (nchopin/particles' resampling.Weights, one row per run): the
    normalised log weights in, W and the ESS derived once when asked, the log of the mean increment
    worked out as the value is made.

    Parameters
    ----------
    lw : array (R, N), or None
        log W_i of each run, normalised (each row's exp sums to 1); None: derived from `unnormalised`.
    W, ess : arrays (R, N) and (R,), optional
        exp(lw) and 1 / sum W^2 when the normalisation already read them (the compiled backend).
    unnormalised : (array (R, N), array (R,)), optional
        log w and log sum_i w_i of each run, for `lw` = log w - log total when it is read (a step that
        resamples every time reads W only, so it never writes log W).
    increment : (array (R,), bool array (R,) or bool, array (R,) or float, int), optional
        For `log_mean_increment`: each run's log sum_i w_i of the reweighting (w_i = W_{k-1}^i G_k^i,
        G the increment), which runs' w_i are fresh (resampled: G_k^i alone, W_{k-1}^i = 1/N left out;
        True or False: every run or none), the log factor those lack (the APF's first-stage total; 0
        otherwise) and N.

    Attributes
    ----------
    log_mean_increment : array (R,)
        log sum_i W_{k-1}^i G_k^i per run (given `increment`): the log of the mean increment G_k =
        p(z_k | x_k^i) under the previous weights, the estimate of log p(z_k | z_1:k-1) (particles'
        `loglt`). It is the log total of w_i = W_{k-1}^i G_k^i; for fresh weights (W_{k-1}^i = 1/N after
        resampling) the log total less log N, plus the log factor they lack (the APF's first stage, as
        Pitt and Shephard). Worked out as the value is made: every step reads it.
    """

    def __init__(
        self,
        lw: np.ndarray | None,
        W: np.ndarray | None = None,
        ess: np.ndarray | None = None,
        unnormalised: tuple[np.ndarray, np.ndarray] | None = None,
        increment: tuple[np.ndarray, np.ndarray, np.ndarray | float, int] | None = None,
    ):
        values = self.__dict__
        values["_unnormalised"] = unnormalised
        if lw is not None:
            values["lw"] = lw
        if W is not None:
            values["W"] = W
        if ess is not None:
            values["ess"] = ess
        if increment is not None:
            values["log_mean_increment"] = self._mean_increment_logs(*increment)

    @classmethod
    def uniform(cls, runs: int, count: int) -> Weights:
        """Equal weights W_i = 1/N of R runs, as a filter starts: W = exp(-log N), the value exp of the
        normalised log weights gives, one number broadcast to (R, N) (read-only, no memory of its own);
        log W = log w - log N derived when read from log w = 0 (float32 zeros, pages the system gives
        untouched): a filter that reads W only never makes it.

        Parameters
        ----------
        runs, count : int
            R and N.

        Returns
        -------
        Weights
        """
        W = np.broadcast_to(np.exp(np.float64(-math.log(count))), (runs, count))
        return cls(None, W, None, (np.zeros((runs, count), np.float32), np.full(runs, math.log(count))))

    @staticmethod
    def _mean_increment_logs(
        log_totals: np.ndarray, fresh: np.ndarray | bool, log_factor: np.ndarray | float, count: int
    ) -> np.ndarray:
        """log p(z_k | z_1:k-1) estimated per run from the reweighting's log totals (`log_mean_increment`).

        Parameters
        ----------
        log_totals : array (R,)
            log sum_i w_i of each run.
        fresh : bool array (R,), or bool (every run or none)
            The runs whose w_i leave out W_{k-1}^i = 1/N (resampled).
        log_factor : array (R,), or float
            The log factor the fresh runs' w_i lack (the APF's first-stage total; 0 otherwise).
        count : int
            N.

        Returns
        -------
        float64 array (R,): the fresh runs' log total less log N plus the factor, the others' log total
        """
        if fresh is False:
            return log_totals
        if fresh is True and len(log_totals) == 1:  # one run: the same double arithmetic on Python floats
            factor = log_factor[0] if isinstance(log_factor, np.ndarray) and log_factor.ndim else log_factor
            return np.array([(float(log_totals[0]) - math.log(count)) + float(factor)])
        fresh_values = (log_totals - math.log(count)) + log_factor
        return fresh_values if fresh is True else np.where(fresh, fresh_values, log_totals)

    def __setattr__(self, name: str, value: object) -> None:
        if name in self.__dict__:
            raise AttributeError(f"Weights are a value: {name} cannot change (make new Weights)")
        super().__setattr__(name, value)

    @cached_property
    def lw(self) -> np.ndarray:
        """log W_i = log w_i - log sum_j w_j, (R, N) float64."""
        log_w, totals = self._unnormalised
        return np.subtract(log_w, totals[:, None], dtype=float)

    @property
    def log_parts(self) -> tuple[np.ndarray, np.ndarray | None]:
        """(a, shifts) with log W = a - shifts[:, None], without making log W: the log W held and None,
        or log w and the log totals it is derived from (what the APF's first stage reads)."""
        if "lw" in self.__dict__ or self._unnormalised is None:
            return self.lw, None
        return self._unnormalised

    @cached_property
    def W(self) -> np.ndarray:  # noqa: N802 (the paper's W, as particles names it)
        """W_i = exp(log W_i), (R, N)."""
        return np.exp(self.lw)

    @cached_property
    def ess(self) -> np.ndarray:
        """N_eff = 1 / sum_i W_i^2 per run (eq. 51), (R,)."""
        return effective_sample_size(self.W)


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


def exp_in_place(values: np.ndarray) -> np.ndarray:
    """exp(values), written over `values` (a temporary of the caller's): no second array.

    Parameters
    ----------
    values : float array
        Overwritten.

    Returns
    -------
    numpy.ndarray
        `values` itself, now exp(values).
    """
    return np.exp(values, out=values)


def weights_from_logs(log_w: np.ndarray, log_totals: np.ndarray) -> np.ndarray:
    """Normalised weights exp(log w - log total) of R runs; a run whose total is -inf gets NaNs (the
    caller does not draw from it).

    Parameters
    ----------
    log_w : array (R, N)
    log_totals : array (R,)
        Each run's log sum exp(log w).

    Returns
    -------
    float array (R, N)
    """
    if np.isfinite(log_totals).all():
        return exp_in_place(np.subtract(log_w, log_totals[:, None]))
    with np.errstate(invalid="ignore"):
        return exp_in_place(np.subtract(log_w, log_totals[:, None]))


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


def weighted_mean(weights: np.ndarray, points: np.ndarray) -> np.ndarray:
    """sum_i W_i x_i per run, float64 (summed in the points' dtype).

    Parameters
    ----------
    weights : array (N,) or (R, N)
        Normalised weights.
    points : array (N, 2) or (R*N, 2)
        The particles, run r's in the block of rows r*N..(r+1)*N.

    Returns
    -------
    float64 array (2,) for one run, (R, 2) for R runs
    """
    W = weights if weights.ndim > 1 else weights[None]
    w = W.astype(points.dtype, copy=False)
    means = np.empty((len(W), 2))
    for column, c in enumerate(_columns(points, len(W))):
        means[:, column] = (w * c).sum(axis=1)  # summed in the points' dtype, then float64
    return means[0] if weights.ndim == 1 else means


def weighted_covariance(weights: np.ndarray, points: np.ndarray) -> np.ndarray:
    """sum_i W_i (x_i - mean)(x_i - mean)^T per run, float64.

    Parameters
    ----------
    weights : array (N,) or (R, N)
        Normalised weights.
    points : array (N, 2) or (R*N, 2)
        The particles, run r's in the block of rows r*N..(r+1)*N.

    Returns
    -------
    float64 array (2, 2) for one run, (R, 2, 2) for R runs
    """
    W = weights if weights.ndim > 1 else weights[None]
    mean = weighted_mean(W, points)
    x, y = _columns(points, len(W))
    dx, dy = x - mean[:, :1], y - mean[:, 1:]  # float64: the spread may be tiny
    xx, xy, yy = ((W * a * b).sum(axis=1) for a, b in ((dx, dx), (dx, dy), (dy, dy)))
    covariance = np.stack([np.stack([xx, xy], -1), np.stack([xy, yy], -1)], -2)
    return covariance[0] if weights.ndim == 1 else covariance


def mass_within(weights: np.ndarray, points: np.ndarray, centre: np.ndarray, radius: float) -> float | np.ndarray:
    """The total weight of the points at most `radius` from `centre` (distances in the points' dtype).

    Parameters
    ----------
    weights : array (N,) or (R, N)
        Normalised weights.
    points : array (N, 2) or (R*N, 2)
    centre : array (2,), or (R, 2) per run
    radius : float
        Map units.

    Returns
    -------
    float for one run, array (R,) for R runs
    """
    W = weights if weights.ndim > 1 else weights[None]
    c = (centre if centre.ndim > 1 else centre[None]).astype(points.dtype)
    x, y = _columns(points, len(W))
    dx, dy = x - c[:, :1], y - c[:, 1:]
    dx *= dx
    dy *= dy
    dx += dy
    mass = np.sum(W, axis=1, where=dx <= radius * radius)
    return float(mass[0]) if weights.ndim == 1 else mass


__all__ = [
    "Weights",
    "effective_sample_size",
    "exp_in_place",
    "log_sum_exp",
    "mass_within",
    "weighted_covariance",
    "weighted_mean",
    "weights_from_logs",
]
