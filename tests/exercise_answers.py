"""The exercise's reference answers (the shipped SIR written as a StudentFilter) and the broken
variants each check must catch; tests only, never shipped to students."""

from __future__ import annotations

import numpy as np

from mazelab.exercise import OUTSIDE_PENALTY, ROBOT_SPEED, StudentFilter


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


class SignFlipped(ReferenceFilter):
    def weigh(self, positions, z):
        return -super().weigh(positions, z)


class SigmaNotSquared(ReferenceFilter):
    def weigh(self, positions, z):
        distance = self.world.distance_to_nearest_station(positions)
        free = self.world.is_free(positions[:, 0], positions[:, 1])
        return -0.5 * (z - distance) ** 2 / self.sigma + np.where(free, 0.0, np.log(OUTSIDE_PENALTY))


class NoPenalty(ReferenceFilter):
    def weigh(self, positions, z):
        distance = self.world.distance_to_nearest_station(positions)
        return -0.5 * ((z - distance) / self.sigma) ** 2


class IdentityResample(ReferenceFilter):
    def resample(self, weights, rng):
        return np.arange(len(weights))


class NoHeadingNoise(ReferenceFilter):
    def predict(self, positions, compass_angle, rng):
        step = ROBOT_SPEED * np.array([np.cos(compass_angle), np.sin(compass_angle)])
        return positions + step


class UnweightedMean(ReferenceFilter):
    def estimate(self, positions, weights):
        return positions.mean(axis=0)


# each broken variant and the part it must fail
BROKEN = {
    SignFlipped: "weigh",
    SigmaNotSquared: "weigh",
    NoPenalty: "weigh",
    IdentityResample: "resample",
    NoHeadingNoise: "predict",
    UnweightedMean: "estimate",
}
