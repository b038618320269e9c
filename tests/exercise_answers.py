"""The exercise's reference answers (the shipped SIR written as a StudentFilter), the broken variants
each check must catch, the slightly wrong ones that pin each tolerance, and submission files (the
reference with parts replaced, a prelude, another class line) for the isolated grader; tests only,
never shipped to students."""

from __future__ import annotations

import inspect
import math
import textwrap
from pathlib import Path

import numpy as np

from mazelab.exercise import OUTSIDE_PENALTY, ROBOT_SPEED, StudentFilter
from mazelab.exercise.inputs import RESAMPLE_DRAWS


class ReferenceFilter(StudentFilter):
    """Algorithm 4 as the lab ships it: arc motion, equation (3) with the penalty, systematic resampling."""

    def predict(self, positions, compass_angle, rng):
        headings = compass_angle + self.delta * (rng.random(len(positions)) - 0.5)
        return positions + ROBOT_SPEED * np.column_stack([np.cos(headings), np.sin(headings)])

    def weigh(self, positions, z):
        distance = self.world.distance_to_nearest_station(positions)
        log_w = -0.5 * ((z - distance) / self.sigma) ** 2
        free = self.world.is_free(positions[:, 0], positions[:, 1])
        return log_w + np.where(free, 0.0, np.log(OUTSIDE_PENALTY))

    def resample(self, weights, rng):
        n = len(weights)
        points = (rng.random() + np.arange(n)) / n
        return np.minimum(np.searchsorted(np.cumsum(weights), points), n - 1)

    def estimate(self, positions, weights):
        return weights @ positions


class MultinomialFilter(ReferenceFilter):
    def resample(self, weights, rng):
        return rng.choice(len(weights), size=len(weights), p=weights)


class StratifiedFilter(ReferenceFilter):
    def resample(self, weights, rng):
        n = len(weights)
        points = (np.arange(n) + rng.random(n)) / n
        return np.minimum(np.searchsorted(np.cumsum(weights), points, side="right"), n - 1)


class ResidualFilter(ReferenceFilter):
    def resample(self, weights, rng):
        n = len(weights)
        copies = np.floor(n * weights).astype(int)
        kept = np.repeat(np.arange(n), copies)
        left = n - copies.sum()
        if left == 0:
            return kept
        remainder = n * weights - copies
        drawn = rng.choice(n, size=left, p=remainder / remainder.sum())
        return np.concatenate([kept, drawn])


class NormalHeadings(ReferenceFilter):
    """A heading law of the right spread but the wrong shape (a normal of std Delta / sqrt(12))."""

    def predict(self, positions, compass_angle, rng):
        headings = compass_angle + rng.normal(0, self.delta / math.sqrt(12), len(positions))
        return positions + ROBOT_SPEED * np.column_stack([np.cos(headings), np.sin(headings)])


# -- broken: each fails its part, with the hint that names the bug -------------------------------
class SignFlipped(ReferenceFilter):
    def weigh(self, positions, z):
        return -super().weigh(positions, z)


class SigmaNotSquared(ReferenceFilter):
    def weigh(self, positions, z):
        distance = self.world.distance_to_nearest_station(positions)
        free = self.world.is_free(positions[:, 0], positions[:, 1])
        return -0.5 * (z - distance) ** 2 / self.sigma + np.where(free, 0.0, np.log(OUTSIDE_PENALTY))


class NoSquare(ReferenceFilter):
    def weigh(self, positions, z):
        distance = self.world.distance_to_nearest_station(positions)
        free = self.world.is_free(positions[:, 0], positions[:, 1])
        return -np.abs(z - distance) / self.sigma + np.where(free, 0.0, np.log(OUTSIDE_PENALTY))


class NoPenalty(ReferenceFilter):
    def weigh(self, positions, z):
        distance = self.world.distance_to_nearest_station(positions)
        return -0.5 * ((z - distance) / self.sigma) ** 2


class WrongStation(ReferenceFilter):
    """The distance to the first station, not the nearest."""

    def weigh(self, positions, z):
        distance = np.hypot(*(positions - self.world.stations[0]).T)
        free = self.world.is_free(positions[:, 0], positions[:, 1])
        return -0.5 * ((z - distance) / self.sigma) ** 2 + np.where(free, 0.0, np.log(OUTSIDE_PENALTY))


class LikelihoodNotLog(ReferenceFilter):
    def weigh(self, positions, z):
        return np.exp(super().weigh(positions, z))


class IdentityResample(ReferenceFilter):
    def resample(self, weights, rng):
        return np.arange(len(weights))


def ess_gate(share: float) -> type:
    """A resampler that resamples only when the ESS falls below `share` N (the filter's choice, made
    inside resample): below, systematic resampling; above, every particle kept once."""

    class EssGate(ReferenceFilter):
        def resample(self, weights, rng):
            if 1 / np.sum(weights**2) > share * len(weights):
                return np.arange(len(weights))
            return super().resample(weights, rng)

    return EssGate


EssGate = ess_gate(0.5)


class NoHeadingNoise(ReferenceFilter):
    def predict(self, positions, compass_angle, rng):
        step = ROBOT_SPEED * np.array([np.cos(compass_angle), np.sin(compass_angle)])
        return positions + step


class SharedHeading(ReferenceFilter):
    """One heading drawn for all the particles."""

    def predict(self, positions, compass_angle, rng):
        heading = compass_angle + self.delta * (rng.random() - 0.5)
        return positions + ROBOT_SPEED * np.array([np.cos(heading), np.sin(heading)])


class ReusedNoise(ReferenceFilter):
    """Heading noise drawn once and reused at every step."""

    def predict(self, positions, compass_angle, rng):
        if getattr(self, "noise", None) is None or len(self.noise) != len(positions):
            self.noise = rng.random(len(positions)) - 0.5
        headings = compass_angle + self.delta * self.noise
        return positions + ROBOT_SPEED * np.column_stack([np.cos(headings), np.sin(headings)])


class GlobalRandom(ReferenceFilter):
    def predict(self, positions, compass_angle, rng):
        return super().predict(positions, compass_angle, np.random.default_rng())


class UnweightedMean(ReferenceFilter):
    def estimate(self, positions, weights):
        return positions.mean(axis=0)


class HeaviestParticle(ReferenceFilter):
    def estimate(self, positions, weights):
        return positions[np.argmax(weights)]


class PublicInputs(ReferenceFilter):
    """Right only on the old fixed check's 2000-point input, the plain mean otherwise."""

    def estimate(self, positions, weights):
        return weights @ positions if len(positions) == 2000 else positions.mean(axis=0)


class NanEstimate(ReferenceFilter):
    def estimate(self, positions, weights):
        return np.full(2, np.nan)


# each broken variant, the part it must fail and a phrase of its hint
BROKEN = {
    SignFlipped: ("weigh", "the sign"),
    SigmaNotSquared: ("weigh", "sigma where sigma^2 belongs"),
    NoSquare: ("weigh", "the square is missing"),
    NoPenalty: ("weigh", "outside penalty"),
    WrongStation: ("weigh", "distance to the nearest station"),
    LikelihoodNotLog: ("weigh", "not likelihoods"),
    IdentityResample: ("resample", "arange"),
    EssGate: ("resample", "resample always draws"),
    NoHeadingNoise: ("predict", "no heading noise"),
    SharedHeading: ("predict", "one per particle"),
    ReusedNoise: ("predict", "new noise at every call"),
    GlobalRandom: ("predict", "rng argument"),
    NormalHeadings: ("predict", "not normal"),
    UnweightedMean: ("estimate", "plain mean"),
    HeaviestParticle: ("estimate", "heaviest particle"),
    PublicInputs: ("estimate", "plain mean"),
    NanEstimate: ("estimate", "NaN"),
}


# -- slightly wrong: each fails now, and would pass if its check were ten times looser --------------
class PenaltyOnePercentOff(ReferenceFilter):
    """The likelihood outside the free area 1% too high: log(1.01) = 0.00995 off (tolerance 1e-3)."""

    def weigh(self, positions, z):
        free = self.world.is_free(positions[:, 0], positions[:, 1])
        return super().weigh(positions, z) + np.where(free, 0.0, np.log(1.01))


class ExponentOnePercentOff(ReferenceFilter):
    def weigh(self, positions, z):
        distance = self.world.distance_to_nearest_station(positions)
        free = self.world.is_free(positions[:, 0], positions[:, 1])
        return -0.505 * ((z - distance) / self.sigma) ** 2 + np.where(free, 0.0, np.log(OUTSIDE_PENALTY))


class StepSlightlyLong(ReferenceFilter):
    """Steps of 0.2003: 3e-4 off (tolerance 1e-4)."""

    def predict(self, positions, compass_angle, rng):
        moved = super().predict(positions, compass_angle, rng)
        return positions + (moved - positions) * 1.0015


class SpreadTenPercentWide(ReferenceFilter):
    def predict(self, positions, compass_angle, rng):
        headings = compass_angle + 1.1 * self.delta * (rng.random(len(positions)) - 0.5)
        return positions + ROBOT_SPEED * np.column_stack([np.cos(headings), np.sin(headings)])


def ks_distance_predict(x: float) -> type:
    """A predict whose headings are an evenly spaced grid (in random order) over a span slightly wider
    than Delta, chosen so that the KS statistic's scaled distance (sqrt(n) + 0.12 + 0.11 / sqrt(n)) D
    is `x` whatever N: deterministic, so it pins the KS test's level exactly."""

    class KsDistance(ReferenceFilter):
        def predict(self, positions, compass_angle, rng):
            n = len(positions)
            distance = x / (math.sqrt(n) + 0.12 + 0.11 / math.sqrt(n))
            widening = 2 * distance / (1 - 2 * distance)  # D = eps / (2 (1 + eps)) for a grid of span (1 + eps) Delta
            grid = (rng.permutation(n) + 0.5) / n - 0.5
            headings = compass_angle + (1 + widening) * self.delta * grid
            return positions + ROBOT_SPEED * np.column_stack([np.cos(headings), np.sin(headings)])

    return KsDistance


class EstimateSlightlyOff(ReferenceFilter):
    """Off by 3e-4 in x and y (tolerance 1e-4)."""

    def estimate(self, positions, weights):
        return weights @ positions + 3e-4


def biased_resampler(z: float) -> type:
    """Multinomial resampling on weights tilted so that particle 0's mean offspring count is off by
    `z` of its standard errors over the check's RESAMPLE_DRAWS calls (a small, steady bias)."""

    class Biased(ReferenceFilter):
        def resample(self, weights, rng):
            n = len(weights)
            shift = z * math.sqrt(weights[0] * (1 - weights[0]) / (n * RESAMPLE_DRAWS))
            tilted = weights * (1 - shift) / (1 - weights[0])
            tilted[0] = weights[0] + shift
            return rng.choice(n, size=n, p=tilted / tilted.sum())

    return Biased


class ForgetsResampling(ReferenceFilter):
    """Every part right, but its step neither resamples nor carries the weights over: each step's
    weights are the last measurement's alone."""

    def step(self, compass_angle, z):
        self.positions = self.predict(self.positions.copy(), float(compass_angle), self.rng)
        log_w = self.weigh(self.positions.copy(), float(z))
        self.log_weights = log_w - np.logaddexp.reduce(log_w)
        self._estimate = None
        self.steps_done += 1


# -- submission files for the isolated grader --------------------------------------------------------
HEADER = "import numpy as np\n\nfrom mazelab.exercise import OUTSIDE_PENALTY, ROBOT_SPEED, StudentFilter\n"
PARTS_SOURCE = {
    part: textwrap.dedent(inspect.getsource(getattr(ReferenceFilter, "estimate_part" if part == "estimate" else part)))
    for part in ("predict", "weigh", "resample", "estimate")
}


def submission_source(
    prelude: str = "", class_line: str = "class MyFilter(StudentFilter):", **parts: str | None
) -> str:
    """A submission's text: the reference parts, each replaceable by a method's source (or None: not
    written), after `prelude` (module-level code) and under `class_line`."""
    methods = {**PARTS_SOURCE, **parts}
    body = (
        "\n".join(textwrap.indent(textwrap.dedent(code), "    ") for code in methods.values() if code) or "    pass\n"
    )
    return f"{HEADER}\n{textwrap.dedent(prelude)}\n\n{class_line}\n{body}"


def write_submission(
    path: Path, prelude: str = "", class_line: str = "class MyFilter(StudentFilter):", **parts
) -> Path:
    """Write a submission file (making its folder) and return its path."""
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(submission_source(prelude, class_line, **parts))
    return path


def row_of(report, part: str):
    """The report's row of one part (or "whole filter")."""
    return next(row for row in report.rows if row.part == part)
