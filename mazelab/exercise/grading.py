"""Grading a folder of submissions (docs/exercise.md, "Grading a folder"): each one checked in child
processes of its own (mazelab.exercise.report.check_file), several at once, the grader's reference runs
in a pool of worker processes, its CSV row and results.json written as soon as it is graded, and a
summary. Nothing one submission does spoils another's row; only a sandbox that cannot start stops the
grading. The inputs come from the grader's secret key (`KEY_FILE`); the outputs lie outside the class
folder, claimed by one grader at a time, the CSV growing as `NAME.partial.csv` until the end.
"""

from __future__ import annotations

import contextlib
import csv
import io
import json
import multiprocessing
import os
import secrets
import signal
import textwrap
import threading
import time
from collections.abc import Callable, Iterator
from concurrent.futures import Executor, ProcessPoolExecutor, ThreadPoolExecutor
from pathlib import Path
from typing import Any

from mazelab.atomic import WriteError, write_atomically
from mazelab.backend import use_threads
from mazelab.exercise.parts import FAIL, NOT_OWN, NOT_RUN, NOT_WRITTEN, PASS, SHOWN, clean
from mazelab.exercise.report import ROWS, NotGradableError, Report, Submission, check_file, format_report
from mazelab.exercise.sandbox import DEFAULT_BUDGET, SandboxError, allow_children, stop_children
from mazelab.exercise.student import PARTS
from mazelab.exercise.template import FILTER_FILE, Catalogue
from mazelab.experiments.journal import JournalError, claim_outputs

KEY_FILE = ".grading.key"  # hidden: no submission has its name (grading skips names that start with ".")
KEY_BYTES = 32  # 256 bits; a given key needs at least 16 (128 bits)
ROW_NAMES = tuple(ROWS.values())
CSV_COLUMNS = (
    "submission",
    "file",
    *PARTS,
    "whole_filter",
    "farther_on",
    "to_exact",
    "sir_to_exact",
    "converged",
    "sir_converged",
    "seconds",
    "problem",
)
SHORT = {PASS: "pass", FAIL: "FAIL", NOT_WRITTEN: "todo", NOT_RUN: "-", NOT_OWN: "REF", None: "-"}


def discover(folder: Path) -> list[Submission]:
    """The submissions in `folder`, by name: a link is refused (named), and a file that is not Python."""
    if not folder.exists():
        raise ValueError(f"{folder}: no such folder of submissions (check the path)")
    if not folder.is_dir():
        raise ValueError(f"{folder}: not a folder; grade one file with `exercise check {folder}`")
    found = []
    for entry in sorted(folder.iterdir(), key=lambda p: p.name):
        if entry.name.startswith((".", "_")) or not (entry.is_dir() or entry.suffix == ".py" or entry.is_symlink()):
            continue
        if entry.is_symlink():
            why = f"{entry}: a link (to {os.readlink(entry)}), not a submission; not graded (what it leads to is "
            found.append(Submission(entry.name, None, why + "graded under its own name)"))
        elif entry.is_dir():
            found.append(_in_folder(entry))
        else:
            found.append(Submission(entry.name, entry))
    if not found:
        raise ValueError(f"{folder}: no submissions (a subfolder or a .py file each)")
    return found


def _in_folder(folder: Path) -> Submission:
    """A subfolder's file: its my_filter.py, else its only Python file, else the only one that mentions
    StudentFilter; a link there is refused (never read: it could lead to a pipe or another's file)."""
    if (folder / FILTER_FILE).is_symlink():
        return Submission(folder.name, None, f"{folder / FILTER_FILE}: a link, not the student's own file; not graded")
    files = sorted(p for p in folder.glob("*.py") if p.is_file() and not p.is_symlink() and p.name[0] not in "._")
    if (folder / FILTER_FILE) in files:
        files = [folder / FILTER_FILE]
    if len(files) > 1:
        files = [p for p in files if "StudentFilter" in p.read_text(errors="replace")] or files
    if len(files) == 1:
        return Submission(folder.name, files[0], own_folder=True)
    if not files:
        return Submission(folder.name, None, f"{folder}: no Python file to grade")
    names = ", ".join(p.name for p in files[:5])
    return Submission(folder.name, None, f"{folder}: which file? {names} (call the one to grade {FILTER_FILE})")


def grade_one(submission: Submission, timeout: float, references: Executor | None = None, **inputs: Any) -> Report:
    """Check one submission (`exercise check`'s, or one of a class's), its inputs from `inputs` (the
    key, or a seed: check_file): never raises for the submission, nor for the grader's own failure on
    it (its row says so); only a sandbox that cannot start (SandboxError) and a stop propagate."""
    started, problem = time.perf_counter(), submission.problem
    if submission.file is not None:
        try:
            file, own = str(submission.file), submission.own_folder
            report = check_file(file, timeout=timeout, references=references, companions=own, **inputs)
            report.submission = submission
            return report
        except NotGradableError as error:
            problem = str(error)
        except SandboxError:  # the grader's machine: no one's row (a stop is no Exception: it passes too)
            raise
        except Exception as error:  # the grader's own failure on this submission: its row, not the class's
            problem = f"the grader could not check it: {type(error).__name__}: {error}"
    return Report(submission.name, None, submission=submission, problem=problem, seconds=time.perf_counter() - started)


def _quiet_thread() -> None:
    """A grading thread blocks the stop signals: the main thread takes them, and the processes this
    thread starts (the reference runs' workers) inherit the mask, so Ctrl-C never prints their tracebacks."""
    signal.pthread_sigmask(signal.SIG_BLOCK, [signal.SIGINT, signal.SIGTERM, signal.SIGHUP])


def grade_folder(
    submissions: list[Submission],
    *,
    key: bytes,
    timeout: float = DEFAULT_BUDGET,
    jobs: int | None = None,
    on_done: Callable[[Report], None] | None = None,
    claims: list[tuple[Path, str]] | None = None,
    progress: bool = False,
) -> list[Report]:
    """Grade the submissions, `jobs` at a time (default: the cores), in their order, calling `on_done`
    with each as soon as it is graded, the outputs `claims` ((path, option) each) held meanwhile
    (`claimed`), under a progress bar on stderr where `progress`. Ctrl-C (a KeyboardInterrupt), SIGTERM
    and a sandbox that cannot start end every child and the reference runs, and propagate: what
    `on_done` was given is kept."""
    from mazelab.experiments.executor import progress_bar

    jobs, lock = jobs or os.cpu_count() or 1, threading.Lock()
    methods = multiprocessing.get_all_start_methods()  # a fresh interpreter each, never a fork of threads
    context = multiprocessing.get_context("forkserver" if "forkserver" in methods else "spawn")
    bar = progress_bar(len(submissions), progress, what="submissions")
    with claimed(claims or []), use_threads(1), bar as advance:  # use_threads(1): a submission is a thread
        allow_children()
        pool = ProcessPoolExecutor(jobs, context)

        def one(submission: Submission) -> Report:
            graded = grade_one(submission, timeout, pool, key=key)
            with lock:
                if on_done is not None:
                    on_done(graded)
                advance()
            return graded

        threads = ThreadPoolExecutor(jobs, "mazelab-grade", initializer=_quiet_thread if os.name == "posix" else None)
        futures = [threads.submit(one, submission) for submission in submissions]
        try:
            return [future.result() for future in futures]
        except BaseException:  # the waiting ones are cancelled below
            stop_children()
            for process in list((getattr(pool, "_processes", None) or {}).values()):
                with contextlib.suppress(OSError, AttributeError):
                    process.kill()  # a grid run in progress would hold shutdown for seconds
            raise
        finally:
            threads.shutdown(wait=True, cancel_futures=True)
            pool.shutdown(wait=True, cancel_futures=True)
            allow_children()


# -- the key and the outputs --------------------------------------------------------------------------
def read_key(path: Path, make: bool = True) -> bytes:
    """The secret key in `path` (hexadecimal, at least 128 bits); made there (mode 0600) when missing and
    `make`. A ValueError of one line (naming it and the way out) otherwise."""
    try:
        text = path.read_text().strip()
    except FileNotFoundError:
        if not make:
            raise ValueError(f"--key {path}: no such file") from None
        try:
            descriptor = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_NOFOLLOW", 0), 0o600)
            with os.fdopen(descriptor, "w") as file:
                file.write(secrets.token_hex(KEY_BYTES) + "\n")
        except OSError as error:
            raise ValueError(f"cannot write the key {path}: {error.strerror or error}") from None
        return read_key(path, make=False)
    except (OSError, UnicodeDecodeError) as error:
        raise ValueError(f"--key {path}: cannot be read ({getattr(error, 'strerror', None) or error})") from None
    try:
        key = bytes.fromhex(text)
    except ValueError:
        key = b""
    if len(key) < 16:
        raise ValueError(f"--key {path}: not a key of at least 128 bits (32 hexadecimal digits)")
    return key


@contextlib.contextmanager
def claimed(outputs: list[tuple[Path, str]]) -> Iterator[None]:
    """Hold the claims of `outputs` ((path, option) each: a study's locked NAME.lock beside each,
    mazelab.experiments.journal.claim_outputs) while grading; a ValueError at once when another holds one."""
    with contextlib.ExitStack() as releases:
        for output, option in outputs:
            try:
                releases.callback(claim_outputs([(option, output)]))
            except JournalError as error:  # held by another grader (or a study), or not a file at its name
                held = f"{option} {output}: another grader is writing it now; wait for it or choose another name"
                raise ValueError(held if str(error).startswith("another") else str(error)) from None
        yield


def partial_name(path: Path) -> Path:
    """Where the CSV grows until every submission is graded: grades.csv -> grades.partial.csv."""
    return path.with_name(f"{path.stem}.partial{path.suffix}")


class Gradebook:
    """The grading's outputs, written as each submission is graded: its results.json (under
    `gradescope`, a folder per submission) and the CSV so far (`partial_name(csv)`); `finish` puts the
    complete CSV in place. A write that fails is a WriteError naming the file."""

    def __init__(self, csv_path: Path | None, gradescope: Path | None, force: bool, catalogue: Catalogue):
        self.csv, self.gradescope, self.force, self.catalogue = csv_path, gradescope, force, catalogue
        self.graded: list[Report] = []

    def add(self, report: Report) -> None:
        self.graded.append(report)
        if self.gradescope is not None:
            target = self.gradescope / report.submission.name / "results.json"
            try:
                target.parent.mkdir(exist_ok=True)
            except OSError as error:
                raise WriteError(error.errno, error.strerror, str(target.parent)) from None
            write_atomically(target, gradescope_json(report, self.catalogue), replace=True)
        if self.csv is not None:
            write_atomically(partial_name(self.csv), csv_text(self.graded), replace=True)

    def finish(self, graded: list[Report]) -> Path | None:
        """The complete CSV of `graded` (grade_folder's, in the submissions' order) in place of the partial one."""
        if self.csv is None:
            return None
        written = write_atomically(self.csv, csv_text(graded), replace=self.force)
        partial_name(self.csv).unlink(missing_ok=True)
        return written


def csv_row(report: Report) -> dict[str, Any]:
    """One submission's CSV row: its statuses, the whole filter's figures, time and what went wrong."""
    row, file = {name: "" for name in CSV_COLUMNS}, report.submission.file
    row.update(
        submission=report.submission.name, file=clean(file.name) if file else "", seconds=f"{report.seconds:.1f}"
    )
    for part in ROW_NAMES:
        row[part.replace(" ", "_")] = report.status(part) or NOT_RUN
    if report.problem is not None:
        row["problem"] = report.problem
        return row
    if report.figures:
        figures = report.figures
        row["farther_on"] = sum(not f.distance <= f.sir_distance for f in figures)
        row["to_exact"] = f"{sum(f.distance for f in figures) / len(figures):.4f}"
        row["sir_to_exact"] = f"{sum(f.sir_distance for f in figures) / len(figures):.4f}"
        row["converged"] = sum(f.converged for f in figures)
        row["sir_converged"] = sum(f.sir_converged for f in figures)
    row["problem"] = "; ".join([*problems_of(report), *([report.note] if report.note else [])])
    return row


def problems_of(report: Report) -> list[str]:
    """What went wrong: how a process ended, a part that is the lab's code, each failing row's figures."""
    wrong = [  # how a process ended is in report.problems already
        f"{r.part}: {r.got}"
        for r in report.rows
        if r.status not in (PASS, NOT_RUN, NOT_WRITTEN, NOT_OWN) and not r.got.startswith("the student's process")
    ]
    return list(dict.fromkeys([*report.problems, *wrong]))


def csv_text(graded: list[Report]) -> str:
    """The CSV of the graded submissions: every field quoted (a name holding a comma or a quote is one
    field; what does not print was escaped before)."""
    buffer = io.StringIO()
    writer = csv.DictWriter(buffer, fieldnames=CSV_COLUMNS, lineterminator="\n", quoting=csv.QUOTE_ALL)
    writer.writeheader()
    writer.writerows(csv_row(one) for one in graded)
    return buffer.getvalue()


def gradescope_json(report: Report, catalogue: Catalogue | None = None) -> str:
    """Gradescope's results.json for one submission: a test per row (1 point each), the report as
    the submission's output (its published autograder format), in the catalogue's language; a
    submission that could not be checked scores 0 with the reason. No seed nor key is in it."""
    words = catalogue or Catalogue()
    _ = words.gettext
    if report.problem is not None:
        text = words.numbers(words.translate(report.problem))
        tests = [_test(i, _(part), 0.0, text) for i, part in enumerate(ROW_NAMES, 1)]
        results = {"score": 0.0, "execution_time": round(report.seconds), "output": text, "tests": tests}
    else:
        tests = []
        for i, row in enumerate(report.rows, 1):
            status = _(SHOWN.get(row.status, row.status))
            lines = [f"{status}: {words.translate(row.got)}", _("expected: ") + words.translate(row.expected)]
            lines += [_("hint: ") + words.translate(row.hint)] if row.hint and not row.passed else []
            tests.append(_test(i, _(row.part), 1.0 if row.passed else 0.0, words.numbers("\n".join(lines))))
        results = {
            "score": float(sum(t["score"] for t in tests)),
            "execution_time": round(report.seconds),
            "output": format_report(report, catalogue=words),
            "stdout_visibility": "hidden",
            "tests": tests,
            "extra_data": {"problems": report.problems, "sandboxed": not report.note},
        }
    return json.dumps(results, indent=2, allow_nan=False) + "\n"


def _test(number: int, name: str, score: float, output: str) -> dict[str, Any]:
    status = "passed" if score == 1.0 else "failed"
    return {
        "name": name,
        "number": str(number),
        "score": score,
        "max_score": 1.0,
        "status": status,
        "output": output,
        "visibility": "visible",
    }


def summary(graded: list[Report], width: int = 100) -> str:
    """A line per submission (each row's status and the time), what went wrong on its own indented
    line under it (at most two lines), and the counts."""
    name_width = min(24, max([len("submission"), *(len(g.submission.name) for g in graded)]))
    header = f"{'submission':<{name_width}}  " + "  ".join(f"{p[:8]:<8}" for p in (*PARTS, "whole")) + "  seconds"
    lines = [header, "-" * min(width, len(header))]
    for one in graded:
        cells = "  ".join(f"{SHORT.get(one.status(p), '?'):<8}" for p in ROW_NAMES)
        lines.append(f"{one.submission.name[:name_width]:<{name_width}}  {cells}  {one.seconds:7.1f}")
        problem = one.problem or "; ".join(problems_of(one))
        wrapped = textwrap.wrap(problem, width - 4, break_long_words=True, break_on_hyphens=False)
        lines += ["    " + line for line in wrapped[:2]]
        if len(wrapped) > 2:
            lines[-1] = lines[-1][: width - 3] + "..."
    passed = sum(one.passed for one in graded)
    counts = ", ".join(f"{p} {sum(one.status(p) == PASS for one in graded)}" for p in ROW_NAMES)
    lines += ["", *textwrap.wrap(f"{len(graded)} submissions, {passed} pass every row; passing each: {counts}", width)]
    lines.append("pass, FAIL; todo: not written; REF: the lab's code with its names changed; -: not run")
    failed = sum(bool(g.problem and g.problem.startswith("the grader could not check it")) for g in graded)
    lines += [f"{failed} could not be checked by the grader itself (their rows say why)"] if failed else []
    notes = {one.note for one in graded if one.note}
    lines += [line for note in sorted(notes) for line in textwrap.wrap(note, width)]
    return "\n".join(lines)


__all__ = [
    "CSV_COLUMNS",
    "KEY_FILE",
    "Gradebook",
    "Submission",
    "claimed",
    "discover",
    "grade_folder",
    "gradescope_json",
    "read_key",
    "summary",
]
