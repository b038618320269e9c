"""Statistics of a study: Student's t-interval for a mean, exact (no scipy)."""

from __future__ import annotations

import math
import statistics
from collections.abc import Sequence

CONFIDENCE_LEVEL = 0.95  # of the t-interval for the mean final error


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
    "CONFIDENCE_LEVEL",
    "student_t_quantile",
    "student_t_two_sided",
    "t_interval",
]
