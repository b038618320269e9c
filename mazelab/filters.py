"""The paper's particle filters: SIR, APF and RPF (Arulampalam, Maskell, Gordon, Clapp 2002,
Algorithms 4, 5 and 6) with the paper's refinements, weights in the log domain.

Each is the step template (mazelab.engine.SMC.step: resample when it is time, move, reweight) with its
own hooks: SIR is the template's defaults (Algorithm 4); the APF adds the first stage (`log_eta`) and
the second-stage weights (`reweight_resampled`, Algorithm 5); the RPF resamples when N_eff < N_T and
jitters the resampled particles (`move_after_resampling`) before every particle takes the transition
(Algorithm 6). The model and the runs are below the hooks (mazelab.cloud, mazelab.engine).
"""

from __future__ import annotations

import math
from typing import Any, ClassVar

import numpy as np

from mazelab.checks import check_bandwidth_within
from mazelab.cloud import ParticleFilter
from mazelab.constants import RPF_THRESHOLD
from mazelab.declaration import Option, Options, number_in
from mazelab.regularisation import (
    BANDWIDTH_OPTION,
    GaussianKernel,
    Kernel,
    gaussian_jitter,
    mixture_kernel,
    optimal_bandwidth,
)


class SIRParticleFilter(ParticleFilter):
    """Sampling importance resampling (bootstrap filter), Arulampalam et al. Algorithm 4: the step
    template's defaults (mazelab.engine.SMC.step): RESAMPLE, x_k^i ~ p(x_k | x_{k-1}^i), w_k^i = p(z_k | x_k^i)."""

    name = "SIRParticleFilter"


class AuxiliaryParticleFilter(ParticleFilter):
    """Auxiliary particle filter, Arulampalam et al. Algorithm 5, with refinement 2:
    the auxiliary point mu_i is one draw from the transition p(x_k | x_{k-1}^i)."""

    name = "AuxiliaryParticleFilter"

    def log_eta(self) -> np.ndarray:
        """The first stage's factor: log p(z_k | mu_k^i), mu_k^i ~ p(x_k | x_{k-1}^i) (refinement 2).

        Returns
        -------
        array (R, N)
        """
        mu, _ = self.transition(self.positions)  # mu_k^i ~ p(x_k | x_{k-1}^i)
        self.log_mu_lik = self.log_likelihood(mu)  # p(z_k | mu_k^i)
        return self.log_mu_lik

    def reweight_resampled(self, log_lik: np.ndarray, ancestors: np.ndarray) -> tuple[np.ndarray, Any]:
        """The second stage: w_k^j = p(z_k | x_k^j) / p(z_k | mu_k^{i^j}); its mean times the first
        stage's total F = sum_i W_{k-1}^i p(z_k | mu_k^i) estimates p(z_k | z_1:k-1) (Pitt and Shephard).

        Parameters
        ----------
        log_lik : array (R, N)
            log p(z_k | x_k^j).
        ancestors : int array
            i^j.

        Returns
        -------
        (log w (R, N), log F (R,), or 0.0 when the weights carry F already: recovery's)
        """
        log_mu, self.log_mu_lik = self.log_mu_lik, None  # log p(z_k | mu_k^i), spent here
        # log p(z_k | x_k^j) - log p(z_k | mu_k^{i^j}); into log_lik's array unless recovery reads it after
        second_stage = self.ops.second_stage(log_lik, log_mu, ancestors, log_lik if self.recovery is None else None)
        log_F = self.first_stage_log_total
        if self.recovery is not None:  # on recovery's scale: injected particles carry p(z | x^j)
            return predictive_scale(second_stage, log_F, log_lik, self._injected), 0.0
        return second_stage, log_F


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
    moved_by_resampling = False  # the jittered particles take the transition with the rest

    def __init__(self, *args: Any, **options: Any):
        super().__init__(*args, **options)
        self.bandwidth_rule = check_bandwidth_within(self.settings["bandwidth"], self.world.width, self.world.height)

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
        return self.resampled_at

    @property
    def diagnostics(self) -> dict[str, Any]:
        """ParticleFilter's, and whether this step began by regularising (bool, or (R,) for R runs)."""
        now = bool(self.resampled_now[0]) if self.runs == 1 else self.resampled_now.copy()
        return {**super().diagnostics, "regularised": now}

    def ancestors(self, W: np.ndarray) -> np.ndarray:
        """IF N_eff < N_T (`time_to_resample`): the kernel K_h of the weighted cloud, then RESAMPLE; the
        resampled particles are jittered (`move_after_resampling`), injected points (recovery) not.

        Parameters
        ----------
        W : array (R, N)
            The normalised weights (the served rows are resampled).

        Returns
        -------
        int array
            a^i, indices into `positions`.
        """
        self._kernels = self.kernels(self.selected_rows(W), self.selected_points())
        return super().ancestors(W)

    def move_after_resampling(self, ancestors: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """x^i = x^{a^i} + h D eps, eps ~ N(0, I_2), D D^T = S (the kernel K_h); the transition follows.

        Parameters
        ----------
        ancestors : int array

        Returns
        -------
        (positions, headings): the headings zeros, read-only (the transition that follows sets every
        particle's; none is made)
        """
        eps = self.normal_draws(len(ancestors))  # eps ~ N(0, I_2)
        jittered = self.ops.jitter(self.positions, ancestors, eps, self._kernels)
        return jittered, np.broadcast_to(np.zeros(1, dtype=self.positions.dtype), (len(ancestors),))

    def reweight_resampled(self, log_lik: np.ndarray, ancestors: np.ndarray) -> tuple[np.ndarray, None]:
        """W^i = 1 / N after resampling: w_k^i ∝ W^i p(z_k | x_k^i), whose total estimates p(z_k | z_1:k-1).

        Parameters
        ----------
        log_lik : array (R, N)
        ancestors : int array

        Returns
        -------
        (log w (R, N), None)
        """
        return self.ops.equal_weighted(log_lik, -math.log(self.count)), None  # log W^i + log p(z_k | x_k^i)

    def kernels(self, weights: np.ndarray, clouds: np.ndarray) -> list[Kernel]:
        """Each run's kernel: h D_k with its whole cloud's S_k, or one per mode (multimodal).

        Parameters
        ----------
        weights : array (R, N)
            The runs' normalised weights.
        clouds : array (R*N, 2)
            Their particles.

        Returns
        -------
        list of Kernel, one per run
        """
        if self.bandwidth_rule == "multimodal":
            return [mixture_kernel] * len(weights)
        covariance = self.ops.weighted_covariance(weights, clouds)  # S_k per run, the weighted covariance
        D = np.linalg.cholesky(covariance + 1e-12 * np.eye(2))  # D_k D_k^T = S_k (tiny ridge: S may be 0)
        return [GaussianKernel(scale) for scale in self.bandwidth * D]


__all__ = [
    "AuxiliaryParticleFilter",
    "ParticleFilter",
    "RegularizedParticleFilter",
    "SIRParticleFilter",
    "gaussian_jitter",
]
