"""`mazelab exercise new DIR` (the student's files), `mazelab exercise check FILE[:Class]` (one grade)
and `mazelab exercise grade DIR` (a folder of them)."""

from __future__ import annotations

import contextlib
import signal
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Annotated

import typer

from mazelab.atomic import write_bytes_atomically, write_text_atomically
from mazelab.cli.options import UserError, check_output_path, seed_option
from mazelab.exercise.autograder import BundleError, bundle_bytes
from mazelab.exercise.claims import check_outside, claimed
from mazelab.exercise.grading import (
    Graded,
    GradingInterruptedError,
    Submission,
    csv_text,
    discover,
    grade_folder,
    gradescope_json,
    summary,
)
from mazelab.exercise.language import Catalogue, catalogue_for
from mazelab.exercise.layout import format_report
from mazelab.exercise.report import NotGradableError, check_file
from mazelab.exercise.runner import DEFAULT_TIMEOUT, MAX_TIMEOUT
from mazelab.exercise.sandbox import SandboxRequiredError, require_sandbox
from mazelab.exercise.template import write_exercise
from mazelab.invocation import python_prefix
from mazelab.plugins import is_plugin_spec

exercise_app = typer.Typer(
    help="Write your own filter (new), grade it (check), a class's folder (grade), on Gradescope (autograder).",
    short_help="Your own filter: write it, grade it, grade a class.",
    no_args_is_help=True,
    rich_markup_mode=None,
    pretty_exceptions_enable=False,
)
SeedFlag = Annotated[
    int | None,
    typer.Option(callback=seed_option, help="the inputs' seed (default: from the file's content)", show_default=False),
]
TimeoutFlag = Annotated[
    float,
    typer.Option(
        min=1.0, max=MAX_TIMEOUT, help="seconds each run of the student's process may take before it is stopped"
    ),
]
ForceFlag = Annotated[bool, typer.Option("--force", help="replace existing output files")]
GradescopeFlag = Annotated[
    Path | None, typer.Option(metavar="DIR", help="write Gradescope's results.json there", show_default=False)
]


@exercise_app.command(short_help="Write the exercise (my_filter.py, README.md) into DIR.")
def new(
    folder: Annotated[Path, typer.Argument(metavar="DIR", help="the folder to write into (made if missing)")],
    force: Annotated[bool, typer.Option("--force", help="replace existing files")] = False,
) -> None:
    """Write my_filter.py (a StudentFilter with four parts to write) and a short README into DIR."""
    for path in write_exercise(folder, force):
        typer.echo(f"wrote {path}")
    typer.echo(f"Next: {python_prefix()} {folder / 'my_filter.py'}  (says which parts are still to write)")


RequireSandboxFlag = Annotated[
    bool,
    typer.Option("--require-sandbox", help="refuse to grade where no sandbox can be made (bubblewrap on Linux)"),
]
LangFlag = Annotated[
    str | None,
    typer.Option(metavar="LANG", help="the report's language: en or uk (default: the locale's)", show_default=False),
]


@exercise_app.command(name="check", short_help="Grade FILE[:Class]: each part, then the whole filter.")
def check_command(
    spec: Annotated[str, typer.Argument(metavar="FILE[:Class]", help="the student's file, and its class if several")],
    seed: SeedFlag = None,
    timeout: TimeoutFlag = DEFAULT_TIMEOUT,
    gradescope: GradescopeFlag = None,
    force: ForceFlag = False,
    require_sandbox: RequireSandboxFlag = False,
    lang: LangFlag = None,
) -> None:
    """Check each part on fresh inputs and the whole filter against the exact grid posterior, with the
    shipped SIR's figures beside it. The student's code runs in a sandbox of its own with a time
    limit; exit code 0 only when every row passes, 1 when one does not, 2 when the file cannot be
    checked (it does not import, has no such class, or the class is not a StudentFilter): then
    --gradescope writes a results.json of score 0 saying why."""
    if not is_plugin_spec(spec):
        raise ValueError(f"{spec}: give a Python file, path/to/my_filter.py or path/to/my_filter.py:MyFilter")
    catalogue = _catalogue(lang)
    results = _gradescope_file(gradescope, force)
    _sandbox_or_refuse(require_sandbox)
    started = time.perf_counter()
    try:
        with _stop_signals() as stop:
            report = check_file(spec, seed=seed, timeout=timeout)
    except KeyboardInterrupt:  # Ctrl-C or SIGTERM: the student's process has been ended with its sandbox
        typer.echo("stopped: nothing graded", err=True)
        raise typer.Exit(128 + (stop.number or signal.SIGINT)) from None
    except NotGradableError as error:
        if results is not None:
            graded = Graded(Submission(Path(spec).name, None), None, str(error), time.perf_counter() - started)
            write_text_atomically(results, gradescope_json(graded, catalogue), replace=force)
        raise UserError(str(error)) from None
    note = (
        catalogue.gettext(" (given)")
        if seed is not None
        else catalogue.gettext(" (from the file; --seed {seed} repeats it)").format(seed=report.seed)
    )
    typer.echo(format_report(report, seed_note=note, catalogue=catalogue))
    typer.echo(f"checked in {time.perf_counter() - started:.1f} s")
    if results is not None:
        graded = Graded(Submission(Path(spec).name, Path(spec)), report, None, report.seconds)
        write_text_atomically(results, gradescope_json(graded, catalogue), replace=force)
    if not report.passed:
        raise typer.Exit(1)


def _catalogue(lang: str | None) -> Catalogue:
    try:
        return catalogue_for(lang)
    except ValueError as error:
        raise UserError(f"--lang {lang}: {error}") from None


def _sandbox_or_refuse(required: bool) -> None:
    if required:
        try:
            require_sandbox()
        except SandboxRequiredError as error:
            raise UserError(str(error)) from None


def _make_folder(folder: Path) -> None:
    """--gradescope's folder, made when it is missing (as `mkdir -p`); a file of that name is one line."""
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except (FileExistsError, NotADirectoryError):
        raise UserError(f"--gradescope {folder}: not a folder") from None
    except OSError as error:
        raise UserError(f"--gradescope {folder}: cannot make the folder ({error.strerror})") from None


def _gradescope_file(folder: Path | None, force: bool) -> Path | None:
    if folder is None:
        return None
    _make_folder(folder)
    check_output_path(folder / "results.json", force)
    return folder / "results.json"


@exercise_app.command(name="grade", short_help="Grade every submission in DIR, in parallel.")
def grade_command(
    folder: Annotated[Path, typer.Argument(metavar="DIR", help="one subfolder or one .py file per submission")],
    seed: Annotated[
        int | None,
        typer.Option(
            callback=seed_option,
            help="one seed for every submission (kept from the students; the exact runs are then shared)",
            show_default=False,
        ),
    ] = None,
    timeout: TimeoutFlag = DEFAULT_TIMEOUT,
    jobs: Annotated[int | None, typer.Option(min=1, help="submissions at once (default: the cores)")] = None,
    csv_path: Annotated[
        Path | None, typer.Option("--csv", metavar="F", help="one row per submission", show_default=False)
    ] = None,
    gradescope: GradescopeFlag = None,
    force: ForceFlag = False,
    quiet: Annotated[bool, typer.Option("--quiet", help="no progress bar")] = False,
    require_sandbox: RequireSandboxFlag = False,
    lang: LangFlag = None,
) -> None:
    """Check every submission of DIR (each in a sandbox of its own, with the time limit), several at
    once, then print a summary table; --csv writes a row per submission, --gradescope a results.json
    per submission (DIR/NAME/results.json), both outside DIR. Exit code 0 when every submission was
    checked, whatever its grade; Ctrl-C or SIGTERM ends every sandbox and keeps what was graded."""
    catalogue = _catalogue(lang)
    submissions = discover(folder)
    outputs = [(path, option) for path, option in ((csv_path, "--csv"), (gradescope, "--gradescope")) if path]
    for path, option in outputs:
        check_outside(path, folder, option)
    if csv_path is not None:
        check_output_path(csv_path, force)
    targets = _gradescope_targets(gradescope, submissions, force)
    _sandbox_or_refuse(require_sandbox)
    from mazelab.experiments.executor import progress_bar

    started, stopped_by = time.perf_counter(), None
    with claimed(outputs), _stop_signals() as stop:
        try:
            with progress_bar(len(submissions), not quiet, what="submissions") as advance:
                graded = grade_folder(submissions, seed=seed, timeout=timeout, jobs=jobs, on_done=lambda _: advance())
        except GradingInterruptedError as stopped_early:
            graded, stopped_by = stopped_early.graded, stop.number or signal.SIGINT
        typer.echo(summary(graded))
        typer.echo(f"graded in {time.perf_counter() - started:.1f} s")
        if csv_path is not None:
            typer.echo(f"wrote {write_text_atomically(csv_path, csv_text(graded), replace=force)}")
        for one in graded:
            target = targets.get(one.submission.name)
            if target is not None:
                target.parent.mkdir(exist_ok=True)
                write_text_atomically(target, gradescope_json(one, catalogue), replace=True)  # refused above if there
        if targets:
            typer.echo(f"wrote {sum(one.submission.name in targets for one in graded)} results.json under {gradescope}")
    if stopped_by is not None:
        typer.echo(f"stopped: {len(graded)} of {len(submissions)} submissions graded (written above)", err=True)
        raise typer.Exit(128 + stopped_by)


def _gradescope_targets(gradescope: Path | None, submissions: list[Submission], force: bool) -> dict[str, Path]:
    """Each submission's results.json under --gradescope (an existing one refused without --force)."""
    if gradescope is None:
        return {}
    _make_folder(gradescope)
    targets = {}
    for submission in submissions:
        target = gradescope / submission.name / "results.json"
        if target.exists() and not force:
            raise UserError(f"{target} exists; use --force to replace it")
        targets[submission.name] = target
    return targets


@exercise_app.command(name="autograder", short_help="Write Gradescope's autograder bundle (a .zip).")
def autograder_command(
    bundle: Annotated[Path, typer.Argument(metavar="OUT.zip", help="the bundle to write")],
    seed: Annotated[
        int | None,
        typer.Option(callback=seed_option, help="one secret seed for every submission", show_default=False),
    ] = None,
    timeout: TimeoutFlag = DEFAULT_TIMEOUT,
    lang: LangFlag = None,
    force: ForceFlag = False,
) -> None:
    """Write the zip to upload as Gradescope's autograder: setup.sh (bubblewrap, and this lab at this
    version with its locked dependencies) and run_autograder (the check of
    /autograder/submission/my_filter.py, its results.json in /autograder/results)."""
    if bundle.suffix != ".zip":
        raise UserError(f"{bundle}: the bundle is a .zip file (OUT.zip)")
    if lang is not None:
        _catalogue(lang)
    check_output_path(bundle, force)
    try:
        data = bundle_bytes(seed, lang, timeout)
    except BundleError as error:
        raise UserError(str(error)) from None
    typer.echo(f"wrote {write_bytes_atomically(bundle, data, replace=force)} (upload it as the autograder)")


class _Stop:
    """The signal that stopped the grading (None: none yet)."""

    number: int | None = None


@contextlib.contextmanager
def _stop_signals() -> Iterator[_Stop]:
    """SIGTERM and SIGHUP stop the grading as Ctrl-C does (the main thread's wait is interrupted, every
    sandbox ended, what was graded kept); a second one while stopping changes nothing."""
    stop = _Stop()
    if threading.current_thread() is not threading.main_thread():
        yield stop
        return

    def handler(number: int, frame: object) -> None:
        if stop.number is None:
            stop.number = number
            raise KeyboardInterrupt

    wanted = [getattr(signal, name) for name in ("SIGINT", "SIGTERM", "SIGHUP") if hasattr(signal, name)]
    previous = {number: signal.signal(number, handler) for number in wanted}
    try:
        yield stop
    finally:
        for number, old in previous.items():
            signal.signal(number, old)


__all__ = ["autograder_command", "check_command", "exercise_app", "grade_command", "new"]
