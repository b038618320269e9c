"""Output helpers of the experiments: plain-text tables, CSV cells, and figures saved atomically; and the
per-step traces (`study --traces`, `compare --traces`): one row per run, filter and step in long format
(TRACE_COLUMNS, the filter's own diagnostics, its label and the row's parameters: `trace_column_names`;
docs/studies.md, Traces), CSV or Parquet, so that a band plot of the error against the steps is one
pandas `groupby`."""

from __future__ import annotations

import csv
import functools
import io
import math
from collections.abc import Callable, Iterable, Sequence
from dataclasses import fields
from pathlib import Path
from typing import Any

import numpy as np

from mazelab.atomic import write_atomically
from mazelab.registry import described
from mazelab.simulation import RunResult

PLOT_INSTALL_HINT = 'plotting needs matplotlib: pip install -e ".[plot]"'


def pyplot() -> Any:
    """matplotlib.pyplot on the Agg backend (no display needed), or a one-line install hint."""
    try:
        import matplotlib
    except ImportError:
        raise ValueError(PLOT_INSTALL_HINT) from None
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def save_figure(figure: Any, path: Path, *, replace: bool = True, dpi: int = 150) -> None:
    """Save a matplotlib figure atomically in the format of the path's suffix (raster formats at
    `dpi`), then close it (an existing file is replaced only with `replace`)."""
    buffer = io.BytesIO()
    try:
        figure.savefig(buffer, format=path.suffix.lstrip(".").lower() or "png", dpi=dpi)
    finally:
        pyplot().close(figure)
    write_atomically(path, buffer.getvalue(), replace=replace)


def beside(output: str | Path, suffix: str) -> Path:
    """The name of a file that goes with an output, beside it: study.csv -> study{suffix} (the journal,
    the record, the summary CSV)."""
    output = Path(output)
    return output.with_name(output.stem + suffix)


def format_table(headers: Sequence[str], rows: Sequence[Sequence[str]]) -> str:
    """A plain-text table: the first column left-aligned, the others right-aligned."""
    widths = [max(len(str(cell)) for cell in column) for column in zip(headers, *rows, strict=True)]

    def line(cells: Sequence[str]) -> str:
        return "  ".join(
            str(c).ljust(w) if i == 0 else str(c).rjust(w) for i, (c, w) in enumerate(zip(cells, widths, strict=True))
        ).rstrip()

    return "\n".join([line(headers), line(["-" * w for w in widths]), *map(line, rows)])


def column_table(columns: Sequence[tuple[str, Callable[[Any], str]]], items: Iterable[Any]) -> str:
    """A table (`format_table`) of a row per item: a column per (header, the function that makes its cell)."""
    return format_table([header for header, _ in columns], [[cell(item) for _, cell in columns] for item in items])


def format_number(value: float | None, spec: str) -> str:
    """`value` in `spec`, or '-' for none (None, NaN)."""
    return "-" if value is None or math.isnan(value) else spec.format(value)


def format_interval(low: float, high: float, spec: str = "{:.3f}") -> str:
    """'[low, high]' in `spec`, or '-' for an interval that could not be made (NaN)."""
    return "-" if math.isnan(low) else f"[{spec.format(low)}, {spec.format(high)}]"


def csv_cell(value: Any) -> Any:
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return ""
    return repr(value) if isinstance(value, float) else value


def flat_row(record: Any) -> dict[str, Any]:
    """A dataclass record as one row: its fields, with a record's `options` (a dict of the other
    filter options) spread into a column each. The values are the record's own (the records hold
    numbers, words and None, so no copy is needed, as dataclasses.asdict would make)."""
    row = {name: getattr(record, name) for name in _field_names(type(record))}
    row.update(row.pop("options", None) or {})
    return row


@functools.cache
def _field_names(record_class: type) -> tuple[str, ...]:
    return tuple(f.name for f in fields(record_class))


def records_csv(records: Sequence[Any], columns: Sequence[str]) -> str:
    """CSV text of rows (dicts, or dataclass records as `flat_row` spreads them), one row each in
    `columns` order (then any other column the rows carry, in the order they first appear; `columns`
    alone make the header of no rows); an empty cell for None and NaN, floats written in full (repr) so
    that the file reads back bit for bit."""
    rows = [record if isinstance(record, dict) else flat_row(record) for record in records]
    extra = dict.fromkeys(name for row in rows for name in row if name not in columns)
    buffer = io.StringIO()
    writer = csv.DictWriter(buffer, fieldnames=[*columns, *extra], lineterminator="\n")
    writer.writeheader()
    for row in rows:
        writer.writerow({k: csv_cell(v) for k, v in row.items()})
    return buffer.getvalue()


# -- per-step traces (`study --traces`, `compare --traces`) ------------------------------------------
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
    "log_evidence",  # log p(z_1:k) so far as the filter estimates it; empty for a filter that keeps none
]
PARAMETER_COLUMNS = ["maze", "sigma", "delta", "particles"]  # then the options the row's filter ran with
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


def trace_columns(
    setting: int | None,
    run: int,
    seed: int,
    name: str,
    trace: dict[str, Any],
    parameters: dict[str, Any] | None = None,
) -> dict[str, Any]:
    """One run and filter's trace as columns (arrays of one length): TRACE_COLUMNS, the filter's
    diagnostics, and the row's `parameters` (a value each, the same at every step)."""
    steps = len(trace["ess"])
    true, estimate = np.asarray(trace["true"], dtype=float), np.asarray(trace["estimate"], dtype=float)
    diagnostics = {name_: np.asarray(v, dtype=float) for name_, v in (trace.get("diagnostics") or {}).items()}
    constant = {name_: np.full(steps, value, dtype=object) for name_, value in (parameters or {}).items()}
    columns = {
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
        "log_evidence": np.asarray(trace.get("log_evidence", np.full(steps, np.nan)), dtype=float),
        **{f"{DIAGNOSTIC_PREFIX}{name_}": values for name_, values in diagnostics.items()},
        **constant,
    }
    if trace.get("exact") is not None:  # the exact posterior mean per step, and the estimate's distance to it
        exact = np.asarray(trace["exact"], dtype=float)
        columns.update(exact_x=exact[:, 0], exact_y=exact[:, 1], distance_to_exact=np.hypot(*(estimate - exact).T))
    return columns


DIAGNOSTIC_PREFIX = "diagnostic_"  # a filter's own per-step figure, e.g. diagnostic_regularised
# with `study --reference grid`: the exact posterior mean at each step (the grid filter's), and the
# distance of the filter's estimate to it
EXACT_COLUMNS = ["exact_x", "exact_y", "distance_to_exact"]


def per_step(column: str) -> bool:
    """Whether a column beyond TRACE_COLUMNS holds a number per step (a diagnostic, the exact posterior)
    rather than a parameter of the run."""
    return column.startswith(DIAGNOSTIC_PREFIX) or column in EXACT_COLUMNS


def study_traces(records: Iterable[Any]) -> list[dict[str, Any]]:
    """The traces a study's records (RunRecord) carry (RunTask.traces), as columns per run and filter,
    with the row's parameters: its label, why its log evidence is not of p(z_1:K) (if it is not),
    PARAMETER_COLUMNS, then the options its filter ran with (RunRecord.options)."""
    return [
        trace_columns(
            r.setting,
            r.run,
            r.seed,
            r.filter,
            r.trace,
            {
                "label": r.label,
                "log_evidence_caveat": r.log_evidence_caveat,
                **{name: getattr(r, name) for name in PARAMETER_COLUMNS},
                **r.options,
            },
        )
        for r in records
        if r.trace is not None
    ]


def trace_of(result: RunResult) -> dict[str, Any]:
    """A run's per-step arrays: true position, estimate, ESS, confidence, step time, particle count,
    log evidence so far, and the filter's own diagnostics by name (mazelab.simulation.record_steps: the
    RPF's `regularised`, recovery's `injection_probability`)."""
    return {
        "true": result.true_positions,
        "estimate": result.estimates,
        "ess": result.ess,
        "confident": result.confident,
        "step_seconds": result.step_seconds,
        "particle_count": result.extras["particle_count"],
        "log_evidence": result.log_evidence,
        "diagnostics": result.extras["diagnostics"],
    }


def compare_traces(results: dict[str, RunResult]) -> list[dict[str, Any]]:
    """compare's runs (one scenario, every filter) as trace columns, with each run's seed, maze (its
    source), sigma, delta and particle count, read from the run's inputs."""
    blocks = []
    for name, result in results.items():
        inputs = result.inputs
        parameters = {
            "label": described(name).label,
            "log_evidence_caveat": described(name).evidence,
            "maze": inputs.maze.source,
            "sigma": inputs.sigma,
            "delta": inputs.delta,
            "particles": len(inputs.init_particles_pos),
        }
        blocks.append(trace_columns(None, 1, inputs.seed, name, trace_of(result), parameters))
    return blocks


def trace_column_names(blocks: Sequence[dict[str, Any]]) -> list[str]:
    """The columns of these blocks: TRACE_COLUMNS, the diagnostics any of them has, then the parameters."""
    extra = dict.fromkeys(column for block in blocks for column in block if column not in TRACE_COLUMNS)
    diagnostics = [c for c in extra if per_step(c)]
    return [*TRACE_COLUMNS, *diagnostics, *(c for c in extra if c not in diagnostics)]


def trace_csv_rows(blocks: Sequence[dict[str, Any]], columns: Sequence[str]) -> str:
    """The rows of the blocks as CSV text, without the header, in `columns` (`trace_column_names`): exact
    floats (%.17g), an empty cell for NaN, for compare's setting and for a column a block lacks."""
    buffer = io.StringIO()
    numeric = TRACE_COLUMNS[4:]  # step .. log_evidence
    for block in blocks:
        setting = "" if block["setting"][0] == -1 else str(block["setting"][0])
        prefix = f"{setting},{block['run'][0]},{block['seed'][0]},{_cell(block['filter'][0])}"
        steps = len(block["step"])
        diagnostics = [c for c in columns[len(TRACE_COLUMNS) :] if per_step(c)]
        numbers = np.column_stack(
            [block[c].astype(float) for c in numeric] + [block.get(c, np.full(steps, np.nan)) for c in diagnostics]
        )
        text = io.StringIO()
        fmt = ["%d", *["%.17g"] * 6, "%d", "%.17g", "%d", "%.17g", *["%.17g"] * len(diagnostics)]
        np.savetxt(text, numbers, fmt=fmt, delimiter=",")
        constants = [c for c in columns[len(TRACE_COLUMNS) :] if not per_step(c)]
        suffix = "".join(f",{_cell(block[c][0]) if c in block else ''}" for c in constants)
        buffer.writelines(f"{prefix},{line}{suffix}\n" for line in text.getvalue().replace("nan", "").splitlines())
    return buffer.getvalue()


def _cell(value: Any) -> str:
    """A constant cell as CSV writes it (`csv_cell`), quoted where needed."""
    text = str(csv_cell(value))
    if any(ch in text for ch in ',"\n'):
        return '"' + text.replace('"', '""') + '"'
    return text


def write_traces(path: Path, blocks: Sequence[dict[str, Any]]) -> None:
    """Write the traces to `path`, whole (mazelab.atomic): CSV, or Parquet for a .parquet path."""
    if path.suffix.lower() == ".parquet":
        import pyarrow as pa
        import pyarrow.parquet as pq

        columns = trace_table_columns(blocks) or {c: np.array([]) for c in TRACE_COLUMNS}
        columns["setting"] = np.where(columns["setting"] == -1, None, columns["setting"])  # compare's: none
        table = pa.table({c: pa.array(list(v) if v.dtype == object else v) for c, v in columns.items()})
        buffer = io.BytesIO()
        pq.write_table(table, buffer)
        write_atomically(path, buffer.getvalue())
        return
    columns = trace_column_names(blocks)
    write_atomically(path, ",".join(columns) + "\n" + trace_csv_rows(blocks, columns))


def trace_table_columns(blocks: Sequence[dict[str, Any]]) -> dict[str, np.ndarray] | None:
    """The blocks as one set of columns (a diagnostic missing from a block: NaN there), or None."""
    if not blocks:
        return None
    columns = {c: np.concatenate([_filled(b, c) for b in blocks]) for c in trace_column_names(blocks)}
    return {c: numeric(values) for c, values in columns.items()}


def numeric(values: np.ndarray) -> np.ndarray:
    """A column of parameters as numbers when every value is one (sigma, delta, particles: float64 or
    int64, as pandas reads the CSV), else as it is (text, a missing value among numbers)."""
    if values.dtype != object or not len(values):
        return values
    kinds = {type(v) for v in values}
    if kinds <= {int, np.int64} and not any(isinstance(v, bool) for v in values):
        return values.astype(np.int64)
    if kinds <= {int, float, np.int64, np.float64} and not any(isinstance(v, bool) for v in values):
        return values.astype(np.float64)
    return values


def _filled(block: dict[str, Any], column: str) -> np.ndarray:
    """A block's column, or missing values where the block has none (another filter's diagnostic)."""
    if column in block:
        return block[column]
    steps = len(block["step"])
    return np.full(steps, np.nan) if per_step(column) else np.full(steps, None, dtype=object)
