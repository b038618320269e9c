"""A study's CSV as it grows: each finished run's rows are appended (and flushed) as they come, so a
study stopped any way (Ctrl-C, SIGTERM, kill -9) keeps every finished row. At the end the command
replaces the file, whole, by the rows in (setting, run, filter) order."""

from __future__ import annotations

import contextlib
import csv
from collections.abc import Sequence
from dataclasses import asdict
from pathlib import Path
from typing import TextIO

from mazelab.experiments.study import RunRecord
from mazelab.experiments.summary import CSV_COLUMNS
from mazelab.experiments.tables import csv_cell


class RowLog:
    """Appends a study's rows to `path` as runs finish; a write error stops the appending and is kept
    in `error` (the study goes on; the command reports it after the table)."""

    def __init__(self, path: str | Path):
        self.path = Path(path)
        self.error: OSError | None = None
        self._stream: TextIO | None = None
        try:
            self._stream = open(self.path, "w", encoding="utf-8", newline="")  # noqa: SIM115 (held for the study)
            self._writer = csv.DictWriter(self._stream, fieldnames=CSV_COLUMNS, lineterminator="\n")
            self._writer.writeheader()
            self._stream.flush()
        except OSError as error:
            self._fail(error)

    def append(self, records: Sequence[RunRecord]) -> None:
        """Write one finished run's rows and flush them to the file."""
        if self._stream is None:
            return
        try:
            for record in records:
                self._writer.writerow({k: csv_cell(v) for k, v in asdict(record).items()})
            self._stream.flush()
        except OSError as error:
            self._fail(error)

    def close(self) -> None:
        if self._stream is not None:
            try:
                self._stream.close()
            except OSError as error:
                self.error = self.error or error
            self._stream = None

    def _fail(self, error: OSError) -> None:
        self.error = self.error or error
        if self._stream is not None:
            with contextlib.suppress(OSError):
                self._stream.close()
            self._stream = None


__all__ = [
    "RowLog",
]
