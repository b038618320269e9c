"""The resampler, compiled: systematic resampling by counting (mazelab.resampling.systematic_resample is
the numpy reference, the textbook inverse CDF, and these are its ancestors for the same weights and
offset).

The points u_m = (m + U) / M below the cumulative weight c_i = W_1 + ... + W_i number ceil(M c_i - U),
so particle i is the ancestor of the points from ceil(M c_{i-1} - U) to ceil(M c_i - U): one pass over
the weights counts where each particle's points end, a running sum over the points turns the counts
into the ancestors, in order, with no search and no branch that depends on the weights.
"""

from __future__ import annotations

import math

from mazelab.kernels import jit


@jit
def systematic(weights, u, out):  # pragma: no cover - compiled
    """Systematic resampling of one run's weights with offset u: out[m] is the ancestor of the point
    (m + u) / M, M = len(out) (mazelab.resampling.systematic_resample's, by counting).

    Parameters
    ----------
    weights : float array (N,)
        Normalised weights.
    u : float
        U ~ U[0, 1).
    out : int array (M,)
        The ancestors, sorted.
    """
    count, size = len(out), len(weights)
    for m in range(count):
        out[m] = 0
    # out[e] counts the particles whose points end at e: numpy's bincount of the ends
    cumulative = 0.0  # float64 whatever the weights' dtype (numpy's cumsum into a float64 array)
    for i in range(size - 1):  # the last particle takes the rest: round-off may leave the sum short of 1
        cumulative += weights[i]
        end = math.ceil(cumulative * count - u)
        if 0 <= end < count:  # a NaN weight's end is neither: nothing is written outside `out`
            out[end] += 1
    ancestor = 0  # then the running sum: point m's ancestor is the number of ends at or below m
    for m in range(count):
        ancestor += out[m]
        out[m] = ancestor
