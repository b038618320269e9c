"""The robot, the particle filters (SIR, APF, RPF), an exact grid filter, and `run_model`.

State-space model (lab-spec.md; the paper's equations (1)-(3)):
    x_k = x_{k-1} + L (cos th, sin th),   th ~ U(th0_k - Delta/2, th0_k + Delta/2)     (1)
    z_k = |x_k - nearest station| + v_k,  v_k ~ N(0, sigma^2)                          (2)
    p(z_k | x_k) = N(z_k; distance to the nearest station, sigma^2), times 0.5 outside the free area (3)
The filters follow Arulampalam, Maskell, Gordon, Clapp (2002), Algorithms 4 (SIR), 5 (APF), 6 (RPF).
Weights live in the log domain; every random draw comes from a seeded `numpy.random.Generator`.
"""

from __future__ import annotations

import json
import math
import os
import tempfile
import time
import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from statistics import NormalDist
from typing import Annotated, Any

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from draw import Maze, expect_kidnapping, open_view

# -- the model's constants (the paper keeps them here, to be changed by the student) -------------
ROBOT_SPEED = 0.2  # L, the step length in map units
MAX_STRAIGHT_STEPS = 32  # the robot picks a new heading after this many straight steps (paper: 10 or 32)
OUTSIDE_PENALTY = 0.5  # likelihood factor for particles outside the free area (refinement 1)
RPF_THRESHOLD = 0.2  # RPF regularises when ESS < N_T = RPF_THRESHOLD * N_S (refinement 5)
CONFIDENCE_RADIUS = 1.0  # the estimate is "confident" when CONFIDENCE_SHARE of the mass lies this close
CONFIDENCE_SHARE = 0.95
CONVERGENCE_RADIUS = 0.5  # a run has converged from the step after which its error stays below this
DEFAULT_PARTICLE_COUNT = 1500
DEFAULT_STEPS = 200
GRID_RESOLUTION = 0.02  # cell size of GridBayesFilter, map units (divides 1, so cells never straddle walls)
DEFAULT_PARAMETERS_PATH = Path("model_parameters") / "model_parameters.json"
SCENARIO_FORMAT_VERSION = 2  # the newest scenario format this program reads and writes
KIDNAP_FORMAT_VERSION = 2  # scenarios with a kidnapping are version 2; all others stay version 1
# exp(x) is 0 in float64 below this: when the filter's whole predictive likelihood p(z_k | z_1:k-1)
# is that small no particle explains z_k, and the filter starts again from the prior.
LOG_UNDERFLOW = math.log(np.finfo(float).tiny)
LAB_SIGMA_RANGE = (0.2, 0.8)  # the lab's recommended ranges: outside them we warn, not refuse
LAB_DELTA_RANGE = (0.05, 0.6)
# Particle positions and headings are float32 (half the memory traffic of float64; the map is at most
# a few hundred units, where float32 resolves 1e-5). The robot's own path stays float64 and exact.
PARTICLE_DTYPE = np.float32


# -- the model -------------------------------------------------------------------------------------
def sample_headings(
    compass_angle: float, delta: float, count: int, rng: np.random.Generator, dtype: type = np.float64
) -> np.ndarray:
    """Headings actually taken, th ~ U(th0 - Delta/2, th0 + Delta/2), shape (count,), radians."""
    headings = rng.random(count, dtype=dtype)
    headings -= 0.5
    headings *= delta
    headings += float(compass_angle)
    return headings


def move(positions: np.ndarray, headings: np.ndarray, speed: float = ROBOT_SPEED) -> np.ndarray:
    """Equation (1): one step of length `speed` along `headings`; positions (N, 2) -> (N, 2) in their
    dtype, stored column by column (order F) so that the x and y columns are contiguous."""
    moved = np.empty(positions.shape, positions.dtype, order="F")
    for column, direction in ((0, np.cos), (1, np.sin)):
        step = direction(headings)
        step *= speed
        np.add(positions[:, column], step, out=moved[:, column])
    return moved


def take_particles(points: np.ndarray, indices: np.ndarray) -> np.ndarray:
    """points[indices] for points (N, 2), gathered column by column into order-F storage
    (fancy-indexing the rows of an (N, 2) array is several times slower)."""
    taken = np.empty((len(indices), 2), points.dtype, order="F")
    for column in range(2):
        np.take(points[:, column], indices, out=taken[:, column])
    return taken


def log_likelihood(
    z: float, positions: np.ndarray, world: Maze, sigma: float, outside_penalty: float = OUTSIDE_PENALTY
) -> np.ndarray:
    """Equation (3) in logs, with refinement 1: log p(z | x) for positions (N, 2) -> (N,).

    The Gaussian's constant -log(sigma sqrt(2 pi)) is kept so that sums of these are true log-likelihoods.
    """
    distance, free = world.station_distances_and_free(positions[:, 0], positions[:, 1])
    residual = distance  # (d - z) / sigma, computed in place: the sign does not matter once squared
    residual -= float(z)
    residual /= sigma
    log_p = residual
    log_p *= residual
    log_p *= -0.5
    norm = math.log(sigma * math.sqrt(2 * math.pi))
    log_p += np.where(free, log_p.dtype.type(-norm), log_p.dtype.type(math.log(outside_penalty) - norm))
    return log_p


# -- weights ---------------------------------------------------------------------------------------
def log_sum_exp(log_w: np.ndarray) -> float:
    """log(sum(exp(log_w))) without overflow or underflow; -inf when every entry is -inf."""
    top = log_w.max()  # the array methods skip np.max's dispatch: a few us a call, which counts at small N
    if not np.isfinite(top):
        return float(top)
    shifted = np.subtract(log_w, top)
    return float(top + np.log(np.exp(shifted, out=shifted).sum()))


def _exp_in_place(values: np.ndarray) -> np.ndarray:
    """exp(values), written over `values` (a temporary of the caller's): no second array."""
    return np.exp(values, out=values)


def normalise_log_weights(log_w: np.ndarray) -> np.ndarray:
    """Log weights shifted so that their exponentials sum to one."""
    return log_w - log_sum_exp(log_w)


def effective_sample_size(weights: np.ndarray) -> float:
    """N_eff = 1 / sum(W_i^2) for normalised weights W (Arulampalam et al., eq. 51)."""
    return float(1.0 / (weights * weights).sum())


# -- weighted summaries: numpy's pairwise sums, not BLAS (threaded BLAS stalls on a busy machine) -----
def weighted_mean(weights: np.ndarray, points: np.ndarray) -> np.ndarray:
    """sum_i W_i x_i for normalised weights (N,) and points (N, 2), as float64 (2,)."""
    w = weights.astype(points.dtype, copy=False)
    return np.array([(w * points[:, 0]).sum(), (w * points[:, 1]).sum()], dtype=float)


def weighted_covariance(weights: np.ndarray, points: np.ndarray) -> np.ndarray:
    """sum_i W_i (x_i - mean)(x_i - mean)^T, float64 (2, 2)."""
    mean = weighted_mean(weights, points)
    dx, dy = points[:, 0] - mean[0], points[:, 1] - mean[1]  # float64: the spread may be tiny
    xx, xy, yy = np.sum(weights * dx * dx), np.sum(weights * dx * dy), np.sum(weights * dy * dy)
    return np.array([[xx, xy], [xy, yy]])


def mass_within(weights: np.ndarray, points: np.ndarray, centre: np.ndarray, radius: float) -> float:
    """The total weight of the points (N, 2) at most `radius` from `centre`."""
    dx = points[:, 0] - points.dtype.type(centre[0])
    dy = points[:, 1] - points.dtype.type(centre[1])
    dx *= dx
    dy *= dy
    dx += dy
    return float(weights.sum(where=dx <= radius * radius))


# -- resampling: plain functions, normalised weights W (N,) -> ancestor indices (M,) ---------------
def _inverse_cdf(sorted_uniforms: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Indices i with cumsum(W)[i-1] <= u < cumsum(W)[i] for sorted uniforms u in [0, 1)."""
    cumulative = np.cumsum(weights)
    cumulative[-1] = 1.0  # guard against round-off leaving the last bin short of 1
    return np.searchsorted(cumulative, sorted_uniforms, side="right")


def multinomial_resample(weights: np.ndarray, rng: np.random.Generator, count: int | None = None) -> np.ndarray:
    """M independent draws from the categorical distribution W."""
    count = len(weights) if count is None else count
    return _inverse_cdf(np.sort(rng.random(count)), weights)


def stratified_resample(weights: np.ndarray, rng: np.random.Generator, count: int | None = None) -> np.ndarray:
    """One uniform draw in each of the M strata [m/M, (m+1)/M)."""
    count = len(weights) if count is None else count
    return _inverse_cdf((np.arange(count) + rng.random(count)) / count, weights)


def systematic_resample(weights: np.ndarray, rng: np.random.Generator, count: int | None = None) -> np.ndarray:
    """One uniform offset U shared by the M strata: the lowest-variance scheme, used by default.

    The points u_m = (m + U) / M below cumsum(W)[i] number ceil(M cumsum(W)[i] - U), so ancestor i gets
    the difference of two such counts: O(N) counting instead of a binary search per point.
    """
    count = len(weights) if count is None else count
    below = np.empty(len(weights) + 1)  # below[i + 1]: how many points lie below cumsum(W)[i]
    below[0] = 0.0
    np.cumsum(weights, out=below[1:])  # float64 whatever the weights' dtype: the strata are 1/M wide
    below *= count
    below -= rng.random()
    np.ceil(below, out=below)
    ends = below.astype(np.int64)
    ends[0], ends[-1] = 0, count  # the last guards against round-off leaving cumsum(W) short of 1
    return _ancestors_from_counts(np.minimum(ends, count, out=ends), count)  # ends >= 0 already


def _ancestors_from_counts(ends: np.ndarray, count: int) -> np.ndarray:
    """Ancestor indices (count,), sorted: particle i repeated ends[i + 1] - ends[i] times."""
    starts = np.bincount(ends[1:-1], minlength=count)[:count]  # how many particles end before point m
    return np.cumsum(starts)


def residual_resample(weights: np.ndarray, rng: np.random.Generator, count: int | None = None) -> np.ndarray:
    """floor(M W_i) copies of each particle, the remaining draws multinomial on the remainders."""
    count = len(weights) if count is None else count
    copies = np.floor(count * weights).astype(np.int64)
    deterministic = np.repeat(np.arange(len(weights)), copies)
    left = count - len(deterministic)
    if left == 0:
        return deterministic
    remainder = count * weights - copies
    return np.concatenate([deterministic, multinomial_resample(remainder / remainder.sum(), rng, left)])


RESAMPLING_SCHEMES: dict[str, Callable[..., np.ndarray]] = {
    "systematic": systematic_resample,
    "stratified": stratified_resample,
    "multinomial": multinomial_resample,
    "residual": residual_resample,
}


def resampling_scheme(name: str) -> Callable[..., np.ndarray]:
    """The resampling function called `name` (systematic, stratified, multinomial, residual)."""
    try:
        return RESAMPLING_SCHEMES[name.lower()]
    except KeyError:
        raise ValueError(f"unknown resampling scheme {name!r}; choose one of {', '.join(RESAMPLING_SCHEMES)}") from None


# -- parameter checks ------------------------------------------------------------------------------
def check_model_parameters(sigma: float, delta: float) -> tuple[float, float]:
    """Refuse impossible sigma/delta with a clear message; warn outside the lab's recommended ranges."""
    sigma, delta = _finite_number("sigma", sigma), _finite_number("delta", delta)
    if sigma <= 0:
        raise ValueError(f"sigma must be > 0 (the measurement noise's standard deviation), got {sigma}")
    if not 0 <= delta <= 2 * math.pi:
        raise ValueError(f"delta must be in [0, 2*pi] (the compass error's full width, radians), got {delta}")
    for name, value, (low, high) in (("sigma", sigma, LAB_SIGMA_RANGE), ("delta", delta, LAB_DELTA_RANGE)):
        if not low <= value <= high:
            warnings.warn(f"{name} = {value} is outside the lab's range [{low}, {high}]", stacklevel=3)
    return sigma, delta


def _finite_number(name: str, value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise ValueError(f"{name} must be a number, got {value!r}")
    if not math.isfinite(value):
        raise ValueError(f"{name} must be finite, got {value}")
    return float(value)


def _as_point(name: str, value: Any) -> tuple[float, float]:
    try:
        x, y = value
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a pair (x, y), got {value!r}") from None
    return _finite_number(f"{name} x", x), _finite_number(f"{name} y", y)


def _step_number(name: str, value: Any) -> int:
    """A whole step number >= 1, or a clear ValueError."""
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
        raise ValueError(f"{name} must be a step number >= 1, got {value!r}")
    return int(value)


def _as_points(name: str, value: Any) -> np.ndarray:
    """An (N, 2) float array of finite points with N >= 1, or a clear ValueError."""
    try:
        points = np.array(value, dtype=float)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a list of (x, y) pairs") from None
    if points.ndim != 2 or points.shape[1] != 2 or len(points) == 0:
        raise ValueError(f"{name} must be a non-empty list of (x, y) pairs, got shape {points.shape}")
    if not np.isfinite(points).all():
        raise ValueError(f"{name} contains a value that is not finite")
    return points


# -- the robot -------------------------------------------------------------------------------------
class Robot:
    """The lost robot: it wanders the maze (or replays recorded angles) and measures its distance.

    Without angles it wanders as the paper says: it keeps a compass heading th0 and takes th0 plus
    U(-delta/2, delta/2) each step, and picks a new uniform heading when the next step would hit a
    wall or leave the maze, or after `max_straight_steps` straight steps. Every step it takes (and
    every measurement) is recorded, so a second run of the same robot replays the first exactly.
    """

    def __init__(
        self,
        sigma: float,
        delta: float,
        position: Sequence[float],
        actual_angles: Sequence[float] | None = None,
        compass_angles: Sequence[float] | None = None,
        measurements: Sequence[float] | None = None,
        rng: np.random.Generator | None = None,
        *,
        max_straight_steps: int = MAX_STRAIGHT_STEPS,
        speed: float = ROBOT_SPEED,
        kidnap_at: int | None = None,
        kidnap_position: Sequence[float] | None = None,
    ):
        self.sigma, self.delta = check_model_parameters(sigma, delta)
        self.initial_position = _as_point("robot position", position)
        if (actual_angles is None) != (compass_angles is None):
            raise ValueError("give both actual_angles and compass_angles, or neither")
        self.actual_angles = [_finite_number("actual angle", a) for a in actual_angles or []]
        self.compass_angles = [_finite_number("compass angle", a) for a in compass_angles or []]
        if len(self.actual_angles) != len(self.compass_angles):
            raise ValueError(
                f"actual_angles has {len(self.actual_angles)} entries but compass_angles has {len(self.compass_angles)}"
            )
        self.measurements = [_finite_number("measurement", z) for z in measurements or []]
        if measurements is not None and len(self.measurements) != len(self.actual_angles):
            raise ValueError(
                f"measurements has {len(self.measurements)} entries, one per step ({len(self.actual_angles)}) expected"
            )
        if max_straight_steps < 1:
            raise ValueError(f"max_straight_steps must be >= 1, got {max_straight_steps}")
        self.max_straight_steps = max_straight_steps
        self.speed = speed
        self.rng_given = rng is not None
        self.rng = rng if rng is not None else np.random.default_rng()
        self.kidnap_at: int | None = None
        self.kidnap_position: tuple[float, float] | None = None
        if (kidnap_at is None) != (kidnap_position is None):
            raise ValueError("give both kidnap_at and kidnap_position, or neither")
        if kidnap_at is not None:  # recorded angles given with a kidnapping were walked with the jump
            self.kidnap_at, self.kidnap_position = (
                _step_number("kidnap_at", kidnap_at),
                _as_point("kidnap position", kidnap_position),
            )
        self.reset()

    def kidnap(self, step: int, position: Sequence[float]) -> None:
        """Carry the robot to `position` at step `step` (1-based), before that step's move.

        Step K then reads: put the robot down at `position`, move it with actual angle K, measure z_K.
        A walk already recorded up to step K was walked without the jump, so it cannot be kidnapped.
        """
        step, position = _step_number("kidnap_at", step), _as_point("kidnap position", position)
        if step <= self.recorded_steps and (step, position) != (self.kidnap_at, self.kidnap_position):
            raise ValueError(
                f"the robot replays {self.recorded_steps} steps recorded without this kidnapping (step {step}); "
                "kidnap a robot before it walks that far"
            )
        self.kidnap_at, self.kidnap_position = step, position

    def reset(self) -> None:
        """Back to the initial position, before step 1; recorded angles and measurements are kept."""
        self.x, self.y = self.initial_position
        self.steps_taken = 0
        self.heading: float | None = None  # the last actual angle, for drawing
        self._compass: float | None = None  # the wandering compass heading th0
        self._straight = 0

    @property
    def position(self) -> tuple[float, float]:
        return self.x, self.y

    @property
    def recorded_steps(self) -> int:
        """How many steps the robot can replay from its recorded angles."""
        return len(self.actual_angles)

    def step(self, world: Maze) -> tuple[float, float]:
        """Move one step, then measure: (compass angle th0_k the filters use, measured distance z_k)."""
        k = self.steps_taken
        if k + 1 == self.kidnap_at:
            self.x, self.y = self.kidnap_position  # the kidnapping: picked up and put down elsewhere
        if k == len(self.actual_angles):
            compass, actual = self._choose_heading(world)
            self.compass_angles.append(compass)
            self.actual_angles.append(actual)
        self.heading = self.actual_angles[k]
        self.x += self.speed * math.cos(self.heading)  # equation (1), in float64 scalars:
        self.y += self.speed * math.sin(self.heading)  # a replay retraces the path bit for bit
        self.steps_taken = k + 1
        if k == len(self.measurements):
            self.measurements.append(self.measure(world))
        return self.compass_angles[k], self.measurements[k]

    def measure(self, world: Maze) -> float:
        """Equation (2): a fresh noisy distance to the nearest station, N(distance, sigma^2)."""
        return float(world.distance_to_nearest_station(self.x, self.y) + self.rng.normal(0.0, self.sigma))

    def _choose_heading(self, world: Maze, tries: int = 1000) -> tuple[float, float]:
        """The wandering rule: keep th0 unless the step would leave the free area or ran too long."""
        for _ in range(tries):
            if self._compass is None or self._straight >= self.max_straight_steps:
                self._compass, self._straight = float(self.rng.uniform(0.0, 2 * math.pi)), 0
            actual = float(sample_headings(self._compass, self.delta, 1, self.rng)[0])
            dx, dy = self.speed * math.cos(actual), self.speed * math.sin(actual)
            # The midpoint check keeps the robot from cutting the corner of a wall block.
            if world.is_free(self.x + dx, self.y + dy) and world.is_free(self.x + dx / 2, self.y + dy / 2):
                self._straight += 1
                return self._compass, actual
            self._compass = None
        raise RuntimeError(f"the robot at {self.position} found no free direction in {tries} tries")


# -- recovery from kidnapping and adaptive sample size: options of every particle filter, off by default
ALPHA_SLOW, ALPHA_FAST = 0.001, 0.1  # decay rates of the likelihood averages (Thrun et al., Table 8.3)
RECOVERY_MODES = ("augmented", "sensor")
KLD_BIN_SIZE = 0.25  # KLD-sampling counts occupied squares of this side (map units)
KLD_EPSILON = 0.05  # epsilon: the bound on the KL distance between the sample and the binned posterior
KLD_QUANTILE = NormalDist().inv_cdf(0.99)  # z_{1-delta}, the upper normal quantile for delta = 0.01: 2.326
KLD_MIN_COUNT = 100
SENSOR_RESET_BATCHES = 20  # rejection sampling gives up after this many batches (the rest are uniform)
# Sensor resetting injects while w_fast is below this share of the likelihood expected when localised
# (`localised_likelihood`): 0.5 lies over 5 standard deviations of w_fast below its localised level.
SENSOR_RESET_LEVEL = 0.5


def localised_likelihood(sigma: float) -> float:
    """E[p(z | x)] at the robot's own place x: E_v[N(v; 0, sigma^2)] for v ~ N(0, sigma^2) is
    1 / (2 sqrt(pi) sigma), the mean likelihood of a filter whose belief sits on the robot (1/units)."""
    return 1.0 / (2.0 * math.sqrt(math.pi) * sigma)


@dataclass(frozen=True)
class Recovery:
    """Recovery from kidnapping: augmented MCL (Thrun et al., "Probabilistic Robotics", Table 8.3) and
    sensor resetting (Lenser and Veloso 2000).

    The filter keeps w_slow and w_fast, exponential averages (rates alpha_slow < alpha_fast) of w_avg,
    its estimate of the predictive likelihood p(z_k | z_1:k-1), and replaces each particle, with an
    injection probability, by a draw from the free area:
    - "augmented": probability max(0, 1 - w_fast / w_slow), uniform draws;
    - "sensor": probability max(0, 1 - w_fast / (reset_level * localised_likelihood(sigma))), as Lenser
      and Veloso's N (1 - p_avg / p_threshold) with the model's own threshold and w_fast for p_avg, and
      draws matched to the last measurement (`measurement_matched_places`). The learned w_slow is no
      reference here: it starts at the lost filter's likelihood and, at alpha_slow = 0.001, takes
      thousands of steps to learn the localised one, so w_fast seldom falls below it after a kidnapping.
    """

    mode: str = "augmented"
    alpha_slow: float = ALPHA_SLOW
    alpha_fast: float = ALPHA_FAST
    reset_level: float = SENSOR_RESET_LEVEL

    def __post_init__(self) -> None:
        if self.mode not in RECOVERY_MODES:
            raise ValueError(f"unknown recovery {self.mode!r}; choose one of {', '.join(RECOVERY_MODES)}")
        slow, fast = _finite_number("alpha_slow", self.alpha_slow), _finite_number("alpha_fast", self.alpha_fast)
        if not 0 < slow < fast <= 1:
            raise ValueError(
                f"recovery needs 0 < alpha_slow < alpha_fast <= 1, got alpha_slow {slow}, alpha_fast {fast}"
            )
        if not 0 < _finite_number("reset_level", self.reset_level) <= 1:
            raise ValueError(f"recovery needs 0 < reset_level <= 1, got {self.reset_level}")

    def log_reference(self, log_w_slow: float, sigma: float) -> float:
        """log of the likelihood level below which w_fast means "lost": w_slow, or the sensor's level."""
        if self.mode == "sensor":
            return math.log(self.reset_level * localised_likelihood(sigma))
        return log_w_slow


def recovery_options(
    recovery: bool | str | Recovery | None, alpha_slow: float = ALPHA_SLOW, alpha_fast: float = ALPHA_FAST
) -> Recovery | None:
    """The Recovery a filter option asks for: None/False (off), True ("augmented"), a mode name, a Recovery."""
    if recovery is None or recovery is False:
        return None
    if isinstance(recovery, Recovery):
        return recovery
    if recovery is True:
        recovery = "augmented"
    if not isinstance(recovery, str):
        raise ValueError(f"recovery must be True, False, {' or '.join(RECOVERY_MODES)}, got {recovery!r}")
    return Recovery(recovery.lower(), alpha_slow, alpha_fast)


def kld_sample_size(bins: Any, epsilon: float = KLD_EPSILON, z: float = KLD_QUANTILE) -> np.ndarray:
    """Fox (2003), eq. 13: the sample size that keeps the KL distance between the sample's binned
    estimate and the binned posterior below epsilon with probability 1 - delta, for k occupied bins:
        n = (k-1)/(2 eps) (1 - 2/(9(k-1)) + sqrt(2/(9(k-1))) z_{1-delta})^3   (0 for k <= 1)."""
    k_minus_1 = np.asarray(bins, dtype=float) - 1
    safe = np.maximum(k_minus_1, 1.0)
    c = 2 / (9 * safe)
    return np.where(k_minus_1 >= 1, safe / (2 * epsilon) * (1 - c + np.sqrt(c) * z) ** 3, 0.0)


@dataclass(frozen=True)
class KLDSampling:
    """KLD-sampling options (Fox 2003): resample until the count n reaches the bound of `kld_sample_size`
    for the k bins (squares of side `bin_size`) the new particles occupy, within [min_count, max_count].
    `z` is the normal quantile z_{1-delta} (2.326 for delta = 0.01), not the probability 1 - delta;
    max_count None means the filter's initial particle count."""

    epsilon: float = KLD_EPSILON
    z: float = KLD_QUANTILE
    bin_size: float = KLD_BIN_SIZE
    min_count: int = KLD_MIN_COUNT
    max_count: int | None = None

    def __post_init__(self) -> None:
        for name in ("epsilon", "z", "bin_size"):
            if not _finite_number(f"KLD {name}", getattr(self, name)) > 0:
                raise ValueError(f"KLD {name} must be > 0, got {getattr(self, name)}")
        if self.z < 1:
            warnings.warn(
                f"KLD z = {self.z} looks like a probability; z is the normal quantile z_(1-delta), "
                f"e.g. {KLD_QUANTILE:.3f} for delta = 0.01",
                stacklevel=3,
            )
        _step_number("KLD min_count", self.min_count)
        if self.max_count is not None and _step_number("KLD max_count", self.max_count) < self.min_count:
            raise ValueError(f"KLD max_count {self.max_count} is below min_count {self.min_count}")

    def required_count(self, bins: Any) -> np.ndarray:
        """max(min_count, ceil(n_chi(k))): Fox's stopping count for k occupied bins."""
        return np.maximum(self.min_count, np.ceil(kld_sample_size(bins, self.epsilon, self.z))).astype(np.int64)


def kld_options(kld: bool | KLDSampling | None) -> KLDSampling | None:
    """The KLDSampling a filter option asks for: None/False (off), True (the defaults), or a KLDSampling."""
    if kld is None or kld is False:
        return None
    if kld is True:
        return KLDSampling()
    if isinstance(kld, KLDSampling):
        return kld
    raise ValueError(f"kld must be True, False or a KLDSampling, got {kld!r}")


Move = Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]]  # ancestors or points -> (positions, headings)


def kld_resample(
    weights: np.ndarray,
    move: Move,
    options: KLDSampling,
    resample: Callable[..., np.ndarray],
    rng: np.random.Generator,
    max_count: int,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """KLD-sampling (Fox 2003, Table 1) in batches: draw ancestors from W, move them, and stop at the first
    sample n with n >= required_count(k), k the bins occupied by samples 1..n, or at max_count.
    Returns (ancestors, positions, headings). Each batch is shuffled so that cutting a stratified or
    systematic batch short still keeps every ancestor with the same probability."""
    least = min(options.min_count, max_count)
    occupied = np.empty(0, dtype=np.int64)  # sorted keys of the occupied bins
    parts, drawn, target = [], 0, least
    while True:
        batch = min(max(target - drawn, drawn, 64), max_count - drawn)  # at least doubles: O(log n) batches
        ancestors = rng.permutation(resample(weights, rng, batch))
        positions, headings = move(ancestors)
        keys, first = np.unique(_bin_keys(positions, options.bin_size), return_index=True)
        new = np.zeros(batch, dtype=bool)
        new[first[~np.isin(keys, occupied, assume_unique=True)]] = True
        bins = len(occupied) + np.cumsum(new)  # occupied bins after each sample of the batch
        enough = drawn + np.arange(1, batch + 1) >= np.maximum(least, options.required_count(bins))
        stop = int(np.argmax(enough)) + 1 if enough.any() else batch
        parts.append((ancestors[:stop], positions[:stop], headings[:stop]))
        drawn += stop
        if enough.any() or drawn >= max_count:
            break
        occupied = np.union1d(occupied, keys)
        target = int(options.required_count(len(occupied)))
    ancestors, positions, headings = (np.concatenate(part) for part in zip(*parts, strict=True))
    return ancestors, positions, headings


def _bin_keys(positions: np.ndarray, size: float) -> np.ndarray:
    """One int64 key per point for its bin, the size x size square containing it, shape (N,)."""
    cells = np.floor(positions / size).astype(np.int64)
    return cells[:, 0] * (1 << 32) + cells[:, 1]


def measurement_matched_places(world: Maze, z: float, sigma: float, count: int, rng: np.random.Generator) -> np.ndarray:
    """`count` free points with density proportional to p(z | x) on the free area (sensor resetting),
    shape (count, 2): rejection sampling from the uniform law, accepting x with probability
    p(z | x) / max p = exp(-(z - d(x))^2 / (2 sigma^2)). Points still missing after
    SENSOR_RESET_BATCHES batches (when no free point explains z) are drawn uniformly."""
    found, missing = [], count
    for _ in range(SENSOR_RESET_BATCHES):
        candidates = world.random_free_places(max(4 * missing, 256), rng)
        log_accept = log_likelihood(z, candidates, world, sigma) + math.log(sigma * math.sqrt(2 * math.pi))
        accepted = candidates[np.log(rng.random(len(candidates))) < log_accept][:missing]
        found.append(accepted)
        missing -= len(accepted)
        if missing == 0:
            break
    else:
        found.append(world.random_free_places(missing, rng))
    return np.concatenate(found)


class RecoveryAndKLD:
    """The resampling options of a ParticleFilter (mixed into it): recovery and KLD-sampling.

    `draw_particles` is the filter's resampling: with both options off it is exactly
    `resample` + the filter's move, with no extra draw from its generator, so the paper's filters are
    unchanged. Needs the filter's world, sigma, rng, resample, count.
    """

    def _init_options(
        self, recovery: bool | str | Recovery | None, alpha_slow: float, alpha_fast: float, kld: Any
    ) -> None:
        self.recovery = recovery_options(recovery, alpha_slow, alpha_fast)
        self.kld = kld_options(kld)
        self.max_count = self.count if self.kld is None or self.kld.max_count is None else self.kld.max_count
        self.log_w_slow = self.log_w_fast = -math.inf  # log w_slow, log w_fast: set by the first w_avg
        self.last_z: float | None = None
        self._injected: np.ndarray | None = None
        self._injected_step = 0

    @property
    def injection_probability(self) -> float:
        """max(0, 1 - w_fast / reference) (see Recovery); 0 without recovery or before the first measurement."""
        if self.recovery is None or self.last_z is None or self.log_w_slow == -math.inf:
            return 0.0
        return max(0.0, 1.0 - math.exp(self.log_w_fast - self.recovery.log_reference(self.log_w_slow, self.sigma)))

    @property
    def injected(self) -> np.ndarray | None:
        """Which particles this step's resampling replaced by injected draws (bool, (N,)), or None."""
        return self._injected if self._injected_step == self.steps_done else None

    def track_likelihood(self, log_w_avg: float, z: float) -> None:
        """w_slow += alpha_slow (w_avg - w_slow), w_fast likewise; in logs, w <- (1 - a) w + a w_avg.

        Both start at the first w_avg (as ROS AMCL does; Table 8.3 leaves them open): from zero,
        w_slow would take ~1/alpha_slow steps to reach the likelihood's level and hold back recovery.
        """
        if self.recovery is None:
            return
        slow, fast = self.recovery.alpha_slow, self.recovery.alpha_fast
        if self.last_z is None:
            self.log_w_slow = self.log_w_fast = float(log_w_avg)
        else:
            self.log_w_slow = float(np.logaddexp(math.log1p(-slow) + self.log_w_slow, math.log(slow) + log_w_avg))
            self.log_w_fast = float(np.logaddexp(_log1m(fast) + self.log_w_fast, math.log(fast) + log_w_avg))
        self.last_z = z

    def draw_particles(
        self, weights: np.ndarray, move: Move, move_injected: Move
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None]:
        """Resample (N fixed, or KLD-sized) and `move` the ancestors; then, with recovery, replace each
        particle with probability `injection_probability` by an injected point passed through
        `move_injected`. Returns (positions, headings, ancestors, injected mask or None)."""
        if self.kld is None:
            ancestors = self.resample(weights, self.rng)
            positions, headings = move(ancestors)
        else:
            ancestors, positions, headings = kld_resample(
                weights, move, self.kld, self.resample, self.rng, self.max_count
            )
        self.count = len(positions)
        injected = self._inject(positions, headings, move_injected)
        self._injected, self._injected_step = injected, self.steps_done + 1
        return positions, headings, ancestors, injected

    def inject_without_resampling(self, move_injected: Move) -> None:
        """Replace particles with probability `injection_probability`, each injected point keeping the
        weight of the particle it replaces: the selection ignores the weights, so the set represents the
        same mixture (1 - p) belief + p injection as injecting at a resampling."""
        positions, headings = self.positions.copy(order="F"), self.headings.copy()
        injected = self._inject(positions, headings, move_injected)
        self._injected, self._injected_step = injected, self.steps_done + 1
        self.positions, self.headings = positions, headings

    def _inject(self, positions: np.ndarray, headings: np.ndarray, move_injected: Move) -> np.ndarray | None:
        """Replace particles in place with probability `injection_probability`; the mask, or None."""
        probability = self.injection_probability
        if probability == 0:
            return None
        injected = self.rng.random(len(positions)) < probability
        count = int(injected.sum())
        if count:
            if self.recovery.mode == "sensor" and self.last_z is not None:
                places = measurement_matched_places(self.world, self.last_z, self.sigma, count, self.rng)
            else:
                places = self.world.random_free_places(count, self.rng)
            positions[injected], headings[injected] = move_injected(places)
        return injected


def _log1m(a: float) -> float:
    """log(1 - a), -inf for a = 1."""
    return math.log1p(-a) if a < 1 else -math.inf


# -- the filters -----------------------------------------------------------------------------------
class ParticleFilter(RecoveryAndKLD):
    """Weighted particles {x_i, W_i} approximating the posterior p(x_k | z_1:k).

    Arulampalam's algorithms end each step by resampling; here each step starts by resampling the
    previous posterior, the same sequence of operations, so that between steps the filter holds the
    weighted posterior that the estimate, the ESS and the drawing read.
    Options beyond the paper (off by default): `recovery` (True, "augmented" or "sensor", with
    `alpha_slow`, `alpha_fast`) and `kld` (True or a KLDSampling); see RecoveryAndKLD.

    `positions` (N, 2) and `headings` (N,) are float32 (PARTICLE_DTYPE), `log_weights` (N,) float64.
    The filter replaces these arrays rather than writing into them; to change them, assign new arrays
    (the weights, estimate, ESS and confidence are computed once per assignment and cached).
    """

    name = "ParticleFilter"

    def __init__(
        self,
        world: Maze,
        sigma: float,
        delta: float,
        particles: np.ndarray,
        rng: np.random.Generator | None = None,
        *,
        resampling: str = "systematic",
        outside_penalty: float = OUTSIDE_PENALTY,
        speed: float = ROBOT_SPEED,
        recovery: bool | str | Recovery | None = None,
        alpha_slow: float = ALPHA_SLOW,
        alpha_fast: float = ALPHA_FAST,
        kld: bool | KLDSampling | None = None,
    ):
        self.world, self.sigma, self.delta = world, sigma, delta
        self.rng = rng if rng is not None else np.random.default_rng()
        self.resample = resampling_scheme(resampling)
        self.outside_penalty, self.speed = outside_penalty, speed
        self.positions = np.asfortranarray(_as_points("particles", particles), dtype=PARTICLE_DTYPE)  # (N, 2)
        self.count = len(self.positions)
        self.headings = np.zeros(self.count, dtype=PARTICLE_DTYPE)  # each particle's last motion angle
        self.log_weights = np.full(self.count, -math.log(self.count))
        self._summary_of: tuple[np.ndarray, np.ndarray] | None = None  # the arrays _summary describes
        self._summary: dict[str, Any] = {}
        self.steps_done = 0
        self.reinitialised_at: list[int] = []  # steps at which no particle explained z and we restarted
        self._init_options(recovery, alpha_slow, alpha_fast, kld)

    # what a step does, in the paper's words
    def step(self, compass_angle: float, z: float) -> None:
        raise NotImplementedError

    def propagate(self, positions: np.ndarray, compass_angle: float) -> tuple[np.ndarray, np.ndarray]:
        """Draw x_k ~ p(x_k | x_{k-1}): uniform on the arc of radius L around th0 (headings too)."""
        headings = sample_headings(compass_angle, self.delta, len(positions), self.rng, positions.dtype)
        return move(positions, headings, self.speed), headings

    def motion(self, compass_angle: float) -> tuple[Move, Move]:
        """This step's transition, for resampled ancestors and for injected points (draw_particles)."""

        def points(positions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
            return self.propagate(positions, compass_angle)

        return (lambda ancestors: points(take_particles(self.positions, ancestors))), points

    def likelihood(self, z: float, positions: np.ndarray) -> np.ndarray:
        """log p(z_k | x) of equation (3) with the outside penalty, shape (N,)."""
        return log_likelihood(z, positions, self.world, self.sigma, self.outside_penalty)

    # the weighted posterior
    @property
    def weights(self) -> np.ndarray:
        """The normalised weights W_i = exp(log w_i), shape (N,)."""
        return self._cached("weights", lambda: np.exp(self.log_weights))

    @property
    def ess(self) -> float:
        return self._cached("ess", lambda: effective_sample_size(self.weights))

    @property
    def estimate(self) -> np.ndarray:
        """The posterior mean sum_i W_i x_i, shape (2,)."""
        return self._cached("estimate", lambda: weighted_mean(self.weights, self.positions)).copy()

    @property
    def is_confident(self) -> bool:
        """At least 95% of the weight lies within distance 1 of the estimate (the paper's green circle)."""
        return (
            self._cached(
                "confident", lambda: mass_within(self.weights, self.positions, self.estimate, CONFIDENCE_RADIUS)
            )
            >= CONFIDENCE_SHARE
        )

    def _cached(self, name: str, compute: Callable[[], Any]) -> Any:
        """`compute()`, remembered until `positions` or `log_weights` is assigned a new array."""
        described = self._summary_of
        if described is None or described[0] is not self.positions or described[1] is not self.log_weights:
            self._summary_of, self._summary = (self.positions, self.log_weights), {}
        if name not in self._summary:
            self._summary[name] = compute()
        return self._summary[name]

    # shared bookkeeping
    def _set_weights(self, log_w: np.ndarray, z: float) -> None:
        """Normalise new log weights; if their total underflows, no particle explains z: restart."""
        total = log_sum_exp(log_w)
        if total < LOG_UNDERFLOW or np.isnan(total):
            self._reinitialise(z)
        else:
            self.log_weights = np.subtract(log_w, total, dtype=float)

    def _reinitialise(self, z: float) -> None:
        """Start again from the prior (uniform over the free area), weighted by the current z."""
        self.reinitialised_at.append(self.steps_done + 1)
        if self.kld is not None:  # the prior is as spread as a belief gets: the most particles
            self.count, self.headings = self.max_count, np.zeros(self.max_count, dtype=PARTICLE_DTYPE)
        self.positions = np.asfortranarray(self.world.random_free_places(self.count, self.rng), dtype=PARTICLE_DTYPE)
        log_w = self.likelihood(z, self.positions)
        total = log_sum_exp(log_w)
        uniform = total < LOG_UNDERFLOW
        self.log_weights = (
            np.full(self.count, -math.log(self.count)) if uniform else np.subtract(log_w, total, dtype=float)
        )


class SIRParticleFilter(ParticleFilter):
    """Sampling importance resampling (bootstrap filter), Arulampalam et al. Algorithm 4."""

    name = "SIRParticleFilter"

    def step(self, compass_angle: float, z: float) -> None:
        # RESAMPLE (end of Alg. 4, previous step), then x_k^i ~ p(x_k | x_{k-1}^i)
        x, headings, _, _ = self.draw_particles(self.weights, *self.motion(compass_angle))
        self.positions, self.headings = x, headings
        log_lik = self.likelihood(z, x)
        self._set_weights(log_lik, z)  # w_k^i = p(z_k | x_k^i), then normalise
        if self.recovery is not None:  # w_avg = the mean of p(z_k | x_k^i) over the resampled particles
            self.track_likelihood(log_sum_exp(log_lik) - math.log(len(x)), z)
        self.steps_done += 1


class AuxiliaryParticleFilter(ParticleFilter):
    """Auxiliary particle filter, Arulampalam et al. Algorithm 5, with refinement 2:
    the auxiliary point mu_i is one draw from the transition p(x_k | x_{k-1}^i)."""

    name = "AuxiliaryParticleFilter"

    def step(self, compass_angle: float, z: float) -> None:
        mu, _ = self.propagate(self.positions, compass_angle)  # mu_k^i ~ p(x_k | x_{k-1}^i)
        log_mu_likelihood = self.likelihood(z, mu)
        first_stage = self.log_weights + log_mu_likelihood  # w_k^i ∝ p(z_k | mu_k^i) w_{k-1}^i
        log_first_total = log_sum_exp(first_stage)  # log F, F = sum_i W_{k-1}^i p(z_k | mu_k^i)
        if log_first_total < LOG_UNDERFLOW:
            self._reinitialise(z)
            self.track_likelihood(log_first_total, z)
        else:
            # i^j ~ the first stage, then x_k^j ~ p(x_k | x_{k-1}^{i^j})
            x, headings, ancestors, injected = self.draw_particles(
                _exp_in_place(first_stage - log_first_total), *self.motion(compass_angle)
            )
            self.positions, self.headings = x, headings
            log_lik = self.likelihood(z, x)
            second_stage = log_lik - log_mu_likelihood.take(ancestors)  # p(z|x^j) / p(z|mu^{i^j})
            if self.recovery is None:
                self._set_weights(second_stage, z)
            else:
                # On the scale of p(z_k | z_1:k-1): F p(z|x^j) / p(z|mu^{i^j}), whose mean is Pitt and
                # Shephard's estimate of it; an injected particle has no ancestor and carries p(z|x^j).
                log_w = second_stage + log_first_total
                if injected is not None:
                    log_w = np.where(injected, log_lik, log_w)
                self._set_weights(log_w, z)
                self.track_likelihood(log_sum_exp(log_w) - math.log(len(x)), z)
        self.steps_done += 1


class RegularizedParticleFilter(ParticleFilter):
    """Regularised particle filter, Arulampalam et al. Algorithm 6, with refinements 3-5: the prior
    as proposal, a 2-D Gaussian kernel, and regularisation when N_eff < N_T = threshold * N_S."""

    name = "RegularizedParticleFilter"

    def __init__(self, *args: Any, threshold: float = RPF_THRESHOLD, **kwargs: Any):
        super().__init__(*args, **kwargs)
        if not 0 < threshold <= 1:
            raise ValueError(f"the RPF threshold must be in (0, 1] (N_T = threshold * N_S), got {threshold}")
        self.threshold = threshold
        self.regularised_at: list[int] = []

    @property
    def bandwidth(self) -> float:
        """h_opt = A N^(-1/(n+4)), A = (4/(n+2))^(1/(n+4)), for the Gaussian kernel in n = 2 dimensions."""
        n = 2
        return (4 / (n + 2)) ** (1 / (n + 4)) * self.count ** (-1 / (n + 4))

    def step(self, compass_angle: float, z: float) -> None:
        if self.ess < self.threshold * self.count:  # IF N_eff < N_T (end of Alg. 6, previous step)
            self.regularise()
        elif self.injection_probability > 0:  # recovery: lost, though the weights have not degenerated
            self.inject_without_resampling(_unmoved)
        x, headings = self.propagate(self.positions, compass_angle)  # x_k^i ~ q = p(x_k | x_{k-1}^i)
        self.positions, self.headings = x, headings
        log_w = self.log_weights + self.likelihood(z, x)  # w_k^i ∝ w_{k-1}^i p(z_k | x_k^i)
        if self.recovery is not None:  # W_{k-1} is normalised: w_avg = sum_i W_{k-1}^i p(z_k | x_k^i)
            self.track_likelihood(log_sum_exp(log_w), z)
        self._set_weights(log_w, z)
        self.steps_done += 1

    def regularise(self) -> None:
        """Resample, then jitter each particle by h_opt D eps, eps ~ N(0, I_2), D D^T = S."""
        weights = self.weights
        covariance = weighted_covariance(weights, self.positions)  # S_k, the weighted empirical covariance
        D = np.linalg.cholesky(covariance + 1e-12 * np.eye(2))  # D_k D_k^T = S_k (tiny ridge: S may be 0)
        h = self.bandwidth

        def jitter(ancestors: np.ndarray) -> tuple[np.ndarray, np.ndarray]:  # x^{i*} + h D eps
            eps = self.rng.standard_normal((len(ancestors), 2), dtype=PARTICLE_DTYPE)
            return take_particles(self.positions, ancestors) + gaussian_jitter(eps, h * D), self.headings.take(
                ancestors
            )

        # RESAMPLE and jitter; injected points (recovery) are not jittered: the step's move follows
        self.positions, self.headings, _, _ = self.draw_particles(weights, jitter, _unmoved)
        self.log_weights = np.full(self.count, -math.log(self.count))
        self.regularised_at.append(self.steps_done)


def _unmoved(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Injected points as they are (the RPF's step moves them next), with zero headings."""
    return points, np.zeros(len(points), dtype=PARTICLE_DTYPE)


def gaussian_jitter(eps: np.ndarray, scale: np.ndarray) -> np.ndarray:
    """eps @ scale.T for standard normal eps (N, 2) and a lower-triangular scale (2, 2), in eps's dtype:
    the kernel's draws, written out (a BLAS matmul would start threads for two columns)."""
    jitter = np.empty(eps.shape, eps.dtype, order="F")
    a, c, d = (eps.dtype.type(v) for v in (scale[0, 0], scale[1, 0], scale[1, 1]))
    jitter[:, 0] = a * eps[:, 0]
    jitter[:, 1] = c * eps[:, 0] + d * eps[:, 1]
    return jitter


class GridBayesFilter:
    """The exact Bayes filter of the same model on a fine grid: the accuracy limit of the particle filters.

    The density lives on cells of size `resolution` covering the map plus a `margin` (mass that leaves
    it is dropped). Prediction convolves it with the arc kernel p(x_k | x_{k-1}) (an FFT convolution);
    the update multiplies by equation (3) with the outside penalty, evaluated at the cell centres.
    """

    name = "GridBayesFilter"

    def __init__(
        self,
        world: Maze,
        sigma: float,
        delta: float,
        particles: np.ndarray | None = None,
        rng: np.random.Generator | None = None,
        *,
        resolution: float = GRID_RESOLUTION,
        margin: float = 1.0,
        outside_penalty: float = OUTSIDE_PENALTY,
        speed: float = ROBOT_SPEED,
        **_: Any,
    ):
        del particles  # the exact filter starts from the exact prior, not from a sample of it
        self.world, self.sigma, self.delta, self.speed = world, sigma, delta, speed
        self.rng = rng if rng is not None else np.random.default_rng()
        self.resolution = resolution
        self.origin = -margin
        nx = round((world.width + 2 * margin) / resolution)
        ny = round((world.height + 2 * margin) / resolution)
        centres_x = self.origin + (np.arange(nx) + 0.5) * resolution
        centres_y = self.origin + (np.arange(ny) + 0.5) * resolution
        gx, gy = np.meshgrid(centres_x, centres_y)  # row j is y, column i is x
        self.positions = np.column_stack([gx.ravel(), gy.ravel()])  # (M, 2) cell centres
        self.shape = (ny, nx)
        self.free = world.is_free(gx, gy)
        self._log_likelihood_constant = np.where(self.free, 0.0, math.log(outside_penalty))
        self._distance = world.distance_to_nearest_station(self.positions).reshape(self.shape)
        self.density = self._prior()
        self._last_arc: tuple[float, np.ndarray, np.ndarray] | None = None
        self.headings = np.zeros(len(self.positions))
        self.steps_done = 0
        self.reinitialised_at: list[int] = []

    def _prior(self) -> np.ndarray:
        return self.free / self.free.sum()

    def step(self, compass_angle: float, z: float) -> None:
        self.density = self.predict(self.density, compass_angle)  # p(x_k | z_1:k-1), Chapman-Kolmogorov
        self.update(z)  # p(x_k | z_1:k) ∝ p(z_k | x_k) p(x_k | z_1:k-1)
        self.steps_done += 1

    def predict(self, density: np.ndarray, compass_angle: float) -> np.ndarray:
        """Convolve with the arc kernel of this step's compass angle (linear, not circular, FFT)."""
        kernel, spectrum = self._arc(compass_angle)
        return np.clip(fft_convolve_same(density, kernel, spectrum), 0.0, None)

    def _arc(self, compass_angle: float) -> tuple[np.ndarray, np.ndarray]:
        """The arc kernel of this compass angle and its FFT, kept while the angle repeats (the robot
        holds a compass heading for up to MAX_STRAIGHT_STEPS steps)."""
        if self._last_arc is None or self._last_arc[0] != compass_angle:
            kernel = arc_kernel(compass_angle, self.delta, self.speed, self.resolution)
            spectrum = np.fft.rfft2(kernel, fft_shape(self.shape, kernel.shape))
            self._last_arc = (compass_angle, kernel, spectrum)
        return self._last_arc[1], self._last_arc[2]

    def update(self, z: float) -> None:
        log_lik = -0.5 * ((z - self._distance) / self.sigma) ** 2 + self._log_likelihood_constant
        posterior = self._weighted(self.density, log_lik)
        if posterior is None:  # no cell explains z: restart from the prior, as the particle filters do
            self.reinitialised_at.append(self.steps_done + 1)
            posterior = self._weighted(self._prior(), log_lik)
        self.density = self._prior() if posterior is None else posterior

    @staticmethod
    def _weighted(density: np.ndarray, log_lik: np.ndarray) -> np.ndarray | None:
        """density x exp(log_lik), normalised; None when that product's total underflows."""
        support = density > 0
        top = log_lik[support].max()
        posterior = np.where(support, density * np.exp(np.where(support, log_lik - top, 0.0)), 0.0)
        total = posterior.sum()
        if not total > 0 or math.log(total) + top < LOG_UNDERFLOW:
            return None
        return posterior / total

    @property
    def log_weights(self) -> np.ndarray:
        with np.errstate(divide="ignore"):
            return np.log(self.density.ravel())

    @property
    def weights(self) -> np.ndarray:
        return self.density.ravel()

    @property
    def count(self) -> int:
        return len(self.positions)

    @property
    def ess(self) -> float:
        """Not a sample, so no effective sample size: NaN."""
        return math.nan

    @property
    def estimate(self) -> np.ndarray:
        """The posterior mean over the cell centres, shape (2,)."""
        return weighted_mean(self.weights, self.positions)

    @property
    def is_confident(self) -> bool:
        """At least 95% of the mass lies within distance 1 of the estimate (as for the particle filters)."""
        return mass_within(self.weights, self.positions, self.estimate, CONFIDENCE_RADIUS) >= CONFIDENCE_SHARE

    def posterior_std(self) -> float:
        """Root of the trace of the posterior covariance (map units): how spread the belief is."""
        centred = self.positions - self.estimate
        return float(np.sqrt(self.weights @ (centred**2).sum(axis=1)))


def arc_kernel(compass_angle: float, delta: float, speed: float, resolution: float) -> np.ndarray:
    """The transition density on the grid: the arc of radius `speed` spanning `delta` around
    `compass_angle`, spread bilinearly over cells so that its mean is exact. Shape (2R+1, 2R+1),
    centred on the origin cell, rows along y; sums to one."""
    radius = math.ceil(speed / resolution) + 1
    samples = max(16, math.ceil(4 * speed * delta / resolution))
    angles = compass_angle + delta * ((np.arange(samples) + 0.5) / samples - 0.5)
    fx = radius + speed * np.cos(angles) / resolution
    fy = radius + speed * np.sin(angles) / resolution
    ix, iy = np.floor(fx).astype(int), np.floor(fy).astype(int)
    tx, ty = fx - ix, fy - iy
    kernel = np.zeros((2 * radius + 1, 2 * radius + 1))
    for dy, wy in ((0, 1 - ty), (1, ty)):
        for dx, wx in ((0, 1 - tx), (1, tx)):
            np.add.at(kernel, (iy + dy, ix + dx), wy * wx / samples)
    return kernel


def fft_convolve_same(image: np.ndarray, kernel: np.ndarray, kernel_spectrum: np.ndarray | None = None) -> np.ndarray:
    """Linear 2-D convolution of `image` with an odd-sized centred `kernel`, cropped to image's shape.
    `kernel_spectrum`, if given, is `np.fft.rfft2(kernel, fft_shape(image.shape, kernel.shape))`."""
    ky, kx = kernel.shape
    shape = fft_shape(image.shape, kernel.shape)
    if kernel_spectrum is None:
        kernel_spectrum = np.fft.rfft2(kernel, shape)
    full = np.fft.irfft2(np.fft.rfft2(image, shape) * kernel_spectrum, shape)
    return full[ky // 2 : ky // 2 + image.shape[0], kx // 2 : kx // 2 + image.shape[1]]


def fft_shape(image_shape: tuple[int, ...], kernel_shape: tuple[int, ...]) -> tuple[int, int]:
    """The padded size of a linear (not circular) FFT convolution of image and kernel, fast lengths."""
    return _fast_fft_length(image_shape[0] + kernel_shape[0] - 1), _fast_fft_length(
        image_shape[1] + kernel_shape[1] - 1
    )


def _fast_fft_length(n: int) -> int:
    """The smallest 2^a, 3 * 2^a or 5 * 2^a >= n: numpy's FFT is fastest on such lengths (640 takes a
    third of the time of 625 = 5^4)."""
    return min(odd * 2 ** max(0, math.ceil(math.log2(n / odd))) for odd in (1, 3, 5))


FILTERS: dict[str, type] = {
    "SIRParticleFilter": SIRParticleFilter,
    "AuxiliaryParticleFilter": AuxiliaryParticleFilter,
    "RegularizedParticleFilter": RegularizedParticleFilter,
    "GridBayesFilter": GridBayesFilter,
}
SHORT_NAMES = {
    "sir": "SIRParticleFilter",
    "apf": "AuxiliaryParticleFilter",
    "rpf": "RegularizedParticleFilter",
    "grid": "GridBayesFilter",
}


def resolve_filter(name: str | type) -> type:
    """The filter class for a class name, a short name (sir/apf/rpf/grid) or the paper's spaced name
    ("SIR Particle Filter"), case-insensitive."""
    if isinstance(name, type):
        return name
    key = "".join(str(name).split()).lower()
    for full in FILTERS:
        if key in (full.lower(), full.lower().replace("particlefilter", "")):
            return FILTERS[full]
    if key in SHORT_NAMES:
        return FILTERS[SHORT_NAMES[key]]
    valid = ", ".join([*FILTERS, *SHORT_NAMES])
    raise ValueError(f"unknown filtering algorithm {name!r}; valid names: {valid}")


# -- saved scenarios -------------------------------------------------------------------------------
FiniteFloat = Annotated[float, Field(allow_inf_nan=False)]
Point = tuple[FiniteFloat, FiniteFloat]


class Scenario(BaseModel):
    """A saved run (lab step 9): the paper's four keys, the measurements, and metadata.

    Version 2 adds the kidnapping (kidnap_at, kidnap_position: at step kidnap_at the robot is put down
    at kidnap_position before that step's move). A scenario is written with the lowest version that
    holds it, so files without a kidnapping stay version 1 and older readers still read them.
    """

    model_config = ConfigDict(extra="forbid")

    format_version: int = Field(1, ge=1)
    init_robot_pos: Point
    init_particles_pos: list[Point] = Field(min_length=1)
    robot_actual_angles: list[FiniteFloat]
    robot_compass_angles: list[FiniteFloat]
    robot_measurements: list[FiniteFloat] | None = None
    maze: list[list[int]] | None = None
    sigma: FiniteFloat | None = Field(None, gt=0)
    delta: FiniteFloat | None = Field(None, ge=0, le=2 * math.pi)
    seed: int | None = None
    steps: int | None = Field(None, ge=1)
    filtering_algorithm: str | None = None
    kidnap_at: int | None = Field(None, ge=1)
    kidnap_position: Point | None = None

    @model_validator(mode="before")
    @classmethod
    def _lowest_version(cls, data: Any) -> Any:
        """Without an explicit format_version, the lowest that holds the data."""
        if isinstance(data, dict) and "format_version" not in data:
            data = {**data, "format_version": KIDNAP_FORMAT_VERSION if data.get("kidnap_at") is not None else 1}
        return data

    @model_validator(mode="after")
    def _consistent(self) -> Scenario:
        if self.format_version > SCENARIO_FORMAT_VERSION:
            raise ValueError(
                f"format_version {self.format_version} is newer than this program reads ({SCENARIO_FORMAT_VERSION})"
            )
        if (self.kidnap_at is None) != (self.kidnap_position is None):
            raise ValueError("kidnap_at and kidnap_position come together: give both or neither")
        if self.kidnap_at is not None and self.format_version < KIDNAP_FORMAT_VERSION:
            raise ValueError(f"a kidnapping needs format_version {KIDNAP_FORMAT_VERSION}, got {self.format_version}")
        if self.kidnap_at is not None and self.kidnap_at > len(self.robot_actual_angles):
            raise ValueError(f"kidnap_at {self.kidnap_at} is after the last step ({len(self.robot_actual_angles)})")
        steps = len(self.robot_actual_angles)
        if len(self.robot_compass_angles) != steps:
            raise ValueError(
                f"robot_actual_angles has {steps} entries but robot_compass_angles has {len(self.robot_compass_angles)}"
            )
        if self.robot_measurements is not None and len(self.robot_measurements) != steps:
            raise ValueError(f"robot_measurements has {len(self.robot_measurements)} entries, {steps} expected")
        if self.steps is not None and self.steps != steps:
            raise ValueError(f"steps is {self.steps} but there are {steps} angles")
        if self.maze is not None:
            Maze(self.maze, source="the scenario's maze")
        return self

    def world(self) -> Maze | None:
        """The maze stored in the scenario, if any."""
        return None if self.maze is None else Maze(self.maze, source="the scenario's maze")

    def robot(self, sigma: float | None = None, delta: float | None = None, **kwargs: Any) -> Robot:
        """A Robot that replays this scenario's path (and measurements, if stored)."""
        sigma = self.sigma if sigma is None else sigma
        delta = self.delta if delta is None else delta
        if sigma is None or delta is None:
            raise ValueError("the scenario stores no sigma/delta: give them")
        return Robot(
            sigma,
            delta,
            self.init_robot_pos,
            actual_angles=self.robot_actual_angles,
            compass_angles=self.robot_compass_angles,
            measurements=self.robot_measurements,
            kidnap_at=self.kidnap_at,
            kidnap_position=self.kidnap_position,
            **kwargs,
        )

    def to_json(self) -> str:
        """Json with the paper's keys first, one particle per line (readable, and diff-able)."""
        data = self.model_dump(exclude_none=True)
        lines = []
        for key, value in data.items():
            if key in ("init_particles_pos", "maze"):
                inner = ",\n".join(f"    {json.dumps(list(item))}" for item in value)
                lines.append(f'  "{key}": [\n{inner}\n  ]')
            else:
                lines.append(f'  "{key}": {json.dumps(value)}')
        return "{\n" + ",\n".join(lines) + "\n}\n"


class ScenarioError(ValueError):
    """A scenario file that cannot be used; the message is one line naming the file and the problem."""


def save_scenario(scenario: Scenario, path: str | Path = DEFAULT_PARAMETERS_PATH) -> Path:
    """Write the scenario as json, atomically (a reader never sees half a file). Returns the path."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    write_text_atomically(path, scenario.to_json())
    return path


def load_scenario(path: str | Path = DEFAULT_PARAMETERS_PATH) -> Scenario:
    """Read and validate a scenario json file (a file with only the paper's four keys is fine)."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise ScenarioError(f"{path}: no such scenario file") from None
    except (OSError, UnicodeDecodeError) as error:
        raise ScenarioError(f"{path}: cannot be read ({error})") from None
    try:
        data = json.loads(text)
    except json.JSONDecodeError as error:
        raise ScenarioError(f"{path}:{error.lineno}: not valid json ({error.msg})") from None
    try:
        return Scenario.model_validate(data)
    except ValidationError as error:
        raise ScenarioError(f"{path}: {describe_validation_error(error)}") from None


def describe_validation_error(error: ValidationError) -> str:
    """The first problem of a pydantic error, on one line: 'where: what' (and how many more)."""
    first = error.errors()[0]
    parts = (str(part) for part in first["loc"])  # a key may hold a newline: quote those, to keep one line
    where = ".".join(part if part.isprintable() else repr(part) for part in parts) or "the file"
    more = len(error.errors()) - 1
    return f"{where}: {first['msg']}" + (f" (and {more} more problem(s))" if more else "")


def write_text_atomically(path: str | Path, text: str) -> None:
    """Write `text` to `path` whole or not at all: a temporary file in the same folder, then rename."""
    write_bytes_atomically(path, text.encode("utf-8"))


def write_bytes_atomically(path: str | Path, data: bytes) -> None:
    """Write `data` to `path` whole or not at all: a temporary file in the same folder, then rename."""
    path = Path(path)
    handle, temporary = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(handle, "wb") as stream:
            stream.write(data)
            stream.flush()
            os.fsync(stream.fileno())
        os.replace(temporary, path)
    except BaseException:
        Path(temporary).unlink(missing_ok=True)
        raise


# -- running the model -----------------------------------------------------------------------------
@dataclass
class RunResult:
    """Everything one run produced, per step k = 1..steps (arrays of length `steps`)."""

    filter_name: str
    true_positions: np.ndarray  # (steps, 2), after the robot's move of step k
    estimates: np.ndarray  # (steps, 2), the posterior mean after the update with z_k
    ess: np.ndarray  # (steps,), NaN for the grid filter
    confident: np.ndarray  # (steps,) bool
    step_seconds: np.ndarray  # (steps,), the filter's own time per step
    reinitialised_at: list[int]
    scenario: Scenario
    extras: dict[str, Any] = field(default_factory=dict)

    @property
    def errors(self) -> np.ndarray:
        """Distance between estimate and truth per step (map units)."""
        return np.hypot(*(self.estimates - self.true_positions).T)

    @property
    def converged_at(self) -> int | None:
        """The first step from which the error stays below CONVERGENCE_RADIUS, or None."""
        return convergence_step(self.errors)

    def as_pairs(self) -> list[tuple[tuple[float, float], tuple[float, float]]]:
        """The paper's result: one ((x_true, y_true), (x_est, y_est)) per step, plain floats."""
        return [
            ((float(t[0]), float(t[1])), (float(e[0]), float(e[1])))
            for t, e in zip(self.true_positions, self.estimates, strict=True)
        ]


def convergence_step(errors: np.ndarray, radius: float = CONVERGENCE_RADIUS) -> int | None:
    """The first step (1-based) after which every error is below `radius`; None if the last is not."""
    outside = np.flatnonzero(np.asarray(errors) >= radius)
    if len(outside) == 0:
        return 1
    return None if outside[-1] == len(errors) - 1 else int(outside[-1]) + 2


BYTES_PER_PARTICLE = 400  # arrays a particle needs during a step, temporaries included (generous)


def check_memory_for(particle_count: int) -> None:
    """Refuse, before allocating, a particle count whose arrays would not fit in the available memory."""
    needed = particle_count * BYTES_PER_PARTICLE
    available = _available_memory()
    if available is not None and needed > 0.8 * available:
        raise ValueError(
            f"particle_count {particle_count} needs about {needed / 2**30:.1f} GiB, "
            f"but only {available / 2**30:.1f} GiB of memory is available"
        )


def _available_memory() -> int | None:
    """Bytes of physical memory available now, where the system tells (None elsewhere)."""
    try:
        return os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (AttributeError, ValueError, OSError):
        return None


def check_start(world: Maze, robot_position: tuple[float, float], particles: np.ndarray) -> None:
    """The robot must start in the free area; particles may lie anywhere (but we say so)."""
    if not world.is_free(*robot_position):
        raise ValueError(f"the robot's start {robot_position} is not in the free area of the maze ({world.source})")
    outside = int((~world.is_free(particles[:, 0], particles[:, 1])).sum())
    if outside:
        warnings.warn(f"{outside} of the {len(particles)} initial particles lie outside the free area", stacklevel=3)


def new_seed() -> int:
    """A fresh random seed, recorded so that any run can be repeated."""
    return int(np.random.SeedSequence().entropy % 2**63)


def simulate(
    robot: Robot,
    world: Maze,
    sigma: float,
    delta: float,
    particle_count: int | None = None,
    steps: int | None = None,
    init_particles_pos: Sequence[Sequence[float]] | np.ndarray | None = None,
    filtering_algorithm: str | type = "SIRParticleFilter",
    *,
    seed: int | None = None,
    visualize: Any = False,
    on_step: Callable[[int, Robot, Any], None] | None = None,
    kidnap_at: int | None = None,
    **filter_options: Any,
) -> RunResult:
    """Run one filter on the robot's walk and return the full `RunResult` (what run_model summarises).

    Step k: the robot moves with its actual angle k and measures z_k; the filter predicts with
    compass angle k and updates with z_k; `on_step(k, robot, filter)` is called after each step.
    `seed` seeds the robot (unless it has its own rng), the
    initial particles and the filter; the same seed gives the same result bit for bit.
    `kidnap_at=K`: at step K, before its move, the robot is carried to a free place drawn from the
    seed (see Robot.kidnap); a robot that replays a kidnapping keeps it. The scenario stores it.
    result.extras["particle_count"] holds the particle count per step (it varies with KLD-sampling).
    """
    sigma, delta = check_model_parameters(sigma, delta)
    filter_class = resolve_filter(filtering_algorithm)
    seed = new_seed() if seed is None else int(seed)
    # spawn(4)'s first three streams are spawn(3)'s: runs without kidnapping are unchanged
    robot_rng, particles_rng, filter_rng, kidnap_rng = np.random.default_rng(seed).spawn(4)
    if init_particles_pos is not None:
        particles = _as_points("init_particles_pos", init_particles_pos)
    else:
        count = DEFAULT_PARTICLE_COUNT if particle_count is None else particle_count
        if isinstance(count, bool) or not isinstance(count, (int, np.integer)) or count < 1:
            raise ValueError(f"particle_count must be a whole number >= 1, got {count!r}")
        check_memory_for(int(count))
        particles = world.random_free_places(int(count), particles_rng)
    check_start(world, robot.initial_position, particles)
    if steps is None:
        steps = robot.recorded_steps or DEFAULT_STEPS
    if isinstance(steps, bool) or not isinstance(steps, (int, np.integer)) or steps < 1:
        raise ValueError(f"steps must be a whole number >= 1, got {steps!r}")
    if kidnap_at is not None:
        plan_kidnapping(robot, world, kidnap_at, steps, kidnap_rng)

    robot.reset()
    if not robot.rng_given:
        robot.rng = robot_rng
    filt = filter_class(world, sigma, delta, particles, filter_rng, **filter_options)
    view = open_view(visualize, world, filter_class.name)
    expect_kidnapping(view, robot.kidnap_at, robot.kidnap_position)
    true_positions, estimates = np.empty((steps, 2)), np.empty((steps, 2))
    ess, confident, seconds = np.empty(steps), np.empty(steps, dtype=bool), np.empty(steps)
    counts = np.empty(steps, dtype=np.int64)
    try:
        for k in range(steps):
            compass_angle, z = robot.step(world)
            started = time.perf_counter()
            filt.step(compass_angle, z)
            seconds[k] = time.perf_counter() - started
            true_positions[k], estimates[k] = robot.position, filt.estimate
            ess[k], confident[k], counts[k] = filt.ess, filt.is_confident, filt.count
            view.log_step(k + 1, robot.position, robot.heading, filt)
            if on_step is not None:
                on_step(k + 1, robot, filt)
    finally:
        view.close()
    scenario = Scenario(
        init_robot_pos=robot.initial_position,
        init_particles_pos=particles.tolist(),
        robot_actual_angles=robot.actual_angles[:steps],
        robot_compass_angles=robot.compass_angles[:steps],
        robot_measurements=robot.measurements[:steps],
        maze=world.as_lists(),
        sigma=sigma,
        delta=delta,
        seed=seed,
        steps=steps,
        filtering_algorithm=filter_class.name,
        **_kidnapping_fields(robot, steps),
    )
    return RunResult(
        filter_class.name,
        true_positions,
        estimates,
        ess,
        confident,
        seconds,
        list(filt.reinitialised_at),
        scenario,
        extras={"particle_count": counts},
    )


def plan_kidnapping(robot: Robot, world: Maze, kidnap_at: int, steps: int, rng: np.random.Generator) -> None:
    """Kidnap `robot` at step `kidnap_at` to a free place drawn from `rng`, unless it already replays
    that kidnapping; a different recorded kidnapping, or one after the last step, is refused."""
    kidnap_at = _step_number("kidnap_at", kidnap_at)
    if kidnap_at > steps:
        raise ValueError(f"kidnap_at {kidnap_at} is after the last step ({steps})")
    if robot.kidnap_at is None:
        robot.kidnap(kidnap_at, world.random_free_place(rng))
    elif robot.kidnap_at != kidnap_at:
        raise ValueError(f"the robot replays a kidnapping at step {robot.kidnap_at}, not at step {kidnap_at}")


def _kidnapping_fields(robot: Robot, steps: int) -> dict[str, Any]:
    """The scenario's kidnap_at and kidnap_position, if the robot was kidnapped within `steps`."""
    if robot.kidnap_at is None or robot.kidnap_at > steps:
        return {}
    return {"kidnap_at": robot.kidnap_at, "kidnap_position": robot.kidnap_position}


def run_model(
    robot: Robot,
    world: Maze,
    sigma: float,
    delta: float,
    particle_count: int | None = None,
    steps: int | None = None,
    save_parameters: bool = False,
    init_particles_pos: Sequence[Sequence[float]] | np.ndarray | None = None,
    filtering_algorithm: str | type = "SIRParticleFilter",
    *,
    seed: int | None = None,
    visualize: Any = True,
    parameters_path: str | Path = DEFAULT_PARAMETERS_PATH,
    kidnap_at: int | None = None,
    **filter_options: Any,
) -> list[tuple[tuple[float, float], tuple[float, float]]]:
    """The paper's entry point: run a filter and return [((x_true, y_true), (x_est, y_est)), ...].

    With `init_particles_pos` the particle count follows from it, and with a robot that replays
    angles the step count follows from them. `save_parameters=True` saves the scenario (the paper's
    model_parameters.json, in `parameters_path`) so the filters can be compared on identical data.
    `kidnap_at=K` kidnaps the robot at step K; filter options such as `resampling=`, `recovery=`
    and `kld=` pass through to the filter (see ParticleFilter).
    """
    result = simulate(
        robot,
        world,
        sigma,
        delta,
        particle_count,
        steps,
        init_particles_pos,
        filtering_algorithm,
        seed=seed,
        visualize=visualize,
        kidnap_at=kidnap_at,
        **filter_options,
    )
    if save_parameters:
        save_scenario(result.scenario, parameters_path)
    return result.as_pairs()


__all__ = [
    "AuxiliaryParticleFilter",
    "GridBayesFilter",
    "KLDSampling",
    "ParticleFilter",
    "Recovery",
    "RegularizedParticleFilter",
    "Robot",
    "RunResult",
    "SIRParticleFilter",
    "Scenario",
    "ScenarioError",
    "load_scenario",
    "run_model",
    "save_scenario",
    "simulate",
]
