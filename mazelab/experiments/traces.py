"""Per-step traces (`study --traces`, `compare --traces`): one row per run, filter and step, in long
format, so that pandas reads them directly (`pandas.read_csv`, or `read_parquet` for a .parquet file,
which needs pyarrow). Columns: TRACE_COLUMNS, then each filter's own diagnostics (`regularised`,
`injection_probability`, ...: empty where a filter has none), then the filter's label (SIR), why its
log evidence is not an estimate of p(z_1:k) under the model (the RPF's; empty for the others) and the
row's parameters (the maze,
sigma, delta, particles, then every option the filter ran with: empty where a filter does not declare
one), so that a band plot of the error against the steps, by filter and parameter, is one `groupby`."""

from __future__ import annotations

import io
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from mazelab.atomic import write_bytes_atomically, write_text_atomically
from mazelab.experiments.study import RunRecord, trace_of
from mazelab.registry import described
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
        "log_evidence": np.asarray(trace.get("log_evidence", np.full(steps, np.nan)), dtype=float),
        **{f"{DIAGNOSTIC_PREFIX}{name_}": values for name_, values in diagnostics.items()},
        **exact_columns(trace.get("exact"), estimate),
        **constant,
    }


DIAGNOSTIC_PREFIX = "diagnostic_"  # a filter's own per-step figure, e.g. diagnostic_regularised
# with `study --reference grid`: the exact posterior mean at each step (the grid filter's), and the
# distance of the filter's estimate to it
EXACT_COLUMNS = ["exact_x", "exact_y", "distance_to_exact"]


def per_step(column: str) -> bool:
    """Whether a column beyond TRACE_COLUMNS holds a number per step (a diagnostic, the exact posterior)
    rather than a parameter of the run."""
    return column.startswith(DIAGNOSTIC_PREFIX) or column in EXACT_COLUMNS


def exact_columns(exact: Any, estimate: np.ndarray) -> dict[str, np.ndarray]:
    """The exact posterior mean per step and the estimate's distance to it (none without a reference)."""
    if exact is None:
        return {}
    exact = np.asarray(exact, dtype=float)
    return {"exact_x": exact[:, 0], "exact_y": exact[:, 1], "distance_to_exact": np.hypot(*(estimate - exact).T)}


def record_parameters(record: RunRecord) -> dict[str, Any]:
    """A study row's parameters as trace columns: its label, why its log evidence is not of p(z_1:K) (if
    it is not), PARAMETER_COLUMNS, then the options its filter ran with (RunRecord.options)."""
    return {"label": record.label, "log_evidence_caveat": record.log_evidence_caveat,
            **{name: getattr(record, name) for name in PARAMETER_COLUMNS}, **record.options}  # fmt: skip


def study_traces(records: Iterable[RunRecord]) -> list[dict[str, Any]]:
    """The traces a study's records carry (RunTask.traces), as columns per run and filter, with the
    row's parameters."""
    return [
        trace_columns(r.setting, r.run, r.seed, r.filter, r.trace, record_parameters(r))
        for r in records
        if r.trace is not None
    ]


def compare_traces(results: dict[str, RunResult], seed: int, maze: str | None = None) -> list[dict[str, Any]]:
    """compare's runs (one scenario, every filter) as trace columns, with each run's sigma, delta and
    particle count (and `maze`, the scenario's, if given)."""
    blocks = []
    for name, result in results.items():
        inputs = result.inputs
        parameters = {"label": described(name).label, "log_evidence_caveat": described(name).evidence, "maze": maze,
                      "sigma": inputs.sigma, "delta": inputs.delta, "particles": len(inputs.particles)}  # fmt: skip
        blocks.append(trace_columns(None, 1, seed, name, trace_of(result), parameters))
    return blocks


def trace_column_names(blocks: Sequence[dict[str, Any]]) -> list[str]:
    """The columns of these blocks: TRACE_COLUMNS, the diagnostics any of them has, then the parameters."""
    extra = dict.fromkeys(column for block in blocks for column in block if column not in TRACE_COLUMNS)
    diagnostics = [c for c in extra if per_step(c)]
    return [*TRACE_COLUMNS, *diagnostics, *(c for c in extra if c not in diagnostics)]


def trace_csv_rows(blocks: Sequence[dict[str, Any]], columns: Sequence[str] | None = None) -> str:
    """The rows of the blocks as CSV text, without the header, in `columns` (default: the blocks' own):
    exact floats (%.17g), an empty cell for NaN, for compare's setting and for a column a block lacks."""
    columns = trace_column_names(blocks) if columns is None else list(columns)
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
    """A constant cell as CSV writes it: an empty one for None, a float in full, quoted where needed."""
    if value is None or (isinstance(value, float) and np.isnan(value)):
        return ""
    text = repr(value) if isinstance(value, float) else str(value)
    if any(ch in text for ch in ',"\n'):
        return '"' + text.replace('"', '""') + '"'
    return text


def write_traces(path: Path, blocks: Sequence[dict[str, Any]]) -> None:
    """Write the traces to `path`, whole (mazelab.atomic): CSV, or Parquet for a .parquet path."""
    if path.suffix.lower() == ".parquet":
        import pyarrow as pa
        import pyarrow.parquet as pq

        names = trace_column_names(blocks)
        columns = {c: np.concatenate([_filled(b, c) for b in blocks]) if blocks else np.array([]) for c in names}
        columns["setting"] = np.where(columns["setting"] == -1, None, columns["setting"]) if blocks else []
        table = pa.table(
            {c: pa.array(list(v) if v.dtype == object or c == "setting" else v) for c, v in columns.items()}
        )
        buffer = io.BytesIO()
        pq.write_table(table, buffer)
        write_bytes_atomically(path, buffer.getvalue())
        return
    columns = trace_column_names(blocks)
    write_text_atomically(path, ",".join(columns) + "\n" + trace_csv_rows(blocks, columns))


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
