"""A row of the report, and the verdicts on the four parts and the whole filter (against the exact grid
filter's posterior means, beside the shipped SIR's: mazelab.exercise.report.reference_run), made by the
grader from the values the student's process returned for the inputs of mazelab.exercise.inputs: what
each check tests, its tolerance and its false-alarm rate are docs/exercise.md's "What each check promises".
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from statistics import NormalDist
from typing import Any

import numpy as np

from mazelab.exercise.child import Message, WireError
from mazelab.exercise.inputs import SCENARIO_COUNT, PartInputs, ScenarioInputs
from mazelab.experiments.study import distance_to_exact
from mazelab.model import OUTSIDE_PENALTY, ROBOT_SPEED, log_likelihood
from mazelab.simulation import convergence_step
from mazelab.weights import effective_sample_size

PASS, FAIL, NOT_WRITTEN, NOT_RUN, NOT_OWN = "pass", "fail", "not written", "not run", "not own work"
SHOWN = {FAIL: "FAIL"}  # how a status reads in a report and results.json (the others as they are)


def clean(text: object, limit: int = 600) -> str:
    """`text` as data: every character that does not print escaped (CR as \\r, ESC as \\x1b), at most
    `limit` characters, so that no name or error forges a line, a row or a colour of what is shown."""
    shown = "".join(c if c.isprintable() else c.encode("unicode_escape").decode("ascii") for c in str(text))
    return shown[:limit]


@dataclass
class Row:
    """One row of the report: the part (or "whole filter"), its status (pass, fail, not written,
    not run, not own work), what was expected, what came, and a hint when it did not pass."""

    part: str
    status: str
    expected: str
    got: str
    hint: str = ""

    def __post_init__(self) -> None:
        self.expected, self.got, self.hint = clean(self.expected), clean(self.got), clean(self.hint)

    @property
    def passed(self) -> bool:
        return self.status == PASS


def take(message: Message, name: str, shape: tuple[int, ...] | None = None, dtype: str = "<f8") -> np.ndarray:
    """The answer's array `name`, of `shape` (None: any) and dtype, or WireError."""
    array = message.arrays.get(name)
    if array is None:
        raise WireError(f"no {name!r} in the answer")
    if array.dtype.str != dtype or (shape is not None and array.shape != shape):
        raise WireError(f"{name!r} is {array.dtype.str} {array.shape}, not {dtype} {shape}")
    return array


def error_of(message: Message) -> dict[str, str] | None:
    """The stage's error as the student's process described it (kind, text), or None."""
    error = message.meta.get("error")
    if error is None:
        return None
    if not isinstance(error, dict) or not isinstance(error.get("text"), str) or not isinstance(error.get("kind"), str):
        raise WireError("an error that is not a kind and a text")
    return {"kind": error["kind"], "text": error["text"]}


# -- the parts ------------------------------------------------------------------------------------------
WEIGH_TOLERANCE = 1e-3  # log-likelihood units: a weight off by 0.1%
ESTIMATE_TOLERANCE = 1e-4  # map units
STEP_TOLERANCE = 1e-4  # map units, on the step length L = 0.2
PREDICT_ALPHA = 0.001  # predict's false-alarm rate: three KS tests and one correlation test
PREDICT_TESTS = 4
PREDICT_LEVEL = PREDICT_ALPHA / PREDICT_TESTS  # each test's level (Bonferroni): 0.00025
DISTINCT_SHARE = 0.99  # at least this share of the particles' headings differ (continuous draws)

HINTS = {
    "predict": "equation (1): x_k = x_(k-1) + L (cos th, sin th), th ~ U(th0 - Delta/2, th0 + Delta/2), "
    "one th per particle",
    "weigh": "equation (3): log N(z; d, sigma^2) = -(z - d)^2 / (2 sigma^2) + const, + log(OUTSIDE_PENALTY) "
    "outside the free area",
    "resample": "Algorithm 2 (systematic): u_j = (U + j) / N, ancestor j = the first i with cumsum(W)_i > u_j",
    "estimate": "the posterior mean sum_i W_i x_i (weights @ positions; the weights are normalised)",
}
UNDERFLOW_HINT = "work in logs: -(z - d)^2 / (2 sigma^2) directly, not log(exp(...)), which underflows to -inf"
EXPECTED = {
    "predict": f"steps of L = {ROBOT_SPEED:g}, headings U(th0 +- Delta/2), one per particle, fresh per call",
    "weigh": f"log p(z|x) of eq. (3) up to a constant, deviation <= {WEIGH_TOLERANCE:g}",
    "estimate": f"sum_i W_i x_i to {ESTIMATE_TOLERANCE:g}",
}


# -- predict ------------------------------------------------------------------------------------
def kolmogorov_p(statistic: float, n: int) -> float:
    """P(D_n >= statistic) for the one-sample Kolmogorov-Smirnov statistic, Stephens' approximation
    (accurate for n >= 35): Q((sqrt(n) + 0.12 + 0.11 / sqrt(n)) D), Q(x) = 2 sum (-1)^(k-1) e^(-2 k^2 x^2)."""
    x = (math.sqrt(n) + 0.12 + 0.11 / math.sqrt(n)) * statistic
    if x < 0.2:
        return 1.0
    return max(0.0, min(1.0, 2 * sum((-1) ** (k - 1) * math.exp(-2 * k * k * x * x) for k in range(1, 101))))


def ks_uniform(values: np.ndarray) -> float:
    """The KS statistic of values against U(0, 1) (whose CDF is 0 below 0 and 1 above 1)."""
    u = np.clip(np.sort(values), 0.0, 1.0)
    n = len(u)
    grid = np.arange(1, n + 1) / n
    return float(max((grid - u).max(), (u - (grid - 1 / n)).max()))


def heading_deviations(start: np.ndarray, moved: np.ndarray, angle: float) -> tuple[np.ndarray, np.ndarray]:
    """(step lengths, each step's heading minus th0 in (-pi, pi]) of one predict call."""
    step = moved - start
    return np.hypot(step[:, 0], step[:, 1]), np.angle((step[:, 0] + 1j * step[:, 1]) * np.exp(-1j * angle))


def judge_predict(inputs: PartInputs, answer: Message) -> Row:
    """predict's row from its answer (moved/j, again, repeat)."""
    expected = EXPECTED["predict"]
    start, angles, delta = inputs.predict.start, inputs.predict.angles, inputs.delta
    moved = [take(answer, f"moved/{j}", start.shape) for j in range(len(angles))]
    again, repeat = take(answer, "again", start.shape), take(answer, "repeat", start.shape)
    if not all(np.isfinite(m).all() for m in (*moved, again, repeat)):
        return Row("predict", FAIL, expected, "NaN or inf among the moved positions", _nan_hint("predict"))
    alpha, reports = PREDICT_LEVEL, []
    for j, angle in enumerate(angles):
        length, deviation = heading_deviations(start, moved[j], angle)
        if np.abs(length - ROBOT_SPEED).max() > STEP_TOLERANCE:
            got = f"step lengths {length.min():.5f}..{length.max():.5f} at th0 = {angle:.3f}"
            return Row(
                "predict", FAIL, expected, got, f"every particle moves exactly L = ROBOT_SPEED; {HINTS['predict']}"
            )
        shared = _shared_headings(deviation)
        if shared:
            return Row("predict", FAIL, expected, shared[0], shared[1])
        statistic = ks_uniform(deviation / delta + 0.5)
        p = kolmogorov_p(statistic, len(deviation))
        reports.append(f"{p:.2g}")
        if p < alpha:
            spread = f"th - th0 in {deviation.min():+.3f}..{deviation.max():+.3f} at th0 = {angle:.3f}"
            got = f"{spread}: KS p {p:.2g} < {alpha:g}"
            return Row("predict", FAIL, expected, got, _spread_hint(deviation, delta))
    correlation = _call_correlation(start, moved[0], again, angles[0])
    if correlation is not None:
        return Row("predict", FAIL, expected, correlation, "draw new noise at every call (from its rng); keep none")
    if not np.array_equal(repeat, moved[0]):
        hint = "draw from the rng argument (rng.random, rng.uniform), not np.random or self.rng: a seeded run repeats"
        return Row("predict", FAIL, "the same draws from an equally seeded rng", "different draws", hint)
    return Row("predict", PASS, expected, f"KS p {', '.join(reports)} (>= {alpha:g} each); fresh noise per call")


def _shared_headings(deviation: np.ndarray) -> tuple[str, str] | None:
    """(got, hint) when the particles do not each draw their own heading: none drawn at all, one
    shared by all, or the same few repeated; else None."""
    distinct = len(np.unique(np.round(deviation, 12)))
    if distinct == 1 and abs(float(deviation[0])) < 1e-9:
        return "every particle moves exactly along th0", "no heading noise: draw th ~ U(th0 +- Delta/2) (eq. 1)"
    if distinct == 1:
        got = f"every particle takes the same heading (th0 {float(deviation[0]):+.3f})"
        return got, "one heading is drawn for all particles: draw one per particle (size=len(positions))"
    if distinct < DISTINCT_SHARE * len(deviation):
        got = f"{distinct} different headings among {len(deviation)} particles"
        return got, "headings repeat across particles: draw one th per particle, each fresh"
    return None


def _spread_hint(deviation: np.ndarray, delta: float) -> str:
    """What the headings' spread says: half or twice the width, a shift, or another law."""
    width = float(deviation.max() - deviation.min())
    centre = float(deviation.max() + deviation.min()) / 2
    spread = float(np.std(deviation))
    kurtosis = float(np.mean((deviation - deviation.mean()) ** 4)) / spread**4 if spread > 0 else 0.0
    if kurtosis > 2.5:  # a uniform's is 1.8, a normal's 3
        return (
            "the headings are bell-shaped (not normal: the paper's compass error is uniform): "
            "th = th0 + Delta (u - 1/2), u ~ U(0, 1), Delta = self.delta"
        )
    if abs(width - delta) > 0.02 * delta:
        return (
            f"the headings span {width:.3f}, {width / delta:.3g} times the compass error's width "
            f"Delta = self.delta = {delta:.3f}: th = th0 + Delta (u - 1/2), u ~ U(0, 1)"
        )
    if abs(centre) > 0.02 * delta:
        return f"the headings are centred {centre:+.3f} off th0: th = th0 + Delta (u - 1/2), u ~ U(0, 1)"
    return "the heading is uniform within Delta/2 of th0 (not normal): " + HINTS["predict"]


def _call_correlation(start: np.ndarray, first: np.ndarray, again: np.ndarray, angle: float) -> str | None:
    """What is wrong when a second call on the same Generator does not draw new noise: the same
    moves, or headings correlated beyond chance (|r| sqrt(N) past the normal quantile); else None."""
    if np.array_equal(first, again):
        return "the same moves as the previous call (on the same Generator)"
    a, b = heading_deviations(start, first, angle)[1], heading_deviations(start, again, angle)[1]
    if np.std(a) == 0 or np.std(b) == 0:
        return None  # the per-particle check has spoken
    r = float(np.corrcoef(a, b)[0, 1])
    critical = NormalDist().inv_cdf(1 - PREDICT_LEVEL / 2)
    if abs(r) * math.sqrt(len(a)) > critical:
        return f"the heading noise of two calls correlates (r = {r:.3f}, limit {critical / math.sqrt(len(a)):.3f})"
    return None


# -- weigh --------------------------------------------------------------------------------------
def judge_weigh(inputs: PartInputs, answer: Message) -> Row:
    """weigh's row from its answer (log_w/j, one per measurement)."""
    expected = EXPECTED["weigh"]
    world, points, sigma = inputs.world, inputs.weigh.points, inputs.sigma
    got = [take(answer, f"log_w/{j}", (len(points),)) for j in range(len(inputs.weigh.z))]
    if any(np.isnan(g).any() or np.isposinf(g).any() for g in got):
        return Row("weigh", FAIL, expected, "NaN or +inf among the log-likelihoods", _nan_hint("weigh"))
    outside = ~world.is_free(points[:, 0], points[:, 1])
    distance = world.distance_to_nearest_station(points)
    worst, fits, linear = 0.0, [], []
    for z, log_w in zip(inputs.weigh.z, got, strict=True):
        if np.isneginf(log_w).any():
            return Row("weigh", FAIL, expected, "-inf where the likelihood is not 0", UNDERFLOW_HINT)
        deviation = log_w - log_likelihood(z, points, world, sigma)
        worst = max(worst, float(np.abs(deviation - np.median(deviation)).max()))
        fits.append(_fit(log_w, -0.5 * ((z - distance) / sigma) ** 2, outside))
        linear.append(min(_fit(log_w, z - distance, outside)[2], _fit(log_w, np.abs(z - distance), outside)[2]))
    if worst <= WEIGH_TOLERANCE:
        return Row("weigh", PASS, expected, f"largest deviation {worst:.3g}")
    return Row("weigh", FAIL, expected, f"largest deviation {worst:.3g}", _weigh_hint(fits, got, sigma, linear))


def _fit(log_w: np.ndarray, quadratic: np.ndarray, outside: np.ndarray) -> tuple[float, float, float]:
    """(a, b, largest residual) of the least-squares fit log_w ~ a * quadratic + b * outside + c."""
    design = np.column_stack([quadratic, outside, np.ones(len(log_w))])
    coefficients = np.linalg.lstsq(design, log_w, rcond=None)[0]
    residual = float(np.abs(design @ coefficients - log_w).max())
    return float(coefficients[0]), float(coefficients[1]), residual


def _weigh_hint(
    fits: list[tuple[float, float, float]], got: list[np.ndarray], sigma: float, linear: list[float]
) -> str:
    """Which term of equation (3) the fit log_w ~ a q + b outside + c gets wrong; if it does not fit
    at all, whether weigh returned likelihoods instead of logs, left out the square (`linear`: the
    largest residuals of the fits linear in z - d and in |z - d|), or used another distance."""
    spread = max(float(np.ptp(g)) for g in got) or 1.0
    if max(f[2] for f in fits) > 0.01 * spread:
        if all(np.all(g >= 0) for g in got):
            return "weigh returns log-likelihoods, not likelihoods: log N(z; d, sigma^2), not N itself (eq. 3)"
        if max(linear) <= 0.01 * spread:
            return "the square is missing: -(z - d)^2 / (2 sigma^2), not -(z - d) / sigma (eq. 3)"
        return (
            "the weights do not follow -(z - d)^2 / (2 sigma^2) in d, the distance to the nearest station: "
            "d = self.world.distance_to_nearest_station(positions), the nearest of all stations"
        )
    scale, penalty = float(np.mean([f[0] for f in fits])), float(np.mean([f[1] for f in fits]))
    for factor, within, hint in (  # the exponent's factor a mistake gives, how near, and its hint
        (-1, 0.02, "the sign: log N = -(z - d)^2 / (2 sigma^2); a particle far from z must weigh less (eq. 3)"),
        (sigma, 0.02 * sigma, "sigma where sigma^2 belongs: (z - d)^2 / (2 sigma^2), sigma = the noise's std (eq. 3)"),
        (sigma**2, 0.02 * sigma**2, "sigma is missing: -(z - d)^2 / (2 sigma^2), sigma = self.sigma (eq. 3)"),
        (2, 0.02, "the 2 of 2 sigma^2 is missing: -(z - d)^2 / (2 sigma^2) (eq. 3)"),
    ):
        if abs(scale - factor) < within:
            return hint
    if abs(scale - 1) > 1e-3:
        return f"the exponent is {scale:.4g} times -(z - d)^2 / (2 sigma^2) of eq. (3)"
    log_penalty = math.log(OUTSIDE_PENALTY)
    if abs(penalty - log_penalty) > 1e-4:
        if abs(penalty - OUTSIDE_PENALTY) < 0.01:
            return f"add the log of the penalty, log(OUTSIDE_PENALTY) = {log_penalty:.3f}, not the penalty itself"
        return (
            f"the outside penalty: add log(OUTSIDE_PENALTY) = {log_penalty:.4f} where world.is_free is False "
            f"(refinement 1); yours adds {penalty:.4f}"
        )
    return HINTS["weigh"] + "; d = self.world.distance_to_nearest_station(positions)"


def _nan_hint(part: str) -> str:
    return f"{part} must return numbers: NaN or inf comes from 0/0, inf - inf or log of a negative (check each term)"


# -- estimate -----------------------------------------------------------------------------------
def judge_estimate(inputs: PartInputs, answer: Message) -> Row:
    """estimate's row from its answer (point/k, one per weight vector)."""
    expected = EXPECTED["estimate"]
    points, vectors = inputs.estimate.points, inputs.estimate.weights
    got = [take(answer, f"point/{k}", (2,)) for k in range(len(vectors))]
    if not all(np.isfinite(g).all() for g in got):
        return Row("estimate", FAIL, expected, "NaN or inf", _nan_hint("estimate"))
    offsets = [float(np.hypot(*(g - w @ points))) for g, w in zip(got, vectors, strict=True)]
    worst = int(np.argmax(offsets))
    report = f"off by {offsets[worst]:.3g} under the {inputs.estimate.kinds[worst]} weights"
    if offsets[worst] <= ESTIMATE_TOLERANCE:
        return Row("estimate", PASS, expected, f"largest offset {offsets[worst]:.3g}")
    return Row("estimate", FAIL, expected, report, _estimate_hint(got, points, vectors))


def _estimate_hint(got: list[np.ndarray], points: np.ndarray, vectors: tuple[np.ndarray, ...]) -> str:
    """The plain mean, the heaviest particle, or the general hint."""
    unequal = [(g, w) for g, w in zip(got, vectors, strict=True) if np.ptp(w) > 0]

    def near(values: list[np.ndarray]) -> bool:
        return all(np.hypot(*(g - v)) <= ESTIMATE_TOLERANCE for (g, _), v in zip(unequal, values, strict=True))

    if near([points.mean(axis=0)] * len(unequal)):
        return "that is the plain mean of the particles: " + HINTS["estimate"]
    if near([points[np.argmax(w)] for _, w in unequal]):
        return "that is the heaviest particle (the mode); the paper's estimate is the mean: " + HINTS["estimate"]
    return HINTS["estimate"]


# -- resample ------------------------------------------------------------------------------------------
RESAMPLE_ALPHA = 0.001  # the resample check's false-alarm rate (Bonferroni over every particle)
EXACT = 1e-6  # a count that never varies must equal N W_i to this (rounding of N W_i)
RESEMBLANCE_VECTOR = "fractional"  # the vector whose offspring variance names the scheme


def critical_z(particles: int, alpha: float = RESAMPLE_ALPHA) -> float:
    """The two-sided normal quantile of each particle's z-test: alpha / (2 particles) in each tail."""
    return NormalDist().inv_cdf(1 - alpha / (2 * particles))


def offspring_counts(ancestors: np.ndarray, n: int) -> np.ndarray:
    """The offspring counts (R, n) of R calls' ancestor indices (R, n)."""
    calls = len(ancestors)
    rows = np.arange(calls)[:, None] * n
    return np.bincount((ancestors + rows).ravel(), minlength=calls * n).reshape(calls, n)


def z_scores(counts: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Each particle's z: its mean count's deviation from N W_i over the standard error, or for a count
    that never varies the z of its p-value (+-inf for d >= 1). Why the variance has a floor, and why a
    correct resampler fails with probability at most RESAMPLE_ALPHA whatever the correlations between
    its counts (Bonferroni over every particle, `critical_z`): docs/exercise.md, "What each check
    promises"."""
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
    expected = expectations(inputs)["resample"]
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


def expectations(inputs: PartInputs) -> dict[str, str]:
    """What each stage's row expects (its "expected:" line), by stage."""
    resample = inputs.resample
    draws = f"E[offspring] = N W_i under {len(resample.weights)} weight vectors, {resample.draws} calls each"
    return {**EXPECTED, "resample": draws, "whole": whole_expected()}


def judge(
    stage: str, inputs: PartInputs, scenarios: list[ScenarioInputs], answer: Message, report: Any, references: Any
) -> Row:
    """A stage's row from its answer: the error the student's code reported (the whole filter's naming
    its scenario), or its values judged (an estimate that is not a number names its step); the scheme the
    resampler resembles and the whole filter's figures go into `report` (the whole filter's SIR resamples
    with that scheme, on the scenarios' reference runs: `references`, report.reference_run)."""
    error, scheme = error_of(answer), report.scheme
    if error and stage != "whole":  # not written, an exit of its own, the wrong form, or an error (its line)
        expected = expectations(inputs)[stage]
        if error["kind"] == "not written":
            return Row(stage, NOT_WRITTEN, expected, "not implemented", f"write {stage} (see its docstring)")
        hint = "a part returns its answer; it never ends the program" if error["kind"] == "exit" else HINTS[stage]
        return Row(stage, FAIL, expected, error["text"], hint)
    if stage == "resample":
        row, report.scheme = judge_resample(inputs, answer)
        return row
    if stage != "whole":
        return {"predict": judge_predict, "weigh": judge_weigh, "estimate": judge_estimate}[stage](inputs, answer)
    expected = whole_expected(scheme)
    if any(row.status == NOT_WRITTEN for row in report.rows):  # the parts' rows come first
        return Row("whole filter", NOT_RUN, expected, "not run", "write every part first")
    if error:  # naming the scenario
        where = answer.meta.get("scenario")
        prefix = f"scenario {where + 1}: " if isinstance(where, int) and not isinstance(where, bool) else ""
        hint = NAN_HINT if "not finite" in error["text"] else "fix the error first"
        return Row("whole filter", FAIL, expected, prefix + error["text"], hint)
    estimates = []
    for i, scenario in enumerate(scenarios):  # the student's estimates, each a number at every step (or which is not)
        mine = take(answer, f"estimates/{i}", (len(scenario.measurements), 2))
        if not np.isfinite(mine).all():
            step = int(np.argmin(np.isfinite(mine).all(axis=1))) + 1
            got = f"scenario {i + 1}: the estimate is {mine[step - 1].tolist()} at step {step}"
            return Row("whole filter", FAIL, expected, got, NAN_HINT)
        estimates.append(mine)
    sir = [references(s, scheme) for s in scenarios]
    exact = [references(s).result() for s in scenarios]
    row, report.figures = judge_whole(scenarios, estimates, exact, [f.result() for f in sir], scheme)
    return row


# -- the whole filter ----------------------------------------------------------------------------
WORSE_LIMIT = 11  # fail when farther than the SIR from the exact mean on this many of the 12 scenarios
MAGNITUDE_ALPHA = 0.001  # the magnitude test's level (its p-value is a multiple of 1/4096)
NAN_HINT = "the estimate must be a number at every step: check the weights (all 0 or NaN?) and estimate"


def sign_test_alpha(limit: int = WORSE_LIMIT, scenarios: int = SCENARIO_COUNT) -> float:
    """P(Binomial(scenarios, 1/2) >= limit): the whole-filter check's false-alarm rate."""
    return sum(math.comb(scenarios, k) for k in range(limit, scenarios + 1)) / 2**scenarios


def whole_expected(scheme: str = "systematic") -> str:
    return (
        f"no worse than SIR ({scheme}): farther on < {WORSE_LIMIT} of {SCENARIO_COUNT} (alpha "
        f"{sign_test_alpha():.4f}), distance ratio p > {MAGNITUDE_ALPHA:g}"
    )


def magnitude_p(distances: np.ndarray, sir_distances: np.ndarray) -> tuple[float, float]:
    """(the geometric mean of the distance ratios, the randomization test's p-value): the share of the
    2^n sign patterns of the log ratios whose sum reaches theirs (exact given the ratios' sizes)."""
    ratios = np.log((np.asarray(distances) + 1e-12) / (np.asarray(sir_distances) + 1e-12))
    n = len(ratios)
    signs = ((np.arange(2**n)[:, None] >> np.arange(n)) & 1) * 2 - 1
    sums = signs @ np.abs(ratios)
    return float(np.exp(ratios.mean())), float(np.mean(sums >= ratios.sum() - 1e-9))


@dataclass
class ScenarioFigures:
    """One scenario, and the student's and the SIR's distance to the exact mean (second half) and convergence."""

    scenario: ScenarioInputs
    distance: float
    sir_distance: float
    converged: bool
    sir_converged: bool


FIGURE_COLUMNS = (  # the per-scenario table: each column's heading and its cell
    ("maze", lambda f: f.scenario.maze),
    ("sigma", lambda f: f"{f.scenario.sigma:.2f}"),
    ("delta", lambda f: f"{f.scenario.delta:.2f}"),
    ("N", lambda f: str(len(f.scenario.particles))),
    ("to exact", lambda f: f"{f.distance:.3f}"),
    ("SIR's", lambda f: f"{f.sir_distance:.3f}"),
    ("converged", lambda f: "yes" if f.converged else "no"),
    ("SIR's", lambda f: "yes" if f.sir_converged else "no"),
)


def judge_whole(
    scenarios: list[ScenarioInputs],
    estimates: list[np.ndarray],
    exact: list[np.ndarray],
    sir: list[np.ndarray],
    scheme: str,
) -> tuple[Row, list[ScenarioFigures]]:
    """The whole filter's row (the sign and magnitude tests against the SIR) and the figures per scenario."""
    figures = []
    for s, mine, exact_means, sir_means in zip(scenarios, estimates, exact, sir, strict=True):
        distances = (distance_to_exact(mine, exact_means), distance_to_exact(sir_means, exact_means))
        convergence = (convergence_step(np.hypot(*(run - s.true_positions).T)) is not None for run in (mine, sir_means))
        figures.append(ScenarioFigures(s, *distances, *convergence))
    worse = sum(not f.distance <= f.sir_distance for f in figures)  # NaN counts as worse
    mean, sir_mean = np.mean([f.distance for f in figures]), np.mean([f.sir_distance for f in figures])
    ratio, p = magnitude_p(np.array([f.distance for f in figures]), np.array([f.sir_distance for f in figures]))
    got = (
        f"farther on {worse} of {len(figures)}; to exact {mean:.3f} (SIR {sir_mean:.3f}); "
        f"converged {sum(f.converged for f in figures)}/{len(figures)} (SIR {sum(f.sir_converged for f in figures)}); "
        f"distance ratio {ratio:.2f} (p {p:.2g})"
    )
    if worse < WORSE_LIMIT and p > MAGNITUDE_ALPHA:
        return Row("whole filter", PASS, whole_expected(scheme), got), figures
    hint = "the parts pass alone but not together: check what weigh and predict assume of each other"
    return Row("whole filter", FAIL, whole_expected(scheme), got, hint), figures
