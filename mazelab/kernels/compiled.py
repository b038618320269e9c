"""The compiled backend: `CompiledKernels`, mazelab.numpy_ops.NumpyKernels' methods (the same arguments and
results) each calling one kernel for all R runs, and `CompiledWeights`, the weights value it builds.
Anything the kernels do not cover (float64 points such as recovery's injected draws, the multimodal
kernel) goes to the numpy operations."""

from __future__ import annotations

import math
from functools import cached_property
from typing import Any

import numpy as np

from mazelab.constants import CONFIDENCE_RADIUS, PARTICLE_DTYPE
from mazelab.kernels import model, weights
from mazelab.numpy_ops import NumpyKernels, replaced
from mazelab.regularisation import GaussianKernel
from mazelab.smc import UNSIGNED, new_particles
from mazelab.weights import Weights, log_sum_exp, read_only

EVERY_RUN = np.empty(0, dtype=bool)  # the move's `moving` when every run draws (model.move)
NO_ANCESTORS = np.empty((1, 0), dtype=np.uint64)  # the move's `ancestors` when each particle moves itself
QUADS = 4  # the candidates of a lookup cell the likelihood's vectorised loop reads (a few cells have more)


def unsigned(indices: np.ndarray) -> np.ndarray:
    """Indices the engine checked to lie in [0, N) as unsigned integers of their size (a view): a kernel
    then checks no gather by them for wrap-around."""
    return indices.view(UNSIGNED[indices.itemsize])


def planes(x: np.ndarray) -> np.ndarray:
    """(R, N, 2) particles as the (2, R, N) planes the kernels read, x's then y's (a view of particles in
    their layout, smc.particles_array; a copy of others)."""
    return np.ascontiguousarray(x.transpose(2, 0, 1))


def keys_of(rngs: Any) -> np.ndarray:
    """One 64-bit key per run from each run's Generator (0 for None: a run that draws nothing), uint64 (R,)."""
    if len(rngs) == 1 and rngs[0] is not None:  # one run: its key in one call, as an array (a step's 1 us)
        return rngs[0].bit_generator.random_raw(1)
    return np.array([0 if rng is None else rng.bit_generator.random_raw() for rng in rngs], dtype=np.uint64)


def lookup_tables(world: Any) -> tuple:
    """The maze's nearest-station tables (mazelab.lookup) in the layout the likelihood kernel reads:
    (grid: scale, offset, nx, ny; sizes: nx, width uint64 (2,); codes (C,) uint32, quads (C, 8), rows,
    border (b, 2)), float32 coordinates. quads[c] is cell c's first four candidates (x0, y0, ..., x3, y3),
    padded by repeats of the first; `rows` holds, for each cell with more than four, its other K - 4
    (padded likewise), `width` = 2 (K - 4) values a row; a cell's code is its row's first index in `rows`
    times 4, plus 2 if it has a row, plus 1 if the cell is free."""
    lookup = world.prepare()._lookup
    xy = lookup.stations.astype(PARTICLE_DTYPE)  # the numpy path's float32 coordinates
    count = lookup._all.shape[1]  # K: the most candidates a cell has
    candidates = np.repeat(lookup._first[:, None], max(count, QUADS), axis=1)  # (C, K) padded by the first
    candidates[lookup.row >= 0, :count] = lookup._all
    more = np.flatnonzero((candidates[:, QUADS:] != candidates[:, :1]).any(axis=1))  # the cells with a fifth
    quads, rows = xy[candidates[:, :QUADS]].reshape(-1, 2 * QUADS), xy[candidates[more, QUADS:]].reshape(-1)
    width = 2 * (candidates.shape[1] - QUADS)
    codes = (lookup.kind & 1).astype(np.uint64)
    codes[more] += 2 + 4 * width * np.arange(len(more), dtype=np.uint64)
    codes = codes.astype(np.uint32 if codes.max(initial=0) < 2**32 else np.uint64)
    sizes = np.array([lookup.nx, width], dtype=np.uint64)
    return (lookup.scale, lookup.offset, lookup.nx, lookup.ny), sizes, codes, quads, rows, xy[lookup._border]


class CompiledWeights(Weights):
    """The compiled backend's weights value: the unnormalised log weights `log_w` (R, N) (float32 after a
    reweighting, or log W itself with totals 0), their `log_total` (R,), W = exp(log w - log total)
    (R, N) float32 when the normalisation wrote it (every sum over it in float64), and its `reads`:
    (the particles x it read, its (5, R) rows: log total, mean x, mean y, ESS, share within the green
    circle of the mean), read-only, with the ESS and the `mean` (R, 2) views of them. log W is derived
    when read (float64)."""

    threads = 1  # the threads of a large normalisation (mazelab.kernels.Kernel): each filter's subclass sets its own

    def __init__(self, log_w: np.ndarray, log_total: np.ndarray, W: np.ndarray | None = None, reads: Any = None):
        log_w.setflags(write=False)  # setflags: half the time of read_only's flags object
        self.log_w, self.log_total, self.reads = log_w, read_only(log_total), reads
        if W is not None:
            self.__dict__["W"] = read_only(W)
        if reads is not None:  # the normalisation's reads (read-only rows)
            self.__dict__["ess"], self.mean = reads[1][3], reads[1][1:3].T

    @classmethod
    def from_log(cls, log_w: np.ndarray, x: np.ndarray | None = None, added: tuple = (None,) * 3) -> CompiledWeights:
        """Each row normalised in one compiled call of two passes, with the reads of x (float32 particles;
        other arrays are normalised by numpy's arithmetic); `added` (log a, shifts, log g): log_w is
        first written as (log a - shift) + log g in the same pass (`add`)."""
        if x is None or x.dtype != PARTICLE_DTYPE or x.shape[:2] != log_w.shape:
            return cls(log_w, np.atleast_1d(log_sum_exp(log_w)))
        w, reads = np.empty(log_w.shape, dtype=np.float32), np.empty((5, len(log_w)))
        weights.normalise(cls.threads, log_w.size, log_w, *added, planes(x), CONFIDENCE_RADIUS, w, reads)
        reads.setflags(write=False)  # and its rows with it (W is made read-only by the constructor)
        return cls(log_w, reads[0], w, (x, reads))

    @classmethod
    def uniform(cls, runs: int, count: int) -> CompiledWeights:
        """W_i = 1/N: log w = 0 (float32), log total log N; W one number broadcast."""
        W = np.broadcast_to(np.exp(np.float64(-math.log(count))), (runs, count))
        return cls(np.zeros((runs, count), np.float32), np.full(runs, math.log(count)), W)

    def add(self, log_g: np.ndarray, x: np.ndarray | None = None) -> CompiledWeights:
        """log W + log G per run in the normalisation's first pass (float32, log W worked out per particle
        from log w and its total, never stored), then `from_log`'s."""
        if log_g.dtype != PARTICLE_DTYPE or log_g.shape != self.log_w.shape:
            return self.from_log(self.lw + log_g, x)
        if x is None:  # no reads to make: numpy's arithmetic, the same float32 log w
            return self.from_log((np.subtract(self.log_w, self.log_total[:, None]) + log_g).astype(np.float32))
        return self.from_log(np.empty(log_g.shape, PARTICLE_DTYPE), x, (self.log_w, self.log_total, log_g))

    def reset(self, rows: np.ndarray, other: Weights, x: np.ndarray | None = None) -> CompiledWeights:
        """These weights with the given rows' log w replaced by `other`'s, normalised again with the reads
        of x (the same values, row by row, as each run's alone)."""
        if not rows.any():
            return self
        log_w = np.array(self.log_w, dtype=np.result_type(self.log_w, other.log_w))
        log_w[rows] = other.log_w
        return self.from_log(log_w, x)

    @cached_property
    def lw(self) -> np.ndarray:
        """log W_i = log w_i - log total, (R, N) float64."""
        return read_only(np.subtract(self.log_w, self.log_total[:, None], dtype=float))


class CompiledKernels(NumpyKernels):
    """The hot parts of one filter on `world` (its lookup tables read once), compiled (mazelab.kernels),
    a call of THREADED_FROM particles or more on `threads` threads (kernels_for passes shared_threads')."""

    name, log_dtype = "compiled", None  # log weights after resampling in the likelihood's float32

    def __init__(self, world: Any, threads: int | None = None):
        self.tables = lookup_tables(world)
        self._tables_of, self._constants = world, {}
        self.threads = max(1, threads or 1)
        self.Weights = type("CompiledWeights", (CompiledWeights,), {"threads": self.threads})  # its normalisations
        self.schemes = {"systematic": self.systematic}

    def move(
        self, x: np.ndarray, A: np.ndarray | None, rngs: Any, angles: np.ndarray, delta: float, speed: float
    ) -> tuple[np.ndarray, np.ndarray]:
        """Equation (1) with its draws in one compiled pass (mazelab.kernels.model.move; its uniforms from a
        key each run's Generator draws); float64 points go to numpy."""
        if x.dtype != PARTICLE_DTYPE:
            return super().move(x, A, rngs, angles, delta, speed)
        out = np.empty((3, *(x.shape[:2] if A is None else A.shape)), dtype=PARTICLE_DTYPE)  # x, y, the headings
        moving = np.array([rng is not None for rng in rngs]) if None in rngs else EVERY_RUN
        sources = NO_ANCESTORS if A is None else unsigned(A)
        model.move(self.threads, out[2].size, planes(x), sources, keys_of(rngs), moving, angles, delta, speed, out)
        return out[:2].transpose(1, 2, 0), out[2]

    def log_likelihood(
        self, z: np.ndarray, x: np.ndarray, world: Any, sigma: float, outside_penalty: float
    ) -> np.ndarray:
        """Equation (3) in logs, compiled: the locate and the likelihood in one pass (float32, the numpy
        path's values to the bit), the kernel's constants (mazelab.kernels.model.log_likelihood) in one
        array (a kernel call types each argument it is passed)."""
        if x.dtype != PARTICLE_DTYPE or world is not self._tables_of:
            return super().log_likelihood(z, x, world, sigma, outside_penalty)
        out = np.empty(x.shape[:2], dtype=PARTICLE_DTYPE)
        constants = self._constants.get((sigma, outside_penalty))
        if constants is None:  # once per filter (1.6 us: a few % of an APF step at N = 1,000)
            norm = math.log(sigma * math.sqrt(2 * math.pi))
            constants = np.array([sigma, -norm, math.log(outside_penalty) - norm, *self.tables[0]], PARTICLE_DTYPE)
            self._constants[sigma, outside_penalty] = constants
        model.log_likelihood(self.threads, out.size, planes(x), z, constants, *self.tables[1:], out)
        return out

    def systematic(self, W: np.ndarray, rng: Any, count: int | None = None) -> np.ndarray:
        """Systematic resampling of W (N,), or of D runs' (D, N) with a Generator each (a sequence), into
        `count` (default N) int64 ancestors a run, all runs in one call of mazelab.kernels.weights.
        systematic, with offsets u = rng.random()."""
        rows, rngs = (W[None], [rng]) if W.ndim == 1 else (W, rng)
        out = np.empty((len(rows), rows.shape[1] if count is None else count), dtype=np.int64)
        offsets = np.array([generator.random() for generator in rngs])
        weights.systematic(self.threads, rows.size, rows, offsets, out)
        return out[0] if W.ndim == 1 else out

    def weighted_mean(self, W: Weights, x: np.ndarray) -> np.ndarray:
        """The posterior mean per run: the normalisation's read for these particles, else computed."""
        reads = getattr(W, "reads", None)
        return W.mean if reads is not None and reads[0] is x else super().weighted_mean(W, x)

    def mass_within(self, W: Weights, x: np.ndarray, centres: np.ndarray, radius: float) -> np.ndarray:
        """The weight within `radius` of each run's centre: the normalisation's read around the mean,
        else numpy's (the mode estimate's)."""
        reads = getattr(W, "reads", None)
        if reads is not None and reads[0] is x and centres is W.mean and radius == CONFIDENCE_RADIUS:
            return reads[1][4]
        return super().mass_within(W, x, centres, radius)

    def jitter(self, x: np.ndarray, A: np.ndarray, due: np.ndarray, rngs: Any, kernels: Any) -> np.ndarray:
        """The RPF's gather, draws and jitter in one pass for Gaussian kernels (mazelab.kernels.model.jitter,
        eps from a key each due run's Generator draws); the multimodal kernel goes to numpy."""
        if x.dtype != PARTICLE_DTYPE or not all(isinstance(k, GaussianKernel) for k in kernels):
            return super().jitter(x, A, due, rngs, kernels)
        rows = np.flatnonzero(due)
        scales = np.array([[k.scale[0, 0], k.scale[1, 0], k.scale[1, 1]] for k in kernels], dtype=PARTICLE_DTYPE)
        moved = new_particles(len(rows), A.shape[1], PARTICLE_DTYPE)
        keys = keys_of([rngs[r] for r in rows])
        model.jitter(self.threads, moved[..., 0].size, planes(x), rows, unsigned(A[rows]), keys, scales, planes(moved))
        return replaced(x, rows, moved)
