"""compare's report: the table, the per-step errors (--csv), the lab's figure (--plot), the per-step
traces (--traces) and its JSON record (beside --csv, --plot or --traces)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import typer

from mazelab.atomic import write_text_atomically
from mazelab.cli.options import check_output_path
from mazelab.cli.outputs import check_one_file_each
from mazelab.cli.provenance import command_line
from mazelab.experiments.compare import comparison_table, errors_csv, plot_errors
from mazelab.experiments.record import Recorder, file_sha256, record_path
from mazelab.experiments.runs import final_error, mean_ess
from mazelab.experiments.traces import check_trace_path, compare_traces, write_traces
from mazelab.experiments.warmup import take_startup_seconds
from mazelab.simulation import RunResult


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
                "ms_per_step": 1e3 * float(result.step_seconds.mean()),
            }
            for name, result in results.items()
        ]
        recorder.finish("finished", summary=summary)
        recorder.write(record_file)
        typer.echo(f"the record (command, versions, scenario hash, summary) written to {record_file}")


__all__ = ["compare_record_file", "finish_compare", "report_compare", "start_compare_record"]
