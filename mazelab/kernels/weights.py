"""The weights, the weighted reads and the resampler, compiled (mazelab.weights and mazelab.resampling are
the numpy reference).

`normalise` turns R runs' log weights into their log totals and normalised weights W, and reads what
a step reports, in two passes over each chunk of CHUNK particles (mazelab.kernels): the chunk's top m_c
= max log w, then e = exp(log w - m_c) (written in place of W) and its sums, of the squares and of the
weighted positions (the total, the ESS, the mean); then, the run's top and total known, W = e exp(m_c
- top) / total and the weight within the green circle around the mean. For a step that does not
resample, log w = log W_{k-1} + log p(z | x) comes first, in the same pass. log W = log w - log total
is left to the Weights value, which derives it when read. W and log w are float32 (a million
particles' weights in the memory the fused kernel takes: benchmarks/peak_memory.py), a weight rounded
by at most 6e-8 of it; every sum is float64.

The exponential is float32 (vector_math.exp32, branch-free, so that the passes vectorise): one ulp, and
x = log w - m_c rounded to float32 (half an ulp of x), so e within 1.2e-7 + 6e-8 |x| of numpy's float64
exp relative to its value, then a float64 product and a rounding for W; 0 below exp(-87) of its chunk's
top (under 1e-38 of the chunk's heaviest weight, never drawn). Each chunk's sums run in LANES partial
sums, added pairwise, and the chunks' in chunk order: an order this code fixes, not the compiler, the
arrays' addresses or the threads (numpy's sums are pairwise: the two paths agree to rounding, not to
the bit). LANES is 16 because numba's loop vectoriser takes a loop of 16 and more (one of 8 it
unrolls; numba leaves the SLP vectoriser off): the lanes are one vector of float64 partial sums.

A run whose log weights are all -inf (no particle explains z) or hold a NaN gets the total -inf or NaN
and NaN weights, as in the numpy path; the filter then restarts it.

`systematic` resamples by counting, in blocks: mazelab.resampling.systematic_resample's ancestors (the
textbook inverse CDF) for the same cumulative weights and offset. The points u_m = (m + U) / M below the
cumulative weight c_i = W_1 + ... + W_i number ceil(M c_i - U), so particle i is the ancestor of the
points from ceil(M c_{i-1} - U) to ceil(M c_i - U) (its offspring count is their difference). In blocks
of CHUNK particles (mazelab.kernels): each block's total (a pass over the weights); the blocks' starting
sums b_k in order; then in each block, c_i = b_k plus the block's running sum (so a block's last c_i is
b_{k+1}, to the bit), the end of each particle's points counted where it falls among the block's own
points, and a running sum over those points turns the counts into the ancestors, with no search. Blocks
write disjoint points, so they run on any thread. The cumulative weights are float64 (numpy's cumsum
into a float64 array) summed in that order: the textbook's own, to the bit, for N <= CHUNK, and
otherwise different from them by rounding, which moves an ancestor only where a point lies within that
rounding of a boundary. A point exactly on a boundary (u_m = c_i) goes to the next particle, as
searchsorted(..., side="right") sends it.
"""

from __future__ import annotations

import math

import numpy as np
from numba import prange

from mazelab.kernels import Kernel, chunk_of, chunks, inline, scratch
from mazelab.kernels.vector_math import exp32

LANES = 16  # partial sums each sum keeps in a chunk: their order is this code's, not the compiler's


@inline
def _lane_total(lanes):  # pragma: no cover - compiled
    """The LANES partial sums `lanes` (1-D, overwritten), added in a fixed order (pairwise)."""
    width = LANES
    while width > 1:
        width //= 2
        for j in range(width):
            lanes[j] += lanes[j + width]
    return lanes[0]


@inline
def _top(values):  # pragma: no cover - compiled
    """max of the 1-D `values` in their dtype (-inf for none) from LANES running maxima, which the
    compiler vectorises (numba's own max checks each value for NaN: four times the time); a NaN is
    passed over here (its exponential makes the run's total NaN: `_combine` checks the total)."""
    maxima = scratch(LANES, values.dtype)  # np.full's broadcast would import numba's ufunc modules
    maxima[:] = -np.inf
    full = len(values) // LANES * LANES
    for block in range(0, full, LANES):  # each loop from 0: numba checks no index of it for wrap-around
        for j in range(LANES):
            maxima[j] = max(values[block + j], maxima[j])
    top = maxima[0]
    for j in range(1, LANES):
        top = max(maxima[j], top)
    for i in range(full, len(values)):
        top = max(values[i], top)
    return top


@inline
def _holds_nan(values):  # pragma: no cover - compiled
    """np.isnan(values).any() of 1-D `values` by a loop: numpy's form would make a kernel loaded from the
    cache import a dozen of numba's ufunc and array-math modules (some 15 ms of a process's start-up)."""
    nan = False
    for value in values:
        nan |= value != value
    return nan


@inline
def _moments(lanes, j, e, x, y):  # pragma: no cover - compiled
    """lanes[:4, j] += e, e^2, e x, e y (float64)."""
    weight = np.float64(e)
    lanes[0, j] += weight
    lanes[1, j] += weight * weight
    lanes[2, j] += weight * x
    lanes[3, j] += weight * y


@inline
def _exponentials_and_moments(log_w, top, xs, ys, w, lanes):  # pragma: no cover - compiled
    """w_i = e_i = exp32(log w_i - top) of a chunk's 1-D arrays, and lanes[:4, i % LANES] += e_i, e_i^2,
    e_i x_i, e_i y_i, in order; a chunk whose top is -inf gets e = 0 (and a NaN sum if it holds a NaN:
    the run then cannot be normalised)."""
    lanes[:, :] = 0.0
    if top == -np.inf:
        w[:] = 0.0
        lanes[0, 0] = np.nan if _holds_nan(log_w) else 0.0
        return
    for i in range(len(log_w)):
        w[i] = exp32(np.float32(log_w[i] - top))
    full = len(w) // LANES * LANES
    for block in range(0, full, LANES):  # each loop from 0: numba checks no index of it for wrap-around
        for j in range(LANES):  # a loop of LANES: the compiler keeps one vector of each sum
            _moments(lanes, j, w[block + j], xs[block + j], ys[block + j])
    for i in range(full, len(w)):
        _moments(lanes, i - full, w[i], xs[i], ys[i])


@inline
def _scaled_within(lanes, j, w, i, factor, dx, dy, r2):  # pragma: no cover - compiled
    """lanes[4, j] += e_i if the particle lies within sqrt(r2) (a select), and w_i = e_i * factor."""
    e = w[i]
    lanes[4, j] += np.float64(e) if dx * dx + dy * dy <= r2 else 0.0
    w[i] = np.float64(e) * factor


@inline
def _scale_and_keep_within(w, factor, xs, ys, centre_x, centre_y, r2, lanes):  # pragma: no cover - compiled
    """w_i = e_i * factor (float64, then float32) of a chunk's 1-D arrays, and lanes[4, i % LANES] += e_i
    where particle i lies within sqrt(r2) of the centre (float32 distances)."""
    full = len(w) // LANES * LANES
    for block in range(0, full, LANES):
        for j in range(LANES):
            _scaled_within(lanes, j, w, block + j, factor, xs[block + j] - centre_x, ys[block + j] - centre_y, r2)
    for i in range(full, len(w)):
        _scaled_within(lanes, i - full, w, i, factor, xs[i] - centre_x, ys[i] - centre_y, r2)


@Kernel
def normalise(log_w, log_a, shifts, log_g, xy, radius, w, reads):  # pragma: no cover - compiled
    """Normalise R runs' log weights `log_w` (R, N) (float32 or float64) and read each run's mean, ESS
    and confidence share, in the two passes of the module's docstring; with `log_a` (R, N), `shifts` (R,)
    and `log_g` (R, N) float32 (else None), log w is first written as (log_a - shift) + log_g (log W_{k-1}
    + log p(z_k | x_k), the sum in float64, then rounded to float32 as the likelihood).

    xy (2, R, N) holds the particles' float32 coordinates (x's plane, then y's); `radius` the green
    circle's (map units); W = w / sum(w) is written into `w` (R, N) float32, and into `reads` (5, R)
    float64, one row each: log sum_j w_j; the mean sum_i W_i x_i (x and y); the ESS 1 / sum_i W_i^2;
    the weight of the particles at most `radius` from the run's mean (float32 distances, as
    mazelab.weights.mass_within); NaN for a run that cannot be normalised."""
    runs, size = log_w.shape
    blocks, jobs = chunks(runs, size)
    lanes, scales = scratch((jobs, 5, LANES), np.float64), scratch(jobs, np.float64)  # each chunk's sums and top
    r2 = np.float32(radius * radius)
    for job in prange(jobs):  # each chunk's log w, top, exponentials and sums
        r, start, stop = chunk_of(job, blocks, size)
        row, xs, ys = log_w[r, start:stop], xy[0, r, start:stop], xy[1, r, start:stop]
        if log_a is not None:
            previous, added, shift = log_a[r, start:stop], log_g[r, start:stop], shifts[r]
            for i in range(stop - start):
                row[i] = np.float64(previous[i]) - shift + np.float64(added[i])
        scales[job] = top = _top(row)
        _exponentials_and_moments(row, top, xs, ys, w[r, start:stop], lanes[job])
    for r in range(runs):  # each run's top and sums, its chunks' in order
        _combine(log_w[r], reads, r, lanes[r * blocks : (r + 1) * blocks], scales[r * blocks : (r + 1) * blocks])
    for job in prange(jobs):  # each chunk's W and weight within the circle
        r, start, stop = chunk_of(job, blocks, size)
        if scales[job] == scales[job]:
            centre_x, centre_y = np.float32(reads[1, r]), np.float32(reads[2, r])
            xs, ys = xy[0, r, start:stop], xy[1, r, start:stop]
            _scale_and_keep_within(w[r, start:stop], scales[job], xs, ys, centre_x, centre_y, r2, lanes[job])
        else:
            w[r, start:stop] = np.nan
    for r in range(runs):
        if reads[4, r] == reads[4, r]:
            share = 0.0
            for c in range(r * blocks, (r + 1) * blocks):
                share += _lane_total(lanes[c, 4]) * scales[c]
            reads[4, r] = share


@inline
def _combine(row, reads, r, lanes, scales):  # pragma: no cover - compiled
    """Run r's log total, mean and ESS into reads[:4, r] from its chunks' tops (`scales`) and sums, in
    chunk order; `scales` then holds each chunk's factor exp(m_c - top) / total (NaN for a run that
    cannot be normalised, whose reads are NaN)."""
    top = -np.inf
    for c in range(len(scales)):
        top = max(scales[c], top)
    total = squares = sum_x = sum_y = 0.0
    for c in range(len(scales)):
        scale = math.exp(scales[c] - top) if abs(top) < np.inf else np.nan
        scales[c] = scale
        total += _lane_total(lanes[c, 0]) * scale
        squares += _lane_total(lanes[c, 1]) * (scale * scale)
        sum_x += _lane_total(lanes[c, 2]) * scale
        sum_y += _lane_total(lanes[c, 3]) * scale
    if total != total:  # every weight is 0, or a NaN: no normalisation (the filter restarts it)
        reads[0, r] = np.nan if _holds_nan(row) else top  # numpy's log_sum_exp: NaN, else -inf or +inf
        reads[1, r] = reads[2, r] = reads[3, r] = reads[4, r] = np.nan
        for c in range(len(scales)):
            scales[c] = np.nan
        return
    reads[0, r], reads[1, r], reads[2, r] = top + math.log(total), sum_x / total, sum_y / total
    reads[3, r], reads[4, r] = total * total / squares, 0.0
    for c in range(len(scales)):
        scales[c] /= total


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
        _ancestors_of_block(
            weights[r, start : min(stop, size - 1)], u[r], count, bases[r, block], start, stops[r, block], points
        )
