"""The state-space model, the one source of truth (the paper's equations (1)-(3)):

    x_k = x_{k-1} + L (cos th, sin th),   th ~ U(th0_k - Delta/2, th0_k + Delta/2)     (1)
    z_k = |x_k - nearest station| + v_k,  v_k ~ N(0, sigma^2)                          (2)
    p(z_k | x_k) = N(z_k; distance to the nearest station, sigma^2), times 0.5 outside the free area (3)

The constants are the paper's (L = ROBOT_SPEED, the outside penalty, the RPF's N_T / N_S) and the
lab's (the green circle's radius, the convergence radius), kept in mazelab.constants and shown here;
the station geometry is the maze's (mazelab.maze). Change a constant there and every filter, test and
command follows. `LostRobot` is the model as a filter uses it.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Callable, Sequence
from types import MappingProxyType
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np

from mazelab.checks import check_sigma_within, finite_number
from mazelab.constants import (
    CONFIDENCE_RADIUS,
    CONFIDENCE_SHARE,
    CONVERGENCE_RADIUS,
    DEFAULT_PARTICLE_COUNT,
    DEFAULT_STEPS,
    LOG_UNDERFLOW,
    MAX_STRAIGHT_STEPS,
    OUTSIDE_PENALTY,
    PARTICLE_DTYPE,
    ROBOT_SPEED,
    RPF_THRESHOLD,
)
from mazelab.declaration import Option, Options, number_in
from mazelab.maze import check_world

if TYPE_CHECKING:
    from mazelab.maze import Maze

# the model's constants (the paper's L, the outside penalty, N_T / N_S and the lab's radii) live in
# mazelab.constants, a module of numbers only, so that the exercise's sandbox can take them too
MAX_SPEED = 1.0  # a filter may assume another L (model mismatch), up to one maze cell per step
MIN_RANGE = 1e-9  # map units: nearer its station, the range's gradient is undefined (the EKF skips the update)


# -- the model's constants as filter options (mazelab.declaration): every filter of the model takes them
SPEED_OPTION = Option(
    "speed",
    ROBOT_SPEED,
    "L, the step length the filter assumes (map units; the robot's is 0.2)",
    check=number_in("speed", 0.0, MAX_SPEED, what=" map units (at most a maze cell a step)"),
)
OUTSIDE_PENALTY_OPTION = Option(
    "outside_penalty",
    OUTSIDE_PENALTY,
    "the likelihood factor outside the free area (refinement 1: 0.5)",
    check=number_in("outside_penalty", 0.0, 1.0, what=" (a factor on a likelihood)"),
)
MODEL_OPTIONS = (OUTSIDE_PENALTY_OPTION, SPEED_OPTION)  # what a filter of the model declares and LostRobot reads


LAB_SIGMA_RANGE = (0.2, 0.8)  # the lab's recommended ranges: outside them we warn, not refuse
LAB_DELTA_RANGE = (0.05, 0.6)


# -- the model -------------------------------------------------------------------------------------
def sample_heading(compass_angle: float, delta: float, rng: np.random.Generator) -> float:
    """One heading th ~ U(th0 - Delta/2, th0 + Delta/2), radians (the robot's, once a step): the particles'
    draw and operations (`headings_from_uniforms`, whose th0 and Delta these are) in plain floats, the
    same value without numpy calls."""
    return (rng.random() - 0.5) * delta + float(compass_angle)


def headings_from_uniforms(uniforms: np.ndarray, compass_angle: float | np.ndarray, delta: float) -> np.ndarray:
    """th = th0 + Delta (u - 1/2) for uniforms u in [0, 1), in place (in the uniforms' dtype).

    Parameters
    ----------
    uniforms : float array
        u ~ U[0, 1); overwritten by the headings.
    compass_angle : float, or array
        th0: one angle, or an array that broadcasts against the uniforms (one per run).
    delta : float
        Delta (radians).

    Returns
    -------
    array, `uniforms` itself, now the headings (radians)
    """
    uniforms -= 0.5
    uniforms *= delta
    uniforms += compass_angle if isinstance(compass_angle, np.ndarray) else float(compass_angle)
    return uniforms


def move(positions: np.ndarray, headings: np.ndarray, speed: float = ROBOT_SPEED) -> np.ndarray:
    """Equation (1): one step of length `speed` along `headings`.

    Parameters
    ----------
    positions : array (N, 2)
    headings : array (N,)
        th of each particle (radians).
    speed : float
        L (map units).

    Returns
    -------
    array (N, 2) in the positions' dtype, stored column by column (order F) so that the x and y
    columns are contiguous
    """
    moved = np.empty(positions.shape, positions.dtype, order="F")
    for column, direction in ((0, np.cos), (1, np.sin)):
        step = direction(headings)
        step *= speed
        np.add(positions[:, column], step, out=moved[:, column])
    return moved


def take_particles(points: np.ndarray, indices: np.ndarray) -> np.ndarray:
    """points[indices], gathered column by column into order-F storage (fancy-indexing the rows of an
    (N, 2) array is several times slower).

    Parameters
    ----------
    points : array (N, 2)
    indices : int array (M,)

    Returns
    -------
    array (M, 2), order F, in the points' dtype
    """
    taken = np.empty((len(indices), 2), points.dtype, order="F")
    for column in range(2):
        np.take(points[:, column], indices, out=taken[:, column])
    return taken


def log_likelihood(
    z: float | np.ndarray, positions: np.ndarray, world: Maze, sigma: float, outside_penalty: float = OUTSIDE_PENALTY
) -> np.ndarray:
    """Equation (3) in logs, with refinement 1: log p(z | x) = log N(z; d(x), sigma^2), plus log of the
    outside penalty outside the free area. The Gaussian's constant -log(sigma sqrt(2 pi)) is kept, so
    that sums of these are true log-likelihoods (and the log evidence is the model's).

    Parameters
    ----------
    z : float, or array (R,)
        One measurement, or R measurements for positions in R equal blocks (runs advanced together).
    positions : array (N, 2), or (R*N, 2)
    world : Maze
    sigma : float
        The measurement noise's standard deviation (map units).
    outside_penalty : float
        The factor outside the free area.

    Returns
    -------
    array (N,) or (R*N,), in the positions' dtype
    """
    distance, free = world.station_distances_and_free(positions[:, 0], positions[:, 1])
    residual = distance  # (d - z) / sigma, computed in place: the sign does not matter once squared
    if isinstance(z, np.ndarray):
        blocks = residual.reshape(len(z), -1)
        blocks -= z.astype(residual.dtype)[:, None]
    else:
        residual -= float(z)
    residual /= sigma
    log_p = residual
    log_p *= residual
    log_p *= -0.5
    norm = math.log(sigma * math.sqrt(2 * math.pi))
    levels = np.array([math.log(outside_penalty) - norm, -norm], dtype=log_p.dtype)  # outside, free
    log_p += levels.take(free.view(np.uint8))  # np.where's values, by one gather
    return log_p


class Sensor:
    """The measurement model, equations (2) and (3) as one definition: the robot's reading z ~ p(z | x)
    (`sample`) and the filters' log p(z | x) (`log_pdf`), with the station geometry (the maze's), sigma
    and the outside penalty. A second sensor is added here (and to the compiled likelihood it mirrors).

    Parameters
    ----------
    sigma : float
        The measurement noise's standard deviation (map units).
    outside_penalty : float
        The likelihood's factor outside the free area (refinement 1).
    """

    def __init__(self, sigma: float, outside_penalty: float = OUTSIDE_PENALTY):
        self.sigma, self.outside_penalty = sigma, outside_penalty

    def sample(self, world: Maze, x: float, y: float, rng: np.random.Generator) -> float:
        """Equation (2): the robot's reading at (x, y), N(distance to the nearest station, sigma^2)."""
        return world.distance_at(x, y) + rng.normal(0.0, self.sigma)

    def log_pdf(self, z: np.ndarray, x: np.ndarray, world: Maze, ops: Any) -> np.ndarray:
        """Equation (3) in logs with the outside penalty, log p(z | x), on the backend's operations `ops`
        (numpy's `log_likelihood`, or the compiled likelihood): z (R,), x (R, N, 2) -> (R, N)."""
        return ops.log_likelihood(z, x, world, self.sigma, self.outside_penalty)

    def localised_likelihood(self) -> float:
        """E[p(z | x)] at the robot's own place x, per map unit: E_v[N(v; 0, sigma^2)] for v ~ N(0, sigma^2)
        is 1 / (2 sqrt(pi) sigma), the mean likelihood of a filter whose belief sits on the robot (the
        level below which sensor resetting calls a filter lost, mazelab.recovery)."""
        return 1.0 / (2.0 * math.sqrt(math.pi) * self.sigma)

    def log_acceptance(self, z: Any, points: np.ndarray, world: Maze) -> np.ndarray:
        """log p(z | x) / max_x p(z | x) at free `points` (M, 2), (M,): sensor resetting's rejection
        sampling accepts x with this probability, exp(-(z - d(x))^2 / (2 sigma^2))."""
        return log_likelihood(z, points, world, self.sigma) - self.log_norm

    @property
    def log_norm(self) -> float:
        """-log(sigma sqrt(2 pi)), the Gaussian's constant in log p(z | x), the same at every x."""
        return -math.log(self.sigma * math.sqrt(2 * math.pi))

    def log_pdf_at(self, world: Maze, points: np.ndarray, free: np.ndarray) -> Callable[..., np.ndarray]:
        """log p(z | x) less `log_norm` at points that never move (the exact grid filter's cells), as a
        function (z, out=None) -> -0.5 ((z - d(x)) / sigma)^2, plus log(outside penalty) off the free
        area, an array of `free`'s shape (written into `out` if given); d(x) is computed once, here.

        Parameters
        ----------
        world : Maze
        points : float64 array (M, 2)
        free : bool array of M values, in the shape the function returns
            Whether each point lies in the free area.
        """
        distance = world.distance_to_nearest_station(points).reshape(free.shape)
        level = np.where(free, 0.0, math.log(self.outside_penalty))

        def log_pdf(z: Any, out: np.ndarray | None = None) -> np.ndarray:
            log_lik = np.subtract(z, distance, out=out)
            log_lik /= self.sigma
            np.square(log_lik, out=log_lik)
            np.multiply(-0.5, log_lik, out=log_lik)
            log_lik += level
            return log_lik

        return log_pdf

    def linearised(self, world: Maze, at: np.ndarray) -> tuple[float, np.ndarray | None]:
        """Equation (2) linearised at `at` (2,), for the EKF: the expected reading h = |at - s| to the
        station s nearest `at` (the data association) and its gradient H = (at - s) / h, (2,), or None
        within MIN_RANGE of the station, where it is undefined. The noise's variance is sigma^2."""
        offset = at - world.nearest_station(at)
        expected = float(np.hypot(*offset))
        return expected, None if expected < MIN_RANGE else offset / expected


class LostRobot:
    """The lost robot's state-space model as a filter uses it (nchopin/particles' FeynmanKac: M0, M,
    logG): the prior, the transition (1) and the log-likelihood (3) with the outside penalty, for R runs
    at once (arrays (R, N, ...)), each run's draws from its own Generator. The engine (mazelab.smc)
    calls these; equations (1)-(3) are called from here only.

    Parameters
    ----------
    world : Maze
        The map: the free area and the stations.
    sigma : float
        The measurement noise's standard deviation (map units).
    delta : float
        The compass error's full width (radians).
    ops : NumpyKernels or CompiledKernels
        The backend's operations (mazelab.backend): the move and the likelihood run there.
    speed : float
        L, the step length the filter assumes (map units).
    outside_penalty : float
        The likelihood's factor outside the free area (refinement 1).
    """

    def __init__(
        self,
        world: Maze,
        sigma: float,
        delta: float,
        ops: Any,
        speed: float = ROBOT_SPEED,
        outside_penalty: float = OUTSIDE_PENALTY,
    ):
        self.world, self.delta, self.ops, self.speed = world, delta, ops, speed
        self.sensor = Sensor(sigma, outside_penalty)  # equations (2)-(3), the robot's own measurement model

    @classmethod
    def of_settings(cls, world: Maze, sigma: float, delta: float, ops: Any, settings: Any) -> LostRobot:
        """The model with a filter's values of MODEL_OPTIONS (its settings, by name): a model option is
        declared and read in this module alone."""
        return cls(world, sigma, delta, ops, **{option.name: settings[option.name] for option in MODEL_OPTIONS})

    def M0(self, count: int, rng: np.random.Generator) -> np.ndarray:  # noqa: N802 (particles' names)
        """x_0 ~ p(x_0), uniform over the free area: the prior a run starts (and restarts) from.

        Parameters
        ----------
        count : int
        rng : numpy.random.Generator

        Returns
        -------
        array (count, 2), float64
        """
        return self.world.random_free_places(count, rng)

    def M(  # noqa: N802
        self, x: np.ndarray, A: np.ndarray | None, th0: np.ndarray, rngs: Sequence[np.random.Generator | None]
    ) -> tuple[np.ndarray, np.ndarray]:
        """Equation (1), x_k ~ p(x_k | x_{k-1}^{A}): each point moves L along th ~ U(th0 - Delta/2, th0 +
        Delta/2), run r's uniforms from rngs[r] (None: a run that does not move this step draws nothing).

        Parameters
        ----------
        x : array (R, N, 2)
            The runs' particles (or any float points: their dtype is the move's).
        A : int array (R, M), or None
            Move x[r, A[r]] (the resampled particles, gathered in the same pass); None: every particle.
        th0 : array (R,)
            th0_k of each run (radians).
        rngs : sequence of R Generators (or None)

        Returns
        -------
        (positions (R, M, 2), headings (R, M)) in x's dtype
        """
        return self.ops.move(x, A, rngs, th0.astype(x.dtype), self.delta, self.speed)

    def logG(self, x: np.ndarray, z: np.ndarray) -> np.ndarray:  # noqa: N802
        """Equation (3) in logs with the outside penalty, log p(z_k | x) (`Sensor.log_pdf`).

        Parameters
        ----------
        x : array (R, N, 2)
            The runs' particles.
        z : array (R,)
            z_k of each run.

        Returns
        -------
        array (R, N)
        """
        return self.sensor.log_pdf(z, x, self.world, self.ops)


class ModelFilter:
    """What a filter of the model that holds no sample shares (the exact grid filter,
    mazelab.grid_filter, and the EKF, mazelab.kalman): made from the map, sigma, delta and its declared
    options (`settings`, L among them), and stepped by `advance` with th0_k, then `update` with z_k,
    which reads the model's `sensor` (Sensor: a second sensor reaches them there). Not a sample: no ESS
    (NaN), and no random draws (`particles` and `rng` are not used).
    """

    name: ClassVar[str]
    options: ClassVar[Options]
    ess = math.nan  # not a sample, so no effective sample size

    def __init__(self, world: Maze, sigma: float, delta: float, particles: Any = None, rng: Any = None, **options: Any):
        self.settings = MappingProxyType(type(self).options.resolve(options, self.name))
        self.world, self.sigma, self.delta, self.speed = check_world(world), sigma, delta, self.settings["speed"]
        check_sigma_within(sigma, world.width, world.height)
        self.sensor = Sensor(sigma, self.settings.get("outside_penalty", OUTSIDE_PENALTY))  # equations (2)-(3)
        self.steps_done = 0
        self.reinitialised_at: list[int] = []
        self._motion: tuple[float, Any] | None = None  # (th0, what `per_angle` computed for it)

    def per_angle(self, compass_angle: float, compute: Callable[[float], Any]) -> Any:
        """`compute(compass_angle)`, the step's motion (the EKF's arc moments, the grid's arc kernel), kept
        while the compass angle repeats (the robot holds a heading for up to MAX_STRAIGHT_STEPS steps)."""
        if self._motion is None or self._motion[0] != compass_angle:
            self._motion = (compass_angle, compute(compass_angle))
        return self._motion[1]

    def step(self, compass_angle: float, z: float) -> None:
        """One step: predict with th0_k, the heading the compass reports (radians), then update with z_k,
        the measured distance to the nearest station (map units)."""
        self.advance(compass_angle)
        self.update(z)
        self.steps_done += 1


def check_model_parameters(
    sigma: float, delta: float, map_size: tuple[float, float] | None = None
) -> tuple[float, float]:
    """Refuse impossible sigma/delta with a clear message; warn outside the lab's recommended ranges.

    Parameters
    ----------
    sigma : float
        Must lie in the range that keeps the arithmetic finite on the map, or without a map on any
        maze (mazelab.checks.sigma_range).
    delta : float
        In [0, 2 pi] (radians).
    map_size : (width, height), optional

    Returns
    -------
    (sigma, delta) as floats
    """
    sigma, delta = finite_number("sigma", sigma), finite_number("delta", delta)
    if sigma <= 0:
        raise ValueError(f"sigma must be > 0 (the measurement noise's standard deviation), got {sigma}")
    check_sigma_within(sigma, *(map_size or (None, None)))
    if not 0 <= delta <= 2 * math.pi:
        raise ValueError(f"delta must be in [0, 2*pi] (the compass error's full width, radians), got {delta}")
    for name, value, (low, high) in (("sigma", sigma, LAB_SIGMA_RANGE), ("delta", delta, LAB_DELTA_RANGE)):
        if not low <= value <= high:
            warnings.warn(f"{name} = {value} is outside the lab's range [{low}, {high}]", stacklevel=3)
    return sigma, delta


__all__ = [
    "CONFIDENCE_RADIUS",
    "CONFIDENCE_SHARE",
    "CONVERGENCE_RADIUS",
    "DEFAULT_PARTICLE_COUNT",
    "DEFAULT_STEPS",
    "LAB_DELTA_RANGE",
    "LAB_SIGMA_RANGE",
    "LOG_UNDERFLOW",
    "MAX_SPEED",
    "MAX_STRAIGHT_STEPS",
    "MIN_RANGE",
    "MODEL_OPTIONS",
    "OUTSIDE_PENALTY",
    "OUTSIDE_PENALTY_OPTION",
    "PARTICLE_DTYPE",
    "ROBOT_SPEED",
    "RPF_THRESHOLD",
    "SPEED_OPTION",
    "LostRobot",
    "ModelFilter",
    "Sensor",
    "check_model_parameters",
    "headings_from_uniforms",
    "log_likelihood",
    "move",
    "sample_heading",
    "take_particles",
]
