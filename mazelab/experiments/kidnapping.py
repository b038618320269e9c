"""The kidnapped robot, measured: does a filter re-localise after the robot is carried elsewhere?

One trial: a lost robot walks `steps` steps, is kidnapped at step `kidnap_at` (see Robot.kidnap) and
the filter runs on the whole walk. It has *re-localised* when its mean error over the last `window`
steps is below CONVERGENCE_RADIUS; its *steps to recover* are R - kidnap_at, R the first step from
which the error stays below CONVERGENCE_RADIUS to the end (`convergence_step` of the errors from the
kidnapping on; None when the last error is not below it). The same seed gives every filter and
recovery variant the same walk, kidnapping and initial particles, so the table compares like with like.

    python -m mazelab.experiments.kidnapping [runs]    the recovery table on mazes/maze_10x10.txt (40 runs by default)
"""

from __future__ import annotations

import math
import statistics
import sys
from collections.abc import Iterable
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from typing import Any

import numpy as np

from mazelab.maze import Maze
from mazelab.model import CONVERGENCE_RADIUS
from mazelab.robot import Robot
from mazelab.seeding import start_place
from mazelab.simulation import RunResult, convergence_step, simulate

RECOVERY_VARIANTS = {"none": None, "augmented": "augmented", "sensor": "sensor"}  # table label -> recovery=
DEFAULT_WINDOW = 30  # re-localised: mean error over this many final steps below CONVERGENCE_RADIUS


@dataclass(frozen=True)
class KidnapOutcome:
    """What one kidnapping trial measured."""

    filter_name: str
    variant: str
    seed: int
    localised_before: bool  # error below CONVERGENCE_RADIUS at the step before the kidnapping
    relocalised: bool
    steps_to_recover: int | None
    mean_particle_count: float


def walk_until(robot: Robot, kidnap_at: int) -> Robot:
    """A copy of `robot` replaying only the steps before `kidnap_at` (angles and measurements), so that it
    can be kidnapped there: a recorded walk after the jump would retrace the old place's path."""
    if isinstance(kidnap_at, bool) or not isinstance(kidnap_at, int) or kidnap_at < 1:
        raise ValueError(f"kidnap_at must be a step number >= 1, got {kidnap_at!r}")
    keep = kidnap_at - 1
    return Robot(
        robot.sigma,
        robot.delta,
        robot.initial_position,
        actual_angles=robot.actual_angles[:keep],
        compass_angles=robot.compass_angles[:keep],
        measurements=robot.measurements[:keep] if robot.measurements else None,
        rng=robot.rng if robot.rng_given else None,
        max_straight_steps=robot.max_straight_steps,
        speed=robot.speed,
    )


def recovery_steps(result: RunResult) -> int | None:
    """R - K: R the first step from which the error stays below CONVERGENCE_RADIUS, K the kidnap step."""
    kidnap_at = result.kidnap_at
    if kidnap_at is None:
        raise ValueError("the run has no kidnapping")
    since = convergence_step(result.errors[kidnap_at - 1 :])  # 1-based within the errors of steps K..end
    return None if since is None else since - 1


def relocalised(result: RunResult, window: int = DEFAULT_WINDOW) -> bool:
    """The mean error over the last `window` steps is below CONVERGENCE_RADIUS."""
    return bool(result.errors[-window:].mean() < CONVERGENCE_RADIUS)


def recovery_trial(
    world: Maze,
    filter_name: str,
    variant: str = "none",
    *,
    seed: int,
    particle_count: int = 2000,
    steps: int = 260,
    kidnap_at: int = 100,
    sigma: float = 0.3,
    delta: float = 0.5,
    window: int = DEFAULT_WINDOW,
    **filter_options: Any,
) -> KidnapOutcome:
    """One seeded kidnapping trial of `filter_name` with recovery `variant` (none, augmented, sensor)."""
    if variant not in RECOVERY_VARIANTS:
        raise ValueError(f"unknown recovery variant {variant!r}; choose one of {', '.join(RECOVERY_VARIANTS)}")
    start = start_place(world, seed)
    robot = Robot(sigma, delta, start)
    result = simulate(
        robot,
        world,
        sigma,
        delta,
        particle_count,
        steps,
        filtering_algorithm=filter_name,
        seed=seed,
        kidnap_at=kidnap_at,
        recovery=RECOVERY_VARIANTS[variant],
        **filter_options,
    )
    return KidnapOutcome(
        filter_name=result.filter_name,
        variant=variant,
        seed=seed,
        localised_before=bool(kidnap_at > 1 and result.errors[kidnap_at - 2] < CONVERGENCE_RADIUS),
        relocalised=relocalised(result, window),
        steps_to_recover=recovery_steps(result),
        mean_particle_count=float(result.extras["particle_count"].mean()),
    )


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


def _trial(arguments: tuple[Maze, str, str, int, dict[str, Any]]) -> KidnapOutcome:
    world, name, variant, seed, options = arguments
    return recovery_trial(world, name, variant, seed=seed, **options)


def recovery_table(
    world: Maze,
    filters: Iterable[str] = ("sir", "apf", "rpf"),
    variants: Iterable[str] = tuple(RECOVERY_VARIANTS),
    runs: int = 40,
    *,
    first_seed: int = 0,
    workers: int = 1,
    **trial_options: Any,
) -> list[RecoveryRow]:
    """`runs` seeded trials (seeds first_seed, first_seed + 1, ...) per filter and variant, summarised.
    `workers` > 1 runs the trials in that many processes (the results do not depend on it)."""
    jobs = [(world, f, v, first_seed + s, trial_options) for f in filters for v in variants for s in range(runs)]
    if workers > 1:
        with ProcessPoolExecutor(workers) as pool:
            outcomes = list(pool.map(_trial, jobs, chunksize=4))
    else:
        outcomes = [_trial(job) for job in jobs]
    rows = []
    for start in range(0, len(outcomes), runs):
        group = outcomes[start : start + runs]
        recovered = [o.steps_to_recover for o in group if o.steps_to_recover is not None]
        rows.append(
            RecoveryRow(
                filter_name=group[0].filter_name,
                variant=group[0].variant,
                runs=len(group),
                localised_before=float(np.mean([o.localised_before for o in group])),
                relocalised=float(np.mean([o.relocalised for o in group])),
                median_steps_to_recover=float(statistics.median(recovered)) if recovered else math.nan,
                mean_particle_count=float(np.mean([o.mean_particle_count for o in group])),
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
    from mazelab.mazes import load_maze

    maze = load_maze("maze_10x10")
    count = int(sys.argv[1]) if len(sys.argv) > 1 else 40
    print(format_recovery_table(recovery_table(maze, runs=count, workers=2)))


__all__ = [
    "DEFAULT_WINDOW",
    "RECOVERY_VARIANTS",
    "KidnapOutcome",
    "RecoveryRow",
    "format_recovery_table",
    "recovery_steps",
    "recovery_table",
    "recovery_trial",
    "relocalised",
    "walk_until",
]
