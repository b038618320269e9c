"""The report as text of at most WIDTH columns (a terminal, a notebook cell, a Gradescope box): a
row per part with what came, and under a row that did not pass what was expected and the hint, each
on its own lines; then the whole filter's figures per scenario and the verdict."""

from __future__ import annotations

import textwrap

from mazelab.exercise.outcome import Report
from mazelab.exercise.rows import FAIL, NOT_RUN, NOT_WRITTEN, PASS, Row
from mazelab.exercise.whole import FIGURE_HEADERS, figures_table
from mazelab.experiments.tables import format_table

WIDTH = 100
PART_WIDTH, RESULT_WIDTH = 12, 12  # "whole filter", "not own work"
SHOWN = {FAIL: "FAIL"}  # how a status reads in the table (the others as they are)


def _wrapped(text: str, first: str, indent: int, width: int) -> list[str]:
    """`first` then `text`, wrapped to `width`, continuation lines indented by `indent`."""
    room = width - indent
    lines = textwrap.wrap(text, room, break_long_words=True, break_on_hyphens=False) or [""]
    return [first + lines[0], *(" " * indent + line for line in lines[1:])]


def format_rows(rows: list[Row], width: int = WIDTH) -> str:
    """The rows: part, result, what came; under a row that did not pass, "expected:" and "hint:"."""
    indent = PART_WIDTH + RESULT_WIDTH + 4
    lines = [f"{'part':<{PART_WIDTH}}  {'result':<{RESULT_WIDTH}}  got", "-" * min(width, 80)]
    for row in rows:
        status = SHOWN.get(row.status, row.status)
        lines += _wrapped(row.got, f"{row.part:<{PART_WIDTH}}  {status:<{RESULT_WIDTH}}  ", indent, width)
        if row.status not in (PASS, NOT_WRITTEN, NOT_RUN):
            lines += _wrapped("expected: " + row.expected, " " * indent, indent, width)
        if not row.passed:
            lines += _wrapped("hint: " + row.hint, " " * indent, indent, width) if row.hint else []
    return "\n".join(lines)


def format_report(report: Report, width: int = WIDTH, seed_note: str = "") -> str:
    """The whole report: the heading, the rows, the figures per scenario, and the verdict."""
    heading = f"Checking {report.filter_name}: inputs from seed {report.seed}{seed_note}"
    lines = [*_wrapped(heading, "", 0, width), "", format_rows(report.rows, width)]
    if report.note:
        lines[1:1] = _wrapped(report.note, "", 0, width)
    if report.figures:
        lines += ["", *_wrapped("The whole filter on each scenario (distance to the exact mean over the "
                                "second half of the steps; yours, then the SIR's):", "", 0, width)]  # fmt: skip
        lines.append(format_table(FIGURE_HEADERS, figures_table(report.figures)))
    failed = [r.part for r in report.rows if not r.passed]
    lines += ["", "All checks pass." if not failed else f"To fix: {', '.join(failed)}."]
    return "\n".join(lines)


__all__ = ["WIDTH", "format_report", "format_rows"]
