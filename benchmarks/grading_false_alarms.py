"""How often the exercise's checks fail a correct part: the false-alarm rates, measured over many seeds.

    uv run python benchmarks/grading_false_alarms.py --seeds 2000 --resample-seeds 300 --whole-seeds 24

Each seed draws fresh inputs (mazelab.exercise.inputs); correct parts (two ways to write predict,
four unbiased resamplers, the reference weigh and estimate) are checked on them as `mazelab exercise
check` checks them (the same verdict functions, in this process). The table gives, per part, the
failures at the check's own level and, to show the tests are calibrated (a rate of 0.001 needs many
thousand seeds to see), the share of seeds whose statistic passes a looser level: predict's smallest
KS p-value and its correlation test, resample's largest |z| against the quantile at 10 and 50 times
the level. The whole filter (optional: each seed runs the exact grid filter on 12 scenarios, about
30 s) is the reference against the shipped SIR; its rate is 13/4096 by construction.
"""

from __future__ import annotations

import argparse
import math
import os
import time
from concurrent.futures import ProcessPoolExecutor
from statistics import NormalDist

import numpy as np

from mazelab.exercise import OUTSIDE_PENALTY, ROBOT_SPEED, StudentFilter
from mazelab.exercise.inputs import draw_part_inputs
from mazelab.exercise.parts import (
    MAGNITUDE_ALPHA,
    PREDICT_LEVEL,
    PREDICT_TESTS,
    critical_z,
    heading_deviations,
    judge_estimate,
    judge_predict,
    judge_resample,
    judge_weigh,
    kolmogorov_p,
    ks_uniform,
    offspring_counts,
    sign_test_alpha,
    take,
    z_scores,
)
from mazelab.exercise.report import check, collect_in_process


class Correct(StudentFilter):
    """Algorithm 4 written as the exercise asks (systematic resampling)."""

    def predict(self, positions, compass_angle, rng):
        headings = compass_angle + self.delta * (rng.random(len(positions)) - 0.5)
        return positions + ROBOT_SPEED * np.column_stack([np.cos(headings), np.sin(headings)])

    def weigh(self, positions, z):
        distance = self.world.distance_to_nearest_station(positions)
        free = self.world.is_free(positions[:, 0], positions[:, 1])
        return -0.5 * ((z - distance) / self.sigma) ** 2 + np.where(free, 0.0, np.log(OUTSIDE_PENALTY))

    def resample(self, weights, rng):
        n = len(weights)
        return np.minimum(np.searchsorted(np.cumsum(weights), (rng.random() + np.arange(n)) / n), n - 1)

    def estimate(self, positions, weights):
        return weights @ positions


class UniformPredict(Correct):
    def predict(self, positions, compass_angle, rng):
        headings = rng.uniform(compass_angle - self.delta / 2, compass_angle + self.delta / 2, len(positions))
        return positions + ROBOT_SPEED * np.stack([np.cos(headings), np.sin(headings)], axis=1)


class Multinomial(Correct):
    def resample(self, weights, rng):
        return rng.choice(len(weights), size=len(weights), p=weights)


class Stratified(Correct):
    def resample(self, weights, rng):
        n = len(weights)
        return np.minimum(np.searchsorted(np.cumsum(weights), (np.arange(n) + rng.random(n)) / n, "right"), n - 1)


class Residual(Correct):
    def resample(self, weights, rng):
        n = len(weights)
        copies = np.floor(n * weights).astype(int)
        left = n - copies.sum()
        remainder = n * weights - copies
        drawn = rng.choice(n, size=left, p=remainder / remainder.sum()) if left else np.array([], int)
        return np.concatenate([np.repeat(np.arange(n), copies), drawn])


PREDICTS = {"rng.random": Correct, "rng.uniform": UniformPredict}
RESAMPLERS = {"systematic": Correct, "multinomial": Multinomial, "stratified": Stratified, "residual": Residual}


def predict_figures(seed: int, cls: type) -> tuple[bool, float, float]:
    """(passed, smallest KS p of the three angles, |r| sqrt(N) of the two calls) of one seed."""
    parts = draw_part_inputs(seed)
    answer = collect_in_process(cls, parts, [], ["predict"]).results["predict"]
    start, angles = parts.predict.start, parts.predict.angles
    p = []
    for j, angle in enumerate(angles):
        deviation = heading_deviations(start, take(answer, f"moved/{j}", start.shape), angle)[1]
        p.append(kolmogorov_p(ks_uniform(deviation / parts.delta + 0.5), len(deviation)))
    a = heading_deviations(start, take(answer, "moved/0", start.shape), angles[0])[1]
    b = heading_deviations(start, take(answer, "again", start.shape), angles[0])[1]
    return judge_predict(parts, answer).passed, min(p), abs(float(np.corrcoef(a, b)[0, 1])) * math.sqrt(len(a))


def resample_figures(seed: int, cls: type) -> tuple[bool, float, int]:
    """(passed, largest |z| over every particle, the particles) of one seed."""
    parts = draw_part_inputs(seed)
    answer = collect_in_process(cls, parts, [], ["resample"]).results["resample"]
    vectors, draws = parts.resample.weights, parts.resample.draws
    ancestors = [take(answer, f"ancestors/{k}", (draws, len(w)), "<i8") for k, w in enumerate(vectors)]
    counts = [offspring_counts(a, len(w)) for a, w in zip(ancestors, vectors, strict=True)]
    worst = max(float(np.abs(z_scores(c, w)).max()) for c, w in zip(counts, vectors, strict=True))
    return judge_resample(parts, answer)[0].passed, worst, sum(len(w) for w in vectors)


def deterministic_figures(seed: int) -> tuple[bool, bool]:
    """(weigh passed, estimate passed) of one seed."""
    parts = draw_part_inputs(seed)
    answers = collect_in_process(Correct, parts, [], ["weigh", "estimate"]).results
    return judge_weigh(parts, answers["weigh"]).passed, judge_estimate(parts, answers["estimate"]).passed


def whole_figures(seed: int) -> bool:
    return check(Correct, seed=seed, stages=("whole",)).rows[0].passed


def _run(function, arguments, workers):
    with ProcessPoolExecutor(max_workers=workers) as pool:
        return list(pool.map(function, *zip(*arguments, strict=True), chunksize=4))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=2000, help="seeds for predict, weigh and estimate")
    parser.add_argument("--resample-seeds", type=int, default=300, help="seeds for each of four resamplers")
    parser.add_argument("--whole-seeds", type=int, default=0, help="seeds for the whole filter (about 30 s each)")
    parser.add_argument("--first", type=int, default=10_000, help="the first seed (the tests use small ones)")
    parser.add_argument("--workers", type=int, default=os.cpu_count())
    options = parser.parse_args()
    seeds = range(options.first, options.first + options.seeds)
    started = time.perf_counter()
    rows = []
    alpha_each = PREDICT_LEVEL
    for name, cls in PREDICTS.items():
        figures = _run(predict_figures, [(s, cls) for s in seeds], options.workers)
        failed = sum(not passed for passed, _, _ in figures)
        loose = {}  # each of the four tests at `factor` times its level
        for factor in (10, 50):
            quantile = NormalDist().inv_cdf(1 - factor * alpha_each / 2)
            loose[factor] = sum(p < factor * alpha_each or r > quantile for _, p, r in figures)
        rows.append((f"predict ({name})", len(figures), failed, PREDICT_TESTS * alpha_each, loose))
    determined = _run(deterministic_figures, [(s,) for s in seeds], options.workers)
    rows.append(("weigh", len(determined), sum(not w for w, _ in determined), 0.0, {}))
    rows.append(("estimate", len(determined), sum(not e for _, e in determined), 0.0, {}))
    resample_seeds = range(options.first, options.first + options.resample_seeds)
    for name, cls in RESAMPLERS.items():
        figures = _run(resample_figures, [(s, cls) for s in resample_seeds], options.workers)
        failed = sum(not passed for passed, _, _ in figures)
        loose = {factor: sum(z > critical_z(m, factor * 0.001) for _, z, m in figures) for factor in (10, 50)}
        rows.append((f"resample ({name})", len(figures), failed, 0.001, loose))
    if options.whole_seeds:
        whole_seeds = range(options.first, options.first + options.whole_seeds)
        passed = _run(whole_figures, [(s,) for s in whole_seeds], options.workers)
        rows.append(("whole filter", len(passed), sum(not p for p in passed), sign_test_alpha() + MAGNITUDE_ALPHA, {}))
    print(f"{'check':<24} {'seeds':>6} {'failed':>7} {'rate':>8} {'nominal':>8}   at 10x / 50x the level")
    for name, count, failed, nominal, loose in rows:
        looser = "  ".join(f"{loose[f] / count:.4f} ({f * nominal:.3f})" for f in loose) if loose else ""
        print(f"{name:<24} {count:>6} {failed:>7} {failed / count:>8.4f} {nominal:>8.4f}   {looser}")
    print(f"measured in {time.perf_counter() - started:.0f} s with {options.workers} workers")


if __name__ == "__main__":
    main()
