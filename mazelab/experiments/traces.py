"""Per-step traces (`study --traces`, `compare --traces`): one row per run, filter and step, in long
format, so that pandas reads them directly (`pandas.read_csv`, or `read_parquet` for a .parquet file,
which needs pyarrow). Columns: TRACE_COLUMNS."""

from __future__ import annotations

import csv
import io
import os
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from mazelab.atomic import write_bytes_atomically, write_text_atomically
from mazelab.experiments.inputs import read_regular_bytes, read_regular_text
from mazelab.experiments.study import RunRecord, RunTask, trace_of
from mazelab.simulation import RunResult

TRACE_COLUMNS = [
    "setting",  # the study's setting (empty for compare)
    "run",
    "seed",
    "filter",
    "step",  # 1..steps
    "true_x",
    "true_y",
    "estimate_x",
    "estimate_y",
    "error",  # |estimate - true position|, map units
    "ess",  # effective sample size; empty for the grid filter and the EKF
    "confident",  # 1: 95% of the belief within distance 1 of the estimate (the paper's green circle)
    "step_ms",  # the filter's own time for the step
    "particle_count",
]
PARQUET_HINT = "a .parquet trace file needs pyarrow (pip install pyarrow); or give a .csv path"


def check_trace_path(path: Path) -> None:
    """Refuse, before any run, a trace format this program cannot write."""
    if path.suffix.lower() == ".parquet":
        try:
            import pyarrow  # noqa: F401
        except ImportError:
            raise ValueError(PARQUET_HINT) from None
    elif path.suffix.lower() != ".csv":
        raise ValueError(f"--traces {path}: give a .csv or .parquet file")


def trace_columns(setting: int | None, run: int, seed: int, name: str, trace: dict[str, np.ndarray]) -> dict[str, Any]:
    """One run and filter's trace as columns (arrays of one length)."""
    steps = len(trace["ess"])
    true, estimate = np.asarray(trace["true"], dtype=float), np.asarray(trace["estimate"], dtype=float)
    return {
        "setting": np.full(steps, -1 if setting is None else setting),
        "run": np.full(steps, run),
        "seed": np.full(steps, seed, dtype=np.int64),
        "filter": np.full(steps, name, dtype=object),
        "step": np.arange(1, steps + 1),
        "true_x": true[:, 0],
        "true_y": true[:, 1],
        "estimate_x": estimate[:, 0],
        "estimate_y": estimate[:, 1],
        "error": np.hypot(*(estimate - true).T),
        "ess": np.asarray(trace["ess"], dtype=float),
        "confident": np.asarray(trace["confident"]).astype(np.int8),
        "step_ms": 1e3 * np.asarray(trace["step_seconds"], dtype=float),
        "particle_count": np.asarray(trace["particle_count"], dtype=np.int64),
    }


def study_traces(records: Iterable[RunRecord]) -> list[dict[str, Any]]:
    """The traces a study's records carry (RunTask.traces), as columns per run and filter."""
    return [trace_columns(r.setting, r.run, r.seed, r.filter, r.trace) for r in records if r.trace is not None]


def compare_traces(results: dict[str, RunResult], seed: int) -> list[dict[str, Any]]:
    """compare's runs (one scenario, every filter) as trace columns."""
    return [trace_columns(None, 1, seed, name, trace_of(result)) for name, result in results.items()]


def trace_csv_rows(blocks: Sequence[dict[str, Any]]) -> str:
    """The rows of the blocks as CSV text, without the header: exact floats (%.17g), an empty cell for
    NaN and for compare's setting."""
    buffer = io.StringIO()
    for block in blocks:
        setting = "" if block["setting"][0] == -1 else str(block["setting"][0])
        prefix = f"{setting},{block['run'][0]},{block['seed'][0]},{block['filter'][0]}"
        numbers = np.column_stack([block[c].astype(float) for c in TRACE_COLUMNS[4:]])  # step .. particle_count
        text = io.StringIO()
        np.savetxt(text, numbers, fmt=["%d", *["%.17g"] * 6, "%d", "%.17g", "%d"], delimiter=",")
        buffer.writelines(f"{prefix},{line}\n" for line in text.getvalue().replace("nan", "").splitlines())
    return buffer.getvalue()


def trace_header() -> str:
    return ",".join(TRACE_COLUMNS) + "\n"


def write_traces(
    path: Path, blocks: Sequence[dict[str, Any]], kept: str | Any = None, *, follow_links: bool = True
) -> None:
    """Write the traces to `path`, whole (mazelab.atomic): CSV, or Parquet for a .parquet path.
    `kept`: rows of an earlier session to keep in front (CSV text without header, or a pyarrow Table);
    `follow_links=False` for a stopped study's partial traces (never written through a link)."""
    if path.suffix.lower() == ".parquet":
        import pyarrow as pa
        import pyarrow.parquet as pq

        columns = {c: np.concatenate([b[c] for b in blocks]) if blocks else np.array([]) for c in TRACE_COLUMNS}
        columns["setting"] = np.where(columns["setting"] == -1, None, columns["setting"]) if blocks else []
        table = pa.table({c: pa.array(list(v) if c in ("setting", "filter") else v) for c, v in columns.items()})
        if kept is not None:
            table = pa.concat_tables([kept, table.cast(kept.schema)])
        buffer = io.BytesIO()
        pq.write_table(table, buffer)
        write_bytes_atomically(path, buffer.getvalue(), follow_links=follow_links)
        return
    write_text_atomically(path, trace_header() + (kept or "") + trace_csv_rows(blocks), follow_links=follow_links)


def check_traces_of_study(path: Path, tasks: Sequence[RunTask]) -> set[tuple[int, int]]:
    """The (setting, run)s an earlier session's trace file (--resume) holds, after refusing (a
    ValueError of one line naming the first) rows that are not this study's: a (setting, run) it does
    not have, another seed, a filter it does not run there, a step beyond its steps. An empty set if the
    file is not there."""
    traced: set[tuple[int, int]] = set()
    if not os.path.lexists(path):
        return traced
    planned = {(t.setting_index, t.run): t for t in tasks}
    for number, (setting, run, seed, name, step) in enumerate(_trace_keys(path), start=2):
        task = planned.get((setting, run))
        if task is None:
            why = f"run {run} of setting {setting} is not in this study"
        elif seed != task.seed:
            why = f"its seed is {seed}, where this study's run {run} of setting {setting} has {task.seed}"
        elif name not in task.filters:
            why = f"its filter {name} is not one this study runs in setting {setting}"
        elif not 1 <= step <= task.steps:
            why = f"its step {step} is not one of this study's {task.steps}"
        else:
            traced.add((setting, run))
            continue
        raise ValueError(
            f"--resume: {path} row {number} is another study's ({why}); traces of another study are never "
            "kept: move that file away, or give another --traces"
        )
    return traced


def _trace_keys(path: Path) -> Iterable[tuple[int | None, int, int, str, int]]:
    """(setting, run, seed, filter, step) of each row of a trace file, CSV or Parquet; a ValueError
    naming the file for one that is not a trace file (or not a regular file, or not UTF-8)."""
    if path.suffix.lower() == ".parquet":
        import pyarrow.parquet as pq

        data = read_regular_bytes(path, "a trace file")
        try:
            table = pq.read_table(pa_buffer(data), columns=["setting", "run", "seed", "filter", "step"]).to_pydict()
        except Exception as error:  # pyarrow's errors: not Parquet, other columns
            raise ValueError(f"--resume: {path} is not a trace file of this version ({error})") from None
        yield from zip(*(table[c] for c in ("setting", "run", "seed", "filter", "step")), strict=True)
        return
    lines = _trace_lines(path)
    try:
        for number, row in enumerate(csv.reader(lines[1:]), start=2):
            if len(row) != len(TRACE_COLUMNS):
                if number == len(lines):
                    return  # cut short
                raise ValueError(f"--resume: {path} row {number} has {len(row)} cells, the header {len(TRACE_COLUMNS)}")
            yield int(row[0]), int(row[1]), int(row[2]), row[3], int(row[4])
    except csv.Error as error:
        raise ValueError(f"--resume: {path} is not a trace file ({error})") from None
    except ValueError as error:
        if str(error).startswith("--resume"):
            raise
        raise ValueError(f"--resume: {path} row {number}: not a trace row ({error})") from None


def _trace_lines(path: Path) -> list[str]:
    """The lines of a CSV trace file, header first (checked), read only if it is a regular file."""
    try:
        lines = read_regular_text(path, "a trace file").splitlines(keepends=True)
    except ValueError as error:
        raise ValueError(f"--resume: {error}") from None
    if lines and lines[0] != trace_header():
        raise ValueError(f"--resume: {path} is not a trace file of this version (its columns differ)")
    return lines


def pa_buffer(data: bytes) -> Any:
    import pyarrow as pa

    return pa.BufferReader(data)


def kept_traces(path: Path, rerun: set[tuple[int, int]]) -> str | Any:
    """An earlier session's traces (for --resume), without the (setting, run)s run again; None if the
    file is not there."""
    if not path.exists():
        return None
    if path.suffix.lower() == ".parquet":
        import pyarrow.compute as pc
        import pyarrow.parquet as pq

        table = pq.read_table(pa_buffer(read_regular_bytes(path, "a trace file")))
        if not rerun:
            return table
        keys = pc.binary_join_element_wise(pc.cast(table["setting"], "string"), pc.cast(table["run"], "string"), ",")
        wanted = pa_array_of({f"{s},{r}" for s, r in rerun})
        return table.filter(pc.invert(pc.is_in(keys, value_set=wanted)))
    lines = _trace_lines(path)[1:]
    kept = []
    for row, line in zip(csv.reader(lines), lines, strict=True):
        if len(row) == len(TRACE_COLUMNS) and line.endswith("\n") and (int(row[0]), int(row[1])) not in rerun:
            kept.append(line)
    return "".join(kept)


def pa_array_of(values: set[str]) -> Any:
    import pyarrow as pa

    return pa.array(sorted(values))


__all__ = [
    "PARQUET_HINT",
    "TRACE_COLUMNS",
    "check_trace_path",
    "check_traces_of_study",
    "compare_traces",
    "kept_traces",
    "study_traces",
    "trace_columns",
    "trace_csv_rows",
    "write_traces",
]
