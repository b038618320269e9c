"""StudentFilter: Algorithm 4 (SIR) with four parts left to the student, wired into the filter contract.

The student writes `predict`, `weigh`, `resample` and `estimate`; StudentFilter is the step template
every particle filter of the lab runs (mazelab.smc.SMC.step) with those parts as its hooks: the
transition is `predict`, the log-likelihood `weigh`, the ancestors `resample`, and the point estimate
`estimate`. The engine does the rest: log-domain normalisation, the effective sample size, the log
evidence, and a restart from the prior when no particle explains z_k. Like the shipped filters, each
step starts by resampling the previous posterior (the end of the previous step's Algorithm 4), so
between steps the filter holds the weighted posterior that is drawn and read.

Nothing here imports the lab's reference implementation (the model, the resampling schemes, the grid
filter): the grading sandbox ships this module and what it imports to the student's process.
"""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np

from mazelab.constants import CONFIDENCE_RADIUS, CONFIDENCE_SHARE, OUTSIDE_PENALTY, ROBOT_SPEED
from mazelab.contract import Particles
from mazelab.declaration import Option, Options
from mazelab.maze import Maze
from mazelab.smc import SMC
from mazelab.weights import mass_within

PARTS = ("predict", "weigh", "resample", "estimate")


def _own_estimate(estimate: Any) -> str:
    """StudentFilter's estimate option: only "mean" (its estimate() is the student's own)."""
    if estimate != "mean":
        raise ValueError(
            f"a StudentFilter estimates with its own estimate() method: estimate={estimate!r} does not apply"
        )
    return estimate


class PartError(ValueError):
    """A part returned something of the wrong shape or kind: one line naming the part and what came."""


class StudentFilter(SMC):
    """Algorithm 4 (SIR) whose four parts the subclass writes; see the methods for each part's job.

    Parameters
    ----------
    world : Maze
        The map: `world.distance_to_nearest_station(points)` and `world.is_free(x, y)`.
    sigma, delta : float
        The measurement noise's standard deviation and the compass error's full width (radians).
    particles : array (N, 2)
        The initial particles, drawn from the prior (uniform over the free area).
    rng : numpy.random.Generator
        Every random draw of the filter; `predict` and `resample` receive it.
    **options
        Only `estimate="mean"`: the point estimate is the student's own `estimate`.

    Notes
    -----
    Attributes the parts may read: `self.world`, `self.sigma`, `self.delta`, `self.ROBOT_SPEED` (L) and
    `self.OUTSIDE_PENALTY` (refinement 1's factor), also importable from mazelab.exercise. The step is
    the lab's template (mazelab.smc.SMC), whose own methods (`move`, `reweight`, `normalise`, `due`, `resampled`,
    ...) and the model's it calls here (`M0`, `M`, `logG`) a helper of yours must not be named after.
    """

    name: ClassVar[str] = "StudentFilter"
    options: ClassVar[Options] = Options(
        Option(
            "estimate",
            "mean",
            "only mean: the point estimate is the student's own estimate()",
            parse=str.strip,
            check=_own_estimate,
        ),
    )
    ROBOT_SPEED: ClassVar[float] = ROBOT_SPEED
    OUTSIDE_PENALTY: ClassVar[float] = OUTSIDE_PENALTY

    def __init_subclass__(cls, **kwargs: Any) -> None:
        """A subclass is named after itself (results and the viewer label it so) unless it sets `name`.

        The contract's `estimate` is the point estimate (2,) of the present posterior; the student's
        `estimate(positions, weights)` method is the part that computes it. A subclass's method is
        kept as `estimate_part`, and `estimate` stays the contract's value."""
        super().__init_subclass__(**kwargs)
        if "name" not in cls.__dict__:
            cls.name = cls.__name__
        written = cls.__dict__.get("estimate")
        if callable(written):
            cls.estimate_part = written
            cls.estimate = StudentFilter.__dict__["estimate"]

    def __init__(
        self,
        world: Maze,
        sigma: float,
        delta: float,
        particles: np.ndarray,
        rng: np.random.Generator | None = None,
        **options: Any,
    ):
        self.settings = type(self).options.resolve(options, self.name)
        self.world, self.sigma, self.delta = world, float(sigma), float(delta)
        self.rng = rng if rng is not None else np.random.default_rng()
        super().__init__(self, particles, self.rng, dtype=float)  # its own model: M0, M and logG below
        self._estimate: tuple[Any, np.ndarray] | None = None  # (the weights it is of, the estimate)

    # -- the student's four parts --------------------------------------------------------------------
    def predict(self, positions: np.ndarray, compass_angle: float, rng: np.random.Generator) -> np.ndarray:
        """Draw x_k^i ~ p(x_k | x_{k-1}^i): positions (N, 2) -> moved positions (N, 2)."""
        raise NotImplementedError("predict is still to write")

    def weigh(self, positions: np.ndarray, z: float) -> np.ndarray:
        """log p(z_k | x_k^i) for positions (N, 2) -> (N,)."""
        raise NotImplementedError("weigh is still to write")

    def resample(self, weights: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """Normalised weights (N,) -> ancestor indices (N,)."""
        raise NotImplementedError("resample is still to write")

    def estimate_part(self, positions: np.ndarray, weights: np.ndarray) -> np.ndarray:
        """The posterior mean, shape (2,): a subclass writes it as `estimate(self, positions, weights)`."""
        raise NotImplementedError("estimate is still to write")

    # -- the model and the scheme the step calls (mazelab.smc.SMC), from the student's parts ----------
    def M0(self, count: int, rng: np.random.Generator) -> np.ndarray:  # noqa: N802 (particles' names)
        """The prior's sample: uniform over the free area, (count, 2)."""
        return self.world.random_free_places(count, rng)

    def M(self, x: np.ndarray, A: np.ndarray | None, th0: np.ndarray, rngs: Any) -> tuple[np.ndarray, np.ndarray]:  # noqa: N802
        """x_k^i ~ p(x_k | x_{k-1}^i) by the student's `predict` on a copy of x[A] (after resampling),
        its answer checked: (1, N, 2), finite."""
        chosen = x[0] if A is None else x[0][A[0]]
        moved = self.predict(chosen.copy(), float(th0[0]), rngs[0])
        moved = answer_array("predict", moved, (len(chosen), 2), finite=True)
        return moved[None], np.zeros((1, len(moved)))

    def logG(self, x: np.ndarray, z: np.ndarray) -> np.ndarray:  # noqa: N802
        """log p(z_k | x_k^i) by the student's `weigh` on a copy of x, its answer checked: (1, N), no NaN
        or +inf."""
        log_w = answer_array("weigh", self.weigh(x[0].copy(), float(z[0])), (x.shape[1],))
        if np.isnan(log_w).any() or np.isposinf(log_w).any():
            raise PartError("weigh returned NaN or +inf; expected log-likelihoods (finite, or -inf for zero)")
        return log_w[None]

    def ancestors(self, W: Any, due: np.ndarray) -> np.ndarray:
        """RESAMPLE by the student's `resample` on a copy of the normalised weights (one run), its answer
        checked: N whole numbers in [0, N), (1, N)."""
        weights = W.W[0]
        drawn = answer_array("resample", self.resample(weights.copy(), self.rng), (len(weights),), indices=True)
        if len(drawn) and (drawn.min() < 0 or drawn.max() >= len(weights)):
            raise PartError(f"resample returned an index outside [0, {len(weights)})")
        return drawn[None]

    # -- the filter contract (the weights, the ESS and the log evidence are the engine's) ------------
    @property
    def is_confident(self) -> bool:
        """At least 95% of the weight lies within distance 1 of the estimate (the green circle)."""
        share = mass_within(self.weights, self.positions, self.estimate, CONFIDENCE_RADIUS)
        return bool(share >= CONFIDENCE_SHARE)

    @property
    def estimate(self) -> np.ndarray:
        """The contract's point estimate: the student's estimate of the present posterior, (2,) (once per step)."""
        if self._estimate is None or self._estimate[0] is not self.W:
            point = self.estimate_part(self.positions.copy(), self.weights.copy())
            self._estimate = (self.W, answer_array("estimate", point, (2,), finite=True))
        return self._estimate[1].copy()

    @property
    def log_evidence(self) -> float:
        """NaN: the student's `weigh` may leave out a constant factor of p(z | x) (the check allows it),
        so the engine's running total is no estimate of log p(z_1:k); `compare` shows '-'."""
        return float("nan")

    def belief(self) -> Particles:
        """What the viewer draws: the particles and their weights."""
        return Particles(self.positions, self.weights)


def answer_array(
    part: str, value: Any, shape: tuple[int, ...], indices: bool = False, finite: bool = False
) -> np.ndarray:
    """A part's answer as a float64 array of `shape` (int64 for `indices`: whole numbers only; finite
    where `finite`), else PartError in one line naming the part and what came. The one check of an
    answer's form: the filter's own steps and the grading's child (mazelab.exercise.child) both use it."""
    try:
        array = np.asarray(value)
        if indices and not np.issubdtype(array.dtype, np.integer):
            raise PartError(f"{part} returned {array.dtype} values, not whole-number indices")
        array = array.astype(np.int64 if indices else np.float64)
    except PartError:
        raise
    except Exception as error:
        raise PartError(f"{part} returned {type(value).__name__}, not numbers ({error})") from None
    if array.shape != shape:
        raise PartError(f"{part} returned shape {array.shape}; expected {shape}")
    if finite and not np.isfinite(array).all():
        raise PartError(f"{part} returned a value that is not finite (NaN or inf)")
    return array


__all__ = ["PARTS", "PartError", "StudentFilter", "answer_array"]
