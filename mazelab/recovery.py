"""Recovery from kidnapping (augmented MCL, sensor resetting): a part handed to a particle filter
(`RecoveryTracker`), off by default, so the paper's filters are unchanged."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from mazelab.checks import finite_number
from mazelab.declaration import Option, number_in
from mazelab.maze import Maze
from mazelab.model import Sensor
from mazelab.resampling import Move

ALPHA_SLOW, ALPHA_FAST = 0.001, 0.1  # decay rates of the likelihood averages (Thrun et al., Table 8.3)
RECOVERY_MODES = ("augmented", "sensor")


SENSOR_RESET_BATCHES = 20  # rejection sampling gives up after this many batches (the rest are uniform)
# Sensor resetting injects while w_fast is below this share of the likelihood expected when localised
# (`Sensor.localised_likelihood`): 0.5 lies over 5 standard deviations of w_fast below its localised level.
SENSOR_RESET_LEVEL = 0.5


@dataclass(frozen=True)
class Recovery:
    """Recovery from kidnapping: augmented MCL (Thrun et al., "Probabilistic Robotics", Table 8.3) and
    sensor resetting (Lenser and Veloso 2000).

    The filter keeps w_slow and w_fast, exponential averages (rates alpha_slow < alpha_fast) of w_avg,
    its estimate of the predictive likelihood p(z_k | z_1:k-1), and replaces each particle, with an
    injection probability, by a draw from the free area:
    - "augmented": probability max(0, 1 - w_fast / w_slow), uniform draws;
    - "sensor": probability max(0, 1 - w_fast / (reset_level * Sensor.localised_likelihood())), as Lenser
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
        slow, fast = finite_number("alpha_slow", self.alpha_slow), finite_number("alpha_fast", self.alpha_fast)
        if not 0 < slow < fast <= 1:
            raise ValueError(
                f"recovery needs 0 < alpha_slow < alpha_fast <= 1, got alpha_slow {slow}, alpha_fast {fast}"
            )
        if not 0 < finite_number("reset_level", self.reset_level) <= 1:
            raise ValueError(f"recovery needs 0 < reset_level <= 1, got {self.reset_level}")


def check_recovery(recovery: Any) -> str | Recovery | None:
    """The recovery option, checked.

    Parameters
    ----------
    recovery : object
        None (off; also False and "none"), "augmented" (also True), "sensor", or a Recovery.

    Returns
    -------
    str, Recovery or None
    """
    if recovery is None or recovery is False or (isinstance(recovery, str) and recovery.strip().lower() == "none"):
        return None
    if recovery is True:
        return "augmented"
    if isinstance(recovery, Recovery):
        return recovery
    if isinstance(recovery, str) and recovery.strip().lower() in RECOVERY_MODES:
        return recovery.strip().lower()
    raise ValueError(f"unknown recovery {recovery!r}; choose none, {' or '.join(RECOVERY_MODES)}")


def recovery_options(recovery: Any, alpha_slow: float = ALPHA_SLOW, alpha_fast: float = ALPHA_FAST) -> Recovery | None:
    """The Recovery the option asks for, a mode's with these rates.

    Parameters
    ----------
    recovery : str, Recovery or None
        The option's value as its declaration checked it (`check_recovery`).
    alpha_slow, alpha_fast : float
        The averages' rates when `recovery` names a mode.
    """
    return Recovery(recovery, alpha_slow, alpha_fast) if isinstance(recovery, str) else recovery


_RATE = " (a rate of an exponential average)"
RECOVERY_OPTIONS = (
    Option(
        "recovery",
        None,
        "recovery from kidnapping (beyond the paper): none, augmented (MCL) or sensor (resetting)",
        parse=str.strip,
        check=check_recovery,
        stored_as=Recovery,
        flag="--recovery/--sensor-resetting",
    ),
    Option(
        "alpha_slow",
        ALPHA_SLOW,
        "recovery: the long-term likelihood average's rate",
        check=number_in("alpha_slow", 0.0, 1.0, what=_RATE),
        flag="--alpha-slow",
    ),
    Option(
        "alpha_fast",
        ALPHA_FAST,
        "recovery: the short-term likelihood average's rate",
        check=number_in("alpha_fast", 0.0, 1.0, what=_RATE),
        flag="--alpha-fast",
    ),
)


def measurement_matched_places(world: Maze, z: Any, sensor: Sensor, count: int, rng: np.random.Generator) -> np.ndarray:
    """Free points with density proportional to p(z | x) on the free area (sensor resetting): rejection
    sampling from the uniform law, accepting x with probability p(z | x) / max p
    (`Sensor.log_acceptance`). Points still missing after SENSOR_RESET_BATCHES batches (when no free
    point explains z) are drawn uniformly.

    Parameters
    ----------
    world : Maze
    z : float, or the model's reading
        The last measurement (map units).
    sensor : Sensor
        The filter's measurement model (mazelab.model).
    count : int
    rng : numpy.random.Generator

    Returns
    -------
    array (count, 2)
    """
    found, missing = [], count
    for _ in range(SENSOR_RESET_BATCHES):
        candidates = world.random_free_places(max(4 * missing, 256), rng)
        log_accept = sensor.log_acceptance(z, candidates, world)
        accepted = candidates[np.log(rng.random(len(candidates))) < log_accept][:missing]
        found.append(accepted)
        missing -= len(accepted)
        if missing == 0:
            break
    else:
        found.append(world.random_free_places(missing, rng))
    return np.concatenate(found)


class RecoveryTracker:
    """What recovery keeps in a filter of one run: w_slow and w_fast (in logs) and the last z, and the
    injection they decide. The filter calls `track` with each step's w_avg, and `inject` where it resamples.

    Parameters
    ----------
    options : Recovery
    world : Maze
        Where injected points are drawn.
    sensor : Sensor
        The filter's measurement model (its localised likelihood, and the matched draws' acceptance).
    """

    def __init__(self, options: Recovery, world: Maze, sensor: Sensor):
        self.options, self.world, self.sensor = options, world, sensor
        self.log_w_slow = self.log_w_fast = -math.inf  # log w_slow, log w_fast: set by the first w_avg
        self.last_z: Any = None  # the last reading (a number; k numbers for a model of k sensors)

    @property
    def injection_probability(self) -> float:
        """max(0, 1 - w_fast / reference) (see Recovery), the reference the likelihood level below which
        w_fast means "lost": w_slow ("augmented"), or reset_level * the sensor's localised likelihood
        ("sensor"); 0 before the first measurement."""
        if self.last_z is None or self.log_w_slow == -math.inf:
            return 0.0
        if self.options.mode == "sensor":
            log_reference = math.log(self.options.reset_level * self.sensor.localised_likelihood())
        else:
            log_reference = self.log_w_slow
        return max(0.0, 1.0 - math.exp(self.log_w_fast - log_reference))

    def track(self, log_w_avg: float, z: Any) -> None:
        """w_slow += alpha_slow (w_avg - w_slow), w_fast likewise; in logs, w <- (1 - a) w + a w_avg.

        Both start at the first w_avg (as ROS AMCL does; Table 8.3 leaves them open): from zero,
        w_slow would take ~1/alpha_slow steps to reach the likelihood's level and hold back recovery.

        Parameters
        ----------
        log_w_avg : float
            log w_avg, this step's estimate of log p(z_k | z_1:k-1) (the filter's log evidence increment).
        z : float, or the model's reading
            z_k, kept as it comes (k numbers for a model of k sensors).
        """
        slow, fast = self.options.alpha_slow, self.options.alpha_fast
        if self.last_z is None:
            self.log_w_slow = self.log_w_fast = float(log_w_avg)
        else:
            self.log_w_slow = float(np.logaddexp(math.log1p(-slow) + self.log_w_slow, math.log(slow) + log_w_avg))
            keep_fast = math.log1p(-fast) if fast < 1 else -math.inf  # log(1 - alpha_fast)
            self.log_w_fast = float(np.logaddexp(keep_fast + self.log_w_fast, math.log(fast) + log_w_avg))
        self.last_z = z

    def inject(
        self, positions: np.ndarray, headings: np.ndarray, move_injected: Move, rng: np.random.Generator
    ) -> np.ndarray | None:
        """Replace particles in place with probability `injection_probability` by draws from the free area
        (uniform, or matched to the last z) passed through `move_injected`.

        Parameters
        ----------
        positions : array (N, 2)
            Overwritten where injected.
        headings : array (N,)
            Overwritten where injected.
        move_injected : callable
            points -> (positions, headings), what the injected points go through.
        rng : numpy.random.Generator

        Returns
        -------
        bool array (N,), the injected particles, or None when nothing is injected
        """
        probability = self.injection_probability
        if probability == 0:
            return None
        injected = rng.random(len(positions)) < probability
        count = int(injected.sum())
        if count:
            if self.options.mode == "sensor":  # a probability above 0 has a last z
                places = measurement_matched_places(self.world, self.last_z, self.sensor, count, rng)
            else:
                places = self.world.random_free_places(count, rng)
            positions[injected], headings[injected] = move_injected(places)
        return injected


__all__ = [
    "ALPHA_FAST",
    "ALPHA_SLOW",
    "RECOVERY_MODES",
    "RECOVERY_OPTIONS",
    "SENSOR_RESET_BATCHES",
    "SENSOR_RESET_LEVEL",
    "Recovery",
    "RecoveryTracker",
    "check_recovery",
    "measurement_matched_places",
    "recovery_options",
]
