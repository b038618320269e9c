"""What `run` starts from: a fresh lost robot (a maze, sigma, delta and a seed) or a saved scenario
replayed; `RunSetup.run` then runs the filter with the progress line. The command (mazelab.cli.app)
parses its flags, builds a setup here and reports the result."""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from typing import Any

import numpy as np

from mazelab.cli.options import DEFAULT_DELTA, DEFAULT_SIGMA
from mazelab.cli.replay import from_scenario, replay_seed
from mazelab.cli.reports import prepare_world, progress_printer
from mazelab.lab import simulate
from mazelab.maze import Maze
from mazelab.mazes import DEFAULT_MAZE, load_maze
from mazelab.model import DEFAULT_PARTICLE_COUNT, DEFAULT_STEPS
from mazelab.robot import Robot
from mazelab.scenario import Scenario
from mazelab.seeding import new_seed, start_place
from mazelab.simulation import RunResult


@dataclass
class RunSetup:
    """A run's inputs: the maze, the robot, sigma and delta, the initial particles (a replay's) or the
    count to draw, the steps (None: the robot's recorded walk), the seed and the filter's options."""

    world: Maze
    robot: Robot
    sigma: float
    delta: float
    initial_particles: np.ndarray | None
    particle_count: int | None
    steps: int | None
    seed: int
    options: dict[str, Any]

    def work(self) -> tuple[int, int]:
        """What the filter does (mazelab.backend.backend_for_work): (the particles its steps move, its steps)."""
        steps = self.steps or self.robot.recorded_steps
        count = len(self.initial_particles) if self.initial_particles is not None else self.particle_count
        return (count or DEFAULT_PARTICLE_COUNT) * steps, steps

    def run(self, filter_name: str, *, visualize: Any, quiet: bool, kidnap_at: int | None) -> RunResult:
        """The filter on this setup, with a progress line unless `quiet`."""
        prepare_world(self.world)
        total = self.steps or self.robot.recorded_steps
        return simulate(
            self.robot,
            self.world,
            self.sigma,
            self.delta,
            self.particle_count,
            self.steps,
            self.initial_particles,
            filter_name,
            seed=self.seed,
            visualize=visualize,
            on_step=None if quiet else progress_printer(total),
            kidnap_at=kidnap_at,
            **self.options,
        )


def replay_setup(
    stored: Scenario, maze: str | None, sigma: float | None, delta: float | None, seed: int | None,
    options: dict[str, Any],
) -> RunSetup:  # fmt: skip
    """A saved scenario replayed: its maze (or --maze), walk, measurements, particles and seed."""
    world, robot, sigma, delta, particles = from_scenario(stored, maze, sigma, delta)
    return RunSetup(world, robot, sigma, delta, particles, None, None, replay_seed(stored, seed), options)


def fresh_setup(
    maze: str | None, sigma: float | None, delta: float | None, seed: int | None, start_seed: int | None,
    particles: int | None, steps: int | None, options: dict[str, Any],
) -> RunSetup:  # fmt: skip
    """A fresh lost robot: the maze (default the lab's), its start drawn from the seed (new if none)."""
    world = load_maze(maze or DEFAULT_MAZE)
    sigma = DEFAULT_SIGMA if sigma is None else sigma
    delta = DEFAULT_DELTA if delta is None else delta
    seed = new_seed() if seed is None else seed
    if start_seed is not None and start_seed != seed:
        warnings.warn(f"--start-seed {start_seed} differs from --seed {seed}: repeat with both", stacklevel=1)
    robot = Robot(sigma, delta, start_place(world, seed if start_seed is None else start_seed))
    return RunSetup(world, robot, sigma, delta, None, particles, steps or DEFAULT_STEPS, seed, options)


__all__ = ["RunSetup", "fresh_setup", "replay_setup"]
