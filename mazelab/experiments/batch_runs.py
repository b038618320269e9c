"""A study's runs in units of work: the runs of one setting advanced together by one filter object of
R runs (mazelab.smc: the same steps as a single run, bit for bit), or one run at a time where the
declared rule says they cannot be (`batchable`)."""

from __future__ import annotations

import math
import traceback
import warnings
from collections.abc import Sequence
from itertools import groupby

import numpy as np

from mazelab.backend import backend_of
from mazelab.contract import check_filter
from mazelab.experiments.runs import WARM_UP_SEED, WARM_UP_STEPS, warm_once
from mazelab.experiments.study import RunFailure, RunRecord, RunTask, run_records, run_task_safely
from mazelab.maze import Maze
from mazelab.registry import filter_entry
from mazelab.robot import Robot
from mazelab.seeding import filter_rng, run_streams
from mazelab.simulation import RunInputs, RunResult, maze_for, plan_kidnapping, record_steps

MAX_BATCH = 32  # runs advanced together: beyond this the fixed cost per step is already small
MAX_BATCH_PARTICLES = 1_000_000  # R x N at most: a batch needs no more memory than a run of 10^6 particles


def batchable(task: RunTask) -> bool:
    """The declared rule: a setting's runs advance together when they share one maze (a maze file, not
    a maze generated per run) and every filter's registry entry declares it `batched` (the lab's
    particle filters; a new class only when it says so) with options that let runs go together
    (`runs_together`: not recovery or KLD-sampling), and no `--reference`; otherwise one run at a time."""
    if task.setting.maze.grid is None or task.reference is not None:  # a reference runs the grid per run
        return False
    for name in task.filters:
        entry = filter_entry(name)
        runs_together = getattr(entry.filter_class, "runs_together", None)
        if not entry.batched or (runs_together is not None and not runs_together(task.setting.filter_options(name))):
            return False
    return True


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
    """Every run of a unit, in order: together when `batchable` says so, else one by one; a run that
    raises becomes a RunFailure, and so does every run of a batched unit that raises (a bug in the
    batched path is reported, never hidden by a quiet second try)."""
    if len(unit) > 1 and all(batchable(task) for task in unit):
        try:
            return list(run_batch(unit))
        except Exception as error:
            where = traceback.extract_tb(error.__traceback__)[-1]
            message = f"{type(error).__name__}: {error} (runs advanced together; at {where.name}, line {where.lineno})"
            return [RunFailure(task, message) for task in unit]
    return [run_task_safely(task) for task in unit]


def walk_of(task: RunTask, world: Maze) -> tuple[RunInputs, np.ndarray]:
    """The run's walk and particles from its seed, the draws simulate makes (robot, particles, kidnapping):
    the run's inputs, as run_task makes them, and the true positions (steps, 2)."""
    s = task.setting
    robot = Robot.of_seed(world, s.sigma, s.delta, task.seed)
    streams = run_streams(task.seed)
    particles = world.random_free_places(s.particles, streams.particles)
    if task.kidnap_at is not None:
        plan_kidnapping(robot, world, task.kidnap_at, task.steps, streams.kidnap)
    robot.reset()
    robot.rng = streams.robot
    positions = []
    for _ in range(task.steps):
        robot.step(world)
        positions.append(robot.position)
    inputs = RunInputs.of_run(robot, particles, world, s.sigma, s.delta, task.seed, task.steps, task.filters[0])
    return inputs, np.array(positions).reshape(task.steps, 2)


def run_batch(tasks: Sequence[RunTask]) -> list[list[RunRecord]]:
    """The runs of one setting (same filters and steps), each filter advancing all of them together."""
    s, steps = tasks[0].setting, tasks[0].steps
    world = s.maze.world(None)
    with warnings.catch_warnings():  # the range warnings were shown once, by study_settings
        warnings.simplefilter("ignore", UserWarning)
        walks = [walk_of(task, world) for task in tasks]
    particles = np.stack([inputs.init_particles_pos for inputs, _ in walks])  # (R, N, 2)
    compass = np.array([inputs.robot_compass_angles for inputs, _ in walks])  # (R, steps)
    z = np.array([inputs.robot_measurements for inputs, _ in walks])
    results: list[dict[str, RunResult]] = [{} for _ in tasks]
    world.prepare()
    for name in tasks[0].filters:
        filter_class = filter_entry(name).filter_class
        options = tasks[0].setting.filter_options(name)
        warm_batch(filter_class, world, tasks, particles, compass, z, options)
        rngs = [filter_rng(task.seed) for task in tasks]  # each run's filter stream, as simulate's
        filt = filter_class(maze_for(filter_class, world), s.sigma, s.delta, particles, rngs, **options)
        runs = None if len(tasks) == 1 else len(tasks)  # one run: the paper's shapes
        if runs is None:
            check_filter(filt)
        steps_of = record_steps(filt, steps, lambda k: (compass[:, k], z[:, k]), runs=runs)
        restarts = filt.reinitialised_at if len(tasks) > 1 else [filt.reinitialised_at]  # one run: one list
        for r, (walk, true_positions) in enumerate(walks):
            inputs = RunInputs(**{**walk.__dict__, "filtering_algorithm": filter_class.name})
            results[r][filter_class.name] = RunResult.of_recorded(
                steps_of, r, true_positions, restarts[r], inputs, backend_of(filt)
            )
    return [run_records(task, world, result) for task, result in zip(tasks, results, strict=True)]


def warm_batch(
    filter_class: type,
    world: Maze,
    tasks: Sequence[RunTask],
    particles: np.ndarray,
    compass: np.ndarray,
    z: np.ndarray,
    options: dict,
) -> None:
    """Before the batch's timed steps: the filter advancing one or two runs together (as the batch
    will) for a few untimed steps, once per process, options and shape (mazelab.experiments.runs.warm_once);
    its random draws come from a stream of its own, its numbers are discarded."""
    r = min(2, len(tasks))
    s = tasks[0].setting

    def warm(warmed: dict) -> None:
        rngs = [filter_rng(WARM_UP_SEED) for _ in range(r)]
        filt = filter_class(maze_for(filter_class, world), s.sigma, s.delta, particles[:r].copy(), rngs, **warmed)
        steps = min(WARM_UP_STEPS, tasks[0].steps)
        record_steps(filt, steps, lambda k: (compass[:r, k], z[:r, k]), runs=None if r == 1 else r)

    warm_once(("batch", r), filter_class, options, warm)
