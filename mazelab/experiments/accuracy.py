"""How close each filter comes to the exact posterior: on seeded runs of each maze, the distance between
a filter's estimate and the exact grid filter's posterior mean, averaged over the second half of the
steps (after the first localisation), and the share of runs that converged (`mazelab accuracy`)."""

from __future__ import annotations

import math
import signal
import statistics
import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass, fields
from typing import Any

import numpy as np

from mazelab.experiments.executor import Units, stop_signals
from mazelab.experiments.stats import bootstrap_interval, wilson_interval
from mazelab.experiments.study import MazeChoice, distance_to_exact  # one definition, a study's too
from mazelab.experiments.tables import format_optional, format_table, records_csv
from mazelab.plugins import is_plugin_spec
from mazelab.registry import resolve_filter
from mazelab.robot import Robot
from mazelab.seeding import start_place, study_seeds
from mazelab.simulation import convergence_step, simulate

AccuracyFilter = tuple[str, Any, dict[str, Any]]  # (label, filter name or class, options)
# the filters of the default table, each against the exact grid filter
ACCURACY_FILTERS: tuple[AccuracyFilter, ...] = (
    ("SIR", "sir", {}),
    ("APF", "apf", {}),
    ("RPF (paper: optimal)", "rpf", {}),
    ("RPF multimodal", "rpf", {"bandwidth": "multimodal"}),
    ("grid (exact)", "grid", {}),
)
EXACT = ("grid (exact)", "grid", {})


def accuracy_filters(names: Sequence[Any] | None) -> tuple[AccuracyFilter, ...]:
    """The filters of the table: ACCURACY_FILTERS, or the given names or classes (each with its default
    options), the exact grid filter last."""
    if names is None:
        return ACCURACY_FILTERS
    chosen: dict[str, AccuracyFilter] = {}
    for name in names:
        filter_class = resolve_filter(name)
        if filter_class is not resolve_filter("grid"):
            label = filter_class.name
            key = name if isinstance(name, type) or is_plugin_spec(str(name)) else filter_class.name
            chosen.setdefault(label, (label, key, {}))  # a plug-in goes to the workers as its spec
    return (*chosen.values(), EXACT)


@dataclass(frozen=True)
class AccuracyTask:
    """One seeded run on one maze: every filter on the same scenario."""

    maze: str
    choice: MazeChoice
    seed: int
    sigma: float
    delta: float
    particles: int
    steps: int
    run: int = 1
    maze_seed: int | None = None  # seeds a generated maze; None for a maze file
    filters: tuple[AccuracyFilter, ...] = ACCURACY_FILTERS


@dataclass(frozen=True)
class AccuracyRecord:
    """One filter in one run: its mean distance to the exact posterior mean over the second half of the
    steps (map units; 0 for the grid itself) and its convergence step against the truth (None: never)."""

    maze: str
    seed: int
    filter: str
    distance_to_exact: float
    converged_at: int | None
    run: int = 1
    maze_seed: int | None = None


def run_accuracy_task(task: AccuracyTask) -> list[AccuracyRecord]:
    """The grid filter and every other filter on one scenario; their distances to the grid's mean."""
    world = task.choice.world(task.maze_seed)
    robot = Robot(task.sigma, task.delta, start_place(world, task.seed))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)  # sigma or delta outside the lab's range: said once by the CLI
        exact = simulate(robot, world, task.sigma, task.delta, task.particles, task.steps, None, "grid", seed=task.seed)
        particles = np.array(exact.initial_particles)
        records = []
        for label, name, options in task.filters:
            if resolve_filter(name) is resolve_filter("grid") and not options:
                result = exact
            else:
                args = (robot, world, task.sigma, task.delta, None, task.steps, particles, name)
                result = simulate(*args, seed=task.seed, **options)
            distance = distance_to_exact(result.estimates, exact.estimates)
            converged = convergence_step(result.errors)
            records.append(AccuracyRecord(task.maze, task.seed, label, distance, converged, task.run, task.maze_seed))
    return records


def accuracy_tasks(
    mazes: Sequence[tuple[str, Any]],
    runs: int,
    sigma: float,
    delta: float,
    particles: int,
    steps: int,
    seed: int,
    filters: tuple[AccuracyFilter, ...] = ACCURACY_FILTERS,
) -> list[AccuracyTask]:
    """`runs` seeded runs per maze (run r has the same seed on every maze, as in a study); a maze is a
    (name, Maze) or (name, MazeChoice) pair (a generated MazeChoice: a new maze per run)."""
    seeds = study_seeds(seed, runs)
    tasks = []
    for name, world in mazes:
        choice = world if isinstance(world, MazeChoice) else MazeChoice.from_maze(name, world)
        for r, (s, maze_seed) in enumerate(seeds, start=1):
            generated = choice.grid is None
            tasks.append(
                AccuracyTask(
                    name, choice, s, sigma, delta, particles, steps, r, maze_seed if generated else None, filters
                )
            )
    return tasks


class AccuracyStopped(KeyboardInterrupt):
    """Ctrl-C, SIGTERM or SIGHUP stopped the runs: the workers are ended, `signum` is the signal (the
    runs that finished were handed to `on_records`)."""

    def __init__(self, signum: int):
        super().__init__(signal.Signals(signum).name)
        self.signum = signum


def run_accuracy_unit(unit: Sequence[AccuracyTask]) -> list[list[AccuracyRecord]]:
    """A unit of accuracy runs (one task: its records)."""
    return [run_accuracy_task(task) for task in unit]


def run_accuracy(
    tasks: Sequence[AccuracyTask], workers: int = 1, advance: Callable[..., None] | None = None,
    on_records: Callable[[list[AccuracyRecord]], None] | None = None,
) -> list[AccuracyRecord]:  # fmt: skip
    """Every task, on `workers` processes (mazelab.experiments.executor.Units: a worker that dies is
    replaced); records in task order, each run's also handed to `on_records` as it ends, and `advance()`
    called. Ctrl-C, SIGTERM or SIGHUP end the worker processes at once and raise AccuracyStopped."""
    advance = advance or (lambda count=1: None)
    finished: dict[tuple[str, int], list[AccuracyRecord]] = {}

    def collect(outcomes: list[list[AccuracyRecord]]) -> None:
        for records in outcomes:
            if isinstance(records, list) and records:
                finished[records[0].maze, records[0].run] = records
                if on_records is not None:
                    on_records(records)

    try:
        with stop_signals():
            if workers <= 1 or len(tasks) <= 1:
                for task in tasks:
                    collect(run_accuracy_unit([task]))
                    advance()
            else:
                Units([(task,) for task in tasks], run_accuracy_unit, min(workers, len(tasks))).run(collect, advance)
    except KeyboardInterrupt as stop:
        raise AccuracyStopped(getattr(stop, "signum", signal.SIGINT)) from None
    return [record for task in tasks for record in finished.get((task.maze, task.run), [])]


def accuracy_summary(records: Sequence[AccuracyRecord]) -> list[dict[str, Any]]:
    """Per maze and filter: runs, the mean distance to the exact mean with its percentile bootstrap
    interval, the worst run, the converged share with its Wilson interval, the median convergence step."""
    groups: dict[tuple[str, str], list[AccuracyRecord]] = {}
    for record in records:
        groups.setdefault((record.maze, record.filter), []).append(record)
    rows = []
    for (maze, name), group in groups.items():
        distances = [r.distance_to_exact for r in group]
        converged = [r.converged_at for r in group if r.converged_at is not None]
        rows.append(
            {
                "maze": maze,
                "filter": name,
                "runs": len(group),
                "mean_distance_to_exact": statistics.fmean(distances),
                "interval": bootstrap_interval(distances, "mean"),
                "worst_distance": max(distances),
                "converged_share": len(converged) / len(group),
                "converged_interval": wilson_interval(len(converged), len(group)),
                "median_convergence_step": statistics.median(converged) if converged else None,
            }
        )
    return rows


def _interval(bounds: tuple[float, float], spec: str) -> str:
    return "-" if math.isnan(bounds[0]) else f"[{spec.format(bounds[0])}, {spec.format(bounds[1])}]"


def accuracy_table(records: Sequence[AccuracyRecord]) -> str:
    """Per maze and filter: the mean (and worst) distance to the exact posterior mean over the second
    half of the steps with its 95% bootstrap interval, the converged share with its Wilson interval
    and the median convergence step."""
    rows = [
        [
            s["maze"],
            s["filter"],
            str(s["runs"]),
            f"{s['mean_distance_to_exact']:.3f}",
            f"{s['worst_distance']:.3f}",
            _interval(s["interval"], "{:.3f}"),
            f"{s['converged_share']:.0%}",
            _interval(s["converged_interval"], "{:.0%}"),
            format_optional(s["median_convergence_step"], "{:g}"),
        ]
        for s in accuracy_summary(records)
    ]
    headers = ["maze", "filter", "runs", "distance to exact mean", "worst run", "95% CI", "converged", "95% CI"]
    headers.append("median conv. step")
    note = "[95% intervals: the mean by percentile bootstrap (B = 2000, seeded), the share by Wilson score]"
    return format_table(headers, rows) + "\n" + note


ACCURACY_COLUMNS = [f.name for f in fields(AccuracyRecord)]


def accuracy_csv(records: Sequence[AccuracyRecord]) -> str:
    """One row per maze, run and filter, columns ACCURACY_COLUMNS; an empty cell for "never"."""
    return records_csv(records, ACCURACY_COLUMNS)


__all__ = [
    "ACCURACY_COLUMNS",
    "ACCURACY_FILTERS",
    "AccuracyRecord",
    "AccuracyStopped",
    "AccuracyTask",
    "accuracy_csv",
    "accuracy_filters",
    "accuracy_summary",
    "accuracy_table",
    "accuracy_tasks",
    "distance_to_exact",
    "run_accuracy",
    "run_accuracy_task",
    "run_accuracy_unit",
]
