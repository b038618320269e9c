"""Statistics of a study: intervals that fit the quantities (no scipy).

- a mean or a median of errors (heavy-tailed, often two-peaked, never negative): the percentile
  bootstrap, B = BOOTSTRAP_SAMPLES resamples from a fixed seed (`bootstrap_interval`); its bounds lie
  within the observed values, so an error's interval never reaches below zero. `method="bca"` gives
  the bias-corrected and accelerated interval (Efron 1987) from the same resamples;
- the difference between two filters on the same runs: the paired bootstrap, resampling runs (the
  pairs) rather than each filter's values apart (`paired_difference`);
- a share (converged, re-localised): the Wilson score interval (`wilson_interval`), within [0, 1];
- a time to an event that some runs never reach (the convergence step): the Kaplan-Meier estimate,
  its median and that median's interval from the log-log pointwise band (`kaplan_meier`, `km_median`).
(Student's t-interval, for comparison: benchmarks/interval_coverage.py.)
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from statistics import NormalDist

import numpy as np

CONFIDENCE_LEVEL = 0.95  # of every interval of a study's table
BOOTSTRAP_SAMPLES = 2000  # B, the bootstrap's resamples
BOOTSTRAP_SEED = 20240531  # the bootstrap's resamples are drawn from this seed: the same rows, the same interval
MEAN_METHOD = "bca"  # a study's means (errors, distances, paired differences): BCa (benchmarks/interval_coverage.py)
MEDIAN_METHOD = "percentile"  # its medians: percentile (BCa's jackknife acceleration does not suit a median)
_RESAMPLES = f"B = {BOOTSTRAP_SAMPLES} resamples of the runs, seed {BOOTSTRAP_SEED}"
INTERVAL_METHODS = {
    "mean": f"a study's table: BCa bootstrap, {_RESAMPLES} (accuracy's table: percentile bootstrap)",
    "median": f"percentile bootstrap, {_RESAMPLES}",
    "paired difference": f"paired BCa bootstrap (the runs resampled as pairs), {_RESAMPLES}",
    "share": "Wilson score interval",
    "convergence step": "Kaplan-Meier median, the runs that never converge censored; interval from the log-log band",
}


INTERVAL_KINDS = ("percentile", "bca")  # what bootstrap_interval's `method` takes
REDUCERS: dict[str, Callable[..., np.ndarray]] = {"mean": np.mean, "median": np.median}


def bootstrap_interval(
    values: Sequence[float],
    statistic: str = "mean",
    level: float = CONFIDENCE_LEVEL,
    samples: int = BOOTSTRAP_SAMPLES,
    seed: int = BOOTSTRAP_SEED,
    method: str = "percentile",
) -> tuple[float, float]:
    """Bootstrap interval for the mean or median of `values`: percentile (the default) or BCa.

    Parameters
    ----------
    values : sequence of float
        One value per run (NaN values are left out).
    statistic : str
        "mean" or "median".
    level : float
        The coverage, e.g. 0.95: the (1 - level) / 2 and (1 + level) / 2 quantiles of the statistic
        over `samples` resamples (with replacement, of the same size) drawn from `seed`.
    method : str
        "percentile", or "bca": the same resamples' quantiles at levels moved by the bias correction
        z0 and the jackknife acceleration a (`bca_levels`).

    Returns
    -------
    (low, high), within [min(values), max(values)]; (NaN, NaN) for fewer than two values.
    """
    if method not in INTERVAL_KINDS:
        raise ValueError(f"method must be one of {', '.join(INTERVAL_KINDS)}, got {method!r}")
    data = np.asarray(values, dtype=float)
    data = data[~np.isnan(data)]
    if len(data) < 2:
        return math.nan, math.nan
    reduce = REDUCERS[statistic]
    estimates = resampled(data, reduce, samples, seed)
    levels = [(1 - level) / 2, (1 + level) / 2]
    if method == "bca":
        levels = bca_levels(data, reduce, estimates, levels)
    low, high = np.quantile(estimates, levels)
    return float(low), float(high)


def resampled(data: np.ndarray, reduce: Callable[..., np.ndarray], samples: int, seed: int) -> np.ndarray:
    """The statistic of `samples` resamples of `data` (with replacement, of its size) from `seed`, (samples,)."""
    picks = np.random.default_rng(seed).integers(0, len(data), size=(samples, len(data)))
    return reduce(data[picks], axis=1)


def bca_levels(
    data: np.ndarray, reduce: Callable[..., np.ndarray], estimates: np.ndarray, levels: Sequence[float]
) -> list[float]:
    """The BCa interval's quantile levels (Efron & Tibshirani 1993, section 14.3): alpha ->
    Phi(z0 + (z0 + z_alpha) / (1 - a (z0 + z_alpha))), with the bias correction z0 = Phi^-1(share of
    the resampled statistics below the observed one, ties counted half) and the acceleration
    a = sum(d^3) / (6 (sum d^2)^1.5), d the jackknife statistics' deviations from their mean.
    Equal to `levels` (the percentile interval) when z0 = a = 0."""
    normal = NormalDist()
    observed = float(reduce(data))
    below = (np.count_nonzero(estimates < observed) + 0.5 * np.count_nonzero(estimates == observed)) / len(estimates)
    below = min(max(below, 0.5 / len(estimates)), 1 - 0.5 / len(estimates))  # z0 finite
    z0 = normal.inv_cdf(below)
    jackknife = leave_one_out(data, reduce)
    d = jackknife.mean() - jackknife
    spread = float((d * d).sum())
    a = float((d**3).sum()) / (6 * spread**1.5) if spread > 0 else 0.0
    moved = []
    for alpha in levels:
        z = z0 + normal.inv_cdf(alpha)
        moved.append(normal.cdf(z0 + z / (1 - a * z)))
    return moved


def leave_one_out(data: np.ndarray, reduce: Callable[..., np.ndarray]) -> np.ndarray:
    """The jackknife: the mean or median of `data` without each value in turn, (n,); O(n log n)."""
    n = len(data)
    if reduce is np.mean:
        return (data.sum() - data) / (n - 1)
    order = np.argsort(data, kind="stable")
    ranks = np.empty(n, dtype=int)
    ranks[order] = np.arange(n)
    ordered = data[order]

    def kept(k: int) -> np.ndarray:  # the k-th smallest of the n - 1 values left, for each left-out one
        return ordered[np.where(k < ranks, k, k + 1)]

    m = n - 1
    return kept(m // 2) if m % 2 else (kept(m // 2 - 1) + kept(m // 2)) / 2


def paired_difference(
    values: Sequence[float],
    reference: Sequence[float],
    level: float = CONFIDENCE_LEVEL,
    samples: int = BOOTSTRAP_SAMPLES,
    seed: int = BOOTSTRAP_SEED,
    method: str = "percentile",
) -> tuple[float, tuple[float, float]]:
    """The mean difference values - reference over pairs (one pair per run: the same scenario) and its
    paired bootstrap interval: the runs are resampled, each keeping its pair, so the luck the two
    share (an easy or a hard walk) cancels. Pairs with a NaN are left out; (NaN, (NaN, NaN)) for no pair.

    The unpaired interval (each filter's runs resampled apart) is wider when the two are positively
    correlated, as filters on the same walk are: its variance adds both spreads, the paired one subtracts
    twice their covariance (tests/test_statistics.py compares the two)."""
    a, b = np.asarray(values, dtype=float), np.asarray(reference, dtype=float)
    if a.shape != b.shape:
        raise ValueError(f"paired values need one reference each, got {len(a)} and {len(b)}")
    differences = a - b
    differences = differences[~np.isnan(differences)]
    if len(differences) == 0:
        return math.nan, (math.nan, math.nan)
    return float(differences.mean()), bootstrap_interval(differences, "mean", level, samples, seed, method)


@dataclass(frozen=True)
class SurvivalCurve:
    """A Kaplan-Meier estimate: at each distinct event time t_j, the number at risk n_j, the events
    d_j, S(t_j) and its log-log pointwise band (low, high) at the given level."""

    times: np.ndarray
    at_risk: np.ndarray
    events: np.ndarray
    survival: np.ndarray
    low: np.ndarray
    high: np.ndarray


def kaplan_meier(times: Sequence[float], observed: Sequence[bool], level: float = CONFIDENCE_LEVEL) -> SurvivalCurve:
    """The Kaplan-Meier estimate of S(t) = P(T > t) from times, each an event (observed) or a
    censoring (the run ended, or was cut off, at that time without the event).

    S(t_j) = prod_{i <= j} (1 - d_i / n_i), n_i the runs with time >= t_i (a run censored at t_i is
    still at risk there). The band is the log-log one (Kalbfleisch & Prentice): with Greenwood's
    v_j = sum_{i <= j} d_i / (n_i (n_i - d_i)), S^exp(+z sqrt(v)/|log S|) to S^exp(-z sqrt(v)/|log S|);
    it stays within [0, 1]. Where S = 1 the band is [1, 1]; where S = 0, [0, 0]."""
    t = np.asarray(times, dtype=float)
    seen = np.asarray(observed, dtype=bool)
    if t.shape != seen.shape:
        raise ValueError(f"kaplan_meier needs one flag per time, got {len(t)} and {len(seen)}")
    event_times = np.unique(t[seen])
    at_risk = np.array([np.count_nonzero(t >= u) for u in event_times], dtype=float)
    events = np.array([np.count_nonzero(seen & (t == u)) for u in event_times], dtype=float)
    survival = np.cumprod(1 - events / at_risk) if len(event_times) else np.empty(0)
    with np.errstate(divide="ignore", invalid="ignore"):
        greenwood = np.cumsum(events / (at_risk * (at_risk - events)))
        spread = NormalDist().inv_cdf((1 + level) / 2) * np.sqrt(greenwood) / np.abs(np.log(survival))
        low, high = survival ** np.exp(spread), survival ** np.exp(-spread)
    low = np.where(survival >= 1, 1.0, np.where(survival <= 0, 0.0, low))
    high = np.where(survival >= 1, 1.0, np.where(survival <= 0, 0.0, high))
    return SurvivalCurve(event_times, at_risk, events, survival, low, high)


def km_median(
    times: Sequence[float], observed: Sequence[bool], level: float = CONFIDENCE_LEVEL
) -> tuple[float, tuple[float, float]]:
    """The Kaplan-Meier median time and its interval (Brookmeyer & Crowley's construction): the first
    time at which S, and each end of its log-log band, reaches 0.5 or below (where a curve equals
    0.5 exactly up to its next event time, the midpoint of the two: with no censoring the median is
    the ordinary median). NaN where a curve never gets to 0.5 (more than half the runs not yet
    reached the event when observed last): not reached."""
    curve = kaplan_meier(times, observed, level)
    return (
        _first_at_half(curve.times, curve.survival),
        (_first_at_half(curve.times, curve.low), _first_at_half(curve.times, curve.high)),
    )


def _first_at_half(times: np.ndarray, curve: np.ndarray) -> float:
    """The first time the step function `curve` (its value from each of `times` on) is <= 0.5."""
    reached = np.flatnonzero(curve <= 0.5 + 1e-12)
    if len(reached) == 0:
        return math.nan
    j = int(reached[0])
    if abs(curve[j] - 0.5) <= 1e-12 and j + 1 < len(times):
        return float((times[j] + times[j + 1]) / 2)
    return float(times[j])


def wilson_interval(successes: int, trials: int, level: float = CONFIDENCE_LEVEL) -> tuple[float, float]:
    """Wilson score interval for a share successes / trials: (p + z^2/2n -/+ z sqrt(p(1-p)/n +
    z^2/4n^2)) / (1 + z^2/n), z the normal (1 + level) / 2 quantile; within [0, 1], (NaN, NaN) for
    no trials."""
    if trials < 1:
        return math.nan, math.nan
    z = NormalDist().inv_cdf((1 + level) / 2)
    p, n = successes / trials, trials
    centre = p + z * z / (2 * n)
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n))
    scale = 1 + z * z / n
    low = 0.0 if successes == 0 else max(0.0, (centre - half) / scale)
    return low, 1.0 if successes == trials else min(1.0, (centre + half) / scale)


__all__ = [
    "BOOTSTRAP_SAMPLES",
    "BOOTSTRAP_SEED",
    "CONFIDENCE_LEVEL",
    "INTERVAL_KINDS",
    "INTERVAL_METHODS",
    "MEAN_METHOD",
    "MEDIAN_METHOD",
    "SurvivalCurve",
    "bca_levels",
    "bootstrap_interval",
    "kaplan_meier",
    "km_median",
    "leave_one_out",
    "paired_difference",
    "resampled",
    "wilson_interval",
]
