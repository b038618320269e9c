"""`mazelab exercise new DIR` (the student's files) and `mazelab exercise check FILE[:Class]` (the grade)."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Annotated

import typer

from mazelab.exercise.report import check as run_check
from mazelab.exercise.report import format_report
from mazelab.exercise.template import write_exercise
from mazelab.invocation import python_prefix
from mazelab.plugins import is_plugin_spec, load_plugin

exercise_app = typer.Typer(
    help="Write your own particle filter (new) and grade it against the exact posterior (check).",
    no_args_is_help=True,
    rich_markup_mode=None,
    pretty_exceptions_enable=False,
)


@exercise_app.command(short_help="Write the exercise (my_filter.py, README.md) into DIR.")
def new(
    folder: Annotated[Path, typer.Argument(metavar="DIR", help="the folder to write into (made if missing)")],
    force: Annotated[bool, typer.Option("--force", help="replace existing files")] = False,
) -> None:
    """Write my_filter.py (a StudentFilter with four parts to write) and a short README into DIR."""
    for path in write_exercise(folder, force):
        typer.echo(f"wrote {path}")
    typer.echo(f"Next: {python_prefix()} {folder / 'my_filter.py'}  (says which parts are still to write)")


@exercise_app.command(name="check", short_help="Grade FILE[:Class]: each part, then the whole filter.")
def check_command(
    spec: Annotated[str, typer.Argument(metavar="FILE[:Class]", help="the student's file, and its class if several")],
) -> None:
    """Check each part on seeded inputs and the whole filter against the exact grid posterior, with
    the shipped SIR's figures beside it; exit code 0 only when every row passes."""
    if not is_plugin_spec(spec):
        raise ValueError(f"{spec}: give a Python file, path/to/my_filter.py or path/to/my_filter.py:MyFilter")
    filter_class = load_plugin(spec)
    started = time.perf_counter()
    report = run_check(filter_class)
    typer.echo(format_report(report))
    typer.echo(f"checked in {time.perf_counter() - started:.1f} s")
    if not report.passed:
        raise typer.Exit(1)


__all__ = ["check_command", "exercise_app", "new"]
