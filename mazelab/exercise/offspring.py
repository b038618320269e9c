"""resample's verdict: unbiased offspring counts under every weight vector, and which shipped scheme
its offspring variance resembles (the whole filter is compared with the SIR using that scheme).

Unbiased means E[N_i] = N W_i for every particle i. Over R calls on one vector, particle i's mean
offspring count m_i has standard error s_i / sqrt(R), and z_i = (m_i - N W_i) / (s_i / sqrt(R)) is
close to standard normal for any unbiased scheme (every N W_i is at least about 0.2, so R N W_i >= 800
offspring are averaged). s_i^2 is the larger of the sample variance and f(1 - f), f the fractional
part of N W_i: no integer count with mean N W_i varies less (systematic resampling attains it), and
where the count leaves its usual value rarely (N W_i = 1.002: 8 times in 4000 calls on average) the
sample variance of a run with fewer such calls is far too small (one call: z = -6.4 for a correct
systematic resampler). The check fails when some
|z_i| exceeds the normal quantile at RESAMPLE_ALPHA / (2 M), M the particles of all the vectors
together: by Bonferroni's inequality a correct resampler fails with probability at most RESAMPLE_ALPHA,
whatever the correlations between its counts. A count that never varies has no sample deviation to
divide by. If it is k with d = |k - N W_i| < 1, the likeliest unbiased way to show it is the scheme of
least variance (systematic resampling: floor or ceil of N W_i), which gives k at all R calls with
probability (1 - d)^R; that is the count's p-value, read as the z of the same two-sided p. So N W_i =
0.99995, always 1 in 4000 calls (probability 0.82), passes, and always 1 for N W_i = 0.99 (probability
4e-18) fails. A constant k with d >= 1 is impossible for an unbiased scheme of that least variance.
"""

from __future__ import annotations

import math
from statistics import NormalDist

import numpy as np

from mazelab.exercise.inputs import PartInputs
from mazelab.exercise.parts import HINTS
from mazelab.exercise.rows import FAIL, PASS, Row, error_of, error_row, take
from mazelab.exercise.wire import Message
from mazelab.weights import effective_sample_size

RESAMPLE_ALPHA = 0.001  # the resample check's false-alarm rate (Bonferroni over every particle)
EXACT = 1e-6  # a count that never varies must equal N W_i to this (rounding of N W_i)
RESEMBLANCE_VECTOR = "fractional"  # the vector whose offspring variance names the scheme


def expected_text(inputs: PartInputs) -> str:
    resample = inputs.resample
    return f"E[offspring] = N W_i under {len(resample.weights)} weight vectors, {resample.draws} calls each"


def critical_z(particles: int, alpha: float = RESAMPLE_ALPHA) -> float:
    """The two-sided normal quantile of each particle's z-test: alpha / (2 particles) in each tail."""
    return NormalDist().inv_cdf(1 - alpha / (2 * particles))


def offspring_counts(ancestors: np.ndarray, n: int) -> np.ndarray:
    """The offspring counts (R, n) of R calls' ancestor indices (R, n)."""
    calls = len(ancestors)
    rows = np.arange(calls)[:, None] * n
    return np.bincount((ancestors + rows).ravel(), minlength=calls * n).reshape(calls, n)


def z_scores(counts: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Each particle's z (see the module docstring): its mean count's deviation over the standard error
    (the variance at least f(1 - f)), or for a count that never varies the z of its p-value (1 - d)^R
    (+-inf for d >= 1)."""
    target = len(weights) * weights
    mean, std = counts.mean(axis=0), counts.std(axis=0, ddof=1)
    fraction = target - np.floor(target)
    error = np.sqrt(np.maximum(std**2, fraction * (1 - fraction)) / len(counts))  # the least variance's floor
    fixed = std == 0
    with np.errstate(divide="ignore", invalid="ignore"):
        z = (mean - target) / error
    z[fixed] = [constant_count_z(m - t, len(counts)) for m, t in zip(mean[fixed], target[fixed], strict=True)]
    return z


def constant_count_z(deviation: float, calls: int) -> float:
    """The signed two-sided z of a count that was the same at all `calls` calls, `deviation` = k - N W_i
    from its expectation: p = (1 - |deviation|)^calls (the least-variance scheme's chance of it)."""
    d = abs(deviation)
    if d <= EXACT:
        return 0.0
    if d >= 1:
        return math.copysign(math.inf, deviation)
    half_p = math.exp(calls * math.log1p(-d)) / 2  # the lower tail's share of the two-sided p
    if half_p == 0.0:  # below the smallest double: far past any critical value
        return math.copysign(math.inf, deviation)
    return math.copysign(-NormalDist().inv_cdf(half_p), deviation)


def judge_resample(inputs: PartInputs, answer: Message) -> tuple[Row, str]:
    """resample's row from its answer (ancestors/k (R, N_k), repeat/k), and the scheme it resembles."""
    expected, error = expected_text(inputs), error_of(answer)
    if error:
        return error_row("resample", expected, error, HINTS["resample"]), "systematic"
    vectors, kinds, draws = inputs.resample.weights, inputs.resample.kinds, inputs.resample.draws
    ancestors = [take(answer, f"ancestors/{k}", (draws, len(w)), "<i8") for k, w in enumerate(vectors)]
    repeats = [take(answer, f"repeat/{k}", (len(w),), "<i8") for k, w in enumerate(vectors)]
    for rows, weights in zip(ancestors, vectors, strict=True):
        if rows.size and (rows.min() < 0 or rows.max() >= len(weights)):
            bad = int(rows.min() if rows.min() < 0 else rows.max())
            hint = "indices of particles 0..N-1 (searchsorted can give N when cumsum(W) ends just below 1)"
            return Row("resample", FAIL, expected, f"an index {bad} outside [0, {len(weights)})", hint), "systematic"
    counts = [offspring_counts(rows, len(w)) for rows, w in zip(ancestors, vectors, strict=True)]
    critical = critical_z(sum(len(w) for w in vectors))
    scores = [z_scores(c, w) for c, w in zip(counts, vectors, strict=True)]
    worst = [float(np.max(np.abs(z))) for z in scores]
    scheme, resemblance = resembles(inputs, counts, vectors)
    failing = [k for k, w in enumerate(worst) if w > critical]
    if failing:
        k = max(failing, key=lambda j: worst[j])
        i = int(np.argmax(np.abs(scores[k])))
        target, mean = len(vectors[k]) * vectors[k][i], counts[k][:, i].mean()
        if np.isfinite(scores[k][i]):
            got = (
                f"under the {kinds[k]} weights particle {i} has mean offspring {mean:.3f} for "
                f"N W = {target:.3f} (|z| {worst[k]:.3g} > {critical:.2f})"
            )
        else:
            got = f"under the {kinds[k]} weights particle {i} gets {mean:.0f} at every call, for N W = {target:.3f}"
        return Row("resample", FAIL, expected, got, _bias_hint(counts, vectors, kinds, failing)), "systematic"
    for k, (rows, again) in enumerate(zip(ancestors, repeats, strict=True)):
        if not np.array_equal(rows[0], again):
            hint = "draw from the rng argument, not np.random or self.rng: a seeded run must repeat"
            return Row(
                "resample", FAIL, "the same draws from an equally seeded rng", f"different draws ({kinds[k]})", hint
            ), scheme
    got = f"largest |z| {max(worst):.2f} <= {critical:.2f}; {resemblance}"
    return Row("resample", PASS, expected, got), scheme


def _bias_hint(
    counts: list[np.ndarray], vectors: tuple[np.ndarray, ...], kinds: tuple[str, ...], failing: list[int]
) -> str:
    """Every particle kept once (everywhere, or only where the ESS is high: a gate), or the general hint."""
    kept = [bool(np.all(c == 1)) for c in counts]
    if all(kept[k] for k in failing):
        if all(kept):
            return "every particle kept once (arange): " + HINTS["resample"]
        k = failing[0]
        ess = float(effective_sample_size(vectors[k]))
        return (
            f"every particle kept once under the {kinds[k]} weights (ESS {ess:.0f} of {len(vectors[k])}) but "
            "resampled under others: resample always draws (whether to resample is the filter's choice)"
        )
    return HINTS["resample"]


def resembles(inputs: PartInputs, counts: list[np.ndarray], vectors: tuple[np.ndarray, ...]) -> tuple[str, str]:
    """The shipped scheme whose total offspring variance on the fractional weights is nearest on a log
    scale, and a phrase comparing the variance with systematic's and multinomial's."""
    k = inputs.resample.kinds.index(RESEMBLANCE_VECTOR)
    variance = float(counts[k].var(axis=0, ddof=1).sum())
    references = scheme_variances(vectors[k])
    nearest = min(references, key=lambda name: abs(math.log((variance + 1e-9) / (references[name] + 1e-9))))
    ratio = variance / references["systematic"] if references["systematic"] else math.inf
    phrase = (
        f"looks {nearest} (offspring variance {variance:.1f}, {ratio:.2g}x systematic's "
        f"{references['systematic']:.1f}; multinomial's {references['multinomial']:.1f})"
    )
    return nearest, phrase


def scheme_variances(weights: np.ndarray) -> dict[str, float]:
    """Each shipped scheme's total offspring variance sum_i Var(N_i) on the weights, exactly.

    With a_i = N cumsum(W)_(i-1), b_i = N cumsum(W)_i and f_i the fractional part of N W_i:
    multinomial: N W_i (1 - W_i); systematic: N_i is floor or ceil of N W_i, so f_i (1 - f_i);
    stratified: a Bernoulli per stratum j with p = the overlap of [j, j + 1) with [a_i, b_i), so the
    partial strata at either end add p (1 - p); residual: floor(N W_i) copies and the remaining
    M = sum f_i drawn multinomially with p_i = f_i / M, so M p_i (1 - p_i)."""
    n = len(weights)
    scaled = n * weights
    fraction = scaled - np.floor(scaled)
    edges = np.concatenate([[0.0], np.cumsum(scaled)])
    low, high = edges[:-1], edges[1:]
    same = np.floor(low) == np.floor(high)  # [a_i, b_i) within one stratum
    first = np.where(same, high - low, np.ceil(low) - low)
    last = np.where(same, 0.0, high - np.floor(high))
    remaining = fraction.sum()
    share = fraction / remaining if remaining > 0 else np.zeros(n)
    return {
        "systematic": float((fraction * (1 - fraction)).sum()),
        "stratified": float((first * (1 - first) + last * (1 - last)).sum()),
        "multinomial": float((scaled * (1 - weights)).sum()),
        "residual": float((remaining * share * (1 - share)).sum()),
    }


__all__ = [
    "RESAMPLE_ALPHA",
    "critical_z",
    "expected_text",
    "judge_resample",
    "offspring_counts",
    "resembles",
    "scheme_variances",
    "z_scores",
]
