"""The paper's particle filters: SIR, APF and RPF (Arulampalam, Maskell, Gordon, Clapp 2002,
Algorithms 4, 5 and 6) with the paper's refinements, weights in the log domain.

Where each algorithm's lines are: SIRParticleFilter.step (Algorithm 4), AuxiliaryParticleFilter.step
(Algorithm 5), RegularizedParticleFilter.step and .regularise (Algorithm 6).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numpy as np

from mazelab.checks import as_points
from mazelab.maze import Maze
from mazelab.model import (
    CONFIDENCE_RADIUS,
    CONFIDENCE_SHARE,
    LOG_UNDERFLOW,
    OUTSIDE_PENALTY,
    PARTICLE_DTYPE,
    ROBOT_SPEED,
    RPF_THRESHOLD,
    log_likelihood,
    move,
    sample_headings,
    take_particles,
)
from mazelab.modes import Mode, check_estimate, find_modes
from mazelab.recovery import ALPHA_FAST, ALPHA_SLOW, Recovery, RecoveryAndKLD
from mazelab.regularisation import (
    Kernel,
    check_bandwidth,
    gaussian_jitter,
    mixture_kernel,
    optimal_bandwidth,
    whole_cloud_kernel,
)
from mazelab.resampling import KLDSampling, Move, resampling_scheme
from mazelab.weights import (
    effective_sample_size,
    exp_in_place,
    log_sum_exp,
    mass_within,
    weighted_mean,
)


class ParticleFilter(RecoveryAndKLD):
    """Weighted particles {x_i, W_i} approximating the posterior p(x_k | z_1:k).

    Arulampalam's algorithms end each step by resampling; here each step starts by resampling the
    previous posterior, the same sequence of operations, so that between steps the filter holds the
    weighted posterior that the estimate, the ESS and the drawing read.
    Options beyond the paper (off by default): `recovery` (True, "augmented" or "sensor", with
    `alpha_slow`, `alpha_fast`) and `kld` (True or a KLDSampling); see RecoveryAndKLD; `estimate="mode"`
    reports the mean of the heaviest mode (mazelab.modes) instead of the paper's posterior mean.

    `positions` (N, 2) and `headings` (N,) are float32 (PARTICLE_DTYPE), `log_weights` (N,) float64.
    The filter replaces these arrays rather than writing into them; to change them, assign new arrays
    (the weights, estimate, ESS and confidence are computed once per assignment and cached).
    """

    name = "ParticleFilter"

    def __init__(
        self,
        world: Maze,
        sigma: float,
        delta: float,
        particles: np.ndarray,
        rng: np.random.Generator | None = None,
        *,
        resampling: str = "systematic",
        outside_penalty: float = OUTSIDE_PENALTY,
        speed: float = ROBOT_SPEED,
        recovery: bool | str | Recovery | None = None,
        alpha_slow: float = ALPHA_SLOW,
        alpha_fast: float = ALPHA_FAST,
        kld: bool | KLDSampling | None = None,
        estimate: str = "mean",
    ):
        self.world, self.sigma, self.delta = world, sigma, delta
        self.estimate_rule = check_estimate(estimate)
        self.rng = rng if rng is not None else np.random.default_rng()
        self.resample = resampling_scheme(resampling)
        self.outside_penalty, self.speed = outside_penalty, speed
        self.positions = np.asfortranarray(as_points("particles", particles), dtype=PARTICLE_DTYPE)  # (N, 2)
        self.count = len(self.positions)
        self.headings = np.zeros(self.count, dtype=PARTICLE_DTYPE)  # each particle's last motion angle
        self.log_weights = np.full(self.count, -math.log(self.count))
        self._summary_of: tuple[np.ndarray, np.ndarray] | None = None  # the arrays _summary describes
        self._summary: dict[str, Any] = {}
        self.steps_done = 0
        self.reinitialised_at: list[int] = []  # steps at which no particle explained z and we restarted
        self._init_options(recovery, alpha_slow, alpha_fast, kld)

    # what a step does, in the paper's words
    def step(self, compass_angle: float, z: float) -> None:
        raise NotImplementedError

    def propagate(self, positions: np.ndarray, compass_angle: float) -> tuple[np.ndarray, np.ndarray]:
        """Draw x_k ~ p(x_k | x_{k-1}): uniform on the arc of radius L around th0 (headings too)."""
        headings = sample_headings(compass_angle, self.delta, len(positions), self.rng, positions.dtype)
        return move(positions, headings, self.speed), headings

    def motion(self, compass_angle: float) -> tuple[Move, Move]:
        """This step's transition, for resampled ancestors and for injected points (draw_particles)."""

        def points(positions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
            return self.propagate(positions, compass_angle)

        return (lambda ancestors: points(take_particles(self.positions, ancestors))), points

    def likelihood(self, z: float, positions: np.ndarray) -> np.ndarray:
        """log p(z_k | x) of equation (3) with the outside penalty, shape (N,)."""
        return log_likelihood(z, positions, self.world, self.sigma, self.outside_penalty)

    # the weighted posterior
    @property
    def weights(self) -> np.ndarray:
        """The normalised weights W_i = exp(log w_i), shape (N,)."""
        return self._cached("weights", lambda: np.exp(self.log_weights))

    @property
    def ess(self) -> float:
        return self._cached("ess", lambda: effective_sample_size(self.weights))

    @property
    def estimate(self) -> np.ndarray:
        """The posterior mean sum_i W_i x_i (the paper's), or the heaviest mode's mean, shape (2,)."""
        if self.estimate_rule == "mode":
            return self.modes[0].mean.copy() if self.modes else self.mean
        return self.mean

    @property
    def mean(self) -> np.ndarray:
        """The posterior mean sum_i W_i x_i, shape (2,)."""
        return self._cached("estimate", lambda: weighted_mean(self.weights, self.positions)).copy()

    @property
    def modes(self) -> list[Mode]:
        """The cloud's modes (connected occupied bins, mazelab.modes), heaviest first."""
        return self._cached("modes", lambda: find_modes(self.positions, self.weights))

    @property
    def is_confident(self) -> bool:
        """At least 95% of the weight lies within distance 1 of the estimate (the paper's green circle)."""
        return (
            self._cached(
                "confident", lambda: mass_within(self.weights, self.positions, self.estimate, CONFIDENCE_RADIUS)
            )
            >= CONFIDENCE_SHARE
        )

    def _cached(self, name: str, compute: Callable[[], Any]) -> Any:
        """`compute()`, remembered until `positions` or `log_weights` is assigned a new array."""
        described = self._summary_of
        if described is None or described[0] is not self.positions or described[1] is not self.log_weights:
            self._summary_of, self._summary = (self.positions, self.log_weights), {}
        if name not in self._summary:
            self._summary[name] = compute()
        return self._summary[name]

    # shared bookkeeping
    def _set_weights(self, log_w: np.ndarray, z: float) -> None:
        """Normalise new log weights; if their total underflows, no particle explains z: restart."""
        total = log_sum_exp(log_w)
        if total < LOG_UNDERFLOW or np.isnan(total):
            self._reinitialise(z)
        else:
            self.log_weights = np.subtract(log_w, total, dtype=float)

    def _reinitialise(self, z: float) -> None:
        """Start again from the prior (uniform over the free area), weighted by the current z."""
        self.reinitialised_at.append(self.steps_done + 1)
        if self.kld is not None:  # the prior is as spread as a belief gets: the most particles
            self.count, self.headings = self.max_count, np.zeros(self.max_count, dtype=PARTICLE_DTYPE)
        self.positions = np.asfortranarray(self.world.random_free_places(self.count, self.rng), dtype=PARTICLE_DTYPE)
        log_w = self.likelihood(z, self.positions)
        total = log_sum_exp(log_w)
        uniform = total < LOG_UNDERFLOW
        self.log_weights = (
            np.full(self.count, -math.log(self.count)) if uniform else np.subtract(log_w, total, dtype=float)
        )


class SIRParticleFilter(ParticleFilter):
    """Sampling importance resampling (bootstrap filter), Arulampalam et al. Algorithm 4."""

    name = "SIRParticleFilter"

    def step(self, compass_angle: float, z: float) -> None:
        # RESAMPLE (end of Alg. 4, previous step), then x_k^i ~ p(x_k | x_{k-1}^i)
        x, headings, _, _ = self.draw_particles(self.weights, *self.motion(compass_angle))
        self.positions, self.headings = x, headings
        log_lik = self.likelihood(z, x)
        self._set_weights(log_lik, z)  # w_k^i = p(z_k | x_k^i), then normalise
        if self.recovery is not None:  # w_avg = the mean of p(z_k | x_k^i) over the resampled particles
            self.track_likelihood(log_sum_exp(log_lik) - math.log(len(x)), z)
        self.steps_done += 1


class AuxiliaryParticleFilter(ParticleFilter):
    """Auxiliary particle filter, Arulampalam et al. Algorithm 5, with refinement 2:
    the auxiliary point mu_i is one draw from the transition p(x_k | x_{k-1}^i)."""

    name = "AuxiliaryParticleFilter"

    def step(self, compass_angle: float, z: float) -> None:
        mu, _ = self.propagate(self.positions, compass_angle)  # mu_k^i ~ p(x_k | x_{k-1}^i)
        log_mu_likelihood = self.likelihood(z, mu)
        first_stage = self.log_weights + log_mu_likelihood  # w_k^i ∝ p(z_k | mu_k^i) w_{k-1}^i
        log_first_total = log_sum_exp(first_stage)  # log F, F = sum_i W_{k-1}^i p(z_k | mu_k^i)
        if log_first_total < LOG_UNDERFLOW:
            self._reinitialise(z)
            self.track_likelihood(log_first_total, z)
        else:
            # i^j ~ the first stage, then x_k^j ~ p(x_k | x_{k-1}^{i^j})
            x, headings, ancestors, injected = self.draw_particles(
                exp_in_place(first_stage - log_first_total), *self.motion(compass_angle)
            )
            self.positions, self.headings = x, headings
            log_lik = self.likelihood(z, x)
            second_stage = log_lik - log_mu_likelihood.take(ancestors)  # p(z|x^j) / p(z|mu^{i^j})
            if self.recovery is None:
                self._set_weights(second_stage, z)
            else:
                # On the scale of p(z_k | z_1:k-1): F p(z|x^j) / p(z|mu^{i^j}), whose mean is Pitt and
                # Shephard's estimate of it; an injected particle has no ancestor and carries p(z|x^j).
                log_w = second_stage + log_first_total
                if injected is not None:
                    log_w = np.where(injected, log_lik, log_w)
                self._set_weights(log_w, z)
                self.track_likelihood(log_sum_exp(log_w) - math.log(len(x)), z)
        self.steps_done += 1


class RegularizedParticleFilter(ParticleFilter):
    """Regularised particle filter, Arulampalam et al. Algorithm 6, with refinements 3-5: the prior
    as proposal, a 2-D Gaussian kernel, and regularisation when N_eff < N_T = threshold * N_S.

    `bandwidth`: "optimal" (the paper's h_opt with the whole cloud's covariance), "multimodal" (one
    kernel per mode, beyond the paper) or a number h; see mazelab.regularisation."""

    name = "RegularizedParticleFilter"

    def __init__(self, *args: Any, threshold: float = RPF_THRESHOLD, bandwidth: str | float = "optimal", **kwargs: Any):
        super().__init__(*args, **kwargs)
        if not 0 < threshold <= 1:
            raise ValueError(f"the RPF threshold must be in (0, 1] (N_T = threshold * N_S), got {threshold}")
        self.threshold = threshold
        self.bandwidth_rule = check_bandwidth(bandwidth)
        self.regularised_at: list[int] = []

    @property
    def bandwidth(self) -> float:
        """h of the whole-cloud kernel: h_opt = A N^(-1/(n+4)), A = (4/(n+2))^(1/(n+4)) in n = 2
        dimensions, or the number given (with "multimodal" each mode has its own h_opt(n_c))."""
        if isinstance(self.bandwidth_rule, float):
            return self.bandwidth_rule
        return optimal_bandwidth(self.count)

    def step(self, compass_angle: float, z: float) -> None:
        if self.ess < self.threshold * self.count:  # IF N_eff < N_T (end of Alg. 6, previous step)
            self.regularise()
        elif self.injection_probability > 0:  # recovery: lost, though the weights have not degenerated
            self.inject_without_resampling(_unmoved)
        x, headings = self.propagate(self.positions, compass_angle)  # x_k^i ~ q = p(x_k | x_{k-1}^i)
        self.positions, self.headings = x, headings
        log_w = self.log_weights + self.likelihood(z, x)  # w_k^i ∝ w_{k-1}^i p(z_k | x_k^i)
        if self.recovery is not None:  # W_{k-1} is normalised: w_avg = sum_i W_{k-1}^i p(z_k | x_k^i)
            self.track_likelihood(log_sum_exp(log_w), z)
        self._set_weights(log_w, z)
        self.steps_done += 1

    def regularise(self) -> None:
        """Resample, then jitter each particle by h D eps, eps ~ N(0, I_2), D D^T = S (the kernel K_h)."""
        weights = self.weights
        kernel = self.kernel(weights)

        def jitter(ancestors: np.ndarray) -> tuple[np.ndarray, np.ndarray]:  # x^{i*} + h D eps
            eps = self.rng.standard_normal((len(ancestors), 2), dtype=PARTICLE_DTYPE)
            resampled = take_particles(self.positions, ancestors)
            return resampled + kernel(resampled, eps), self.headings.take(ancestors)

        # RESAMPLE and jitter; injected points (recovery) are not jittered: the step's move follows
        self.positions, self.headings, _, _ = self.draw_particles(weights, jitter, _unmoved)
        self.log_weights = np.full(self.count, -math.log(self.count))
        self.regularised_at.append(self.steps_done)

    def kernel(self, weights: np.ndarray) -> Kernel:
        """This regularisation's kernel: h D_k with the whole cloud's S_k, or one per mode (multimodal)."""
        if self.bandwidth_rule == "multimodal":
            return mixture_kernel
        return whole_cloud_kernel(weights, self.positions, self.bandwidth)


def _unmoved(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Injected points as they are (the RPF's step moves them next), with zero headings."""
    return points, np.zeros(len(points), dtype=PARTICLE_DTYPE)


__all__ = [
    "AuxiliaryParticleFilter",
    "ParticleFilter",
    "RegularizedParticleFilter",
    "SIRParticleFilter",
    "gaussian_jitter",
]
