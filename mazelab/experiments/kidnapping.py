"""The kidnapped robot, measured: does a filter re-localise after the robot is carried elsewhere?

One trial: a lost robot walks `steps` steps, is kidnapped at step `kidnap_at` (see Robot.kidnap) and
the filter runs on the whole walk; it has re-localised, and in how many steps, as a run's figures say
(mazelab.experiments.runs.relocalised, recovery_steps). The trials are a study's runs (every filter on
the same walk, kidnapping and initial particles; a setting per recovery variant; trial s has seed s), so
the table compares like with like.

    python -m mazelab.experiments.kidnapping [runs]    the recovery table on mazes/maze_10x10.txt (40 runs by default)
"""

from __future__ import annotations

import sys
from collections.abc import Iterable, Sequence

import numpy as np

from mazelab.experiments.executor import run_study
from mazelab.experiments.study import MazeChoice, RunRecord, RunTask, StudySetting
from mazelab.experiments.summary import recovery_summary
from mazelab.experiments.tables import column_table, format_number
from mazelab.maze import Maze
from mazelab.model import CONVERGENCE_RADIUS
from mazelab.registry import described

RECOVERY_VARIANTS = {"none": None, "augmented": "augmented", "sensor": "sensor"}  # table label -> recovery=


def recovery_records(
    world: Maze,
    filters: Sequence[str] = ("sir", "apf", "rpf"),
    variants: Iterable[str] = tuple(RECOVERY_VARIANTS),
    runs: int = 40,
    *,
    first_seed: int = 0,
    workers: int = 1,
    particle_count: int = 2000,
    steps: int = 260,
    kidnap_at: int = 100,
    sigma: float = 0.3,
    delta: float = 0.5,
) -> list[RunRecord]:
    """`runs` seeded kidnapping trials (seeds first_seed, first_seed + 1, ...) of every filter with each recovery
    variant (none, augmented, sensor), as a study's runs with their per-step traces, on `workers` processes (the
    results do not depend on it); one record per trial and filter, in (variant, trial, filter) order."""
    maze = MazeChoice.from_maze("maze", world)
    settings = [
        StudySetting(maze, sigma, delta, particle_count, (("recovery", RECOVERY_VARIANTS[v]),)) for v in variants
    ]
    tasks = [
        RunTask(i, setting, r, first_seed + r - 1, None, tuple(filters), steps, kidnap_at, traces=True)
        for i, setting in enumerate(settings, start=1)
        for r in range(1, runs + 1)
    ]
    return run_study(tasks, workers).records


def localised_before(record: RunRecord) -> bool:
    """The error was below CONVERGENCE_RADIUS at the step before the kidnapping (from the record's trace)."""
    k = record.kidnap_at
    trace = record.trace or {}
    return bool(k and k > 1 and np.hypot(*(trace["estimate"][k - 2] - trace["true"][k - 2])) < CONVERGENCE_RADIUS)


def recovery_table(world: Maze, filters: Sequence[str] = ("sir", "apf", "rpf"), **trials: object) -> str:
    """The recovery trials (`recovery_records`, with `trials` its other arguments) as a table, a row per
    filter (its registry label) and variant: the share of the runs localised before the kidnapping and
    re-localised at the end, the median steps to recover over the runs that recovered ('-': none did;
    mazelab.experiments.summary.recovery_summary), the mean particle count."""
    groups: dict[tuple[str, str], list[RunRecord]] = {}
    for record in recovery_records(world, filters, **trials):  # type: ignore[arg-type]
        groups.setdefault((record.filter, record.options["recovery"]), []).append(record)
    names, variants = list(dict.fromkeys(k[0] for k in groups)), list(dict.fromkeys(k[1] for k in groups))
    ordered = sorted(groups, key=lambda key: (names.index(key[0]), variants.index(key[1])))
    columns = [
        ("filter", lambda g: described(g[0].filter).label),
        ("recovery", lambda g: g[0].options["recovery"]),
        ("runs", lambda g: str(len(g))),
        ("localised before", lambda g: f"{np.mean([localised_before(r) for r in g]):.0%}"),
        ("re-localised", lambda g: f"{recovery_summary(g)[0]:.0%}"),
        ("median steps to recover", lambda g: format_number(recovery_summary(g)[1], "{:g}")),
        ("mean N", lambda g: f"{np.mean([r.mean_particle_count for r in g]):.0f}"),
    ]
    return column_table(columns, [groups[key] for key in ordered])


if __name__ == "__main__":
    from mazelab.maze import load_maze

    maze = load_maze("maze_10x10")
    count = int(sys.argv[1]) if len(sys.argv) > 1 else 40
    print(recovery_table(maze, runs=count, workers=2))
