"""How often a study's 95% intervals hold the true value: percentile bootstrap, BCa and Student's t.

    uv run python benchmarks/interval_coverage.py [--trials 1000] [--sizes 5,10,20,30,50] [--csv STUDY.csv]

For populations like a study's last-20% errors (two-peaked: most runs localise, some are lost;
skewed; and a normal one for reference), `--trials` samples of n runs each are drawn, each sample's
interval for the mean (and the median) is computed as the study computes it (B = 2000 resamples,
each trial its own bootstrap seed), and the share of intervals that hold the population's value is
printed with the intervals' mean width. With `--csv`, a study's own `final_error` column (all rows)
is one more population, resampled as it is. The binomial standard error of a share near 0.95 is
sqrt(0.95 * 0.05 / trials), 0.007 for 1000 trials.
"""

from __future__ import annotations

import argparse
import csv
import math
import statistics
import sys
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from mazelab.experiments.summary import CONFIDENCE_LEVEL, bootstrap_interval

Draw = Callable[[np.random.Generator, int], np.ndarray]
LARGE = 2_000_000  # draws that fix a population's median (and a mean without a closed form)


# -- Student's t-interval, exact (no scipy): what the bootstrap intervals are measured against ----------
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


def two_peaked(rng: np.random.Generator, n: int) -> np.ndarray:
    """80% of the runs localised (lognormal around 0.1 map units), 20% lost (uniform 1 to 4)."""
    lost = rng.random(n) < 0.2
    return np.where(lost, rng.uniform(1.0, 4.0, n), rng.lognormal(np.log(0.1), 0.5, n))


def mostly_localised(rng: np.random.Generator, n: int) -> np.ndarray:
    """95% localised, 5% lost: a rare far value, the hardest case for a mean's interval."""
    lost = rng.random(n) < 0.05
    return np.where(lost, rng.uniform(1.0, 4.0, n), rng.lognormal(np.log(0.1), 0.5, n))


def skewed(rng: np.random.Generator, n: int) -> np.ndarray:
    return rng.lognormal(0.0, 1.0, n)


def normal(rng: np.random.Generator, n: int) -> np.ndarray:
    return rng.normal(1.0, 0.2, n)


def empirical(values: np.ndarray) -> Draw:
    return lambda rng, n: rng.choice(values, size=n, replace=True)


def truth(draw: Draw, statistic: str) -> float:
    sample = draw(np.random.default_rng(0), LARGE)
    return float(np.mean(sample) if statistic == "mean" else np.median(sample))


def coverage(draw: Draw, n: int, trials: int, statistic: str) -> dict[str, tuple[float, float]]:
    """{method: (share of the intervals holding the true value, their mean width)}."""
    target = truth(draw, statistic)
    rng = np.random.default_rng(n)
    methods: dict[str, list[tuple[float, float]]] = {"percentile": [], "bca": []}
    if statistic == "mean":
        methods["t"] = []
    for trial in range(trials):
        sample = draw(rng, n)
        for method in ("percentile", "bca"):
            methods[method].append(bootstrap_interval(sample, statistic, seed=trial, method=method))
        if statistic == "mean":
            methods["t"].append(t_interval(list(sample)))
    return {
        name: (float(np.mean([low <= target <= high for low, high in bounds])), float(np.mean(np.diff(bounds))))
        for name, bounds in methods.items()
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--trials", type=int, default=1000)
    parser.add_argument("--sizes", default="5,10,20,30,50")
    parser.add_argument("--csv", type=Path, help="a study's CSV: its final_error column as one more population")
    args = parser.parse_args()
    populations: dict[str, Draw] = {
        "two-peaked (20% lost)": two_peaked,
        "mostly localised (5% lost)": mostly_localised,
        "lognormal(0, 1)": skewed,
        "normal": normal,
    }
    if args.csv is not None:
        with args.csv.open(newline="") as handle:
            finals = np.array([float(row["final_error"]) for row in csv.DictReader(handle)])
        populations[f"{args.csv.name} ({len(finals)} rows)"] = empirical(finals)
    sizes = [int(n) for n in args.sizes.split(",")]
    print(f"{args.trials} samples per cell; coverage of nominal 95% intervals (mean width)")
    for statistic in ("mean", "median"):
        print(f"\nthe {statistic}")
        names = ["percentile", "bca", *(["t"] if statistic == "mean" else [])]
        print(f"{'population':<28} {'n':>3}  " + "  ".join(f"{name:>16}" for name in names))
        for label, draw in populations.items():
            for n in sizes:
                cells = coverage(draw, n, args.trials, statistic)
                print(f"{label:<28} {n:>3}  " + "  ".join(f"{cells[m][0]:>7.3f} ({cells[m][1]:>6.3f})" for m in names))


if __name__ == "__main__":
    main()
