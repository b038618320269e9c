"""What a run prints: its summary, the per-step progress, the kidnapping and the particle count."""

from __future__ import annotations

from typing import Any

import numpy as np
import typer

from mazelab.experiments.kidnapping import recovery_steps
from mazelab.experiments.runs import final_error
from mazelab.robot import Robot
from mazelab.simulation import RunResult


def summarise(result: RunResult) -> str:
    """A short report of a run: final error, convergence step, time per step."""
    errors = result.errors
    converged = result.converged_at
    when = f"converged at step {converged} (error < 0.5 from then on)" if converged else "not converged"
    return (
        f"{result.filter_name}: final error {errors[-1]:.3f}, mean error over the last 20% "
        f"{final_error(errors):.3f}; {when}; "
        f"{1e3 * result.step_seconds.mean():.2f} ms per step; seed {result.seed}"
    )


def progress_printer(steps: int, every: int = 20) -> Any:
    """A per-step callback that prints the error every `every` steps."""

    def report(k: int, robot: Robot, filt: Any) -> None:
        if k % every == 0 or k == steps:
            error = float(np.hypot(*(filt.estimate - np.array(robot.position))))
            state = "confident" if filt.is_confident else "searching"
            typer.echo(f"  step {k:4d}/{steps}: error {error:6.3f}  ({state})")

    return report


def kidnap_report(result: RunResult) -> str | None:
    """Where the robot was carried, and when (if ever) the filter found it again."""
    if result.kidnap_at is None or result.kidnap_position is None:
        return None
    x, y = result.kidnap_position
    steps = recovery_steps(result)
    found = f"re-localised {steps} steps later" if steps is not None else "not re-localised by the end"
    return f"kidnapped at step {result.kidnap_at} to ({x:.2f}, {y:.2f}): {found}"


def particle_count_report(result: RunResult) -> str:
    """The particle count per step (KLD-sampling): mean, least and most."""
    counts = result.extras["particle_count"]
    return f"particle count: mean {counts.mean():.0f}, least {counts.min()}, most {counts.max()}"


__all__ = [
    "kidnap_report",
    "particle_count_report",
    "progress_printer",
    "summarise",
]
