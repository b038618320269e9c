"""The kidnapped robot, measured: does a filter re-localise after the robot is carried elsewhere?

One trial: a lost robot walks `steps` steps, is kidnapped at step `kidnap_at` (see Robot.kidnap) and
the filter runs on the whole walk; it has re-localised, and in how many steps, as a run's figures say
(mazelab.experiments.runs.relocalised, recovery_steps). The trials are a study's runs (every filter on
the same walk, kidnapping and initial particles; a setting per recovery variant; trial s has seed s), so
the table compares like with like.

    python -m mazelab.experiments.kidnapping [runs]    the recovery table on mazes/maze_10x10.txt (40 runs by default)
"""

from __future__ import annotations

import math
import statistics
import sys
from collections.abc import Iterable, Sequence
from dataclasses import dataclass

import numpy as np

from mazelab.experiments.executor import run_study
from mazelab.experiments.study import MazeChoice, RunRecord, RunTask, StudySetting
from mazelab.maze import Maze
from mazelab.model import CONVERGENCE_RADIUS

RECOVERY_VARIANTS = {"none": None, "augmented": "augmented", "sensor": "sensor"}  # table label -> recovery=


def recovery_records(
    world: Maze, filters: Sequence[str] = ("sir", "apf", "rpf"), variants: Iterable[str] = tuple(RECOVERY_VARIANTS),
    runs: int = 40, *, first_seed: int = 0, workers: int = 1, particle_count: int = 2000, steps: int = 260,
    kidnap_at: int = 100, sigma: float = 0.3, delta: float = 0.5,
) -> list[RunRecord]:  # fmt: skip
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


@dataclass(frozen=True)
class RecoveryRow:
    """One line of the recovery table: a filter and a recovery variant over `runs` seeded trials."""

    filter_name: str
    variant: str
    runs: int
    localised_before: float  # share of runs localised just before the kidnapping
    relocalised: float  # share of runs re-localised at the end
    median_steps_to_recover: float  # over the runs that recovered; NaN if none did
    mean_particle_count: float


def recovery_table(world: Maze, filters: Sequence[str] = ("sir", "apf", "rpf"), **trials: object) -> list[RecoveryRow]:
    """The recovery trials (`recovery_records`, with `trials` its other arguments), summarised per filter and
    variant: the share localised before the kidnapping and re-localised at the end, the median steps to
    recover over the runs that recovered, the mean particle count."""
    groups: dict[tuple[str, str], list[RunRecord]] = {}
    for record in recovery_records(world, filters, **trials):  # type: ignore[arg-type]
        groups.setdefault((record.filter, record.options["recovery"]), []).append(record)
    names, variants = list(dict.fromkeys(k[0] for k in groups)), list(dict.fromkeys(k[1] for k in groups))
    rows = []
    for name, variant in sorted(groups, key=lambda key: (names.index(key[0]), variants.index(key[1]))):
        group = groups[name, variant]
        recovered = [r.steps_to_recover for r in group if r.steps_to_recover is not None]
        rows.append(
            RecoveryRow(
                filter_name=name,
                variant=variant,
                runs=len(group),
                localised_before=float(np.mean([localised_before(r) for r in group])),
                relocalised=float(np.mean([bool(r.relocalised) for r in group])),
                median_steps_to_recover=float(statistics.median(recovered)) if recovered else math.nan,
                mean_particle_count=float(np.mean([r.mean_particle_count for r in group])),
            )
        )
    return rows


def format_recovery_table(rows: Iterable[RecoveryRow]) -> str:
    """The table as aligned text, one row per filter and variant."""
    lines = [
        f"{'filter':<26} {'recovery':<10} {'runs':>4} {'localised before':>16} {'re-localised':>12} "
        f"{'median steps to recover':>23} {'mean N':>7}"
    ]
    for row in rows:
        lines.append(
            f"{row.filter_name:<26} {row.variant:<10} {row.runs:>4} {row.localised_before:>16.0%} "
            f"{row.relocalised:>12.0%} {row.median_steps_to_recover:>23.1f} {row.mean_particle_count:>7.0f}"
        )
    return "\n".join(lines)


if __name__ == "__main__":
    from mazelab.maze import load_maze

    maze = load_maze("maze_10x10")
    count = int(sys.argv[1]) if len(sys.argv) > 1 else 40
    print(format_recovery_table(recovery_table(maze, runs=count, workers=2)))
