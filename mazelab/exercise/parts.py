"""One check per part of the exercise, each on fixed seeded inputs, each a row of the report.

weigh     against mazelab.model.log_likelihood up to a constant per measurement: |deviation| <= 1e-3
estimate  against sum_i W_i x_i on two sets of unequal weights: |deviation| <= 1e-4 map units
predict   every step of length L (to 1e-4), the heading's deviation from th0 uniform on [-Delta/2, Delta/2]:
          a Kolmogorov-Smirnov test at each of two compass angles, each at 0.0005 (0.001 together)
resample  unbiased offspring counts, E[N_i] = N W_i: a z-test per particle over R seeded calls,
          Bonferroni over the N particles (0.001 together); which scheme its variance resembles
predict and resample must also repeat their draws from an equally seeded Generator.
A correct part fails a statistical check with at most the stated probability (the false-alarm rate);
the deterministic checks (tolerances far above float64 rounding) never fail a correct part.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from statistics import NormalDist
from typing import Any

import numpy as np

from mazelab.exercise.student import PartError, StudentFilter
from mazelab.maze import Maze
from mazelab.mazes import load_maze
from mazelab.model import OUTSIDE_PENALTY, ROBOT_SPEED, log_likelihood
from mazelab.plugins import student_frames
from mazelab.resampling import RESAMPLING_SCHEMES

CHECK_MAZE = "maze_10x10"
SIGMA, DELTA = 0.3, 0.4  # delta is not the command line's default 0.5: a hard-coded 0.5 shows
SEED = 2024  # every check's inputs and draws come from seeds derived from this one
WEIGH_TOLERANCE = 1e-3  # log-likelihood units: a weight off by 0.1%
ESTIMATE_TOLERANCE = 1e-4  # map units
STEP_TOLERANCE = 1e-4  # map units, on the step length L = 0.2
PREDICT_ALPHA = 0.001  # false-alarm rate of the predict check (two KS tests at half of it each)
PREDICT_COUNT = 20_000
PREDICT_ANGLES = (0.7, 3.0)  # the second straddles +-pi: an angle wrapped wrongly shows
RESAMPLE_ALPHA = 0.001  # false-alarm rate of the resample check (Bonferroni over the particles)
RESAMPLE_DRAWS = 4000  # R calls of resample on the same weights


@dataclass
class Row:
    """A row of the report: the part, pass or fail, what was expected, what came, and a hint."""

    part: str
    passed: bool
    expected: str
    got: str
    hint: str = ""
    not_written: bool = False


def make_filter(filter_class: type, world: Maze | None = None, count: int = 200) -> Any:
    """The student's filter on the check maze with SIGMA, DELTA and `count` seeded prior particles."""
    world = world if world is not None else load_maze(CHECK_MAZE)
    rng = np.random.default_rng(SEED)
    return filter_class(world, SIGMA, DELTA, world.random_free_places(count, rng), rng)


def call_part(part: str, call: Callable[[], Any]) -> tuple[Any, Row | None]:
    """(the part's answer, None), or (None, the failing row): not written, or the error it raised."""
    try:
        return call(), None
    except NotImplementedError:
        return None, Row(part, False, "written", "not implemented", f"write {part} (see its docstring)", True)
    except PartError as error:
        return None, Row(part, False, "an answer of the right shape", str(error), HINTS[part])
    except Exception as error:
        frames = student_frames(error.__traceback__)
        where = f" ({Path(frames[-1].filename).name}, line {frames[-1].lineno})" if frames else ""
        return None, Row(part, False, "no error", f"{type(error).__name__}: {error}{where}", HINTS[part])


HINTS = {
    "predict": "equation (1): x_k = x_{k-1} + L (cos th, sin th), th ~ U(th0 - Delta/2, th0 + Delta/2), per particle",
    "weigh": "equation (3): log N(z; d, sigma^2) = -(z - d)^2 / (2 sigma^2) + const, + log 0.5 outside the free area",
    "resample": "Algorithm 2 (systematic): u_j = (U + j) / N, ancestor j = the first i with cumsum(W)_i > u_j",
    "estimate": "the posterior mean sum_i W_i x_i (weighted by W, not a plain average of the particles)",
}


# -- weigh --------------------------------------------------------------------------------------------
def check_weigh(filter_class: type) -> Row:
    """weigh against mazelab.model.log_likelihood, up to a constant per z, on points in and out of the free area."""
    filt = make_filter(filter_class)
    world = filt.world
    rng = np.random.default_rng([SEED, 1])
    points = rng.uniform([-0.5, -0.5], [world.width + 0.5, world.height + 0.5], size=(3000, 2))
    outside = ~world.is_free(points[:, 0], points[:, 1])
    distance = world.distance_to_nearest_station(points)
    worst, fits = 0.0, []
    for z in (0.4, 1.3, 2.6):
        got, failed = call_part("weigh", lambda z=z: filt.call_weigh(points, z))
        if failed:
            return failed
        expected = log_likelihood(z, points, world, SIGMA)
        deviation = got - expected
        if not np.isfinite(deviation).all():
            return Row("weigh", False, _weigh_expected(), "-inf where the likelihood is not 0", HINTS["weigh"])
        worst = max(worst, float(np.abs(deviation - np.median(deviation)).max()))
        quadratic = -0.5 * ((z - distance) / SIGMA) ** 2
        design = np.column_stack([quadratic, outside, np.ones(len(points))])
        fits.append(np.linalg.lstsq(design, got, rcond=None)[0][:2])
    passed = worst <= WEIGH_TOLERANCE
    scale, penalty = np.mean(fits, axis=0)
    hint = "" if passed else _weigh_hint(float(scale), float(penalty))
    return Row("weigh", passed, _weigh_expected(), f"largest deviation {worst:.3g}", hint)


def _weigh_expected() -> str:
    return f"log p(z|x) of eq. (3) up to a constant, deviation <= {WEIGH_TOLERANCE:g}"


def _weigh_hint(scale: float, penalty: float) -> str:
    """Which term of equation (3) the fit got ≈ scale * quadratic + penalty * outside + c gets wrong."""
    if abs(scale + 1) < 0.05:
        return "the sign: log N = -(z - d)^2 / (2 sigma^2); a particle far from z must weigh less (eq. 3)"
    if abs(scale - SIGMA) < 0.05:
        return "sigma where sigma^2 belongs: (z - d)^2 / (2 sigma^2), sigma = the noise's std (eq. 3)"
    if abs(scale - 1) > 0.01:
        return f"the exponent is {scale:.2f} times -(z - d)^2 / (2 sigma^2) of eq. (3)"
    if abs(penalty - math.log(OUTSIDE_PENALTY)) > 0.01:
        return (
            f"the outside penalty: add log(OUTSIDE_PENALTY) = {math.log(OUTSIDE_PENALTY):.3f} where "
            f"world.is_free is False (refinement 1); yours adds {penalty:.3f}"
        )
    return HINTS["weigh"] + "; d = world.distance_to_nearest_station(positions)"


# -- estimate -----------------------------------------------------------------------------------------
def check_estimate(filter_class: type) -> Row:
    """estimate against sum_i W_i x_i on two sets of very unequal weights."""
    filt = make_filter(filter_class)
    rng = np.random.default_rng([SEED, 2])
    points = filt.world.random_free_places(2000, rng)
    worst, plain = 0.0, True
    for power in (4, 12):  # W_i ∝ e_i^power, e exponential: a few particles carry most of the weight
        weights = rng.exponential(size=len(points)) ** power
        weights /= weights.sum()
        got, failed = call_part("estimate", lambda w=weights: filt.call_estimate(points, w))
        if failed:
            return failed
        worst = max(worst, float(np.hypot(*(got - weights @ points))))
        plain &= bool(np.hypot(*(got - points.mean(axis=0))) <= ESTIMATE_TOLERANCE)
    passed = worst <= ESTIMATE_TOLERANCE
    hint = (
        ""
        if passed
        else "that is the plain mean of the particles: " + HINTS["estimate"]
        if plain
        else HINTS["estimate"]
    )
    return Row(
        "estimate", passed, f"sum W_i x_i to {ESTIMATE_TOLERANCE:g}", f"off by {worst:.3g}", "" if passed else hint
    )


# -- predict ------------------------------------------------------------------------------------------
def kolmogorov_p(statistic: float, n: int) -> float:
    """P(D_n >= statistic) for the one-sample Kolmogorov-Smirnov statistic, Stephens' approximation
    (accurate for n >= 35): Q((sqrt(n) + 0.12 + 0.11 / sqrt(n)) D), Q(x) = 2 sum (-1)^(k-1) e^(-2 k^2 x^2)."""
    x = (math.sqrt(n) + 0.12 + 0.11 / math.sqrt(n)) * statistic
    if x < 0.2:
        return 1.0
    return max(0.0, min(1.0, 2 * sum((-1) ** (k - 1) * math.exp(-2 * k * k * x * x) for k in range(1, 101))))


def ks_uniform(values: np.ndarray) -> float:
    """The KS statistic of values against U(0, 1)."""
    u = np.sort(values)
    n = len(u)
    grid = np.arange(1, n + 1) / n
    return float(max((grid - u).max(), (u - (grid - 1 / n)).max()))


def check_predict(filter_class: type) -> Row:
    """predict: steps of length L, and the heading's deviation from th0 uniform within Delta/2 (KS)."""
    filt = make_filter(filter_class)
    rng = np.random.default_rng([SEED, 3])
    start = filt.world.random_free_places(PREDICT_COUNT, rng)
    alpha = PREDICT_ALPHA / len(PREDICT_ANGLES)
    expected = f"steps of L = {ROBOT_SPEED:g}; headings U(th0 +- Delta/2): KS p >= {alpha:g} at each of 2 angles"
    reports = []
    for index, angle in enumerate(PREDICT_ANGLES):

        def draw(angle: float = angle, index: int = index) -> np.ndarray:
            return filt.call_predict(start, angle, np.random.default_rng([SEED, 4, index]))

        moved, failed = call_part("predict", draw)
        if failed:
            return failed
        again, _ = call_part("predict", draw)
        step = moved - start
        length = np.hypot(step[:, 0], step[:, 1])
        deviation = np.angle((step[:, 0] + 1j * step[:, 1]) * np.exp(-1j * angle))
        spread = f"headings th0 {deviation.min():+.3f}..{deviation.max():+.3f}"
        if np.abs(length - ROBOT_SPEED).max() > STEP_TOLERANCE:
            got = f"step lengths {length.min():.4f}..{length.max():.4f}"
            return Row(
                "predict", False, expected, got, f"every particle moves exactly L = ROBOT_SPEED; {HINTS['predict']}"
            )
        statistic = ks_uniform(deviation / DELTA + 0.5)
        p = kolmogorov_p(statistic, len(deviation))
        reports.append(f"KS p {p:.2g}")
        if p < alpha:
            return Row(
                "predict", False, expected, f"{spread}, KS D {statistic:.3f}, p {p:.2g}", _predict_hint(deviation)
            )
        if again is None or not np.array_equal(np.asarray(again, dtype=float), moved):
            hint = "draw from the rng argument (rng.random, rng.uniform), not np.random: a seeded run must repeat"
            return Row("predict", False, "the same draws from an equally seeded rng", "different draws", hint)
    return Row("predict", True, expected, ", ".join(reports))


def _predict_hint(deviation: np.ndarray) -> str:
    """What the headings' spread says: none, half or twice the width, or another law."""
    width = float(deviation.max() - deviation.min())
    if width < 1e-9:
        return "no heading noise: draw th ~ U(th0 - Delta/2, th0 + Delta/2) for each particle (eq. 1)"
    if abs(width - DELTA) > 0.05 * DELTA:
        return f"the headings span {width:.3f}, the compass error's width is Delta = {DELTA:g}: th0 +- Delta/2"
    return "the heading is uniform within Delta/2 of th0 (not normal, not shifted): " + HINTS["predict"]


# -- resample -----------------------------------------------------------------------------------------
def resample_weights(count: int = 40) -> np.ndarray:
    """Weights whose N W_i have fractional parts in [0.1, 0.9] (so every unbiased scheme varies each
    count), in pairs f, 1 - f that sum to whole numbers; some particles get several offspring."""
    rng = np.random.default_rng([SEED, 5])
    pairs = count // 2
    fractions = rng.uniform(0.1, 0.9, size=pairs)
    whole = np.zeros((pairs, 2))
    whole[pairs // 2 : 3 * pairs // 4] = (1, 1)
    whole[3 * pairs // 4 :] = (2, 0)
    expected = (whole + np.column_stack([fractions, 1 - fractions])).ravel()
    expected *= count / expected.sum()  # the pairs sum to `count` already; this only removes rounding
    return rng.permutation(expected) / count


def offspring_counts(
    resample: Callable[[np.ndarray, np.random.Generator], np.ndarray], weights: np.ndarray, seed: int
) -> np.ndarray:
    """The offspring counts (R, N) of RESAMPLE_DRAWS calls of `resample` on `weights`, from one seeded rng."""
    rng = np.random.default_rng([SEED, seed])
    n = len(weights)
    ancestors = np.stack([np.asarray(resample(weights.copy(), rng)) for _ in range(RESAMPLE_DRAWS)])
    rows = np.arange(RESAMPLE_DRAWS)[:, None] * n
    return np.bincount((ancestors + rows).ravel(), minlength=RESAMPLE_DRAWS * n).reshape(RESAMPLE_DRAWS, n)


def check_resample(filter_class: type) -> tuple[Row, str]:
    """resample: E[N_i] = N W_i for every particle (z-tests, Bonferroni), and the scheme it resembles
    by its offspring variance; returns the row and that scheme's name (for the whole-filter check)."""
    filt = make_filter(filter_class)
    weights = resample_weights()
    n = len(weights)
    expected = f"E[offspring] = N W_i: z-tests over {RESAMPLE_DRAWS} calls, alpha {RESAMPLE_ALPHA:g} overall"
    counts, failed = call_part("resample", lambda: offspring_counts(filt.call_resample, weights, 6))
    if failed:
        return failed, "systematic"
    again, _ = call_part("resample", lambda: offspring_counts(filt.call_resample, weights, 6)[:1])
    target = n * weights
    mean, std = counts.mean(axis=0), counts.std(axis=0, ddof=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        z = np.where(std > 0, (mean - target) / (std / math.sqrt(RESAMPLE_DRAWS)), np.inf)
    critical = NormalDist().inv_cdf(1 - RESAMPLE_ALPHA / (2 * n))
    worst = int(np.argmax(np.abs(z)))
    scheme, resemblance = resembles(counts.var(axis=0, ddof=1).sum(), weights)
    if abs(z[worst]) > critical:
        got = f"particle {worst}: mean offspring {mean[worst]:.3f} for N W = {target[worst]:.3f}"
        if np.all(std == 0):
            got += " (the same counts every call)"
        hint = "every particle kept once (arange): " if np.array_equal(mean, np.ones(n)) else ""
        return Row("resample", False, expected, got, hint + HINTS["resample"]), "systematic"
    if again is None or not np.array_equal(again, counts[:1]):
        hint = "draw from the rng argument, not np.random: a seeded run must repeat"
        return Row("resample", False, "the same draws from an equally seeded rng", "different draws", hint), scheme
    return Row("resample", True, expected, f"largest |z| {abs(z[worst]):.2f} < {critical:.2f}; {resemblance}"), scheme


def resembles(variance: float, weights: np.ndarray) -> tuple[str, str]:
    """The shipped scheme whose total offspring variance (over the same seeded calls) is nearest on a
    log scale, and a phrase comparing the variance with systematic's and multinomial's."""
    references = {
        name: offspring_counts(scheme, weights, 7).var(axis=0, ddof=1).sum()
        for name, scheme in RESAMPLING_SCHEMES.items()
    }
    nearest = min(references, key=lambda name: abs(math.log((variance + 1e-9) / (references[name] + 1e-9))))
    ratio = variance / references["systematic"]
    phrase = (
        f"looks {nearest} (offspring variance {variance:.2f}: {ratio:.2g}x systematic's "
        f"{references['systematic']:.2f}, multinomial's {references['multinomial']:.2f})"
    )
    return nearest, phrase


def check_parts(filter_class: type) -> tuple[list[Row], str]:
    """Every part's row, in Algorithm 4's order, and the scheme the resampler resembles."""
    resample_row, scheme = check_resample(filter_class)
    rows = [check_predict(filter_class), check_weigh(filter_class), resample_row, check_estimate(filter_class)]
    return rows, scheme


def is_student_filter(filter_class: type) -> bool:
    """Whether the class is the exercise's (its parts can be checked one by one)."""
    return isinstance(filter_class, type) and issubclass(filter_class, StudentFilter)


__all__ = [
    "HINTS",
    "Row",
    "check_estimate",
    "check_parts",
    "check_predict",
    "check_resample",
    "check_weigh",
    "is_student_filter",
    "kolmogorov_p",
    "ks_uniform",
    "make_filter",
    "resample_weights",
    "resembles",
]
