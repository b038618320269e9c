"""A study's CSV as it grows: each finished run's rows are appended (and flushed) to a partial file
beside the CSV, `NAME.csv.partial`, so a study stopped any way (Ctrl-C, SIGTERM, kill -9, a lost
cluster, a full disk) keeps every finished row there, and the CSV itself is the old file or the new
whole one, never a cut one. At the end the whole CSV, in (setting, run, filter) order, is written
through mazelab.atomic and the partial file removed.

The partial file is a regular file the study creates itself: a symlink (or a second name of another
file, a pipe, a folder) at its name is refused, never followed. It is created exclusively and locked
while its study runs: a second study with the same CSV is refused, and a partial file left by a study
that was stopped is reported (and replaced only with --force).

The study's record goes the same way: while the study runs (and when it is stopped) its record is
`NAME.record.json.partial`, beside the partial rows it describes; the record beside the CSV is
replaced right after the CSV itself, so that it always describes the CSV beside it."""

from __future__ import annotations

import contextlib
import csv
import errno
import io
import os
import stat
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from mazelab.atomic import file_kind, output_target, temporary_name, write_all, write_text_atomically
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


def _not_ours(partial: Path, what: str) -> str:
    return (
        f"{partial} is {what}; a study's partial file is a regular file the study creates itself (it never "
        "writes through a link): move it away or give another --csv"
    )


def check_partial_name(partial: str | Path) -> None:
    """Refuse, in one line, a partial file's name (rows or record) held by anything but a regular file
    of one name: a symlink (dangling or not), a second name of another file (a hard link), a folder,
    pipe, device or socket. Nothing there is fine."""
    partial = Path(partial)
    try:
        status = os.lstat(partial)
    except FileNotFoundError:
        return
    except OSError as error:
        raise PartialFileError(f"{partial}: cannot look at it ({error.strerror or error})") from None
    _check_partial_status(partial, status)


def _check_partial_status(partial: Path, status: os.stat_result) -> None:
    if stat.S_ISLNK(status.st_mode):
        raise PartialFileError(_not_ours(partial, "a symlink"))
    if not stat.S_ISREG(status.st_mode):
        raise PartialFileError(_not_ours(partial, file_kind(status.st_mode)))
    if status.st_nlink > 1:
        raise PartialFileError(_not_ours(partial, "a second name of another file (a hard link)"))


def check_left_over(path: str | Path, replace: bool = False, adopt: bool = False) -> None:
    """Refuse, in one line, a CSV whose partial file is not a regular file of its own (a symlink, a
    hard link, a pipe), one whose partial file another study is writing, or (unless `replace` or
    `adopt`, --resume) one that a stopped study left: checked before the study's other outputs, so
    that the line names the partial file and --resume, not the record the stopped study also left."""
    partial = partial_path(path)
    check_partial_name(partial)
    if not partial.exists():
        return
    try:
        handle = os.open(partial, os.O_RDONLY | _NOFOLLOW | _NONBLOCK)
    except OSError:
        return  # RowLog reports what is wrong with it
    try:
        if not lock(handle):
            raise PartialFileError(_busy(partial))
        if not (replace or adopt):
            raise PartialFileError(_left_over(partial))
    finally:
        os.close(handle)  # and with it the lock


class AppendedFile:
    """A partial file a study appends to as its runs finish (`partial`, open as the descriptor
    `_handle`): `close` releases it and leaves it (a stopped study's, for --resume), `discard` removes it
    (its whole file is written, or the study did not start). RowLog and TraceLog are such files."""

    partial: Path
    _handle: int | None = None

    def close(self) -> None:
        """Stop appending and release the partial file (it stays where it is)."""
        if self._handle is not None:
            with contextlib.suppress(OSError):
                os.close(self._handle)
            self._handle = None

    def discard(self) -> None:
        """Remove the partial file."""
        self.close()
        with contextlib.suppress(OSError):
            self.partial.unlink()


class RowLog(AppendedFile):
    """Appends a study's rows to `partial` (NAME.csv.partial) as runs finish. A write error stops the
    appending (the partial file is cut back to its last whole row) and is kept in `error`: the study
    goes on, and `finish` still tries to write the whole CSV from the rows in memory.

    Raises PartialFileError (a ValueError: one line) when another study writes the same partial file,
    or when one is left from a stopped study and `replace` is False; `note` says when one was replaced.

    `kept` (--resume): the rows kept from an earlier session, written at once after the header. A
    partial file that a stopped session left (`adopt`) is replaced whole by the header and the kept
    rows (a new file renamed over it), so that no moment leaves the kept rows only in memory.
    `columns`: the study's (CSV_COLUMNS, then a column per other filter option it sets)."""

    def __init__(
        self,
        path: str | Path,
        *,
        replace: bool = False,
        adopt: bool = False,
        record: str | Path | None = None,
        kept: Sequence[RunRecord] = (),
        columns: Sequence[str] = CSV_COLUMNS,
    ):
        self.path = Path(path)
        self.columns = list(columns)  # the study's columns: CSV_COLUMNS, then a column per other option
        self.adopt = adopt  # --resume: a leftover partial file is this study's own (rewritten with the kept rows)
        self.partial = partial_path(self.path)
        self.record = None if record is None else Path(record)  # the study's record beside the CSV
        self.record_partial = None if record is None else partial_path(record)  # ... beside the partial rows
        if self.record_partial is not None:
            check_partial_name(self.record_partial)
        self.replace = replace
        self.error: OSError | None = None
        self.note: str | None = None
        self._size = 0  # bytes of whole rows in the partial file
        output_target(self.path, replace)  # a device, pipe or folder; an existing CSV without --force
        self._handle: int | None = self._open_partial()
        text = rows_text(kept, header=True, columns=self.columns)
        if self._adopted:
            try:
                self._handle = self._rewrite(self._handle, text)
            except OSError as error:  # the partial file stays as the stopped session left it
                self.error = error
            return
        try:
            self._write(text)
        except OSError as error:
            self._fail(error)

    def _open_partial(self) -> int:
        check_partial_name(self.partial)  # a symlink, hard link, device or folder of that name is never written
        try:
            handle = os.open(self.partial, os.O_WRONLY | os.O_CREAT | os.O_EXCL | _NOFOLLOW, 0o666)
            left = False
        except FileExistsError:
            handle = self._open_left_over()
            left = True
        if not lock(handle):
            os.close(handle)
            raise PartialFileError(_busy(self.partial))
        self._adopted = left and self.adopt
        if left and not self.adopt:
            if not self.replace:
                os.close(handle)
                raise PartialFileError(_left_over(self.partial))
            os.ftruncate(handle, 0)
            self.note = f"discarded the rows of an earlier stopped study in {self.partial} (--force)"
        return handle

    def _rewrite(self, old: int, text: str) -> int:
        """Replace the adopted partial file (locked by `old`) by a new one holding `text`, locked before
        it takes the name; returns the new one's handle. On an error the old file stays whole and is
        released (raised; no more rows are appended)."""
        temporary = self.partial.parent / temporary_name(self.partial)
        try:
            new = os.open(temporary, os.O_WRONLY | os.O_CREAT | os.O_EXCL | _NOFOLLOW, 0o666)
        except OSError:
            os.close(old)
            self._handle = None
            raise
        try:
            lock(new)
            write_all(new, text.encode("utf-8"))
            os.fsync(new)
            os.replace(temporary, self.partial)
        except OSError:
            os.close(new)
            with contextlib.suppress(OSError):
                temporary.unlink()
            os.close(old)
            self._handle = None
            raise
        os.close(old)
        self._size = len(text.encode("utf-8"))
        return new

    def _open_left_over(self) -> int:
        """The partial file an earlier study left, opened without following a link and checked again
        on the open file (a symlink put there meanwhile is refused, not followed)."""
        try:
            handle = os.open(self.partial, os.O_WRONLY | _NOFOLLOW | _NONBLOCK)
        except OSError as error:
            if error.errno in (errno.ELOOP, errno.EMLINK, errno.ENXIO):  # a symlink; a pipe with no reader
                check_partial_name(self.partial)
                raise PartialFileError(_not_ours(self.partial, "not a regular file")) from None
            raise
        try:
            _check_partial_status(self.partial, os.fstat(handle))
        except PartialFileError:
            os.close(handle)
            raise
        return handle

    def write_record(self, recorder: Any) -> None:
        """Write the study's record beside its partial rows (NAME.record.json.partial), whole: the
        record beside the CSV stays the one that describes that CSV until the new CSV replaces it."""
        if self.record_partial is not None:
            check_partial_name(self.record_partial)
            recorder.write(self.record_partial, follow_links=False)

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

    def finish(self, records: Sequence[RunRecord], recorder: Any = None) -> None:
        """Write the whole CSV (old file or new whole one) from `records`, right after it the record
        beside it (with `recorder`), then remove the partial files; on a write error (raised) the
        partial files stay, named by `kept` (--resume goes on from them), the partial record updated
        (best effort) to the finished session's."""
        if recorder is not None:
            with contextlib.suppress(OSError, PartialFileError):
                self.write_record(recorder)
        write_text_atomically(self.path, study_csv(records, self.columns), replace=self.replace)
        if recorder is not None and self.record is not None:
            recorder.write(self.record)
        for partial in (self.partial, self.record_partial):
            if partial is not None:
                with contextlib.suppress(OSError):
                    partial.unlink()
        self.close()

    def kept(self) -> str:
        """Where the finished rows are, for a message: 'they are in NAME.csv.partial'."""
        return f"the finished rows are in {self.partial}"

    def _fail(self, error: OSError) -> None:
        self.error = self.error or error
        if self._handle is not None:
            with contextlib.suppress(OSError):
                os.ftruncate(self._handle, self._size)  # no row cut in half
        self.close()


_NOFOLLOW = getattr(os, "O_NOFOLLOW", 0)  # a symlink at the name: ELOOP, never its target
_NONBLOCK = getattr(os, "O_NONBLOCK", 0)  # a pipe at the name: no wait for its other end


def lock(handle: int) -> bool:
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
    "AppendedFile",
    "PartialFileError",
    "RowLog",
    "check_left_over",
    "check_partial_name",
    "lock",
    "partial_path",
    "rows_text",
]
