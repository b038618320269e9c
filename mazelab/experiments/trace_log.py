"""A study's traces as they grow (`study --csv ... --traces T`): each finished run's trace rows are
appended to `T.partial` (CSV, whatever T's format) as its rows are to the CSV's partial file, so a study
stopped any way (kill -9 included) keeps every finished run's traces beside its rows, and `--resume`
keeps those runs instead of running them again. The file is created by the study itself (never through
a link), locked while the study runs (a second study with the same --traces is refused before its
runs), and removed when the whole traces file is written at the end.

Its header is the columns seen so far: a run whose filter brings a diagnostic not seen before widens it
(the file is rewritten whole, the earlier rows given empty cells there)."""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from mazelab.atomic import write_all
from mazelab.experiments.rowlog import AppendedFile, PartialFileError, check_partial_name, lock, partial_path
from mazelab.experiments.study import RunRecord
from mazelab.experiments.traces import (
    TRACE_COLUMNS,
    ordered,
    relaid,
    study_traces,
    trace_column_names,
    trace_csv_rows,
    trace_header,
)

_FLAGS = os.O_WRONLY | os.O_APPEND | getattr(os, "O_NOFOLLOW", 0)


class TraceLog(AppendedFile):
    """The partial traces of a study: `kept` (the header and rows an earlier session kept, --resume)
    written at once, then each finished run's traces appended (`append`)."""

    def __init__(self, traces: Path, *, replace: bool = False, adopt: bool = False, kept: Any = None):
        self.partial = partial_path(traces)
        check_partial_name(self.partial)
        header, rows = kept if isinstance(kept, tuple) else (list(TRACE_COLUMNS), "")
        self.columns: list[str] = list(header)
        self._handle: int | None = None
        self._open(replace or adopt)
        self._rewrite(trace_header(self.columns) + rows)

    def _open(self, replace: bool) -> None:
        """Create the partial traces exclusively, or take over a stopped session's (`replace`): locked."""
        try:
            handle = os.open(self.partial, _FLAGS | os.O_CREAT | os.O_EXCL, 0o666)
        except FileExistsError:
            handle = os.open(self.partial, _FLAGS)
            if not lock(handle):
                os.close(handle)
                raise PartialFileError(
                    f"{self.partial} is being written by another study now: give it another --traces"
                ) from None
            if not replace:
                os.close(handle)
                raise PartialFileError(
                    f"{self.partial} is left from a stopped study: go on with --resume, or replace it with --force"
                ) from None
        else:
            if not lock(handle):  # pragma: no cover (a file just created exclusively)
                os.close(handle)
                raise PartialFileError(f"{self.partial} is being written by another study now")
        self._handle = handle

    def _rewrite(self, text: str) -> None:
        """Replace the file's contents with `text` (truncated and written in place: the lock stays)."""
        if self._handle is None:
            return
        os.ftruncate(self._handle, 0)
        write_all(self._handle, text.encode("utf-8"))

    def append(self, records: Sequence[RunRecord]) -> None:
        """Append one finished run's traces; a write error stops the log (the final file is still whole)."""
        blocks = study_traces(records)
        if self._handle is None or not blocks:
            return
        wanted = ordered([*self.columns, *trace_column_names(blocks)])
        try:
            if wanted != self.columns:
                old = self.partial.read_text(encoding="utf-8").split("\n", 1)[1] if self.partial.exists() else ""
                self._rewrite(trace_header(wanted) + relaid(old, self.columns, wanted))
                self.columns = wanted
            write_all(self._handle, trace_csv_rows(blocks, self.columns).encode("utf-8"))
        except OSError:
            self.close()


__all__ = ["TraceLog"]
