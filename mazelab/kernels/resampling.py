"""The resampler, compiled: systematic resampling by counting, in blocks (mazelab.resampling.
systematic_resample is the numpy reference, the textbook inverse CDF, and these are its ancestors for
the same cumulative weights and offset).

The points u_m = (m + U) / M below the cumulative weight c_i = W_1 + ... + W_i number ceil(M c_i - U),
so particle i is the ancestor of the points from ceil(M c_{i-1} - U) to ceil(M c_i - U) (its offspring
count is their difference). In blocks of CHUNK particles (mazelab.kernels): each block's total (a
pass over the weights); the blocks' starting sums b_k in order; then in each block, c_i = b_k plus the
block's running sum (so a block's last c_i is b_{k+1}, to the bit), the end of each particle's points
counted where it falls among the block's own points, and a running sum over those points turns the
counts into the ancestors, with no search. Blocks write disjoint points, so they run on any thread.
The cumulative weights are float64 (numpy's cumsum into a float64 array) summed in that order: the
textbook's own, to the bit, for N <= CHUNK, and otherwise different from them by rounding, which moves
an ancestor only where a point lies within that rounding of a boundary. A point exactly on a boundary
(u_m = c_i) goes to the next particle, as searchsorted(..., side="right") sends it.
"""

from __future__ import annotations

import math

import numpy as np
from numba import prange

from mazelab.kernels import Kernel, chunk_of, chunks, inline, scratch


@inline
def _ancestors_of_block(weights, u, count, base, start, offset, out):  # pragma: no cover - compiled
    """`out`: the points offset.. of the particles start.. (their weights `weights`; the last particle
    of all is left out: it takes the rest). out[e] counts the particles whose points end at point
    offset + e, then their running sum, from `start`."""
    out[:] = 0
    cumulative = 0.0
    for i in range(len(weights)):
        cumulative += weights[i]
        end = ((base + cumulative) * count - u) - offset  # particle i's points end at offset + ceil(end)
        if end > -1 and end <= len(out) - 1:  # a NaN weight's end is neither: nothing is written outside
            out[math.ceil(end)] += 1
    ancestor = start
    for m in range(len(out)):
        ancestor += out[m]
        out[m] = ancestor


@Kernel
def systematic(weights, u, out):  # pragma: no cover - compiled
    """Systematic resampling of R runs' normalised weights (R, N) with offsets u (R,) ~ U[0, 1): out[r, m]
    is the ancestor of the point (m + u_r) / M in run r, M = out.shape[1], sorted
    (mazelab.resampling.systematic_resample's, by counting in blocks; each run's as alone)."""
    runs, size = weights.shape
    count = out.shape[1]
    blocks, jobs = chunks(runs, size)
    bases = scratch((runs, blocks + 1), np.float64)  # each value written first
    stops = scratch((runs, blocks + 1), np.int64)
    for job in prange(jobs if blocks > 1 else 0):  # each block's total, in order (a run of one block: none read)
        r, start, stop = chunk_of(job, blocks, size)
        total, part = 0.0, weights[r, start:stop]  # float64 whatever the weights' dtype
        for i in range(len(part)):
            total += part[i]
        bases[r, job - r * blocks + 1] = total
    for r in range(runs):  # each run's blocks' starting sums b_k, and where their points end
        base, stop = bases[r], stops[r]
        base[0], stop[0], stop[blocks] = 0.0, 0, count
        for block in range(1, blocks + 1):
            base[block] += base[block - 1]
            if block < blocks:
                end = base[block] * count - u[r]  # the points below b_k: ceil(end), within [the last, M]
                stop[block] = stop[block - 1] if not end > stop[block - 1] - 1 else min(math.ceil(end), count)
    for job in prange(jobs):
        r, start, stop = chunk_of(job, blocks, size)
        block = job - r * blocks
        points = out[r, stops[r, block] : stops[r, block + 1]]
        _ancestors_of_block(weights[r, start : min(stop, size - 1)], u[r], count, bases[r, block], start,
                            stops[r, block], points)  # fmt: skip
