"""What a run prints: its summary, the per-step progress, the kidnapping and the particle count."""

from __future__ import annotations

import sys
import time
from typing import Any

import numpy as np
import typer

from mazelab.experiments.kidnapping import recovery_steps
from mazelab.experiments.runs import FINAL_SHARE, final_error
from mazelab.maze import Maze
from mazelab.robot import Robot
from mazelab.simulation import RunResult


def summarise(result: RunResult) -> str:
    """A short report of a run: the last step's error, the last-20% error (the mean error over the last
    20% of the steps, what compare and study report), the convergence step and the seed."""
    errors = result.errors
    converged = result.converged_at
    when = f"converged at step {converged} (error < 0.5 from then on)" if converged else "not converged"
    return (
        f"{result.filter_name}: last-step error {errors[-1]:.3f}, last-{FINAL_SHARE:.0%} error "
        f"{final_error(errors):.3f}; {when}; seed {result.seed}"
    )


def report_run(result: RunResult) -> None:
    """The run's summary: the same text for the same seed (timings, which vary, are compare's and bench's)."""
    typer.echo(summarise(result))


def progress_printer(steps: int, every: int = 20) -> Any:
    """A per-step callback that prints the error every `every` steps."""

    def report(k: int, robot: Robot, filt: Any) -> None:
        if k % every == 0 or k == steps:
            error = float(np.hypot(*(filt.estimate - np.array(robot.position))))
            state = "confident" if filt.is_confident else "searching"
            typer.echo(f"  step {k:4d}/{steps}: error {error:6.3f}  ({state})")

    return report


LOOKUP_PROGRESS_CELLS = 2**18  # a nearest-station table this large takes seconds: say so while building it
GENERATE_PROGRESS_CELLS = 2**18  # generating a maze this large takes seconds (512 x 512)


def prepare_world(world: Maze, min_cells: int = LOOKUP_PROGRESS_CELLS) -> Maze:
    """Build a large maze's nearest-station table up front, with a progress line on stderr (a 1000 x
    1000 maze takes tens of seconds); a small maze's table is built on first use, silently."""
    if world.lookup_cells >= min_cells and not world.has_lookup:
        world.prepare(ProgressLine(f"building the nearest-station table of {world.source}"))
    return world


def generation_progress(rows: int, columns: int) -> ProgressLine | None:
    """A progress line for generating a large maze (None for a small one, made in a blink)."""
    return ProgressLine(f"generating a {rows}x{columns} maze") if rows * columns >= GENERATE_PROGRESS_CELLS else None


class ProgressLine:
    """progress(done, total) as one line on stderr: redrawn in place on a terminal, else a line at the
    start and one at the end (a log file gets no carriage returns)."""

    def __init__(self, what: str):
        self.what = what
        self.started = time.perf_counter()
        self.shown = -1  # the last percentage drawn
        self.terminal = sys.stderr.isatty()
        typer.echo(f"{what} ...", err=True, nl=not self.terminal)

    def __call__(self, done: int, total: int) -> None:
        percent = 100 * done // max(total, 1)
        if done == total:
            seconds = time.perf_counter() - self.started
            start = "\r" if self.terminal else ""
            typer.echo(f"{start}{self.what}: done in {seconds:.1f} s", err=True)
        elif self.terminal and percent != self.shown:
            typer.echo(f"\r{self.what}: {percent}%", err=True, nl=False)
        self.shown = percent


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
    "GENERATE_PROGRESS_CELLS",
    "LOOKUP_PROGRESS_CELLS",
    "ProgressLine",
    "generation_progress",
    "kidnap_report",
    "particle_count_report",
    "prepare_world",
    "progress_printer",
    "report_run",
    "summarise",
]
