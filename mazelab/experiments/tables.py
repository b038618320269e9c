"""Output helpers of the experiments: plain-text tables, CSV cells, and figures saved atomically."""

from __future__ import annotations

import csv
import functools
import io
import math
from collections.abc import Sequence
from dataclasses import fields
from pathlib import Path
from typing import Any

from mazelab.atomic import write_bytes_atomically

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
    write_bytes_atomically(path, buffer.getvalue(), replace=replace)


def format_table(headers: Sequence[str], rows: Sequence[Sequence[str]]) -> str:
    """A plain-text table: the first column left-aligned, the others right-aligned."""
    widths = [max(len(str(cell)) for cell in column) for column in zip(headers, *rows, strict=True)]

    def line(cells: Sequence[str]) -> str:
        return "  ".join(
            str(c).ljust(w) if i == 0 else str(c).rjust(w) for i, (c, w) in enumerate(zip(cells, widths, strict=True))
        ).rstrip()

    return "\n".join([line(headers), line(["-" * w for w in widths]), *map(line, rows)])


def format_number(value: float, spec: str) -> str:
    return "-" if math.isnan(value) else spec.format(value)


def format_interval(low: float, high: float, spec: str = "{:.3f}") -> str:
    """'[low, high]' in `spec`, or '-' for an interval that could not be made (NaN)."""
    return "-" if math.isnan(low) else f"[{spec.format(low)}, {spec.format(high)}]"


def format_optional(value: float | None, spec: str) -> str:
    return "-" if value is None else spec.format(value)


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
