"""A study's runs in units of work: the runs of one setting advanced together by the batched filters
(mazelab.batch), bit for bit as run_task runs them one by one, or one run at a time where the
batch does not apply (generated mazes, recovery, KLD-sampling, the grid filter and the EKF)."""

from __future__ import annotations

import math
import time
import warnings
from collections.abc import Sequence
from dataclasses import dataclass
from itertools import groupby

import numpy as np

from mazelab.batch import BATCH_FILTERS
from mazelab.experiments.study import RunFailure, RunRecord, RunTask, run_records, run_task_safely
from mazelab.maze import Maze
from mazelab.robot import Robot
from mazelab.simulation import RunInputs, RunResult, plan_kidnapping

MAX_BATCH = 32  # runs advanced together: beyond this the fixed cost per step is already small
MAX_BATCH_PARTICLES = 1_000_000  # R x N at most: a batch needs no more memory than a run of 10^6 particles


def batchable(task: RunTask) -> bool:
    """Whether the batched filters run this task as run_task would: a maze file, the paper's
    particle filters with their default options."""
    s = task.setting
    paper_options = s.recovery == "none" and not task.kld
    paper_options &= getattr(s, "bandwidth", "optimal") == "optimal" and getattr(task, "estimate", "mean") == "mean"
    return s.maze.grid is not None and paper_options and set(task.filters) <= set(BATCH_FILTERS)


def study_units(tasks: Sequence[RunTask], workers: int) -> list[tuple[RunTask, ...]]:
    """The tasks cut into units of work: the runs of a setting together (at most MAX_BATCH runs and
    MAX_BATCH_PARTICLES particles, and small enough that every worker gets two units), or one run
    each where the batch does not apply."""
    units: list[tuple[RunTask, ...]] = []
    batches = [list(group) for _, group in groupby(tasks, key=lambda t: t.setting_index)]
    size = max(1, min(MAX_BATCH, math.ceil(len(tasks) / (2 * workers))))
    for batch in batches:
        fits = max(1, MAX_BATCH_PARTICLES // batch[0].setting.particles)
        if len(batch) > 1 and batchable(batch[0]) and min(size, fits) > 1:
            parts = math.ceil(len(batch) / min(size, fits))
            step = math.ceil(len(batch) / parts)
            units += [tuple(batch[i : i + step]) for i in range(0, len(batch), step)]
        else:
            units += [(task,) for task in batch]
    return units


def run_unit_safely(unit: Sequence[RunTask]) -> list[list[RunRecord] | RunFailure]:
    """Every run of a unit, in order: together when they can be, else (or if that fails) one by one,
    a run that raises becoming a RunFailure."""
    if len(unit) > 1 and all(batchable(task) for task in unit):
        try:
            return list(run_batch(unit))
        except Exception:  # find which run fails, and let the others finish
            pass
    return [run_task_safely(task) for task in unit]


@dataclass
class Walk:
    """One run's scenario, as run_task makes it: the robot's walk and the initial particles."""

    inputs: RunInputs
    true_positions: np.ndarray  # (steps, 2)

    @property
    def compass_angles(self) -> list[float]:
        return self.inputs.compass_angles

    @property
    def measurements(self) -> list[float]:
        return self.inputs.measurements


def walk_of(task: RunTask, world: Maze) -> Walk:
    """The run's walk and particles from its seed: the draws simulate makes (robot, particles, kidnapping)."""
    s = task.setting
    robot = Robot(s.sigma, s.delta, world.random_free_place(np.random.default_rng(task.seed)))
    robot_rng, particles_rng, _, kidnap_rng = np.random.default_rng(task.seed).spawn(4)
    particles = world.random_free_places(s.particles, particles_rng)
    if task.kidnap_at is not None:
        plan_kidnapping(robot, world, task.kidnap_at, task.steps, kidnap_rng)
    robot.reset()
    robot.rng = robot_rng
    true_positions = np.empty((task.steps, 2))
    for k in range(task.steps):
        robot.step(world)
        true_positions[k] = robot.position
    inputs = RunInputs.of_run(robot, particles, world, s.sigma, s.delta, task.seed, task.steps, task.filters[0])
    return Walk(inputs, true_positions)


def run_batch(tasks: Sequence[RunTask]) -> list[list[RunRecord]]:
    """The runs of one setting (same filters and steps), every filter advancing all of them together."""
    s, steps = tasks[0].setting, tasks[0].steps
    world = s.maze.world(None)
    with warnings.catch_warnings():  # the range warnings were shown once, by study_settings
        warnings.simplefilter("ignore", UserWarning)
        walks = [walk_of(task, world) for task in tasks]
    particles = np.stack([walk.inputs.particles for walk in walks])  # (R, N, 2)
    compass = np.array([walk.compass_angles for walk in walks])  # (R, steps)
    z = np.array([walk.measurements for walk in walks])
    results: list[dict[str, RunResult]] = [{} for _ in tasks]
    for name in tasks[0].filters:
        rngs = [np.random.default_rng(task.seed).spawn(4)[2] for task in tasks]  # each run's filter stream
        options = {"threshold": s.threshold} if name == "RegularizedParticleFilter" else {}
        filt = BATCH_FILTERS[name](world, s.sigma, s.delta, particles, rngs, **options)
        estimates, ess = np.empty((len(tasks), steps, 2)), np.empty((len(tasks), steps))
        confident, seconds = np.empty((len(tasks), steps), dtype=bool), np.empty(steps)
        for k in range(steps):
            started = time.perf_counter()
            filt.step(compass[:, k], z[:, k])
            estimates[:, k], ess[:, k], confident[:, k] = filt.estimate, filt.ess, filt.is_confident
            seconds[k] = (time.perf_counter() - started) / len(tasks)  # each run's share of the step
        for r, walk in enumerate(walks):
            inputs = RunInputs(**{**walk.inputs.__dict__, "filtering_algorithm": name})
            results[r][name] = RunResult(
                name,
                walk.true_positions,
                estimates[r],
                ess[r],
                confident[r],
                seconds,
                filt.reinitialised_at[r],
                inputs,
                extras={"particle_count": np.full(steps, s.particles, dtype=np.int64)},
            )
    return [run_records(task, world, result) for task, result in zip(tasks, results, strict=True)]


__all__ = [
    "MAX_BATCH",
    "MAX_BATCH_PARTICLES",
    "Walk",
    "batchable",
    "run_batch",
    "run_unit_safely",
    "study_units",
    "walk_of",
]
