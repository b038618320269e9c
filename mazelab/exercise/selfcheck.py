"""The student's own checks, in the student's own process: what `python my_filter.py` prints (the
parts still to write, and the written ones checked), the notebook's check cell after each part, and
its last cell (every part and the whole filter). The same inputs and verdicts as the grade
(mazelab.exercise.report), but nothing isolates them: they are for finding bugs, the grade is
`mazelab exercise check`, which runs the code in a process of its own."""

from __future__ import annotations

from collections.abc import Callable

from mazelab.exercise.language import catalogue_for
from mazelab.exercise.parts import Row
from mazelab.exercise.report import Report, check, check_command, format_report, format_rows, progress, source_seed
from mazelab.exercise.student import PARTS, StudentFilter


def check_part(part: str, function: Callable[..., object], lang: str = "en") -> Row:
    """Check one part written as a plain function `part(self, ...)` (a notebook cell), print its row
    (in `lang`: en or uk)."""
    if part not in PARTS:
        raise ValueError(f"unknown part {part!r}; the parts are {', '.join(PARTS)}")
    notebook_filter = type("NotebookFilter", (StudentFilter,), {part: function})
    row = check(notebook_filter, seed=source_seed(function), stages=(part,)).rows[0]
    print(format_rows([row], catalogue=catalogue_for(lang)))
    return row


def check_and_print(filter_class: type, lang: str = "en") -> Report:
    """Check every part and the whole filter, and print the report (the notebook's last check cell),
    in `lang` (en or uk)."""
    report = check(filter_class)
    print(format_report(report, catalogue=catalogue_for(lang)))
    return report


__all__ = ["check_and_print", "check_command", "check_part", "progress"]
