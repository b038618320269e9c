"""Resuming and extending a study (`study --resume`): the rows already in its CSV are read back, and
only the missing (setting, run, filter) rows are run. Run r's seeds do not depend on the number of
runs (mazelab.seeding.study_seeds), so a larger --runs extends the study and the rows it had stay.

Only this study's rows are kept: a row whose seed, maze (its file's sha256, a generated maze's seed)
or parameters differ from what the plan gives its (setting, run) is another study's, and is refused
in one line naming it (a CSV of another seed or maze, a partial file copied from another study). The
files read back (the record, the CSV, the partial file) must be regular files of UTF-8 text."""

from __future__ import annotations

import csv
import dataclasses
import math
import types
import typing
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

from mazelab.checks import check_seed
from mazelab.declaration import parse_literal
from mazelab.experiments.inputs import read_regular_text
from mazelab.experiments.record import read_record
from mazelab.experiments.study import RunRecord, RunTask, option_cell, option_cells
from mazelab.experiments.tables import csv_cell

RESUME_IGNORES = ("runs",)  # parameters that may differ between the record and a resumed study
# The columns of a row that the plan fixes for its (setting, run): seed and maze first (the message
# names the first that differs), then the parameters. The rest are the run's results.
PLANNED_COLUMNS = (
    "seed",
    "maze_sha256",
    "maze_seed",
    "maze",
    "wall_share",
    "sigma",
    "delta",
    "particles",
    "steps",
    "kidnap_at",
)  # fmt: skip, then the option columns of the row's filter (`planned_cells`)


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
    shown = text if len(text) <= 40 else f"{text[:40]}..."
    raise ValueError(f"{shown!r} is not a {kind}")


def read_study_csv(path: str | Path, expected: Sequence[str] | None = None) -> list[RunRecord]:
    """The rows of a study's CSV as RunRecords: the fixed columns, then a column per filter option (its
    non-empty cells read back as the values they spell, as `option_cell` writes them, into
    RunRecord.options); with `expected`,
    the header must be exactly those columns. A last row cut short (a study killed while writing it)
    is left out; any other bad row is a ValueError of one line naming the file and row (row 2 is the
    first after the header). A pipe, device or folder, or text that is not UTF-8, is refused."""
    path = Path(path)
    hints = typing.get_type_hints(RunRecord)
    fixed = [f.name for f in dataclasses.fields(RunRecord) if f.name != "options"]
    try:
        text = read_regular_text(path, "a study CSV")
    except FileNotFoundError:
        raise ValueError(f"--resume: {path} does not exist (nothing to resume)") from None
    except ValueError as error:
        raise ValueError(f"--resume: {error}") from None
    lines = text.splitlines(keepends=True)
    if not lines:
        return []
    reader = csv.reader(lines)
    records = []
    try:
        header = next(reader)
        if header[: len(fixed)] != fixed or (expected is not None and header != list(expected)):
            raise ValueError(f"--resume: {path} is not a study CSV of this version (its columns differ)")
        columns, others = header, header[len(fixed) :]
        for number, row in enumerate(reader, start=2):
            last = number == len(lines)
            if last and (len(row) != len(columns) or not lines[-1].endswith("\n")):
                break  # cut short by a kill: that run is run again
            if len(row) != len(columns):
                raise ValueError(f"--resume: {path} row {number} has {len(row)} cells, the header {len(columns)}")
            try:
                cells = dict(zip(columns, row, strict=True))
                values = {name: _parse(cells[name], hints[name]) for name in fixed}
                options = {name: option_cell(parse_literal(cells[name])) for name in others if cells[name] != ""}
                records.append(RunRecord(**values, options=options))
            except ValueError as error:
                raise ValueError(f"--resume: {path} row {number}: {error}") from None
    except csv.Error as error:  # a NUL byte, a cell over the field size limit
        raise ValueError(f"--resume: {path} is not a study CSV ({error})") from None
    return records


def read_study_record(path: str | Path) -> dict[str, Any]:
    """The record of a study to resume: a record (mazelab.experiments.record.read_record) of kind
    "study" whose parameters are a mapping with a root seed and a run count, and whose sessions, if
    any, a list of mappings; a ValueError of one line naming the file otherwise."""
    data = read_record(path)
    parameters = data["parameters"]
    if data.get("kind") != "study":
        raise ValueError(f"{path}: not a study's record (its kind is {data.get('kind')!r})")
    if not isinstance(parameters, Mapping):
        raise ValueError(f"{path}: its parameters are {type(parameters).__name__}, not a mapping of names to values")
    try:
        check_seed("its parameters' root_seed", parameters.get("root_seed"))
    except ValueError as error:
        raise ValueError(f"{path}: {error}") from None
    runs = parameters.get("runs")
    if isinstance(runs, bool) or not isinstance(runs, int) or runs < 1:
        raise ValueError(f"{path}: its parameters' runs must be a whole number >= 1, got {runs!r}")
    sessions = data.get("sessions", [])
    if not isinstance(sessions, list) or not all(isinstance(item, Mapping) for item in sessions):
        raise ValueError(f"{path}: its sessions must be a list of the earlier sessions, got {sessions!r:.60}")
    return data


def planned_cells(task: RunTask, filter_name: str) -> dict[str, str]:
    """The cells (as the CSV writes them) that run `task`'s row of filter `filter_name` must hold:
    PLANNED_COLUMNS, then every option the filter runs with in the task's setting."""
    s = task.setting
    values = {
        "seed": task.seed, "maze_sha256": s.maze.sha256, "maze_seed": task.maze_seed, "maze": s.maze.label,
        "wall_share": s.maze.wall_share, "sigma": s.sigma, "delta": s.delta, "particles": s.particles,
        "steps": task.steps, "kidnap_at": task.kidnap_at,
    }  # fmt: skip
    generated = s.maze.grid is None  # its maze_sha256 is its run's own maze's, which maze_seed fixes
    return {
        **{column: _cell(values[column]) for column in PLANNED_COLUMNS if not (generated and column == "maze_sha256")},
        **{name: _option_cell(value) for name, value in option_cells(s, filter_name).items()},
    }


def _cell(value: Any) -> str:
    return str(csv_cell(value))


def _option_cell(value: Any) -> str:
    """An option's value as the CSV writes it (in its cell's words: None as "none")."""
    return _cell(option_cell(value))


def foreign_row(tasks: Sequence[RunTask], records: Iterable[RunRecord]) -> tuple[int, str] | None:
    """(the index of the first record that is not one of `tasks`' rows, why), or None when every
    record is: a (setting, run) the tasks have, one of its filters, and the seed, maze and parameters
    the task gives it."""
    planned = {(t.setting_index, t.run): t for t in tasks}
    cells: dict[tuple[int, int, str], dict[str, str]] = {}
    for index, record in enumerate(records):
        task = planned.get((record.setting, record.run))
        if task is None:
            return index, f"run {record.run} of setting {record.setting} is not in this study"
        if record.filter not in task.row_filters():
            return index, f"its filter {record.filter} is not one this study runs in setting {record.setting}"
        key = (task.setting_index, task.run, record.filter)
        if key not in cells:
            cells[key] = planned_cells(task, task.row_filters()[record.filter])
        expected = cells[key]
        options = {name: _option_cell(value) for name, value in record.options.items()}
        for name in options.keys() - expected.keys():
            return index, f"its {name} is {options[name]}, an option {record.filter} does not take"
        for column in expected:
            found = _cell(getattr(record, column)) if column in PLANNED_COLUMNS else options.get(column, "")
            if found != expected[column]:
                return index, (
                    f"its {column} is {found or 'empty'}, where this study's run {task.run} of setting "
                    f"{task.setting_index} has {expected[column] or 'none'}"
                )
    return None


def check_rows_of_study(tasks: Sequence[RunTask], records: Sequence[RunRecord], path: str | Path) -> None:
    """Refuse, in one line naming the first, rows of `path` that are not this study's (`foreign_row`):
    another seed, maze or parameters are another study's results, never to be kept as this one's."""
    found = foreign_row(tasks, records)
    if found is not None:
        index, why = found
        raise ValueError(
            f"--resume: {path} row {index + 2} is another study's ({why}); rows of another study are never "
            "kept: give this study's own --csv and parameters, or another --csv"
        )


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
        if set(task.row_filters()) <= have:
            complete[task.setting_index, task.run] = set(task.row_filters())
        else:
            todo.append(task)
    kept, seen = [], set()
    for r in records:
        key = (r.setting, r.run, r.filter)
        if r.filter in complete.get((r.setting, r.run), ()) and key not in seen:
            seen.add(key)
            kept.append(r)
    return todo, kept


__all__ = [
    "PLANNED_COLUMNS",
    "RESUME_IGNORES",
    "check_rows_of_study",
    "foreign_row",
    "missing_tasks",
    "planned_cells",
    "read_study_csv",
    "read_study_record",
]
