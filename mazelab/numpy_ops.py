"""The hot parts of the particle filters in numpy: the reference backend (mazelab.backend), each
operation the very numpy calls the lab always made, so that the numpy path stays bit for bit as it was.
The compiled backend (mazelab.kernels.compiled.CompiledKernels) offers the same methods."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from mazelab.model import headings_from_uniforms, log_likelihood, move, take_particles
from mazelab.resampling import systematic_resample_runs
from mazelab.weights import (
    effective_sample_size,
    log_sum_exp,
    mass_within,
    weighted_covariance,
    weighted_mean,
    weights_from_logs,
)


class NumpyKernels:
    """The hot parts in numpy: the lab's reference, each operation the same numpy calls as always.

    Every method returns fresh arrays (nothing is reused); `CompiledKernels` has the same methods.
    """

    name = "numpy"

    def buffer(self, name: str, shape: tuple[int, ...], dtype: Any) -> np.ndarray:
        """An array to be filled (np.empty: numpy makes a fresh one each time).

        Parameters
        ----------
        name : str
            What it holds (the compiled backend reuses one array per name).
        shape : tuple of int
        dtype : numpy dtype

        Returns
        -------
        numpy.ndarray, C order
        """
        return np.empty(shape, dtype=dtype)

    def move(
        self,
        positions: np.ndarray,
        ancestors: np.ndarray | None,
        uniforms: np.ndarray,
        angles: np.ndarray,
        delta: float,
        speed: float,
    ) -> tuple[np.ndarray, np.ndarray]:
        """Equation (1): positions[ancestors] moved along th = th0 + Delta (u - 1/2), for R runs.

        Parameters
        ----------
        positions : array (P, 2)
        ancestors : int array (R*M,), or None for every particle in order
        uniforms : array (R, M)
            u ~ U[0, 1) in the positions' dtype, run r's in row r (overwritten by the headings).
        angles : array (R,)
            th0_k of each run, in the positions' dtype.
        delta, speed : float
            Delta (radians) and L (map units).

        Returns
        -------
        (moved positions (R*M, 2) order F, headings (R*M,)), in the positions' dtype
        """
        if ancestors is not None:
            positions = take_particles(positions, ancestors)
        headings = headings_from_uniforms(uniforms, angles[:, None], delta).reshape(-1)
        return move(positions, headings, speed), headings

    def log_likelihood(
        self, z: np.ndarray, positions: np.ndarray, world: Any, sigma: float, outside_penalty: float
    ) -> np.ndarray:
        """Equation (3) in logs with the outside penalty, for R runs (mazelab.model.log_likelihood).

        Parameters
        ----------
        z : array (R,)
            z_k of each run whose block `positions` holds.
        positions : array (R*N, 2)
        world : Maze
        sigma, outside_penalty : float

        Returns
        -------
        array (R, N), in the positions' dtype
        """
        one = float(z[0]) if len(z) == 1 else z  # one run: a plain number (the same float32 arithmetic)
        return log_likelihood(one, positions, world, sigma, outside_penalty).reshape(len(z), -1)

    def systematic(self, weights: np.ndarray, uniforms: np.ndarray, runs: np.ndarray | None, count: int) -> np.ndarray:
        """Systematic resampling of the given runs (mazelab.resampling.systematic_resample_runs).

        Parameters
        ----------
        weights : array (R, N)
            Every run's normalised weights.
        uniforms : array (len(runs),)
            Each resampled run's offset U.
        runs : int array, or None for every run
        count : int
            N, the particles per run.

        Returns
        -------
        int array (len(runs) * N,)
            Indices into the (R*N,) particles, block b run runs[b]'s.
        """
        if runs is None:
            return systematic_resample_runs(weights, uniforms)
        ancestors = systematic_resample_runs(weights[runs], uniforms)  # block b of the result is run runs[b]'s
        ancestors += np.repeat(count * (runs - np.arange(len(runs))), count)
        return ancestors

    def normalise(self, log_w: np.ndarray, positions: np.ndarray) -> tuple[np.ndarray, np.ndarray, None]:
        """log W = log w - log sum exp(log w) per run.

        Parameters
        ----------
        log_w : array (R, N)
        positions : array (R*N, 2)
            The particles the weights belong to (the compiled backend reads them too).

        Returns
        -------
        (log totals (R,), log W (R, N) float64, None): no reads (the cloud computes them when asked)
        """
        totals = np.atleast_1d(log_sum_exp(log_w))
        return totals, np.subtract(log_w, totals[:, None], dtype=float), None

    def reweighted(self, log_a: np.ndarray, log_lik: np.ndarray, shifts: np.ndarray | None = None) -> np.ndarray:
        """log w_k = log W_{k-1} + log p(z_k | x_k) of runs that do not resample (log W_{k-1} = log_a -
        shifts, as the Weights value derives it; shifts None: log_a is log W_{k-1}).

        Parameters
        ----------
        log_a, log_lik : arrays (R, N)
        shifts : array (R,), optional

        Returns
        -------
        float64 array (R, N)
        """
        if shifts is not None:
            log_a = np.subtract(log_a, shifts[:, None], dtype=float)
        return log_a + log_lik

    def equal_weighted(self, log_lik: np.ndarray, log_weight: float) -> np.ndarray:
        """log W + log p(z_k | x_k) of resampled particles, whose weights are equal (log_weight = -log N).

        Parameters
        ----------
        log_lik : array (R, N)
        log_weight : float

        Returns
        -------
        float64 array (R, N)
        """
        return np.add(log_lik, log_weight, dtype=float)

    def normalised(
        self, log_a: np.ndarray, log_b: np.ndarray, shifts: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """W ∝ exp(log_a - shifts + log_b) per run, and log sum exp(log_a - shifts + log_b).

        Parameters
        ----------
        log_a, log_b : arrays (R, N)
        shifts : array (R,), optional
            Subtracted from each run's log_a (log w and its log total: log_a - shifts is log W, as the
            Weights value derives it); None: none.

        Returns
        -------
        (W (R, N), log totals (R,)); a run whose total is -inf has NaN weights
        """
        log_w = self.reweighted(log_a, log_b, shifts)  # log_a - shifts + log_b
        totals = np.atleast_1d(log_sum_exp(log_w))
        return weights_from_logs(log_w, totals), totals

    def second_stage(
        self, log_lik: np.ndarray, log_mu: np.ndarray, ancestors: np.ndarray, out: np.ndarray | None = None
    ) -> np.ndarray:
        """The APF's second-stage log weights log p(z_k | x^j) - log p(z_k | mu^{a^j}): the first stage's
        values gathered by the ancestors, then subtracted (into the gathered array where the dtypes agree;
        `out` is for the compiled backend, which writes in place).

        Parameters
        ----------
        log_lik : array (R, N)
        log_mu : array (R', N)
            The first stage's values of every run.
        ancestors : int array (R*N,)
            Rows of the particles of all runs.
        out : array (R, N), optional
            Ignored.

        Returns
        -------
        array (R, N)
        """
        gathered = log_mu.reshape(-1)[ancestors].reshape(len(log_lik), -1)  # log p(z_k | mu_k^{a^j})
        same = log_lik.dtype == gathered.dtype  # float64 where recovery injected float64 points
        return np.subtract(log_lik, gathered, out=gathered if same else None)

    def effective_sample_size(self, weights: np.ndarray) -> np.ndarray:
        """N_eff = 1 / sum_i W_i^2 per run (mazelab.weights.effective_sample_size).

        Parameters
        ----------
        weights : array (R, N)

        Returns
        -------
        array (R,)
        """
        return effective_sample_size(weights)

    def weighted_mean(self, weights: np.ndarray, positions: np.ndarray) -> np.ndarray:
        """sum_i W_i x_i per run (mazelab.weights.weighted_mean).

        Parameters
        ----------
        weights : array (R, N)
        positions : array (R*N, 2)

        Returns
        -------
        array (R, 2) float64
        """
        return weighted_mean(weights, positions)

    def mass_within(self, weights: np.ndarray, positions: np.ndarray, centres: np.ndarray, radius: float) -> np.ndarray:
        """The weight within `radius` of each run's centre (mazelab.weights.mass_within).

        Parameters
        ----------
        weights : array (R, N)
        positions : array (R*N, 2)
        centres : array (R, 2)
        radius : float

        Returns
        -------
        array (R,)
        """
        return mass_within(weights, positions, centres, radius)

    def weighted_covariance(self, weights: np.ndarray, positions: np.ndarray) -> np.ndarray:
        """Each run's weighted covariance (mazelab.weights.weighted_covariance).

        Parameters
        ----------
        weights : array (R, N)
        positions : array (R*N, 2)

        Returns
        -------
        array (R, 2, 2) float64
        """
        return weighted_covariance(weights, positions)

    def jitter(self, positions: np.ndarray, ancestors: np.ndarray, eps: np.ndarray, kernels: Sequence) -> np.ndarray:
        """The RPF's resampled particles, each run's block jittered by its kernel (mazelab.regularisation).

        Parameters
        ----------
        positions : array (P, 2)
        ancestors : int array (R*M,)
        eps : array (R*M, 2)
            Standard normal draws, block r run r's.
        kernels : sequence of R kernels
            (points, eps) -> jitter, each run's.

        Returns
        -------
        positions[ancestors] + jitter (R*M, 2), order F
        """
        moved = take_particles(positions, ancestors)
        size = len(ancestors) // len(kernels)
        for block, kernel in enumerate(kernels):
            rows = slice(block * size, (block + 1) * size)
            moved[rows] += kernel(moved[rows], eps[rows])
        return moved


__all__ = ["NumpyKernels"]
