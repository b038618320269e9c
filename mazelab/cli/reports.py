"""What the commands print and write: a run's summary, per-step progress, kidnapping and particle count;
compare's table, per-step errors (--csv), figure (--plot), traces (--traces) and its JSON record (beside
its first output)."""

from __future__ import annotations

import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import typer

from mazelab.atomic import write_text_atomically
from mazelab.cli.options import check_one_file_each, check_output_path
from mazelab.cli.provenance import command_line
from mazelab.experiments.compare import comparison_table, errors_csv, plot_errors
from mazelab.experiments.kidnapping import recovery_steps
from mazelab.experiments.record import Recorder, file_sha256, record_path
from mazelab.experiments.runs import FINAL_SHARE, final_error, mean_ess
from mazelab.experiments.study import final_log_evidence
from mazelab.experiments.traces import check_trace_path, compare_traces, write_traces
from mazelab.experiments.warmup import take_startup_seconds
from mazelab.maze import Maze
from mazelab.registry import evidence_caveat
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


# -- compare's outputs ------------------------------------------------------------------------------------
def compare_record_file(
    csv_path: Path | None, plot: Path | None, traces: Path | None, force: bool, rrd: Path | None = None
) -> Path | None:
    """Where compare's record goes (beside its first output), checked like the outputs; the traces'
    format checked too; two outputs that are one file refused first, in one line naming both."""
    path = next((record_path(p) for p in (csv_path, plot, traces) if p is not None), None)
    check_one_file_each(
        [("--csv", csv_path), ("--plot", plot), ("--traces", traces), ("--rrd", rrd), ("the record", path)]
    )
    if traces is not None:
        check_output_path(traces, force)
        check_trace_path(traces)
    if path is not None:
        check_output_path(path, force)
    return path


def start_compare_record(scenario: Path, parameters: dict[str, Any]) -> Recorder:
    """The record of a compare, started before its runs."""
    return Recorder("compare", command_line(), {**parameters, "scenario": str(scenario)},
                    scenario_sha256=file_sha256(scenario))  # fmt: skip


def report_compare(
    results: dict[str, RunResult], *, kld: bool, csv_path: Path | None, plot: Path | None, title: str, force: bool
) -> None:
    """The kidnapping (if any), the table, then the per-step errors and the figure."""
    kidnapping = next(iter(results.values()))
    if kidnapping.kidnap_at is not None and kidnapping.kidnap_position is not None:
        x, y = kidnapping.kidnap_position
        typer.echo(f"kidnapped at step {kidnapping.kidnap_at} to ({x:.2f}, {y:.2f})")
    typer.echo(comparison_table(results, kld=kld, startup_seconds=take_startup_seconds()))
    if csv_path is not None:
        write_text_atomically(csv_path, errors_csv(results), replace=force)
        typer.echo(f"per-step errors written to {csv_path}")
    if plot is not None:
        plot_errors(results, plot, title, replace=force)
        typer.echo(f"figure written to {plot}")


def finish_compare(
    results: dict[str, RunResult],
    seed: int,
    traces: Path | None,
    recorder: Recorder,
    record_file: Path | None,
    maze: str | None = None,
) -> None:
    """Write the traces (with the scenario's `maze`, sigma, delta and particle count) and the record
    (with each filter's figures)."""
    if traces is not None:
        write_traces(traces, compare_traces(results, seed, maze))
        typer.echo(f"per-step traces written to {traces}")
    if record_file is not None:
        summary = [
            {
                "filter": name,
                "mean_error": float(result.errors.mean()),
                "final_error": final_error(result.errors),
                "converged_at": result.converged_at,
                "mean_ess": mean_ess(result),
                "log_evidence": final_log_evidence(result),
                "log_evidence_caveat": evidence_caveat(name),
                "ms_per_step": 1e3 * float(result.step_seconds.mean()),
                "backend": result.extras.get("backend"),
            }
            for name, result in results.items()
        ]
        recorder.finish("finished", summary=summary)
        recorder.write(record_file)
        typer.echo(f"the record (command, versions, scenario hash, summary) written to {record_file}")


__all__ = [
    "GENERATE_PROGRESS_CELLS",
    "LOOKUP_PROGRESS_CELLS",
    "ProgressLine",
    "compare_record_file",
    "finish_compare",
    "generation_progress",
    "kidnap_report",
    "particle_count_report",
    "prepare_world",
    "progress_printer",
    "report_compare",
    "report_run",
    "start_compare_record",
    "summarise",
]
