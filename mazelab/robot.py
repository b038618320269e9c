"""The lost robot: it wanders the maze (or replays a recorded walk) and measures its distance."""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from mazelab.checks import angle, as_point, coordinate, step_number
from mazelab.maze import Maze
from mazelab.model import MAX_STRAIGHT_STEPS, ROBOT_SPEED, Sensor, check_model_parameters, sample_heading
from mazelab.seeding import start_place


class Robot:
    """The lost robot: it wanders the maze (or replays recorded angles) and measures its distance.

    Without angles it wanders as the paper says: it keeps a compass heading th0 and takes th0 plus
    U(-delta/2, delta/2) each step, and picks a new uniform heading when the next step would hit a
    wall or leave the maze, or after `max_straight_steps` straight steps. Every step it takes (and
    every measurement) is recorded, so a second run of the same robot replays the first exactly.
    Its readings are the model's (mazelab.model.Sensor: by default the paper's, of noise `sigma`).
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
        sensor: Sensor | None = None,
    ):
        self.sigma, self.delta = check_model_parameters(sigma, delta)
        self.sensor = Sensor(self.sigma) if sensor is None else sensor  # what the filters' likelihood scores
        self.initial_position = as_point("robot position", position)
        if (actual_angles is None) != (compass_angles is None):
            raise ValueError("give both actual_angles and compass_angles, or neither")
        self.actual_angles = [angle("actual angle", a) for a in actual_angles or []]
        self.compass_angles = [angle("compass angle", a) for a in compass_angles or []]
        self.measurements = [coordinate("measurement", z) for z in measurements or []]
        check_walk_lists(self.actual_angles, self.compass_angles, measurements, kidnap_at, kidnap_position)
        self.max_straight_steps = step_number("max_straight_steps", max_straight_steps, "a whole number")
        self.speed = speed
        self.rng_given = rng is not None
        self.rng = rng if rng is not None else np.random.default_rng()
        # recorded angles given with a kidnapping were walked with the jump
        self.kidnap_at = None if kidnap_at is None else step_number("kidnap_at", kidnap_at)
        self.kidnap_position = None if kidnap_position is None else as_point("kidnap position", kidnap_position)
        self.reset()

    @classmethod
    def of_seed(cls, world: Maze, sigma: float, delta: float, seed: int, *, sensor: Sensor | None = None) -> Robot:
        """The lost robot of run `seed` (mazelab.seeding): it starts at a free place of `world` drawn from
        default_rng(seed) (`start_place`) and reads `sensor` (default: the paper's, of noise `sigma`); every
        command builds its fresh robot here, so a sensor chosen for a run reaches each of them."""
        return cls(sigma, delta, start_place(world, seed), sensor=sensor)

    def kidnap(self, step: int, position: Sequence[float]) -> None:
        """Carry the robot to `position` at step `step` (1-based), before that step's move.

        Step K then reads: put the robot down at `position`, move it with actual angle K, measure z_K.
        A walk already recorded up to step K was walked without the jump, so it cannot be kidnapped.
        """
        step, position = step_number("kidnap_at", step), as_point("kidnap position", position)
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
        """Move one step, then measure.

        Parameters
        ----------
        world : Maze
            The maze the robot walks in (its walls turn it; its stations are measured).

        Returns
        -------
        compass_angle : float
            th0_k, the heading the compass reports (radians), what the filters predict with.
        z : float
            z_k, the measured distance to the nearest station (map units).
        """
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
        """Equation (2): a fresh reading of the robot's sensor (mazelab.model.Sensor.sample)."""
        return self.sensor.sample(world, self.x, self.y, self.rng)

    def _choose_heading(self, world: Maze, tries: int = 1000) -> tuple[float, float]:
        """The wandering rule: keep th0 unless the step would leave the free area or ran too long."""
        free = world.free_at
        for _ in range(tries):
            if self._compass is None or self._straight >= self.max_straight_steps:
                self._compass, self._straight = float(self.rng.uniform(0.0, 2 * math.pi)), 0
            actual = sample_heading(self._compass, self.delta, self.rng)
            dx, dy = self.speed * math.cos(actual), self.speed * math.sin(actual)
            # The midpoint check keeps the robot from cutting the corner of a wall block.
            if free(self.x + dx, self.y + dy) and free(self.x + dx / 2, self.y + dy / 2):
                self._straight += 1
                return self._compass, actual
            self._compass = None
        raise RuntimeError(f"the robot at {self.position} found no free direction in {tries} tries")


def check_walk_lists(
    actual: Sequence[float],
    compass: Sequence[float],
    measurements: Sequence[float] | None,
    kidnap_at: int | None,
    kidnap_position: Sequence[float] | None,
    keys: str = "",
) -> None:
    """A recorded walk's lists, one entry per step each (measurements may be None), and its kidnapping's
    step and place, both or neither: one line for the first wrong, naming the lists `keys` + name (a
    scenario's keys: "robot_")."""
    steps = len(actual)
    if len(compass) != steps:
        raise ValueError(f"{keys}actual_angles has {steps} entries but {keys}compass_angles has {len(compass)}")
    if measurements is not None and len(measurements) != steps:
        raise ValueError(f"{keys}measurements has {len(measurements)} entries, {steps} expected")
    if (kidnap_at is None) != (kidnap_position is None):
        raise ValueError("kidnap_at and kidnap_position come together: give both or neither")


__all__ = [
    "Robot",
    "check_walk_lists",
]
