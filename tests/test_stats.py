"""The study's statistics (mazelab.experiments.summary): Student's t quantiles as the tables give them (the
t-interval of benchmarks/interval_coverage.py, which the bootstrap intervals are measured against), the
percentile bootstrap interval covering the mean at its level, intervals within the quantity's range, and
the Wilson interval in closed form and from the tables."""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np
import pytest

from mazelab.experiments.summary import bootstrap_interval, wilson_interval

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "benchmarks"))  # the t-interval is a benchmark's
from interval_coverage import student_t_quantile, t_interval

# With 2 degrees of freedom Student's t has F(t) = 1/2 + t / (2 sqrt(2 + t^2)), so F(t) = q at
# t = (2q - 1) / sqrt(2 q (1 - q)): the 97.5% quantile in closed form.
T_975_DF2 = 0.95 / math.sqrt(2 * 0.975 * 0.025)


@pytest.mark.parametrize(
    ("df", "quantile"),  # t_{0.975, df} from statistical tables, 10 significant digits
    [(1, 12.70620474), (2, 4.302652730), (3, 3.182446305), (4, 2.776445105), (9, 2.262157163), (29, 2.045229642),
     (100, 1.983971519)],
)  # fmt: skip
def test_student_t_quantile_matches_the_tables(df, quantile):
    assert student_t_quantile(0.95, df) == pytest.approx(quantile, rel=1e-9)
    assert student_t_quantile(0.95, 2) == pytest.approx(T_975_DF2, rel=1e-11)


def test_the_t_interval_of_three_errors_reaches_below_zero():
    """Final errors 0.1, 0.2, 0.6: mean 0.3, half width T_975_DF2 sqrt(0.07 / 3) = 0.657, so the interval
    of a quantity that is never negative reaches below zero (the study's bootstrap stays within the
    values: test_experiments); one run gives no interval."""
    half = T_975_DF2 * math.sqrt(0.07 / 3)
    assert t_interval([0.1, 0.2, 0.6]) == pytest.approx((0.3 - half, 0.3 + half)) and 0.3 - half < 0
    assert all(math.isnan(v) for v in t_interval([0.4]))


def test_bootstrap_interval_covers_the_mean_at_its_level():
    """400 samples of 30 normal values: the share of percentile bootstrap intervals that hold the true
    mean is near 0.95; the percentile bootstrap is known to run a little low at n = 30 (the plug-in
    spread is s sqrt((n-1)/n)), so the bound below is 0.95 - 0.02 - 4 binomial standard errors."""
    rng = np.random.default_rng(7)
    hits = [low <= 0 <= high for low, high in (bootstrap_interval(rng.normal(size=30), seed=s) for s in range(400))]
    standard_error = math.sqrt(0.95 * 0.05 / 400)
    assert 0.95 - 0.02 - 4 * standard_error <= np.mean(hits) <= 0.95 + 4 * standard_error


def test_intervals_respect_the_quantity():
    errors = [0.05, 0.07, 0.1, 0.09, 6.3]  # one lost run: the t-interval reaches below zero
    for statistic in ("mean", "median"):
        low, high = bootstrap_interval(errors, statistic)
        assert 0.05 <= low <= high <= 6.3
    assert bootstrap_interval(errors) == bootstrap_interval(errors)  # seeded
    z2 = 1.959963984540054**2
    assert wilson_interval(0, 10) == (0.0, pytest.approx(z2 / (10 + z2)))  # closed form at p = 0
    assert wilson_interval(10, 10) == (pytest.approx(10 / (10 + z2)), 1.0)
    low, high = wilson_interval(7, 20)
    assert low == pytest.approx(0.1812, abs=1e-4) and high == pytest.approx(0.5671, abs=1e-4)  # tables
