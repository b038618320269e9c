"""The paper's three filters advancing R runs of one setting together, bit for bit as R single runs.

Each run keeps its own particles, weights and Generator (the stream its single-run filter would use),
so run r's estimates equal those of mazelab.filters' filter on run r exactly. What changes is that
each array operation covers all R runs in one numpy call: the particles of the R runs lie in one
(R*N, 2) array, run r's in rows r*N..(r+1)*N, and the model's functions (mazelab.model) apply to it
unchanged, with the compass angle and the measurement repeated per particle. Reductions (the weights'
totals, the estimate, the ESS) are per run, along axis 1 of (R, N) views: numpy sums each row as it
sums a single run's array. Random draws stay per run, in the single-run order.

The paper's defaults only (systematic resampling, no recovery, no KLD-sampling): a study with other
options runs run by run. The steps read as the single-run filters' steps in mazelab.filters.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from mazelab.filters import RegularizedParticleFilter, gaussian_jitter
from mazelab.maze import Maze
from mazelab.model import (
    CONFIDENCE_RADIUS,
    CONFIDENCE_SHARE,
    LOG_UNDERFLOW,
    OUTSIDE_PENALTY,
    PARTICLE_DTYPE,
    ROBOT_SPEED,
    RPF_THRESHOLD,
    headings_from_uniforms,
    log_likelihood,
    move,
    take_particles,
)
from mazelab.weights import log_sum_exp


# -- per-run operations on (R, N) arrays -------------------------------------------------------------
def log_sum_exp_rows(log_w: np.ndarray) -> np.ndarray:
    """weights.log_sum_exp of each row of log_w (R, N), float64 (R,): the same operations, per row."""
    top = log_w.max(axis=1)
    with np.errstate(invalid="ignore"):  # rows whose top is -inf give NaN here and -inf below
        shifted = np.subtract(log_w, top[:, None])
        totals = top + np.log(np.exp(shifted, out=shifted).sum(axis=1))
    return np.where(np.isfinite(top), totals, top).astype(float)


def systematic_resample_rows(weights: np.ndarray, uniforms: np.ndarray, rows: np.ndarray | None = None) -> np.ndarray:
    """resampling.systematic_resample of each row of weights (R, N), row r with the offset U_r: the
    ancestors as indices into the (R*N,) particles, shape (R*N,); `rows`, the runs the rows are
    (default 0..R-1)."""
    runs, count = weights.shape
    below = np.empty((runs, count + 1))
    below[:, 0] = 0.0
    np.cumsum(weights, axis=1, out=below[:, 1:])
    below *= count
    below -= uniforms[:, None]
    np.ceil(below, out=below)
    ends = below.astype(np.int64)
    ends[:, 0], ends[:, -1] = 0, count
    np.minimum(ends, count, out=ends)
    bins = ends[:, 1:-1] + (count + 1) * np.arange(runs)[:, None]  # each run counts in its own bins
    starts = np.bincount(bins.ravel(), minlength=runs * (count + 1)).reshape(runs, count + 1)[:, :count]
    ancestors = np.cumsum(starts, axis=1)
    ancestors += count * (np.arange(runs) if rows is None else rows)[:, None]
    return ancestors.ravel()


class BatchParticleFilter:
    """R runs of one particle filter: positions (R*N, 2) float32, headings (R*N,), log_weights (R, N).

    Like ParticleFilter, the arrays are replaced, not written into, and the summaries (weights,
    estimate, ESS, confidence) are computed once per assignment.
    """

    name = "ParticleFilter"

    def __init__(
        self,
        world: Maze,
        sigma: float,
        delta: float,
        particles: np.ndarray,
        rngs: Sequence[np.random.Generator],
        *,
        outside_penalty: float = OUTSIDE_PENALTY,
        speed: float = ROBOT_SPEED,
    ):
        """particles (R, N, 2), the initial particles of each run; rngs, each run's filter Generator."""
        self.world, self.sigma, self.delta = world, sigma, delta
        self.runs, self.count = particles.shape[:2]
        if len(rngs) != self.runs:
            raise ValueError(f"{self.runs} runs need {self.runs} generators, got {len(rngs)}")
        self.rngs = list(rngs)
        self.outside_penalty, self.speed = outside_penalty, speed
        self.positions = np.asfortranarray(particles.reshape(-1, 2), dtype=PARTICLE_DTYPE)
        self.headings = np.zeros(self.runs * self.count, dtype=PARTICLE_DTYPE)
        self.log_weights = np.full((self.runs, self.count), -math.log(self.count))
        self.steps_done = 0
        self.reinitialised_at: list[list[int]] = [[] for _ in range(self.runs)]
        self._summary_of: tuple[np.ndarray, np.ndarray] | None = None
        self._summary: dict[str, Any] = {}

    # the model, for all runs at once
    def run_rows(self, run: int) -> slice:
        """The rows of run `run` in the (R*N,) arrays."""
        return slice(run * self.count, (run + 1) * self.count)

    @staticmethod
    def per_run(values: np.ndarray) -> np.ndarray:
        """One value per run (R,) -> a column (R, 1) in the particles' dtype, for (R, N) arrays."""
        return np.asarray(values, dtype=float).astype(PARTICLE_DTYPE)[:, None]

    def propagate(
        self, positions: np.ndarray, compass_angles: np.ndarray, active: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """x_k ~ p(x_k | x_{k-1}) for every run (the `active` ones draw; the others' rows are left
        unmoved-looking garbage that the caller replaces)."""
        uniforms = np.zeros((self.runs, self.count), dtype=PARTICLE_DTYPE)
        for run, rng in enumerate(self.rngs):
            if active is None or active[run]:
                rng.random(dtype=PARTICLE_DTYPE, out=uniforms[run])
        headings = headings_from_uniforms(uniforms, self.per_run(compass_angles), self.delta).reshape(-1)
        return move(positions, headings, self.speed), headings

    def resample(self, weights: np.ndarray, active: np.ndarray | None = None) -> np.ndarray:
        """Systematic resampling of every (active) run: ancestors (R*N,) into the particles."""
        uniforms = np.zeros(self.runs)
        for run, rng in enumerate(self.rngs):
            if active is None or active[run]:
                uniforms[run] = rng.random()
        return systematic_resample_rows(weights, uniforms)

    def draw_particles(
        self, weights: np.ndarray, compass_angles: np.ndarray, active: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Resample each run's particles by its weights (R, N), then move them: (positions, headings, ancestors)."""
        ancestors = self.resample(weights, active)
        positions, headings = self.propagate(take_particles(self.positions, ancestors), compass_angles, active)
        return positions, headings, ancestors

    def likelihood(self, z: np.ndarray, positions: np.ndarray) -> np.ndarray:
        """log p(z_k | x) of equation (3) for every particle of every run, z (R,) -> (R, N)."""
        log_lik = log_likelihood(np.asarray(z, dtype=float), positions, self.world, self.sigma, self.outside_penalty)
        return log_lik.reshape(self.runs, self.count)

    # the weighted posteriors, per run
    @property
    def weights(self) -> np.ndarray:
        """W_i = exp(log w_i), shape (R, N)."""
        return self._cached("weights", lambda: np.exp(self.log_weights))

    @property
    def ess(self) -> np.ndarray:
        """N_eff = 1 / sum W_i^2 per run, shape (R,)."""
        return self._cached("ess", lambda: 1.0 / (self.weights * self.weights).sum(axis=1))

    @property
    def estimate(self) -> np.ndarray:
        """The posterior means sum_i W_i x_i, shape (R, 2), float64."""

        def mean() -> np.ndarray:
            w = self.weights.astype(PARTICLE_DTYPE, copy=False)
            columns = [(w * self.positions[:, c].reshape(self.runs, -1)).sum(axis=1) for c in range(2)]
            return np.stack(columns, axis=1).astype(float)

        return self._cached("estimate", mean).copy()

    @property
    def is_confident(self) -> np.ndarray:
        """Per run: at least CONFIDENCE_SHARE of the weight within CONFIDENCE_RADIUS of the estimate."""

        def share() -> np.ndarray:
            centre = self.estimate.astype(PARTICLE_DTYPE)
            dx = self.positions[:, 0].reshape(self.runs, -1) - centre[:, :1]
            dy = self.positions[:, 1].reshape(self.runs, -1) - centre[:, 1:]
            dx *= dx
            dy *= dy
            dx += dy
            return np.sum(self.weights, axis=1, where=dx <= CONFIDENCE_RADIUS * CONFIDENCE_RADIUS)

        return self._cached("confident", share) >= CONFIDENCE_SHARE

    def _cached(self, name: str, compute: Any) -> Any:
        described = self._summary_of
        if described is None or described[0] is not self.positions or described[1] is not self.log_weights:
            self._summary_of, self._summary = (self.positions, self.log_weights), {}
        if name not in self._summary:
            self._summary[name] = compute()
        return self._summary[name]

    # bookkeeping, per run
    def _set_weights(self, log_w: np.ndarray, z: np.ndarray, lost: np.ndarray | None = None) -> None:
        """Normalise each run's log weights (R, N); a run whose total underflows (or is `lost`) restarts."""
        totals = log_sum_exp_rows(log_w)
        log_weights = np.subtract(log_w, totals[:, None], dtype=float)
        restart = (totals < LOG_UNDERFLOW) | np.isnan(totals)
        if lost is not None:
            restart |= lost
        if restart.any():
            self.positions = self.positions.copy(order="F")
            for run in np.flatnonzero(restart):
                self._reinitialise(int(run), float(z[run]), log_weights)
        self.log_weights = log_weights

    def _reinitialise(self, run: int, z: float, log_weights: np.ndarray) -> None:
        """Run `run` starts again from the prior, weighted by its z (ParticleFilter._reinitialise)."""
        self.reinitialised_at[run].append(self.steps_done + 1)
        rows = self.run_rows(run)
        self.positions[rows] = self.world.random_free_places(self.count, self.rngs[run])
        log_w = log_likelihood(z, self.positions[rows], self.world, self.sigma, self.outside_penalty)
        total = log_sum_exp(log_w)
        if total < LOG_UNDERFLOW:
            log_weights[run] = -math.log(self.count)
        else:
            log_weights[run] = np.subtract(log_w, total, dtype=float)


class BatchSIR(BatchParticleFilter):
    """SIRParticleFilter.step (Algorithm 4) for R runs."""

    name = "SIRParticleFilter"

    def step(self, compass_angles: np.ndarray, z: np.ndarray) -> None:
        # RESAMPLE (end of Alg. 4, previous step), then x_k^i ~ p(x_k | x_{k-1}^i)
        x, headings, _ = self.draw_particles(self.weights, compass_angles)
        self.positions, self.headings = x, headings
        self._set_weights(self.likelihood(z, x), z)  # w_k^i = p(z_k | x_k^i), then normalise
        self.steps_done += 1


class BatchAPF(BatchParticleFilter):
    """AuxiliaryParticleFilter.step (Algorithm 5, mu_i one draw from the transition) for R runs."""

    name = "AuxiliaryParticleFilter"

    def step(self, compass_angles: np.ndarray, z: np.ndarray) -> None:
        mu, _ = self.propagate(self.positions, compass_angles)  # mu_k^i ~ p(x_k | x_{k-1}^i)
        log_mu_likelihood = self.likelihood(z, mu)
        first_stage = self.log_weights + log_mu_likelihood  # w_k^i ∝ p(z_k | mu_k^i) w_{k-1}^i
        log_first_total = log_sum_exp_rows(first_stage)
        lost = log_first_total < LOG_UNDERFLOW  # these runs restart from the prior instead
        with np.errstate(invalid="ignore"):
            first_weights = np.exp(np.subtract(first_stage, log_first_total[:, None]))
        first_weights[lost] = 1.0 / self.count  # (not drawn from: any valid weights)
        # i^j ~ the first stage, then x_k^j ~ p(x_k | x_{k-1}^{i^j})
        x, headings, ancestors = self.draw_particles(first_weights, compass_angles, active=~lost)
        log_lik = self.likelihood(z, x)
        second_stage = log_lik - log_mu_likelihood.ravel().take(ancestors).reshape(self.runs, -1)
        if lost.any():  # a restarted run keeps its positions (replaced below) and headings
            x, headings = x.copy(order="F"), headings.copy()
            for run in np.flatnonzero(lost):
                rows = self.run_rows(int(run))
                x[rows], headings[rows] = self.positions[rows], self.headings[rows]
        self.positions, self.headings = x, headings
        self._set_weights(second_stage, z, lost)  # p(z|x^j) / p(z|mu^{i^j}), normalised
        self.steps_done += 1


class BatchRPF(BatchParticleFilter):
    """RegularizedParticleFilter.step (Algorithm 6) for R runs."""

    name = "RegularizedParticleFilter"

    def __init__(self, *args: Any, threshold: float = RPF_THRESHOLD, **kwargs: Any):
        super().__init__(*args, **kwargs)
        if not 0 < threshold <= 1:
            raise ValueError(f"the RPF threshold must be in (0, 1] (N_T = threshold * N_S), got {threshold}")
        self.threshold = threshold
        self.bandwidth_rule = "optimal"  # the paper's h_opt, as the single filter's default
        self.regularised_at: list[list[int]] = [[] for _ in range(self.runs)]

    bandwidth = RegularizedParticleFilter.bandwidth  # h_opt for N = self.count: the single filter's

    def step(self, compass_angles: np.ndarray, z: np.ndarray) -> None:
        regularise = self.ess < self.threshold * self.count  # IF N_eff < N_T (end of Alg. 6, previous step)
        if regularise.any():
            self.regularise(regularise)
        x, headings = self.propagate(self.positions, compass_angles)  # x_k^i ~ q = p(x_k | x_{k-1}^i)
        self.positions, self.headings = x, headings
        log_w = self.log_weights + self.likelihood(z, x)  # w_k^i ∝ w_{k-1}^i p(z_k | x_k^i)
        self._set_weights(log_w, z)
        self.steps_done += 1

    def regularise(self, runs: np.ndarray) -> None:
        """RegularizedParticleFilter.regularise for the runs marked in `runs` (R,) bool: resample, then
        jitter each particle by h_opt D eps, eps ~ N(0, I_2), D D^T = S, S each run's covariance."""
        chosen = np.flatnonzero(runs)
        weights = self.weights[chosen]
        x = self.positions[:, 0].reshape(self.runs, -1)[chosen]
        y = self.positions[:, 1].reshape(self.runs, -1)[chosen]
        mean = self.estimate[chosen]  # weighted_mean, as weighted_covariance computes it
        dx, dy = x - mean[:, :1], y - mean[:, 1:]  # float64: the spread may be tiny
        xx, xy, yy = ((weights * a * b).sum(axis=1) for a, b in ((dx, dx), (dx, dy), (dy, dy)))
        covariance = np.stack([np.stack([xx, xy], -1), np.stack([xy, yy], -1)], -2)  # S_k per run, (M, 2, 2)
        D = np.linalg.cholesky(covariance + 1e-12 * np.eye(2))  # D_k D_k^T = S_k (tiny ridge: S may be 0)
        uniforms = np.array([self.rngs[run].random() for run in chosen])
        ancestors = systematic_resample_rows(weights, uniforms, chosen)  # RESAMPLE
        eps = np.empty((len(ancestors), 2), dtype=PARTICLE_DTYPE)
        for i, run in enumerate(chosen):
            self.rngs[run].standard_normal(dtype=PARTICLE_DTYPE, out=eps[i * self.count : (i + 1) * self.count])
        moved = take_particles(self.positions, ancestors)
        for i, scale in enumerate(self.bandwidth * D):  # x^{i*} + h D eps, each run with its own D
            moved[i * self.count : (i + 1) * self.count] += gaussian_jitter(
                eps[i * self.count : (i + 1) * self.count], scale
            )
        positions, headings, log_weights = self.positions.copy(order="F"), self.headings.copy(), self.log_weights.copy()
        for column in range(2):
            positions[:, column].reshape(self.runs, -1)[chosen] = moved[:, column].reshape(len(chosen), -1)
        headings.reshape(self.runs, -1)[chosen] = self.headings.take(ancestors).reshape(len(chosen), -1)
        log_weights[chosen] = -math.log(self.count)
        for run in chosen:
            self.regularised_at[run].append(self.steps_done)
        self.positions, self.headings, self.log_weights = positions, headings, log_weights


BATCH_FILTERS: dict[str, type[BatchParticleFilter]] = {cls.name: cls for cls in (BatchSIR, BatchAPF, BatchRPF)}


__all__ = [
    "BATCH_FILTERS",
    "BatchAPF",
    "BatchParticleFilter",
    "BatchRPF",
    "BatchSIR",
    "log_sum_exp_rows",
    "systematic_resample_rows",
]
