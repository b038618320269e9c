"""The checker's report: a row per part and one for the whole filter (pass or fail, expected against
got, a hint to the equation), the whole filter's figures per scenario, and what the student still has
to write (`progress`, what `python my_filter.py` prints)."""

from __future__ import annotations

import contextlib
import inspect
import shlex
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from mazelab.exercise.parts import (
    Row,
    check_estimate,
    check_parts,
    check_predict,
    check_resample,
    check_weigh,
    is_student_filter,
)
from mazelab.exercise.student import PARTS, StudentFilter
from mazelab.exercise.whole import FIGURE_HEADERS, ScenarioFigures, check_whole, figures_table, sign_test_alpha
from mazelab.experiments.tables import format_table
from mazelab.invocation import command_prefix


@dataclass
class Report:
    """What `check` found: the rows (parts, then the whole filter) and the whole filter's figures."""

    filter_name: str
    rows: list[Row] = field(default_factory=list)
    figures: list[ScenarioFigures] = field(default_factory=list)

    @property
    def passed(self) -> bool:
        """Every row passed (exit code 0)."""
        return bool(self.rows) and all(row.passed for row in self.rows)

    def row(self, part: str) -> Row:
        """The row of one part (or "whole filter")."""
        return next(row for row in self.rows if row.part == part)


def check(filter_class: type, *, whole: bool = True) -> Report:
    """Check each part (a StudentFilter) and, when every part is written, the whole filter."""
    report = Report(filter_class.name)
    scheme = "systematic"
    if is_student_filter(filter_class):
        report.rows, scheme = check_parts(filter_class)
    if whole:
        if any(row.not_written for row in report.rows):
            expected = f"no worse than SIR, alpha {sign_test_alpha():.4f}"
            report.rows.append(Row("whole filter", False, expected, "not run", "write every part first"))
        else:
            row, report.figures = check_whole(filter_class, scheme)
            failed = [r.part for r in report.rows if not r.passed]
            if failed and not row.passed and row.hint.startswith("the parts pass alone"):
                row.hint = f"fix {', '.join(failed)} first: the whole filter runs with every part"
            report.rows.append(row)
    return report


def format_report(report: Report) -> str:
    """The table of rows, the per-scenario figures, and the verdict."""
    headers = ["part", "result", "expected", "got", "hint"]
    rows = [[r.part, "pass" if r.passed else "FAIL", r.expected, r.got, r.hint] for r in report.rows]
    lines = [f"Checking {report.filter_name}", format_table(headers, rows)]
    if report.figures:
        lines += ["", "The whole filter on each scenario (distance to the exact mean over the second half):"]
        lines.append(format_table(FIGURE_HEADERS, figures_table(report.figures)))
    failed = [r.part for r in report.rows if not r.passed]
    lines.append("")
    lines.append("All checks pass." if not failed else f"To fix: {', '.join(failed)}.")
    return "\n".join(lines)


def progress(filter_class: type) -> str:
    """Which parts are still to write, and the quick checks of those written (what running the file says)."""
    report = check(filter_class, whole=False)
    todo = [row.part for row in report.rows if row.not_written]
    lines = [f"{filter_class.name}: " + (f"still to write: {', '.join(todo)}" if todo else "all four parts written")]
    written = [row for row in report.rows if not row.not_written]
    if written:
        lines.append(
            format_table(
                ["part", "result", "got", "hint"],
                [[r.part, "pass" if r.passed else "FAIL", r.got, r.hint] for r in written],
            )
        )
    if not todo:
        lines.append(f"Grade the whole filter against the exact posterior: {check_command(filter_class)}")
    return "\n".join(lines)


def check_command(filter_class: type) -> str:
    """The command that grades `filter_class`, to paste back: `mazelab exercise check my_filter.py`
    (with the prefix the program was started with, and `:Class` unless the class is MyFilter)."""
    try:
        source = Path(inspect.getsourcefile(filter_class) or "")
    except TypeError:  # a class defined in a notebook cell or at the prompt has no file
        source = Path()
    if not source.name:
        return f"{command_prefix()} exercise check FILE"
    shown = source.resolve()
    with contextlib.suppress(ValueError):  # outside the folder you are in: the whole path
        shown = shown.relative_to(Path.cwd().resolve())
    spec = str(shown) if filter_class.__name__ == "MyFilter" else f"{shown}:{filter_class.__name__}"
    return f"{command_prefix()} exercise check {shlex.quote(spec)}"


PART_CHECKS: dict[str, Callable[[type], Row]] = {
    "predict": check_predict,
    "weigh": check_weigh,
    "resample": lambda filter_class: check_resample(filter_class)[0],
    "estimate": check_estimate,
}


def check_part(part: str, function: Callable[..., object]) -> Row:
    """Check one part written as a plain function `part(self, ...)` (a notebook cell), print its row."""
    if part not in PART_CHECKS:
        raise ValueError(f"unknown part {part!r}; the parts are {', '.join(PARTS)}")
    row = PART_CHECKS[part](type("NotebookFilter", (StudentFilter,), {part: function}))
    print(
        format_table(
            ["part", "result", "expected", "got", "hint"],
            [[row.part, "pass" if row.passed else "FAIL", row.expected, row.got, row.hint]],
        )
    )
    return row


def check_and_print(filter_class: type) -> Report:
    """`check` the whole filter and print the report (the notebook's last check cell)."""
    report = check(filter_class)
    print(format_report(report))
    return report


__all__ = ["PARTS", "Report", "check", "check_and_print", "check_command", "check_part", "format_report", "progress"]
