"""How close each filter comes to the exact posterior: on seeded runs of each maze, the distance between
a filter's estimate and the exact grid filter's posterior mean, averaged over the second half of the
steps (after the first localisation), and the share of runs that converged (`mazelab accuracy`)."""

from __future__ import annotations

import statistics
import warnings
from collections.abc import Sequence
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from typing import Any

import numpy as np

from mazelab.experiments.tables import format_optional, format_table
from mazelab.maze import Maze
from mazelab.robot import Robot
from mazelab.seeding import start_place, study_seeds
from mazelab.simulation import convergence_step, simulate

# (label, filter, options): the filters of the table, each against the exact grid filter
ACCURACY_FILTERS: tuple[tuple[str, str, dict[str, Any]], ...] = (
    ("SIR", "sir", {}),
    ("APF", "apf", {}),
    ("RPF (paper: optimal)", "rpf", {}),
    ("RPF multimodal", "rpf", {"bandwidth": "multimodal"}),
    ("grid (exact)", "grid", {}),
)


@dataclass(frozen=True)
class AccuracyTask:
    """One seeded run on one maze: every filter of ACCURACY_FILTERS on the same scenario."""

    maze: str
    grid: tuple[tuple[int, ...], ...]
    seed: int
    sigma: float
    delta: float
    particles: int
    steps: int
    filters: tuple[tuple[str, str, dict[str, Any]], ...] = ACCURACY_FILTERS  # (label, filter or FILE.py:Class, options)


@dataclass(frozen=True)
class AccuracyRecord:
    """One filter in one run: its mean distance to the exact posterior mean over the second half of the
    steps (map units; 0 for the grid itself) and its convergence step against the truth (None: never)."""

    maze: str
    seed: int
    filter: str
    distance_to_exact: float
    converged_at: int | None


def run_accuracy_task(task: AccuracyTask) -> list[AccuracyRecord]:
    """The grid filter and every particle filter on one scenario; their distances to the grid's mean."""
    world = Maze(task.grid, source=task.maze)
    robot = Robot(task.sigma, task.delta, start_place(world, task.seed))
    window = slice(task.steps // 2, task.steps)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)  # sigma or delta outside the lab's range: said once by the CLI
        exact = simulate(robot, world, task.sigma, task.delta, task.particles, task.steps, None, "grid", seed=task.seed)
        particles = np.array(exact.scenario.init_particles_pos)
        records = []
        for label, name, options in task.filters:
            if name in ("grid", "GridBayesFilter"):
                result = exact
            else:
                args = (robot, world, task.sigma, task.delta, None, task.steps, particles, name)
                result = simulate(*args, seed=task.seed, **options)
            distance = float(np.hypot(*(result.estimates - exact.estimates)[window].T).mean())
            records.append(AccuracyRecord(task.maze, task.seed, label, distance, convergence_step(result.errors)))
    return records


def accuracy_tasks(
    mazes: Sequence[tuple[str, Maze]],
    runs: int,
    sigma: float,
    delta: float,
    particles: int,
    steps: int,
    seed: int,
    filters: tuple[tuple[str, str, dict[str, Any]], ...] = ACCURACY_FILTERS,
) -> list[AccuracyTask]:
    """`runs` seeded runs per maze (run r has the same seed on every maze, as in a study); `filters`:
    (label, filter name or plug-in spec, options) of each filter measured (the exact grid always runs)."""
    seeds = [s for s, _ in study_seeds(seed, runs)]
    return [
        AccuracyTask(name, tuple(map(tuple, world.as_lists())), s, sigma, delta, particles, steps, filters)
        for name, world in mazes
        for s in seeds
    ]


def run_accuracy(tasks: Sequence[AccuracyTask], workers: int = 1) -> list[AccuracyRecord]:
    """Every task, on `workers` processes; records in task order."""
    if workers <= 1 or len(tasks) <= 1:
        outcomes = [run_accuracy_task(t) for t in tasks]
    else:
        with ProcessPoolExecutor(max_workers=min(workers, len(tasks))) as pool:
            outcomes = list(pool.map(run_accuracy_task, tasks))
    return [record for outcome in outcomes for record in outcome]


def accuracy_table(records: Sequence[AccuracyRecord]) -> str:
    """Per maze and filter: the mean (and worst) distance to the exact posterior mean over the second
    half of the steps, the converged share and the median convergence step."""
    groups: dict[tuple[str, str], list[AccuracyRecord]] = {}
    for record in records:
        groups.setdefault((record.maze, record.filter), []).append(record)
    rows = []
    for (maze, name), group in groups.items():
        distances = [r.distance_to_exact for r in group]
        converged = [r.converged_at for r in group if r.converged_at is not None]
        rows.append(
            [
                maze,
                name,
                str(len(group)),
                f"{statistics.fmean(distances):.3f}",
                f"{max(distances):.3f}",
                f"{len(converged) / len(group):.0%}",
                format_optional(statistics.median(converged) if converged else None, "{:g}"),
            ]
        )
    headers = ["maze", "filter", "runs", "distance to exact mean", "worst run", "converged", "median conv. step"]
    return format_table(headers, rows)


__all__ = [
    "ACCURACY_FILTERS",
    "AccuracyRecord",
    "AccuracyTask",
    "accuracy_table",
    "accuracy_tasks",
    "run_accuracy",
    "run_accuracy_task",
]
