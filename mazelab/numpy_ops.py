"""The hot parts of the particle filters in numpy: the reference backend (mazelab.backend), each
operation the very numpy calls the lab always made, so that the numpy path stays bit for bit as it was.
The compiled backend (mazelab.kernels.compiled.CompiledKernels) offers the same methods.

Particles are (R, N, 2) arrays stored column by column (mazelab.smc.particles_array), ancestors (R, M)
indices into each run's own particles; the numpy calls work on the (R*N, 2) view of the particles.
"""

from __future__ import annotations

import ctypes
import os
from collections.abc import Callable, Mapping, Sequence
from functools import cache
from types import MappingProxyType
from typing import Any

import numpy as np

from mazelab.model import headings_from_uniforms, log_likelihood, move, take_particles
from mazelab.smc import particles_array
from mazelab.weights import Weights, mass_within, weighted_mean

MALLOC_KEEPS = 32 << 20  # bytes: glibc's malloc serves arrays up to this from its heap (keep_freed_memory)


@cache
def keep_freed_memory() -> None:
    """Let glibc's malloc serve arrays up to MALLOC_KEEPS bytes from its heap and keep twice that of freed
    memory: a step of R runs frees and makes arrays of hundreds of KB each, which malloc would otherwise
    give back to the system and fault in again (the paper's study on one worker: some 170,000 page
    faults, 6% of its CPU). The values its own threshold reaches by itself after freeing a 32 MB array;
    nothing on another C library. Once per process, when it makes its first filter."""
    if "CS_GNU_LIBC_VERSION" in getattr(os, "confstr_names", {}):
        mallopt = ctypes.CDLL(None).mallopt
        mallopt(-3, MALLOC_KEEPS)  # M_MMAP_THRESHOLD
        mallopt(-1, 2 * MALLOC_KEEPS)  # M_TRIM_THRESHOLD


def flat_ancestors(A: np.ndarray, count: int) -> np.ndarray:
    """Row-local ancestors (R, M) as indices into the (R*N, 2) particles of all runs, (R*M,)."""
    if len(A) == 1:
        return A.reshape(-1)
    return (A + (np.arange(len(A)) * count)[:, None]).reshape(-1)


class NumpyKernels:
    """The hot parts in numpy (see the module's docstring). `Weights` is the backend's weights value
    (mazelab.weights.Weights: float64 log W), `log_dtype` the dtype of its log weights after resampling
    (float64; None: the likelihood's); `schemes` the faster forms of resampling schemes by name (none:
    numpy runs mazelab.resampling's textbook ones)."""

    name = "numpy"
    Weights: type = Weights
    log_dtype: type | None = float
    schemes: Mapping[str, Callable[..., np.ndarray]] = MappingProxyType({})

    def move(
        self, x: np.ndarray, A: np.ndarray | None, rngs: Sequence, angles: np.ndarray, delta: float, speed: float
    ) -> tuple[np.ndarray, np.ndarray]:
        """Equation (1): x[r, A[r]] moved along th = th0_r + Delta (u - 1/2), u ~ U[0, 1) from rngs[r]
        (None: a run that draws nothing, u = 1/2), for R runs: mazelab.model.LostRobot.M, with th0 as
        `angles` (R,) in x's dtype, Delta (radians) and L (map units) given."""
        uniforms = np.empty(x.shape[:2] if A is None else A.shape, dtype=x.dtype)
        for row, rng in zip(uniforms, rngs, strict=True):  # None: a run restarting after this step, no draw
            row[:] = 0.5 if rng is None else rng.random(row.shape, dtype=x.dtype)
        points = x.reshape(-1, 2)
        if A is not None:
            points = take_particles(points, flat_ancestors(A, x.shape[1]))
        headings = headings_from_uniforms(uniforms, angles[:, None], delta)
        return move(points, headings.reshape(-1), speed).reshape((*uniforms.shape, 2)), headings

    def log_likelihood(
        self, z: np.ndarray, x: np.ndarray, world: Any, sigma: float, outside_penalty: float
    ) -> np.ndarray:
        """Equation (3) in logs with the outside penalty (mazelab.model.log_likelihood) for R runs: z (R,)
        and x (R, N, 2) -> (R, N) in x's dtype (mazelab.model.LostRobot.logG)."""
        one = float(z[0]) if len(z) == 1 else z  # one run: a plain number (the same float32 arithmetic)
        return log_likelihood(one, x.reshape(-1, 2), world, sigma, outside_penalty).reshape(len(z), -1)

    def equal_weighted(self, log_lik: np.ndarray, log_weight: float) -> np.ndarray:
        """log W + log p(z_k | x_k) of resampled particles, whose weights are equal (log_weight = -log N):
        (R, N) of `log_dtype`."""
        return np.add(log_lik, log_weight, dtype=self.log_dtype)

    def second_stage(self, log_lik: np.ndarray, log_mu: np.ndarray, A: np.ndarray) -> np.ndarray:
        """The APF's second-stage log weights log p(z_k | x^j) - log p(z_k | mu^{a^j}), (R, M): the first
        stage's values log_mu (R, N) gathered by the ancestors A (R, M), then subtracted from log_lik (R,
        M) (into the gathered array where the dtypes agree)."""
        gathered = log_mu.reshape(-1).take(flat_ancestors(A, log_mu.shape[1])).reshape(A.shape)  # p(z_k | mu^{a^j})
        return np.subtract(log_lik, gathered, out=gathered if log_lik.dtype == gathered.dtype else None)

    def weighted_mean(self, W: Weights, x: np.ndarray) -> np.ndarray:
        """sum_i W_i x_i per run (mazelab.weights.weighted_mean), (R, 2) float64."""
        return weighted_mean(W.W, x.reshape(-1, 2))

    def mass_within(self, W: Weights, x: np.ndarray, centres: np.ndarray, radius: float) -> np.ndarray:
        """The weight within `radius` of each run's centre (R, 2) (mazelab.weights.mass_within), (R,)."""
        return mass_within(W.W, x.reshape(-1, 2), centres, radius)

    def jitter(self, x: np.ndarray, A: np.ndarray, due: np.ndarray, rngs: Sequence, kernels: Sequence) -> np.ndarray:
        """The RPF's resampled particles (R, M, 2): each due run's x[r, A[r]] (x (R, N, 2), A (R, M), due
        bool (R,)) jittered by its kernel (D `kernels`, (points, eps) -> jitter: mazelab.regularisation)
        with eps ~ N(0, I_2) from its Generator rngs[r]; the other runs' particles as they were."""
        rows = np.flatnonzero(due)
        moved = take_particles(x.reshape(-1, 2), (A[rows] + (rows * x.shape[1])[:, None]).reshape(-1))
        size = A.shape[1]
        for block, (r, kernel) in enumerate(zip(rows, kernels, strict=True)):
            part = slice(block * size, (block + 1) * size)
            moved[part] += kernel(moved[part], rngs[r].standard_normal((size, 2), dtype=x.dtype))  # eps ~ N(0, I_2)
        return replaced(x, rows, moved.reshape(len(rows), size, 2))


def replaced(x: np.ndarray, rows: np.ndarray, moved: np.ndarray) -> np.ndarray:
    """x (R, N, 2) with the runs `rows` (D,) replaced by `moved` (D, M, 2) (M = N), or `moved` itself
    when it holds every run's: the RPF's jittered particles."""
    if len(rows) == len(x):
        return moved
    out = particles_array(x, x.dtype)
    out[rows] = moved
    return out
