"""Resuming and extending a study (`study --resume`): the rows already in its CSV are read back, and
only the missing (setting, run, filter) rows are run. Run r's seeds do not depend on the number of
runs (mazelab.seeding.study_seeds), so a larger --runs extends the study and the rows it had stay."""

from __future__ import annotations

import csv
import dataclasses
import math
import types
import typing
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from mazelab.declaration import parse_literal
from mazelab.experiments.study import RunRecord, RunTask

RESUME_IGNORES = ("runs",)  # parameters that may differ between the record and a resumed study


def _parse(text: str, kind: Any) -> Any:
    """One CSV cell as the RunRecord field's type (an empty cell: None, or NaN for a float)."""
    options = typing.get_args(kind) if isinstance(kind, types.UnionType) else (kind,)
    if text == "":
        return None if type(None) in options else math.nan
    for option in options:
        if option is bool:
            if text in ("True", "False"):
                return text == "True"
        elif option is int:
            try:
                return int(text)
            except ValueError:
                continue
        elif option is float:
            try:
                return float(text)
            except ValueError:
                continue
        elif option is str:
            return text
    raise ValueError(f"{text!r} is not a {kind}")


def read_study_csv(path: str | Path, expected: Sequence[str] | None = None) -> list[RunRecord]:
    """The rows of a study's CSV as RunRecords: the fixed columns, then a column per other filter
    option (its cells read back as the values they spell, into RunRecord.options); with `expected`,
    the header must be exactly those columns. A last row cut short (a study killed while writing it)
    is left out; any other bad row is a ValueError of one line naming the file and row."""
    path = Path(path)
    hints = typing.get_type_hints(RunRecord)
    fixed = [f.name for f in dataclasses.fields(RunRecord) if f.name != "options"]
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise ValueError(f"--resume: {path} does not exist (nothing to resume)") from None
    lines = text.splitlines(keepends=True)
    if not lines:
        return []
    reader = csv.reader(lines)
    header = next(reader)
    if header[: len(fixed)] != fixed or (expected is not None and header != list(expected)):
        raise ValueError(f"--resume: {path} is not a study CSV of this version (its columns differ)")
    columns, others = header, header[len(fixed) :]
    records = []
    for number, row in enumerate(reader, start=2):
        last = number == len(lines)
        if last and (len(row) != len(columns) or not lines[-1].endswith("\n")):
            break  # cut short by a kill: that run is run again
        try:
            cells = dict(zip(columns, row, strict=True))
            values = {name: _parse(cells[name], hints[name]) for name in fixed}
            options = {name: parse_literal(cells[name]) if cells[name] != "" else None for name in others}
            records.append(RunRecord(**values, options=options))
        except ValueError as error:
            raise ValueError(f"--resume: {path} row {number}: {error}") from None
    return records


def missing_tasks(tasks: Sequence[RunTask], records: Sequence[RunRecord]) -> tuple[list[RunTask], list[RunRecord]]:
    """(the tasks whose rows are missing, the rows to keep). A run with some of its filters' rows is
    run again whole (its rows come out the same, bit for bit) and its old rows are dropped; rows of
    runs the tasks do not have are dropped too."""
    present: dict[tuple[int, int], set[str]] = {}
    for r in records:
        present.setdefault((r.setting, r.run), set()).add(r.filter)
    todo, complete = [], {}
    for task in tasks:
        have = present.get((task.setting_index, task.run), set())
        if set(task.filters) <= have:
            complete[task.setting_index, task.run] = set(task.filters)
        else:
            todo.append(task)
    kept, seen = [], set()
    for r in records:
        key = (r.setting, r.run, r.filter)
        if r.filter in complete.get((r.setting, r.run), ()) and key not in seen:
            seen.add(key)
            kept.append(r)
    return todo, kept


__all__ = ["RESUME_IGNORES", "missing_tasks", "read_study_csv"]
