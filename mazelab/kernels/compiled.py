"""The compiled backend's operations for one filter (mazelab.backend.NumpyKernels has the same
methods): each calls one kernel for all R runs, into buffers it reuses.

A buffer is reused only when nothing else holds it: the pool checks its reference count, so an array
the filter still holds (its positions, the weights it cached) or one a caller kept (a student's list of
`filt.positions`, a view of it) is never written over; the pool then makes another. Anything the
kernels do not cover (float64 points such as recovery's injected draws, the multimodal kernel)
goes to the numpy operations.
"""

from __future__ import annotations

import math
import sys
from collections.abc import Sequence
from typing import Any

import numba
import numpy as np

from mazelab.kernels import model, resampling, weights
from mazelab.model import CONFIDENCE_RADIUS, PARTICLE_DTYPE
from mazelab.numpy_ops import NumpyKernels
from mazelab.regularisation import GaussianKernel

THREADED_FROM = 1 << 16  # particles in a call from which the likelihood and the normalisation use the threads
_KEEP = 2  # arrays kept per buffer name and shape: the filter's and the one being filled (more are made
# while a caller holds one, and not kept: the step lets go of what it has spent, so two are enough)


class BufferPool:
    """Arrays by name, handed out again once nothing outside the pool refers to them."""

    def __init__(self) -> None:
        self._slots: dict[str, tuple] = {}  # name -> (shape, dtype, order, [arrays])
        probe = [np.empty(1)]
        # an array only the pool holds, as `take` sees it: its list's reference, the loop's and the call's
        self._unheld = sys.getrefcount(probe[0]) + 1

    def take(self, name: str, shape: tuple[int, ...], dtype: Any, order: str = "C") -> np.ndarray:
        """An array of this shape, dtype and order, not referred to by anything but the pool.

        Parameters
        ----------
        name : str
            What it holds (positions, weights, ...).
        shape : tuple of int
        dtype : numpy dtype
        order : "C" or "F"

        Returns
        -------
        numpy.ndarray
            Uninitialised (its old values, or new memory).
        """
        held = self._slots.get(name)
        if held is None or held[0] != shape or held[1] != dtype or held[2] != order:
            held = self._slots[name] = (shape, dtype, order, [])  # new, or another shape (KLD, some runs)
        unheld = self._unheld
        for array in held[3]:
            if _references(array) == unheld:
                return array
        array = np.empty(shape, dtype=dtype, order=order)
        if len(held[3]) < _KEEP:
            held[3].append(array)
        return array


_references = sys.getrefcount


def lookup_tables(world: Any) -> tuple:
    """The maze's nearest-station tables (mazelab.lookup) in the layout the likelihood kernel reads:
    float32, each cell's first two candidates side by side, the rest of the few cells with more in
    one flat array, and one code a cell.

    Parameters
    ----------
    world : Maze

    Returns
    -------
    tuple
        (scale, offset, nx, ny, codes (C,) uint32, pairs (C, 4), rows, width, border (b, 2)), the
        numbers plain Python ones. pairs[c] is cell c's first and second candidate (x0, y0, x1, y1),
        the second a repeat of the first in a cell with one; `rows` holds, for each cell with more than
        two, its other K - 2 candidates' (x, y) (padded by repeats of its first), `width` = 2 (K - 2)
        values a row; a cell's code is its row's first index in `rows` times 4, plus 2 if it has a
        row, plus 1 if the cell is free.
    """
    lookup = world.prepare()._lookup
    tables = lookup._station_tables(np.dtype(PARTICLE_DTYPE))
    ambiguous = np.flatnonzero(lookup.row >= 0)
    pairs = np.concatenate([tables.first, tables.first], axis=1)
    pairs[ambiguous, 2] = tables.all_x[1, lookup.row[ambiguous]]
    pairs[ambiguous, 3] = tables.all_y[1, lookup.row[ambiguous]]
    candidates = lookup._all  # (A, K) station indices, padded by repeats of the first
    more = np.flatnonzero((candidates[:, 2:] != candidates[:, :1]).any(axis=1))  # rows with a third candidate
    rows = np.stack([tables.all_x[2:, more].T, tables.all_y[2:, more].T], axis=-1)  # (rows, K - 2, 2)
    width = rows.shape[1] * 2
    codes = (lookup.kind & 1).astype(np.uint64)
    codes[ambiguous[more]] += 2 + 4 * width * np.arange(len(more), dtype=np.uint64)
    return (
        float(lookup.scale),
        float(lookup.offset),
        int(lookup.nx),
        int(lookup.ny),
        codes.astype(np.uint32 if codes.max(initial=0) < 2**32 else np.uint64),
        np.ascontiguousarray(pairs),
        np.ascontiguousarray(rows).reshape(-1),
        width,
        np.ascontiguousarray(tables.border),
    )


class CompiledKernels(NumpyKernels):
    """The hot parts of one filter on `world`, compiled (mazelab.kernels), with reused buffers; what
    the kernels do not cover is NumpyKernels' (this class's parent).

    Parameters
    ----------
    world : Maze
        The filter's maze: its lookup tables are read once.
    threads : int, optional
        The threads one call's particles are spread over from THREADED_FROM particles on (the
        likelihood, its values the same to the bit; the normalisation, its sums in blocks: the same
        numbers for any count above one); default 1 (mazelab.backend.kernels_for passes MAZELAB_THREADS's).
    """

    name = "compiled"

    def __init__(self, world: Any, threads: int | None = None):
        self.tables = lookup_tables(world)
        self.pool = BufferPool()
        self._tables_of = world
        self.threads = min(threads or 1, numba.config.NUMBA_NUM_THREADS)
        self._terms_of: tuple = (None, ())  # (sigma, penalty), the likelihood's constants
        self._bases_of: tuple = (None, _NO_ANCESTORS)  # (R, N), each run's first row

    def _threaded(self, particles: int) -> bool:
        """Whether a call over `particles` runs on the threads (and numba's thread count set for it)."""
        if self.threads < 2 or particles < THREADED_FROM:
            return False
        numba.set_num_threads(self.threads)
        return True

    def buffer(self, name: str, shape: tuple[int, ...], dtype: Any) -> np.ndarray:
        """An array to be filled, C order, reused once no one else holds it (see BufferPool.take).

        Parameters
        ----------
        name : str
        shape : tuple of int
        dtype : numpy dtype

        Returns
        -------
        numpy.ndarray
        """
        return self.pool.take(name, shape, dtype)

    def move(
        self,
        positions: np.ndarray,
        ancestors: np.ndarray | None,
        uniforms: np.ndarray,
        angles: np.ndarray,
        delta: float,
        speed: float,
    ) -> tuple[np.ndarray, np.ndarray]:
        """Equation (1): NumpyKernels.move's arguments and results in one compiled pass (the headings,
        their cos and sin, the gather and the step); the headings are numpy's to the bit, cos and sin
        within 0.502 ulp of the exact value (mazelab.kernels.model.move). float64 points (or angles)
        go to numpy.

        Parameters
        ----------
        positions : array (P, 2)
        ancestors : int array (R*M,), or None
        uniforms : array (R, M)
        angles : array (R,)
        delta, speed : float

        Returns
        -------
        (moved positions (R*M, 2) order F, headings (R*M,)): the headings are the uniforms' array
        """
        if not positions.dtype == uniforms.dtype == angles.dtype == PARTICLE_DTYPE:
            return super().move(positions, ancestors, uniforms, angles, delta, speed)
        out = self.pool.take("positions", (uniforms.size, 2), PARTICLE_DTYPE, "F")
        sources = _NO_ANCESTORS if ancestors is None else ancestors
        model.move(positions, sources, uniforms, angles, float(delta), float(speed), out)
        return out, uniforms.reshape(-1)

    def log_likelihood(
        self, z: np.ndarray, positions: np.ndarray, world: Any, sigma: float, outside_penalty: float
    ) -> np.ndarray:
        """Equation (3) in logs, compiled: the locate and the likelihood in one pass (float32, the
        numpy path's values to the bit).

        Parameters
        ----------
        z : array (R,)
        positions : array (R*N, 2)
        world : Maze
        sigma, outside_penalty : float

        Returns
        -------
        float32 array (R, N)
        """
        if positions.dtype != PARTICLE_DTYPE or world is not self._tables_of:
            return super().log_likelihood(z, positions, world, sigma, outside_penalty)
        out = self.pool.take("log_likelihood", (len(z), len(positions) // len(z)), PARTICLE_DTYPE)
        kernel = model.log_likelihood_threads if self._threaded(len(positions)) else model.log_likelihood
        kernel(positions, z, *self._terms(sigma, outside_penalty), self.tables, out)
        return out

    def _terms(self, sigma: float, outside_penalty: float) -> tuple:
        """The likelihood kernel's constants: sigma, -log(sigma sqrt(2 pi)) and that plus log(outside
        penalty), worked out once for the filter's sigma and penalty (kept for the last pair)."""
        if self._terms_of[0] != (sigma, outside_penalty):
            norm = math.log(sigma * math.sqrt(2 * math.pi))
            self._terms_of = ((sigma, outside_penalty), (float(sigma), -norm, math.log(outside_penalty) - norm))
        return self._terms_of[1]

    def systematic(self, weights_: np.ndarray, uniforms: np.ndarray, runs: np.ndarray | None, count: int) -> np.ndarray:
        """Systematic resampling by counting, compiled (NumpyKernels.systematic's arguments and results).

        Parameters
        ----------
        weights_ : array (R, N)
            float32 as this backend's normalisation writes them (others are rounded to float32 first).
        uniforms : array (len(runs),)
        runs : int array, or None
        count : int

        Returns
        -------
        int32 array (len(runs) * N,) (int64 from 2**31 particles on)
        """
        if weights_.dtype != np.float32:  # the uniform start's (or derived) float64 W: the kernel of float32 W's
            weights_ = weights_.astype(np.float32)
        if runs is None:
            chosen, bases = weights_, self._bases(len(weights_), count)
        else:
            rows = np.asarray(runs, dtype=np.int64)
            chosen, bases = weights_[rows], rows * count
        index = np.int32 if len(weights_) * count < 2**31 else np.int64  # half the memory of numpy's int64
        out = self.pool.take("ancestors", (len(chosen) * count,), index)
        resampling.systematic(chosen, uniforms, count, bases, out)
        return out

    def _bases(self, runs: int, count: int) -> np.ndarray:
        """r * count for each of `runs` runs (int64 (R,)): the first row of each run's particles, made
        once for the filter's R and N (kept for the last pair, never written into)."""
        if self._bases_of[0] != (runs, count):
            self._bases_of = ((runs, count), np.arange(runs) * count)
        return self._bases_of[1]

    def normalise(self, log_w: np.ndarray, positions: np.ndarray) -> tuple[np.ndarray, None, dict | None]:
        """Each run's log total and W, with the step's reads: the top, the exponentials and the sums,
        then the normalisation, in three compiled passes over each run. log W is not written: the
        Weights value derives it from log w and the totals when it is read (the same values as log w -
        log total here), which saves a float64 array's writes and memory.

        Parameters
        ----------
        log_w : array (R, N)
        positions : array (R*N, 2)

        Returns
        -------
        (log totals (R,), None, reads): reads holds "weights" (R, N) float32, "ess" (R,), "mean" (R, 2)
        and "share" (R,), the weight within CONFIDENCE_RADIUS of the mean
        """
        if positions.dtype != PARTICLE_DTYPE or len(positions) != log_w.size:
            return super().normalise(log_w, positions)
        runs, size = log_w.shape
        w = self.pool.take("weights", (runs, size), np.float32)
        reads = np.empty((5, runs))  # the totals, the mean's x and y, the ESS, the share: one row each
        kernel = weights.normalise_threads if self._threaded(log_w.size) else weights.normalise
        kernel(log_w, positions, CONFIDENCE_RADIUS, w, reads)
        return reads[0], None, {"weights": w, "ess": reads[3], "mean": reads[1:3].T, "share": reads[4]}

    def normalised(
        self, log_a: np.ndarray, log_b: np.ndarray, shifts: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """W ∝ exp(log_a - shifts + log_b) per run and its log total (NumpyKernels.normalised), compiled
        into a reused array, with one exponential per particle (numpy's log_sum_exp and weights_from_logs
        take two); log_a - shifts is worked out per particle, never stored.

        Parameters
        ----------
        log_a, log_b : arrays (R, N)
        shifts : array (R,), optional

        Returns
        -------
        (W (R, N) float32, log totals (R,)); a run whose total is -inf (or NaN) gets NaN weights
        """
        w = self.pool.take("first_weights", log_a.shape, np.float32)
        totals = np.empty(len(log_a))
        weights.first_stage(log_a, np.zeros(len(log_a)) if shifts is None else shifts, log_b, w, totals)
        return w, totals

    def reweighted(self, log_a: np.ndarray, log_lik: np.ndarray, shifts: np.ndarray | None = None) -> np.ndarray:
        """NumpyKernels.reweighted's log W_{k-1} + log p(z_k | x_k) (its arguments) in one compiled pass:
        its float64 sum rounded to float32, written into log_lik's array (spent after it), no float64
        array made; float64 likelihoods (recovery's draws) go to numpy."""
        if log_lik.dtype != PARTICLE_DTYPE:
            return super().reweighted(log_a, log_lik, shifts)
        weights.reweighted(log_a, np.zeros(len(log_a)) if shifts is None else shifts, log_lik, log_lik)
        return log_lik

    def equal_weighted(self, log_lik: np.ndarray, log_weight: float) -> np.ndarray:
        """NumpyKernels.equal_weighted's log W + log p(z_k | x_k) (its arguments) in float32, into
        log_lik's array (spent after it); float64 likelihoods go to numpy."""
        if log_lik.dtype != PARTICLE_DTYPE:
            return super().equal_weighted(log_lik, log_weight)
        return np.add(log_lik, log_weight, out=log_lik)

    def second_stage(
        self, log_lik: np.ndarray, log_mu: np.ndarray, ancestors: np.ndarray, out: np.ndarray | None = None
    ) -> np.ndarray:
        """NumpyKernels.second_stage's log p(z_k | x^j) - log p(z_k | mu^{a^j}) (its arguments) in one
        compiled pass, the same float32 values, into `out` (log_lik itself, say) or a new array; float64
        values (recovery's draws) go to numpy."""
        if not log_lik.dtype == log_mu.dtype == PARTICLE_DTYPE or (out is not None and out.dtype != PARTICLE_DTYPE):
            return super().second_stage(log_lik, log_mu, ancestors, out)
        out = np.empty_like(log_lik) if out is None else out
        weights.second_stage(log_lik, log_mu, ancestors, out)
        return out

    def mass_within(
        self, weights_: np.ndarray, positions: np.ndarray, centres: np.ndarray, radius: float
    ) -> np.ndarray:
        """The weight within `radius` of each run's centre (R, 2), compiled.

        Parameters
        ----------
        weights_ : array (R, N)
        positions : array (R*N, 2)
        centres : array (R, 2)
        radius : float

        Returns
        -------
        array (R,)
        """
        shares = np.empty(len(weights_))
        weights.mass_within(weights_, positions, np.asarray(centres, dtype=float).reshape(-1, 2), radius, shares)
        return shares

    def weighted_covariance(self, weights_: np.ndarray, positions: np.ndarray) -> np.ndarray:
        """Each run's weighted covariance, compiled (two passes: the mean, then the moments).

        Parameters
        ----------
        weights_ : array (R, N)
        positions : array (R*N, 2)

        Returns
        -------
        array (R, 2, 2) float64
        """
        if positions.dtype != PARTICLE_DTYPE:
            return super().weighted_covariance(weights_, positions)
        out = np.empty((len(weights_), 2, 2))
        weights.covariance(weights_, positions, out)
        return out

    def jitter(self, positions: np.ndarray, ancestors: np.ndarray, eps: np.ndarray, kernels: Sequence) -> np.ndarray:
        """The RPF's gather and jitter in one pass for Gaussian kernels (h D eps, one D per run); the
        multimodal kernel goes to numpy.

        Parameters
        ----------
        positions : array (P, 2)
        ancestors : int array (R*M,)
        eps : array (R*M, 2)
        kernels : sequence of R kernels

        Returns
        -------
        jittered positions (R*M, 2), order F
        """
        if positions.dtype != PARTICLE_DTYPE or not all(isinstance(k, GaussianKernel) for k in kernels):
            return super().jitter(positions, ancestors, eps, kernels)
        scales = np.array([[k.scale[0, 0], k.scale[1, 0], k.scale[1, 1]] for k in kernels], dtype=PARTICLE_DTYPE)
        out = self.pool.take("positions", (len(ancestors), 2), PARTICLE_DTYPE, "F")
        model.jitter(positions, ancestors, eps, scales, out)
        return out


_NO_ANCESTORS = np.empty(0, dtype=np.int64)


__all__ = ["THREADED_FROM", "BufferPool", "CompiledKernels", "lookup_tables"]
