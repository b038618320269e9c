"""Statistics of a study: intervals that fit the quantities (no scipy).

- a mean or a median of errors (heavy-tailed, often two-peaked, never negative): the percentile
  bootstrap, B = BOOTSTRAP_SAMPLES resamples from a fixed seed (`bootstrap_interval`); its bounds lie
  within the observed values, so an error's interval never reaches below zero;
- a share (converged, re-localised): the Wilson score interval (`wilson_interval`), within [0, 1];
- Student's t-interval for a mean, exact, kept for comparison (`t_interval`).
"""

from __future__ import annotations

import math
import statistics
from collections.abc import Callable, Sequence
from statistics import NormalDist

import numpy as np

CONFIDENCE_LEVEL = 0.95  # of every interval of a study's table
BOOTSTRAP_SAMPLES = 2000  # B, the bootstrap's resamples
BOOTSTRAP_SEED = 20240531  # the bootstrap's resamples are drawn from this seed: the same rows, the same interval
INTERVAL_METHODS = {
    "mean": f"percentile bootstrap, B = {BOOTSTRAP_SAMPLES} resamples of the runs, seed {BOOTSTRAP_SEED}",
    "median": f"percentile bootstrap, B = {BOOTSTRAP_SAMPLES} resamples of the runs, seed {BOOTSTRAP_SEED}",
    "share": "Wilson score interval",
}


def bootstrap_interval(
    values: Sequence[float],
    statistic: str = "mean",
    level: float = CONFIDENCE_LEVEL,
    samples: int = BOOTSTRAP_SAMPLES,
    seed: int = BOOTSTRAP_SEED,
) -> tuple[float, float]:
    """Percentile bootstrap interval for the mean or median of `values`.

    Parameters
    ----------
    values : sequence of float
        One value per run (NaN values are left out).
    statistic : str
        "mean" or "median".
    level : float
        The coverage, e.g. 0.95: the (1 - level) / 2 and (1 + level) / 2 quantiles of the statistic
        over `samples` resamples (with replacement, of the same size) drawn from `seed`.

    Returns
    -------
    (low, high), within [min(values), max(values)]; (NaN, NaN) for fewer than two values.
    """
    data = np.asarray(values, dtype=float)
    data = data[~np.isnan(data)]
    if len(data) < 2:
        return math.nan, math.nan
    reduce: Callable[..., np.ndarray] = {"mean": np.mean, "median": np.median}[statistic]
    picks = np.random.default_rng(seed).integers(0, len(data), size=(samples, len(data)))
    estimates = reduce(data[picks], axis=1)
    low, high = np.quantile(estimates, [(1 - level) / 2, (1 + level) / 2])
    return float(low), float(high)


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


def student_t_two_sided(t: float, df: int) -> float:
    """P(|T| <= t) for Student's t with `df` degrees of freedom (Abramowitz & Stegun 26.7.3-4, exact)."""
    theta = math.atan(t / math.sqrt(df))
    c2, s = math.cos(theta) ** 2, math.sin(theta)
    if df % 2 == 0:  # sin th [1 + 1/2 cos^2 th + (1*3)/(2*4) cos^4 th + ... up to cos^(df-2) th]
        term = total = 1.0
        for j in range(0, df - 2, 2):
            term *= c2 * (j + 1) / (j + 2)
            total += term
        return s * total
    if df == 1:
        return 2 * theta / math.pi
    term = total = math.cos(theta)  # 2/pi [th + sin th (cos th + 2/3 cos^3 th + ... up to cos^(df-2) th)]
    for j in range(1, df - 2, 2):
        term *= c2 * (j + 1) / (j + 2)
        total += term
    return 2 / math.pi * (theta + s * total)


def student_t_quantile(level: float, df: int) -> float:
    """The t with P(|T| <= t) = level, e.g. level 0.95 gives the 97.5% quantile (bisection to 1e-12)."""
    if not 0 < level < 1 or df < 1:
        raise ValueError(f"need 0 < level < 1 and df >= 1, got {level} and {df}")
    low, high = 0.0, 1.0
    while student_t_two_sided(high, df) < level:
        low, high = high, 2 * high
    while high - low > 1e-12 * high:
        middle = (low + high) / 2
        low, high = (middle, high) if student_t_two_sided(middle, df) < level else (low, middle)
    return (low + high) / 2


def t_interval(values: Sequence[float], level: float = CONFIDENCE_LEVEL) -> tuple[float, float]:
    """Confidence interval for the mean: mean -/+ t_{(1+level)/2, n-1} s / sqrt(n), s the sample
    standard deviation; (NaN, NaN) for fewer than two values."""
    n = len(values)
    if n < 2:
        return math.nan, math.nan
    mean = statistics.fmean(values)
    half = student_t_quantile(level, n - 1) * statistics.stdev(values) / math.sqrt(n)
    return mean - half, mean + half


__all__ = [
    "BOOTSTRAP_SAMPLES",
    "BOOTSTRAP_SEED",
    "CONFIDENCE_LEVEL",
    "INTERVAL_METHODS",
    "bootstrap_interval",
    "student_t_quantile",
    "student_t_two_sided",
    "t_interval",
    "wilson_interval",
]
