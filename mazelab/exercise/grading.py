"""Grading a folder of submissions: each one checked in child processes of its own (mazelab.exercise.
report.check_file), several at once over the cores, the grader's reference runs computed once per
scenario in a pool of worker processes; then one CSV row per submission, Gradescope's results.json
per submission, and a summary table.

A submission is a subfolder (its my_filter.py, else its only Python file, else the only one that
mentions StudentFilter) or a .py file directly in the folder; names starting with "." or "_" are
skipped. One that cannot be checked (no file to grade, an import error, not a StudentFilter) gets a
row saying why, never a pass.
"""

from __future__ import annotations

import contextlib
import csv
import io
import json
import multiprocessing
import os
import textwrap
import threading
import time
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor, ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from mazelab.exercise.language import Catalogue
from mazelab.exercise.layout import format_report
from mazelab.exercise.outcome import Report
from mazelab.exercise.report import STAGES, WHOLE, NotGradableError, check_file
from mazelab.exercise.rows import FAIL, NOT_OWN, NOT_RUN, NOT_WRITTEN, PASS
from mazelab.exercise.runner import DEFAULT_TIMEOUT, allow_children, stop_children
from mazelab.exercise.student import PARTS
from mazelab.exercise.template import FILTER_FILE
from mazelab.exercise.whole import References

ROW_NAMES = (*PARTS, WHOLE)
CSV_COLUMNS = (
    "submission", "file", "seed", *PARTS, "whole_filter", "farther_on", "to_exact", "sir_to_exact",
    "converged", "sir_converged", "seconds", "problem",
)  # fmt: skip
SHORT = {PASS: "pass", FAIL: "FAIL", NOT_WRITTEN: "todo", NOT_RUN: "-", NOT_OWN: "REF", None: "-"}


@dataclass
class Submission:
    """One submission: its name (the folder's or the file's), the file to grade, or why there is none."""

    name: str
    file: Path | None
    problem: str | None = None
    own_folder: bool = False  # a subfolder of its own: the Python files beside the file are its too


@dataclass
class Graded:
    """A submission's outcome: its report, or the one line why it could not be checked."""

    submission: Submission
    report: Report | None
    problem: str | None
    seconds: float

    def status(self, part: str) -> str | None:
        if self.report is None:
            return FAIL
        return next((row.status for row in self.report.rows if row.part == part), None)

    @property
    def passed(self) -> bool:
        return self.report is not None and self.report.passed


def discover(folder: Path) -> list[Submission]:
    """The submissions in `folder`, by name: a link that leads out of the folder or to a file that is
    not Python is refused (named), and two names for one file are graded once."""
    if not folder.exists():
        raise ValueError(f"{folder}: no such folder of submissions (check the path)")
    if not folder.is_dir():
        raise ValueError(f"{folder}: not a folder; grade one file with `exercise check {folder}`")
    found, by_file = [], {}
    for entry in sorted(folder.iterdir(), key=lambda p: p.name):
        if entry.name.startswith((".", "_")):
            continue
        if entry.is_dir():
            submission = _in_folder(entry)
        elif entry.suffix == ".py" or entry.is_symlink():
            submission = Submission(entry.name, entry)
        else:
            continue
        submission = _refused_link(submission, folder) if submission.file else submission
        if submission.file is not None:
            real = submission.file.resolve()
            if real in by_file:
                first = by_file[real]
                why = f"{submission.file}: the same file as {first.file} (a link); graded once, as {first.name}"
                submission = Submission(submission.name, None, why)
            else:
                by_file[real] = submission
        found.append(submission)
    if not found:
        raise ValueError(f"{folder}: no submissions (a subfolder or a .py file each)")
    return found


def _refused_link(submission: Submission, folder: Path) -> Submission:
    """The submission, or why its file is refused: a link out of the class folder, or to what is not
    a Python file (a student's link to /etc/passwd is never read)."""
    file = submission.file
    real = file.resolve()
    if not real.is_relative_to(folder.resolve()):
        return Submission(submission.name, None, f"{file}: a link out of the class folder; not graded")
    if submission.own_folder and file.parent.resolve() != real.parent:
        return Submission(submission.name, None, f"{file}: a link to another folder's file; not graded")
    if real.suffix != ".py" or not real.is_file():
        return Submission(submission.name, None, f"{file}: a link to {real.name}, not a Python file; not graded")
    return submission


def _in_folder(folder: Path) -> Submission:
    if (folder / FILTER_FILE).is_file() or (folder / FILTER_FILE).is_symlink():
        return Submission(folder.name, folder / FILTER_FILE, own_folder=True)
    files = sorted(p for p in folder.glob("*.py") if p.is_file() and not p.name.startswith((".", "_")))
    mentioning = [p for p in files if "StudentFilter" in p.read_text(errors="replace")]
    for candidates in (files, mentioning):
        if len(candidates) == 1:
            return Submission(folder.name, candidates[0], own_folder=True)
    if not files:
        return Submission(folder.name, None, f"{folder}: no Python file to grade")
    names = ", ".join(p.name for p in files[:5])
    return Submission(folder.name, None, f"{folder}: which file? {names} (call the one to grade {FILTER_FILE})")


def grade_one(submission: Submission, seed: int | None, timeout: float, references: References) -> Graded:
    """Check one submission (never raises for the submission's own problems)."""
    started = time.perf_counter()
    if submission.file is None:
        return Graded(submission, None, submission.problem, 0.0)
    try:
        report = check_file(
            str(submission.file), seed=seed, timeout=timeout, references=references, companions=submission.own_folder
        )
    except NotGradableError as error:
        return Graded(submission, None, str(error), time.perf_counter() - started)
    return Graded(submission, report, None, time.perf_counter() - started)


class GradingInterruptedError(Exception):
    """Ctrl-C or SIGTERM stopped the grading: the submissions graded before it (`graded`, in order)."""

    def __init__(self, graded: list[Graded]):
        super().__init__("the grading was stopped")
        self.graded = graded


def grade_folder(
    submissions: list[Submission],
    *,
    seed: int | None = None,
    timeout: float = DEFAULT_TIMEOUT,
    jobs: int | None = None,
    on_done: Callable[[Graded], None] | None = None,
) -> list[Graded]:
    """Grade the submissions, `jobs` at a time (default: the cores), in their order."""
    jobs = jobs or os.cpu_count() or 1
    lock = threading.Lock()
    allow_children()
    pool = ProcessPoolExecutor(max_workers=jobs, mp_context=_reference_context())
    references = References(pool)

    def one(submission: Submission) -> Graded:
        graded = grade_one(submission, seed, timeout, references)
        if on_done is not None:
            with lock:
                on_done(graded)
        return graded

    threads = ThreadPoolExecutor(max_workers=jobs, thread_name_prefix="mazelab-grade")
    futures = [threads.submit(one, submission) for submission in submissions]
    try:
        return [future.result() for future in futures]
    except BaseException as error:  # Ctrl-C, SIGTERM: end the running children, start no new one, keep what was graded
        stop_children()
        _end_workers(pool)
        for future in futures:
            future.cancel()
        threads.shutdown(wait=True, cancel_futures=True)
        if not isinstance(error, KeyboardInterrupt):
            raise  # the grader's own error is not a stop: it is shown as it is
        done = [f.result() for f in futures if f.done() and not f.cancelled() and f.exception() is None]
        raise GradingInterruptedError(done) from None
    finally:
        threads.shutdown(wait=True, cancel_futures=True)
        pool.shutdown(wait=True, cancel_futures=True)
        allow_children()


def _end_workers(pool: ProcessPoolExecutor) -> None:
    """Kill the reference runs' workers now (a grid run in progress would hold shutdown for seconds)."""
    for process in list((getattr(pool, "_processes", None) or {}).values()):
        with contextlib.suppress(OSError, AttributeError):
            process.kill()


def _reference_context() -> Any:
    """The reference runs' workers: a fresh interpreter each (forkserver, or spawn where there is none),
    never a fork of the grader's threads."""
    methods = multiprocessing.get_all_start_methods()
    return multiprocessing.get_context("forkserver" if "forkserver" in methods else "spawn")


# -- what grading writes ----------------------------------------------------------------------------
def csv_row(graded: Graded) -> dict[str, Any]:
    """One submission's CSV row: its statuses, the whole filter's figures, time and what went wrong."""
    report, row = graded.report, {name: "" for name in CSV_COLUMNS}
    row.update(submission=graded.submission.name, seconds=f"{graded.seconds:.1f}")
    row["file"] = graded.submission.file.name if graded.submission.file else ""
    for part in ROW_NAMES:
        row[part.replace(" ", "_")] = graded.status(part) or NOT_RUN
    if report is None:
        row["problem"] = graded.problem or ""
        return row
    row["seed"] = report.seed
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


def csv_text(graded: list[Graded]) -> str:
    buffer = io.StringIO()
    writer = csv.DictWriter(buffer, fieldnames=CSV_COLUMNS, lineterminator="\n")
    writer.writeheader()
    for one in graded:
        writer.writerow(csv_row(one))
    return buffer.getvalue()


def gradescope_results(graded: Graded, catalogue: Catalogue | None = None) -> dict[str, Any]:
    """Gradescope's results.json for one submission: a test per row (1 point each), the report as
    the submission's output (its published autograder format), in the catalogue's language; a
    submission that could not be checked scores 0 with the reason."""
    words, report = catalogue or Catalogue(), graded.report
    _ = words.gettext
    if report is None:
        text = graded.problem or "not checked"
        tests = [_test(i, _(part), 0.0, text) for i, part in enumerate(ROW_NAMES, 1)]
        return {"score": 0.0, "execution_time": round(graded.seconds), "output": text, "tests": tests}
    tests = []
    for i, row in enumerate(report.rows, 1):
        status = _(FAIL.upper() if row.status == FAIL else row.status)
        lines = [f"{status}: {words.translate(row.got)}", _("expected: ") + words.translate(row.expected)]
        lines += [_("hint: ") + words.translate(row.hint)] if row.hint and not row.passed else []
        tests.append(_test(i, _(row.part), 1.0 if row.passed else 0.0, "\n".join(lines)))
    return {
        "score": float(sum(t["score"] for t in tests)),
        "execution_time": round(graded.seconds),
        "output": format_report(report, catalogue=words),
        "stdout_visibility": "hidden",
        "tests": tests,
        "extra_data": {"seed": report.seed, "problems": report.problems, "sandboxed": not report.note},
    }


def _test(number: int, name: str, score: float, output: str) -> dict[str, Any]:
    return {
        "name": name,
        "number": str(number),
        "score": score,
        "max_score": 1.0,
        "status": "passed" if score == 1.0 else "failed",
        "output": output,
        "visibility": "visible",
    }


def gradescope_json(graded: Graded, catalogue: Catalogue | None = None) -> str:
    return json.dumps(gradescope_results(graded, catalogue), indent=2, allow_nan=False) + "\n"


def summary(graded: list[Graded], width: int = 100) -> str:
    """A line per submission (each row's status and the time), what went wrong on its own indented
    line under it (at most two lines), and the counts."""
    name_width = min(24, max([len("submission"), *(len(g.submission.name) for g in graded)]))
    header = f"{'submission':<{name_width}}  " + "  ".join(f"{p[:8]:<8}" for p in (*PARTS, "whole")) + "  seconds"
    lines = [header, "-" * min(width, len(header))]
    for one in graded:
        cells = "  ".join(f"{SHORT.get(one.status(p), '?'):<8}" for p in ROW_NAMES)
        lines.append(f"{one.submission.name[:name_width]:<{name_width}}  {cells}  {one.seconds:7.1f}")
        problem = one.problem or ("; ".join(problems_of(one.report)) if one.report else "")
        if problem:
            wrapped = textwrap.wrap(problem, width - 4, break_long_words=True, break_on_hyphens=False)
            lines += ["    " + line for line in wrapped[:2]]
            if len(wrapped) > 2:
                lines[-1] = lines[-1][: width - 3] + "..."
    passed = sum(one.passed for one in graded)
    counts = ", ".join(f"{p} {sum(one.status(p) == PASS for one in graded)}" for p in ROW_NAMES)
    lines += ["", *textwrap.wrap(f"{len(graded)} submissions, {passed} pass every row; passing each: {counts}", width)]
    lines.append("pass, FAIL; todo: not written; REF: the lab's code with its names changed; -: not run")
    notes = {one.report.note for one in graded if one.report and one.report.note}
    lines += [line for note in sorted(notes) for line in textwrap.wrap(note, width)]
    return "\n".join(lines)


__all__ = [
    "CSV_COLUMNS",
    "STAGES",
    "Graded",
    "GradingInterruptedError",
    "Submission",
    "csv_row",
    "csv_text",
    "discover",
    "grade_folder",
    "grade_one",
    "gradescope_json",
    "gradescope_results",
    "summary",
]
