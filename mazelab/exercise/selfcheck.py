"""The student's own checks, in the student's own process: what `python my_filter.py` prints (the
parts still to write, and the written ones checked), the notebook's check cell after each part, and
its last cell (every part and the whole filter). The same inputs and verdicts as the grade
(mazelab.exercise.report), but nothing isolates them: they are for finding bugs, the grade is
`mazelab exercise check`, which runs the code in a process of its own."""

from __future__ import annotations

import contextlib
import inspect
import shlex
from collections.abc import Callable
from pathlib import Path

from mazelab.exercise.layout import format_report, format_rows
from mazelab.exercise.report import Report, check, source_seed
from mazelab.exercise.rows import Row
from mazelab.exercise.student import PARTS, StudentFilter
from mazelab.invocation import command_prefix


def progress(filter_class: type) -> str:
    """Which parts are still to write, and the checks of those written (what running the file says)."""
    report = check(filter_class, stages=PARTS)
    todo = [row.part for row in report.rows if row.not_written]
    lines = [f"{filter_class.name}: " + (f"still to write: {', '.join(todo)}" if todo else "all four parts written")]
    written = [row for row in report.rows if not row.not_written]
    if written:
        lines.append(format_rows(written))
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


def check_part(part: str, function: Callable[..., object]) -> Row:
    """Check one part written as a plain function `part(self, ...)` (a notebook cell), print its row."""
    if part not in PARTS:
        raise ValueError(f"unknown part {part!r}; the parts are {', '.join(PARTS)}")
    notebook_filter = type("NotebookFilter", (StudentFilter,), {part: function})
    row = check(notebook_filter, seed=source_seed(function), stages=(part,)).rows[0]
    print(format_rows([row]))
    return row


def check_and_print(filter_class: type) -> Report:
    """Check every part and the whole filter, and print the report (the notebook's last check cell)."""
    report = check(filter_class)
    print(format_report(report, seed_note=" (from the class's source)"))
    return report


__all__ = ["check_and_print", "check_command", "check_part", "progress"]
