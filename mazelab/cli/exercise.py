"""`mazelab exercise new DIR` (the student's files), `mazelab exercise check FILE[:Class]` (one grade),
`mazelab exercise grade DIR` (a folder of them) and `mazelab exercise autograder OUT.zip` (Gradescope)."""

from __future__ import annotations

import functools
import secrets
import signal
import time
from collections.abc import Callable
from pathlib import Path
from typing import Annotated, Any

import typer

from mazelab.atomic import write_atomically
from mazelab.cli.options import Force, UserError, check_outputs, opt, seed_option
from mazelab.exercise.grading import (
    KEY_FILE,
    Gradebook,
    Submission,
    discover,
    grade_folder,
    grade_one,
    gradescope_json,
    partial_name,
    read_key,
    summary,
)
from mazelab.exercise.report import format_report
from mazelab.exercise.sandbox import DEFAULT_BUDGET, MAX_TIMEOUT, SandboxError, sandbox
from mazelab.exercise.template import Catalogue, bundle_bytes, catalogue_for, write_exercise
from mazelab.invocation import python_prefix
from mazelab.registry import is_plugin_spec, split_spec
from mazelab.stops import STOP_SIGNALS, signal_handlers

exercise_app = typer.Typer(
    help="Write your own filter (new), grade it (check), a class's folder (grade), on Gradescope (autograder).",
    short_help="Your own filter: write it, grade it, grade a class.",
    no_args_is_help=True,
    rich_markup_mode=None,
    pretty_exceptions_enable=False,
)
TimeoutFlag = opt(
    float, min=1.0, max=MAX_TIMEOUT, help="seconds the student's processes of one submission may take in all"
)
GradescopeFlag = opt(Path | None, metavar="DIR", help="write Gradescope's results.json there", show_default=False)
RequireSandboxFlag = opt(
    bool, "--require-sandbox", help="refuse to grade where no sandbox can be made (bubblewrap on Linux)"
)
LangFlag = opt(
    str | None, metavar="LANG", show_default=False, help="en or uk (default: the exercise file's, else the locale's)"
)
KeyFlag = opt(
    Path | None,
    metavar="FILE",
    show_default=False,
    help=f"the grader's secret key (default: {KEY_FILE} beside the outputs)",
)


@exercise_app.command(short_help="Write the exercise (my_filter.py, README.md) into DIR.")
def new(
    folder: Annotated[Path, typer.Argument(metavar="DIR", help="the folder to write into (made if missing)")],
    force: opt(bool, "--force", help="replace existing files") = False,
    lang: opt(str, metavar="LANG", help="the exercise's language: en or uk") = "en",
) -> None:
    """Write my_filter.py (a StudentFilter with four parts to write) and a short README into DIR, in
    LANG; my_filter.py keeps its language, so that its checks answer in it."""
    for path in write_exercise(folder, force, _catalogue(lang).language):
        typer.echo(f"wrote {path}")
    typer.echo(f"Next: {python_prefix()} {folder / 'my_filter.py'}  (says which parts are still to write)")


@exercise_app.command(name="check", short_help="Grade FILE[:Class]: each part, then the whole filter.")
def check_command(
    spec: Annotated[str, typer.Argument(metavar="FILE[:Class]", help="the student's file, and its class if several")],
    seed: opt(
        int | None, callback=seed_option, show_default=False, help="the inputs' seed (default: from the files)"
    ) = None,
    key: KeyFlag = None,
    timeout: TimeoutFlag = DEFAULT_BUDGET,
    gradescope: GradescopeFlag = None,
    force: Force = False,
    require_sandbox: RequireSandboxFlag = False,
    lang: LangFlag = None,
) -> None:
    """Check each part on fresh inputs and the whole filter against the exact grid posterior, with the
    shipped SIR's figures beside it. The student's code runs in a sandbox of its own within the time
    budget; exit code 0 only when every row passes, 1 when one does not, 2 when the file cannot be
    checked (it does not import, has no such class, or the class is not a StudentFilter): then
    --gradescope writes a results.json of score 0 saying why. With --key (the grader's, as the
    Gradescope bundle runs it) the inputs are secret: no report shows them."""
    if not is_plugin_spec(spec):
        raise ValueError(f"{spec}: give a Python file, path/to/my_filter.py or path/to/my_filter.py:MyFilter")
    catalogue = _catalogue(lang, split_spec(spec)[0])
    if seed is not None and key is not None:
        raise UserError("--seed and --key: give one (a seed repeats a report, the key draws secret inputs)")
    secret = read_key(key, make=False) if key is not None else None  # a ValueError of one line, exit 2
    results = None if gradescope is None else _made_folder(gradescope) / "results.json"
    if results is not None:
        check_outputs([("--gradescope", results)], force)
    _sandbox_or_refuse(require_sandbox)
    submission = Submission(Path(spec).name, Path(spec), own_folder=True)  # the files beside it are its own
    graded = functools.partial(grade_one, submission, timeout, seed=seed, key=secret)
    report, stopped_by = _until_stopped(graded, "nothing graded (the grader's machine, not the submission)")
    if stopped_by is not None:  # Ctrl-C or SIGTERM: the student's process has been ended with its sandbox
        typer.echo("stopped: nothing graded", err=True)
        raise typer.Exit(128 + stopped_by)
    if report.problem is None:
        typer.echo(format_report(report, catalogue=catalogue))
        took = {"seconds": f"{report.seconds:.1f}", "student": f"{report.student_seconds:.1f}"}
        line = catalogue.gettext("checked in {seconds} s (the student's processes: {student} s)").format(**took)
        typer.echo(catalogue.numbers(line))
    if results is not None:  # score 0 and why for a file that cannot be checked
        write_atomically(results, gradescope_json(report, catalogue), replace=force)
    if report.problem is not None:
        typer.echo(catalogue.numbers(catalogue.gettext("error: ") + catalogue.translate(report.problem)), err=True)
        raise typer.Exit(2)
    if not report.passed:
        raise typer.Exit(1)


def _catalogue(lang: str | None, file: Path | None = None) -> Catalogue:
    try:
        return catalogue_for(lang, file)
    except ValueError as error:
        raise UserError(f"--lang {lang}: {error}") from None


def _sandbox_or_refuse(required: bool) -> None:
    """--require-sandbox: one line saying why where no sandbox can be made."""
    if required and not sandbox().sandboxed:
        raise UserError(f"--require-sandbox: {sandbox().why}")


def _made_folder(folder: Path) -> Path:
    """--gradescope's folder, made when it is missing (as `mkdir -p`); a file of that name is one line."""
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except (FileExistsError, NotADirectoryError):
        raise UserError(f"--gradescope {folder}: not a folder") from None
    except OSError as error:
        raise UserError(f"--gradescope {folder}: cannot make the folder ({error.strerror})") from None
    return folder


@exercise_app.command(name="grade", short_help="Grade every submission in DIR, in parallel.")
def grade_command(
    folder: Annotated[Path, typer.Argument(metavar="DIR", help="one subfolder or one .py file per submission")],
    key: KeyFlag = None,
    timeout: TimeoutFlag = DEFAULT_BUDGET,
    jobs: opt(int | None, min=1, help="submissions at once (default: the cores)") = None,
    csv_path: opt(Path | None, "--csv", metavar="F", help="one row per submission", show_default=False) = None,
    gradescope: GradescopeFlag = None,
    force: Force = False,
    quiet: opt(bool, "--quiet", help="no progress bar") = False,
    require_sandbox: RequireSandboxFlag = False,
    lang: LangFlag = None,
) -> None:
    """Check every submission of DIR (each in a sandbox of its own, within the time budget), several
    at once, on inputs from the grader's secret key; then print a summary table. --csv writes a row
    per submission, --gradescope a results.json per submission (DIR/NAME/results.json), each as soon
    as it is graded, all outside DIR. Exit code 0 when every submission was checked, whatever its
    grade; Ctrl-C or SIGTERM ends every sandbox and keeps what was graded (the CSV as F.partial.csv,
    beside the last complete one)."""
    catalogue, submissions = _catalogue(lang), discover(folder)
    outputs = [(path, option) for path, option in ((csv_path, "--csv"), (gradescope, "--gradescope")) if path]
    keyfile = key or next((p.parent / KEY_FILE if o == "--csv" else p / KEY_FILE for p, o in outputs), None)
    _check_outputs(folder, submissions, csv_path, gradescope, keyfile, force)
    _sandbox_or_refuse(require_sandbox)
    secret = read_key(keyfile) if keyfile else secrets.token_bytes(32)
    book, started = Gradebook(csv_path, gradescope, force, catalogue), time.perf_counter()
    grade = functools.partial(
        grade_folder,
        submissions,
        key=secret,
        timeout=timeout,
        jobs=jobs,
        on_done=book.add,
        claims=outputs,
        progress=not quiet,
    )
    graded, stopped_by = _until_stopped(grade, "grading stopped, nobody graded by it")  # a stop: book.graded so far
    typer.echo(summary(book.graded))
    typer.echo(f"graded in {time.perf_counter() - started:.1f} s")
    if not keyfile:
        typer.echo("inputs from a new secret key, not kept (give --key FILE, --csv or --gradescope to keep it)")
    if book.gradescope is not None:
        typer.echo(f"wrote {len(book.graded)} results.json under {gradescope}")
    if stopped_by is not None:
        kept = f"; the rows so far are in {partial_name(csv_path)}" if csv_path is not None and book.graded else ""
        typer.echo(f"stopped: {len(book.graded)} of {len(submissions)} submissions graded{kept}", err=True)
        raise typer.Exit(128 + stopped_by)
    if csv_path is not None:
        typer.echo(f"wrote {book.finish(graded)}")


def _check_outputs(
    folder: Path,
    submissions: list[Submission],
    csv_path: Path | None,
    gradescope: Path | None,
    keyfile: Path | None,
    force: bool,
) -> None:
    """Refuse, before any grading, an output or the key inside the class folder, an existing output
    without --force, and a --csv that a submission's results.json folder would take."""
    for path, option in ((csv_path, "--csv"), (gradescope, "--gradescope"), (keyfile, "--key")):
        if path is not None and path.resolve().is_relative_to(folder.resolve()):  # or the folder itself
            raise UserError(
                f"{option} {path}: inside the class folder {folder}; write the grader's outputs outside "
                "it (a submission must not see them, nor be replaced by them)"
            )
    if gradescope is not None:
        _made_folder(gradescope)
        taken = [s.name for s in submissions if (gradescope / s.name / "results.json").exists()]
        if taken and not force:
            raise UserError(f"{gradescope / taken[0] / 'results.json'} exists; use --force to replace it")
    if csv_path is not None:
        check_outputs([("--csv", csv_path)], force)
        check_outputs([("--csv", partial_name(csv_path))], True)
        mine = (csv_path.name, partial_name(csv_path).name)
        clash = [s.name for s in submissions if gradescope == csv_path.parent and s.name in mine]
        if clash:
            raise UserError(f"--csv {csv_path}: a submission's results.json folder would be {gradescope / clash[0]}")


@exercise_app.command(name="autograder", short_help="Write Gradescope's autograder bundle (a .zip).")
def autograder_command(
    bundle: Annotated[Path, typer.Argument(metavar="OUT.zip", help="the bundle to write")],
    key: opt(
        Path | None,
        metavar="FILE",
        show_default=False,
        help="the grader's secret key (default: a new one, in the bundle)",
    ) = None,
    timeout: TimeoutFlag = DEFAULT_BUDGET,
    lang: LangFlag = None,
    force: Force = False,
) -> None:
    """Write the zip to upload as Gradescope's autograder: setup.sh (bubblewrap, and this lab at this
    version with its pinned dependencies), the secret key (read only by the grader), and run_autograder
    (the check of /autograder/submission/my_filter.py, its results.json in /autograder/results)."""
    if bundle.suffix != ".zip":
        raise UserError(f"{bundle}: the bundle is a .zip file (OUT.zip)")
    if lang is not None:
        _catalogue(lang)
    secret = read_key(key, make=False) if key is not None else secrets.token_bytes(32)
    check_outputs([("OUT.zip", bundle)], force)
    data = bundle_bytes(secret, lang, timeout)  # a BundleError is one line, exit 2
    typer.echo(f"wrote {write_atomically(bundle, data, replace=force)} (upload it as the autograder)")


def _until_stopped(work: Callable[[], Any], graded: str) -> tuple[Any, int | None]:
    """`work()` with SIGTERM and SIGHUP stopping it as Ctrl-C does (the main thread's wait is interrupted,
    every sandbox ended, what was graded kept; a second signal while stopping changes nothing): its
    result and None, or None and the number of the signal that stopped it. A sandbox that cannot start is
    one line, `graded` saying what was graded."""
    stopped: list[int] = []

    def handler(number: int, frame: object) -> None:
        if not stopped:
            stopped.append(number)
            raise KeyboardInterrupt

    try:
        with signal_handlers(STOP_SIGNALS, handler):
            return work(), None
    except KeyboardInterrupt:
        return None, (stopped or [signal.SIGINT])[0]
    except SandboxError as error:
        raise UserError(f"{error}; {graded}") from None


__all__ = ["autograder_command", "check_command", "exercise_app", "grade_command", "new"]
