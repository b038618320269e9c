"""The report as text of at most WIDTH columns (a terminal, a notebook cell, a Gradescope box): a
row per part with what came, and under a row that did not pass what was expected and the hint, each
on its own lines; then the whole filter's figures per scenario and the verdict."""

from __future__ import annotations

import textwrap

from mazelab.exercise.language import Catalogue
from mazelab.exercise.outcome import Report
from mazelab.exercise.rows import FAIL, NOT_OWN, NOT_RUN, NOT_WRITTEN, PASS, Row
from mazelab.exercise.whole import FIGURE_HEADERS, figures_table
from mazelab.experiments.tables import format_table

WIDTH = 100
PART_WIDTH, RESULT_WIDTH = 12, 12  # "whole filter", "not own work" (wider where a language's words are)
SHOWN = {FAIL: "FAIL"}  # how a status reads in the table (the others as they are)


def _wrapped(text: str, first: str, indent: int, width: int) -> list[str]:
    """`first` then `text`, wrapped to `width`, continuation lines indented by `indent`."""
    room = width - indent
    lines = textwrap.wrap(text, room, break_long_words=True, break_on_hyphens=False) or [""]
    return [first + lines[0], *(" " * indent + line for line in lines[1:])]


def format_rows(rows: list[Row], width: int = WIDTH, catalogue: Catalogue | None = None) -> str:
    """The rows: part, result, what came; under a row that did not pass, "expected:" and "hint:" (in
    the catalogue's language: English by default)."""
    words = catalogue or Catalogue()
    _ = words.gettext
    part_width = max(PART_WIDTH, *(len(_(row.part)) for row in rows))
    result_width = max(RESULT_WIDTH, *(len(_(SHOWN.get(s, s))) for s in (PASS, FAIL, NOT_WRITTEN, NOT_RUN, NOT_OWN)))
    indent = part_width + result_width + 4
    lines = [f"{_('part'):<{part_width}}  {_('result'):<{result_width}}  {_('got')}", "-" * min(width, 80)]
    for row in rows:
        status = _(SHOWN.get(row.status, row.status))
        first = f"{_(row.part):<{part_width}}  {status:<{result_width}}  "
        lines += _wrapped(words.translate(row.got), first, indent, width)
        if row.status not in (PASS, NOT_WRITTEN, NOT_RUN):
            lines += _wrapped(_("expected: ") + words.translate(row.expected), " " * indent, indent, width)
        if not row.passed and row.hint:
            lines += _wrapped(_("hint: ") + words.translate(row.hint), " " * indent, indent, width)
    return "\n".join(lines)


def format_report(report: Report, width: int = WIDTH, seed_note: str = "", catalogue: Catalogue | None = None) -> str:
    """The whole report: the heading, the rows, the figures per scenario, and the verdict."""
    words = catalogue or Catalogue()
    _ = words.gettext
    heading = _("Checking {name}: inputs from seed {seed}{note}").format(
        name=report.filter_name, seed=report.seed, note=seed_note
    )
    lines = [*_wrapped(heading, "", 0, width), "", format_rows(report.rows, width, words)]
    if report.note:
        lines[1:1] = _wrapped(words.translate(report.note), "", 0, width)
    if report.figures:
        intro = _("The whole filter on each scenario (distance to the exact mean over the second half of the "
                  "steps; yours, then the SIR's):")  # fmt: skip
        lines += ["", *_wrapped(intro, "", 0, width)]
        table = [[_(cell) for cell in row] for row in figures_table(report.figures)]
        lines.append(format_table([_(h) for h in FIGURE_HEADERS], table))
    failed = [_(r.part) for r in report.rows if not r.passed]
    lines += ["", _("All checks pass.") if not failed else _("To fix: {parts}.").format(parts=", ".join(failed))]
    return "\n".join(lines)


__all__ = ["WIDTH", "format_report", "format_rows"]
