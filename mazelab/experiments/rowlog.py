"""A study's CSV as it grows: each finished run's rows are appended (and flushed) to a partial file
beside the CSV, `NAME.csv.partial`, so a study stopped any way (Ctrl-C, SIGTERM, kill -9, a lost
cluster, a full disk) keeps every finished row there, and the CSV itself is the old file or the new
whole one, never a cut one. At the end the whole CSV, in (setting, run, filter) order, is written
through mazelab.atomic and the partial file removed.

The partial file is created exclusively and locked while its study runs: a second study with the
same CSV is refused, and a partial file left by a study that was stopped is reported (and replaced
only with --force)."""

from __future__ import annotations

import contextlib
import csv
import io
import os
from collections.abc import Sequence
from pathlib import Path

from mazelab.atomic import output_target, write_all, write_text_atomically
from mazelab.experiments.study import RunRecord
from mazelab.experiments.summary import CSV_COLUMNS, study_csv
from mazelab.experiments.tables import csv_cell, flat_row

try:
    import fcntl
except ImportError:  # Windows: no advisory locks; the exclusive creation still refuses a second study
    fcntl = None  # type: ignore[assignment]

PARTIAL_SUFFIX = ".partial"


class PartialFileError(ValueError):
    """A study's partial file that is in the way: another study's, or an earlier stopped one's."""


def partial_path(path: str | Path) -> Path:
    """Where a study's rows go while it runs: NAME.csv.partial beside NAME.csv."""
    path = Path(path)
    return path.with_name(path.name + PARTIAL_SUFFIX)


def rows_text(records: Sequence[RunRecord], header: bool = False, columns: Sequence[str] = CSV_COLUMNS) -> str:
    """CSV lines of `records` in `columns` (the study's: CSV_COLUMNS, then its other options), with the
    header line first if asked."""
    buffer = io.StringIO()
    writer = csv.DictWriter(buffer, fieldnames=list(columns), lineterminator="\n")
    if header:
        writer.writeheader()
    for record in records:
        writer.writerow({k: csv_cell(v) for k, v in flat_row(record).items()})
    return buffer.getvalue()


def _busy(partial: Path) -> str:
    return f"another study is writing {partial}: give this one another --csv"


def _left_over(partial: Path) -> str:
    return (
        f"{partial} holds the rows of an earlier study that was stopped: add --resume to the same command "
        "to go on with it, or use --force to discard it"
    )


def check_left_over(path: str | Path, replace: bool = False) -> None:
    """Refuse, in one line, a CSV whose partial file another study is writing, or (unless `replace`)
    one that a stopped study left: checked before the study's other outputs, so that the line names
    the partial file and --resume, not the record the stopped study also left."""
    partial = partial_path(path)
    if not partial.is_file():
        return
    try:
        handle = os.open(partial, os.O_RDONLY)
    except OSError:
        return  # RowLog reports what is wrong with it
    try:
        if not _lock(handle):
            raise PartialFileError(_busy(partial))
        if not replace:
            raise PartialFileError(_left_over(partial))
    finally:
        os.close(handle)  # and with it the lock


class RowLog:
    """Appends a study's rows to `partial` (NAME.csv.partial) as runs finish. A write error stops the
    appending (the partial file is cut back to its last whole row) and is kept in `error`: the study
    goes on, and `finish` still tries to write the whole CSV from the rows in memory.

    Raises PartialFileError (a ValueError: one line) when another study writes the same partial file,
    or when one is left from a stopped study and `replace` is False; `note` says when one was replaced."""

    def __init__(
        self, path: str | Path, *, replace: bool = False, adopt: bool = False, columns: Sequence[str] = CSV_COLUMNS
    ):
        self.path = Path(path)
        self.columns = list(columns)  # the study's columns: CSV_COLUMNS, then a column per other option
        self.adopt = adopt  # --resume: a leftover partial file is this study's own (its kept rows are re-appended)
        self.partial = partial_path(self.path)
        self.replace = replace
        self.error: OSError | None = None
        self.note: str | None = None
        self._size = 0  # bytes of whole rows in the partial file
        output_target(self.path, replace)  # a device, pipe or folder; an existing CSV without --force
        self._handle: int | None = self._open_partial()
        try:
            self._write(rows_text([], header=True, columns=self.columns))
        except OSError as error:
            self._fail(error)

    def _open_partial(self) -> int:
        output_target(self.partial, True)  # a device or folder of that name is never written
        try:
            handle = os.open(self.partial, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
            left = False
        except FileExistsError:
            handle = os.open(self.partial, os.O_WRONLY)
            left = True
        if not _lock(handle):
            os.close(handle)
            raise PartialFileError(_busy(self.partial))
        if left:
            if not (self.replace or self.adopt):
                os.close(handle)
                raise PartialFileError(_left_over(self.partial))
            os.ftruncate(handle, 0)
            if not self.adopt:
                self.note = f"discarded the rows of an earlier stopped study in {self.partial} (--force)"
        return handle

    def append(self, records: Sequence[RunRecord]) -> None:
        """Write one finished run's rows to the partial file."""
        if self._handle is None:
            return
        try:
            self._write(rows_text(records, columns=self.columns))
        except OSError as error:
            self._fail(error)

    def _write(self, text: str) -> None:
        if self._handle is None:
            return
        write_all(self._handle, text.encode("utf-8"))
        self._size += len(text.encode("utf-8"))

    def finish(self, records: Sequence[RunRecord]) -> None:
        """Write the whole CSV (old file or new whole one) from `records`, then remove the partial
        file; on a write error (raised) the partial file stays, named by `kept`."""
        write_text_atomically(self.path, study_csv(records, self.columns), replace=self.replace)
        with contextlib.suppress(OSError):
            self.partial.unlink()
        self.close()

    def kept(self) -> str:
        """Where the finished rows are, for a message: 'they are in NAME.csv.partial'."""
        return f"the finished rows are in {self.partial}"

    def close(self) -> None:
        """Stop appending and release the partial file (it stays where it is)."""
        if self._handle is not None:
            with contextlib.suppress(OSError):
                os.close(self._handle)
            self._handle = None

    def discard(self) -> None:
        """Remove the partial file (a study that did not start)."""
        self.close()
        with contextlib.suppress(OSError):
            self.partial.unlink()

    def _fail(self, error: OSError) -> None:
        self.error = self.error or error
        if self._handle is not None:
            with contextlib.suppress(OSError):
                os.ftruncate(self._handle, self._size)  # no row cut in half
        self.close()


def _lock(handle: int) -> bool:
    """Lock the partial file for this study; False if another study holds it."""
    if fcntl is None:
        return True
    try:
        fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        return False
    return True


__all__ = [
    "PARTIAL_SUFFIX",
    "PartialFileError",
    "RowLog",
    "check_left_over",
    "partial_path",
    "rows_text",
]
