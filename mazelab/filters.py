"""The paper's particle filters: SIR, APF and RPF (Arulampalam, Maskell, Gordon, Clapp 2002,
Algorithms 4, 5 and 6) with the paper's refinements, weights in the log domain.

Where each algorithm's lines are: SIRParticleFilter.step (Algorithm 4), AuxiliaryParticleFilter.step
(Algorithm 5), RegularizedParticleFilter.step and .regularise (Algorithm 6). The cloud they share (its
weights, estimate, ESS, resampling and restarts) is mazelab.cloud.ParticleFilter. Each step serves one
run (compass angle and z plain numbers) and R runs together (arrays (R,)), with the same lines.
"""

from __future__ import annotations

import math
from typing import Any, ClassVar

import numpy as np

from mazelab.checks import check_bandwidth_within
from mazelab.cloud import ParticleFilter
from mazelab.declaration import Option, Options, number_in
from mazelab.model import LOG_UNDERFLOW, PARTICLE_DTYPE, RPF_THRESHOLD
from mazelab.regularisation import (
    BANDWIDTH_OPTION,
    GaussianKernel,
    Kernel,
    gaussian_jitter,
    mixture_kernel,
    optimal_bandwidth,
)
from mazelab.run_axis import per_run
from mazelab.weights import log_sum_exp


class SIRParticleFilter(ParticleFilter):
    """Sampling importance resampling (bootstrap filter), Arulampalam et al. Algorithm 4."""

    name = "SIRParticleFilter"

    def step(self, compass_angle: float | np.ndarray, z: float | np.ndarray) -> None:
        """One step of Algorithm 4.

        Parameters
        ----------
        compass_angle : float, or array (R,)
            th0_k, the heading the compass reports for this step (radians), of each run.
        z : float, or array (R,)
            z_k, the measured distance to the nearest station (map units), of each run.
        """
        compass_angle, z = per_run(compass_angle, self.runs), per_run(z, self.runs)
        # RESAMPLE (end of Alg. 4, previous step), then x_k^i ~ p(x_k | x_{k-1}^i)
        x, headings, _, _ = self.draw_particles(self.run_weights, *self.motion(compass_angle), None)
        self.replace_runs(x, headings)
        log_lik = self.likelihood(z, x)
        self.normalise(log_lik, z)  # w_k^i = p(z_k | x_k^i), then normalise
        if self.recovery is not None:  # w_avg = the mean of p(z_k | x_k^i) over the resampled particles
            self.track_likelihood(log_sum_exp(log_lik) - math.log(self.count), z)
        self.steps_done += 1


class AuxiliaryParticleFilter(ParticleFilter):
    """Auxiliary particle filter, Arulampalam et al. Algorithm 5, with refinement 2:
    the auxiliary point mu_i is one draw from the transition p(x_k | x_{k-1}^i)."""

    name = "AuxiliaryParticleFilter"

    def step(self, compass_angle: float | np.ndarray, z: float | np.ndarray) -> None:
        """One step of Algorithm 5.

        Parameters
        ----------
        compass_angle : float, or array (R,)
            th0_k, the heading the compass reports for this step (radians), of each run.
        z : float, or array (R,)
            z_k, the measured distance to the nearest station (map units), of each run.
        """
        compass_angle, z = per_run(compass_angle, self.runs), per_run(z, self.runs)
        mu, _ = self.propagate(self.positions, compass_angle)  # mu_k^i ~ p(x_k | x_{k-1}^i)
        log_mu_lik = self.likelihood(z, mu)
        # the first stage w_k^i ∝ p(z_k | mu_k^i) w_{k-1}^i, normalised, and F = sum_i W_{k-1}^i p(z_k | mu_k^i)
        first_weights, log_F = self.normalised(self.run_log_weights, log_mu_lik)
        lost = log_F < LOG_UNDERFLOW  # no mu explains z_k: these runs restart from the prior
        drawn, second_stage = (np.flatnonzero(~lost) if lost.any() else None), None  # None: every run
        if drawn is None or len(drawn):
            # i^j ~ the first stage, then x_k^j ~ p(x_k | x_{k-1}^{i^j})
            x, headings, ancestors, injected = self.draw_particles(first_weights, *self.motion(compass_angle), drawn)
            self.replace_runs(x, headings, drawn)
            log_lik = self.likelihood(z if drawn is None else z[drawn], x)
            log_mu_ancestor = log_mu_lik.ravel().take(ancestors).reshape(len(log_lik), -1)
            second_stage = log_lik - log_mu_ancestor  # w_k^j = p(z_k | x_k^j) / p(z_k | mu_k^{i^j})
            if self.recovery is not None:
                second_stage = predictive_scale(second_stage, log_F, log_lik, injected)
        log_w = self.all_runs(second_stage, drawn)
        self.normalise(log_w, z, lost)  # normalise; the lost runs restart
        if self.recovery is not None:  # w_avg of this step (one run)
            self.track_likelihood(log_F if lost[0] else log_sum_exp(log_w) - math.log(self.count), z)
        self.steps_done += 1


def predictive_scale(
    second_stage: np.ndarray, log_F: np.ndarray, log_lik: np.ndarray, injected: np.ndarray | None
) -> np.ndarray:
    """The APF's weights on the scale of p(z_k | z_1:k-1), for recovery's w_avg: F p(z|x^j) / p(z|mu^{i^j}),
    whose mean is Pitt and Shephard's estimate of it; an injected particle has no ancestor and carries
    p(z|x^j). Normalising them gives the second-stage weights again.

    Parameters
    ----------
    second_stage : array (R, N)
        log p(z | x^j) - log p(z | mu^{i^j}).
    log_F : array (R,)
        log F, the first stage's total.
    log_lik : array (R, N)
        log p(z | x^j).
    injected : bool array (N,), or None
        Recovery's injected particles.

    Returns
    -------
    array (R, N)
    """
    log_w = second_stage + log_F.astype(second_stage.dtype)[:, None]
    return log_w if injected is None else np.where(injected, log_lik, log_w)


class RegularizedParticleFilter(ParticleFilter):
    """Regularised particle filter, Arulampalam et al. Algorithm 6, with refinements 3-5: the prior
    as proposal, a 2-D Gaussian kernel, and regularisation when N_eff < N_T = threshold * N_S.

    `threshold`: N_T / N_S (the paper's 0.2). `bandwidth`: "optimal" (the paper's h_opt with the whole
    cloud's covariance), "multimodal" (one kernel per mode, beyond the paper) or a number h; see
    mazelab.regularisation. The other options are ParticleFilter's."""

    name = "RegularizedParticleFilter"
    options: ClassVar[Options] = ParticleFilter.options.extend(
        Option(
            "threshold", RPF_THRESHOLD, "N_T / N_S: regularise when the ESS falls below N_T (refinement 5: 0.2)",
            check=number_in("the RPF threshold", 0.0, 1.0, what=" (N_T = threshold * N_S)"), flag="--threshold",
        ),
        BANDWIDTH_OPTION,
    )  # fmt: skip

    def __init__(self, *args: Any, **options: Any):
        super().__init__(*args, **options)
        self.threshold = self.settings["threshold"]
        self.bandwidth_rule = check_bandwidth_within(self.settings["bandwidth"], self.world.width, self.world.height)
        self._regularised: list[list[int]] = [[] for _ in range(self.runs)]
        self._regularised_now = np.zeros(self.runs, dtype=bool)

    @property
    def bandwidth(self) -> float:
        """h of the whole-cloud kernel: h_opt = A N^(-1/(n+4)), A = (4/(n+2))^(1/(n+4)) in n = 2
        dimensions, or the number given (with "multimodal" each mode has its own h_opt(n_c))."""
        if isinstance(self.bandwidth_rule, float):
            return self.bandwidth_rule
        return optimal_bandwidth(self.count)

    @property
    def regularised_at(self) -> list[int] | list[list[int]]:
        """The steps after which the filter regularised (a list per run for R runs)."""
        return self._one(self._regularised)

    @property
    def diagnostics(self) -> dict[str, Any]:
        """ParticleFilter's, and whether this step began by regularising (bool, or (R,) for R runs)."""
        now = bool(self._regularised_now[0]) if self.runs == 1 else self._regularised_now.copy()
        return {**super().diagnostics, "regularised": now}

    def step(self, compass_angle: float | np.ndarray, z: float | np.ndarray) -> None:
        """One step of Algorithm 6.

        Parameters
        ----------
        compass_angle : float, or array (R,)
            th0_k, the heading the compass reports for this step (radians), of each run.
        z : float, or array (R,)
            z_k, the measured distance to the nearest station (map units), of each run.
        """
        compass_angle, z = per_run(compass_angle, self.runs), per_run(z, self.runs)
        degenerate = self.run_ess < self.threshold * self.count  # IF N_eff < N_T (end of Alg. 6, previous step)
        self._regularised_now = degenerate
        if degenerate.any():
            self.regularise(None if degenerate.all() else np.flatnonzero(degenerate))
        elif self.injection_probability > 0:  # recovery: lost, though the weights have not degenerated
            self.inject_without_resampling(_unmoved)
        x, headings = self.propagate(self.positions, compass_angle)  # x_k^i ~ q = p(x_k | x_{k-1}^i)
        self.positions, self.headings = x, headings
        log_w = self.run_log_weights + self.likelihood(z, x)  # w_k^i ∝ w_{k-1}^i p(z_k | x_k^i)
        if self.recovery is not None:  # W_{k-1} is normalised: w_avg = sum_i W_{k-1}^i p(z_k | x_k^i)
            self.track_likelihood(log_sum_exp(log_w), z)
        self.normalise(log_w, z)
        self.steps_done += 1

    def regularise(self, runs: np.ndarray | None = None) -> None:
        """RESAMPLE the given runs (default all), then jitter each particle by h D eps, eps ~ N(0, I_2),
        D D^T = S (the kernel K_h); their weights become 1/N.

        Parameters
        ----------
        runs : int array, optional
            The runs to regularise (None: every run).
        """
        chosen = np.arange(self.runs) if runs is None else runs
        weights = self.run_weights
        kernels = self.kernels(weights if runs is None else weights[runs], chosen)

        def jitter(ancestors: np.ndarray, _: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:  # x^{i*} + h D eps
            size = len(ancestors) // len(chosen)
            eps = self.ops.buffer("eps", (len(ancestors), 2), PARTICLE_DTYPE)  # eps ~ N(0, I_2), run by run
            for block, run in enumerate(chosen):
                self.rngs[run].standard_normal(dtype=PARTICLE_DTYPE, out=eps[block * size : (block + 1) * size])
            return self.ops.jitter(self.positions, self.headings, ancestors, eps, kernels)

        # RESAMPLE and jitter; injected points (recovery) are not jittered: the step's move follows
        x, headings, _, _ = self.draw_particles(weights, jitter, _unmoved, runs)
        self.replace_runs(x, headings, runs)
        self.set_uniform_weights(runs)  # W^i = 1 / N
        for run in chosen:
            self._regularised[run].append(self.steps_done)

    def kernels(self, weights: np.ndarray, runs: np.ndarray) -> list[Kernel]:
        """Each given run's kernel: h D_k with its whole cloud's S_k, or one per mode (multimodal).

        Parameters
        ----------
        weights : array (len(runs), N)
            The given runs' normalised weights.
        runs : int array

        Returns
        -------
        list of Kernel, one per given run
        """
        if self.bandwidth_rule == "multimodal":
            return [mixture_kernel] * len(runs)
        clouds = np.concatenate([self.run_positions(run) for run in runs]) if len(runs) < self.runs else self.positions
        covariance = self.ops.weighted_covariance(weights, clouds)  # S_k per run, the weighted covariance
        D = np.linalg.cholesky(covariance + 1e-12 * np.eye(2))  # D_k D_k^T = S_k (tiny ridge: S may be 0)
        return [GaussianKernel(scale) for scale in self.bandwidth * D]


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
