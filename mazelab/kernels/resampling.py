"""The resampler, compiled: systematic resampling by counting (mazelab.resampling.systematic_resample_runs
is the numpy reference, and these are its ancestors to the bit for the same weights and offsets).

The points u_m = (m + U) / M below the cumulative weight c_i = W_1 + ... + W_i number ceil(M c_i - U),
so particle i is the ancestor of the points from ceil(M c_{i-1} - U) to ceil(M c_i - U): one pass over
the weights counts where each particle's points end, a running sum over the points turns the counts
into the ancestors, in order, with no search and no branch that depends on the weights.
"""

from __future__ import annotations

import math

from mazelab.kernels import jit


@jit
def systematic(weights, uniforms, count, bases, out):  # pragma: no cover - compiled
    """Systematic resampling of R runs: run b draws `count` ancestors from its weights with offset U_b.

    Parameters
    ----------
    weights : float array (R, N)
        Each run's normalised weights.
    uniforms : float64 array (R,)
        U_b ~ U[0, 1) of each run.
    count : int
        M, the ancestors per run.
    bases : int array (R,)
        Added to run b's ancestors (the row of its first particle in the particles of all runs).
    out : int32 or int64 array (R*M,)
        The ancestors, run b's in block b, each run's sorted.
    """
    runs, size = weights.shape
    for b in range(runs):
        block = b * count
        for m in range(count):
            out[block + m] = 0
        # out[block + e] counts the particles whose points end at e: numpy's bincount of the ends
        cumulative = 0.0  # float64 whatever the weights' dtype (numpy's cumsum into a float64 array)
        for i in range(size - 1):  # the last particle takes the rest: round-off may leave the sum short of 1
            cumulative += weights[b, i]
            end = math.ceil(cumulative * count - uniforms[b])
            if 0 <= end < count:  # a NaN weight's end is neither: nothing is written outside `out`
                out[block + end] += 1
        ancestor = bases[b]  # then the running sum: point m's ancestor is the number of ends at or below m
        for m in range(count):
            ancestor += out[block + m]
            out[block + m] = ancestor
