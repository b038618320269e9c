"""The files a study reads back (its record, its CSV and partial file, its traces, for --resume): read
only when they are regular files, so that a pipe does not hang the program and a link to /dev/zero
does not fill its memory; every problem is one ValueError line naming the file."""

from __future__ import annotations

import errno
import os
import stat
from pathlib import Path

from mazelab.atomic import file_kind
from mazelab.limits import check_memory

READ_CHUNK = 1 << 20  # bytes per read
MEMORY_PER_BYTE = 12  # what reading a study's file takes per byte of it: the text, its lines, the rows (generous)


def read_regular_bytes(path: str | Path, what: str, *, follow_links: bool = True) -> bytes:
    """The bytes of `path`, a regular file (a symlink to one too, unless `follow_links` is False).

    A folder, pipe, device or socket (or, with `follow_links` False, a symlink) is a ValueError of
    one line naming the file and `what` it should be ("a study CSV"); so is a file that cannot be
    read. FileNotFoundError passes through (the caller says what a missing file means)."""
    path = Path(path)
    flags = os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_CLOEXEC", 0)  # a pipe: no wait for a writer
    if not follow_links:
        flags |= getattr(os, "O_NOFOLLOW", 0)
    try:
        handle = os.open(path, flags)
    except FileNotFoundError:
        raise
    except OSError as error:
        if error.errno == errno.ELOOP:
            kind = "a symlink loop" if follow_links else "a symlink"
            raise ValueError(f"{path}: it is {kind}, not a regular file; {what} is a regular file") from None
        raise ValueError(f"{path}: cannot read it ({error.strerror or error})") from None
    try:
        status = os.fstat(handle)
        if not stat.S_ISREG(status.st_mode):
            raise ValueError(f"{path}: it is {file_kind(status.st_mode)}, not a regular file; {what} is a regular file")
        check_memory(f"reading {path} ({status.st_size} bytes)", status.st_size * MEMORY_PER_BYTE)
        chunks = []
        while chunk := os.read(handle, READ_CHUNK):
            chunks.append(chunk)
    except OSError as error:
        raise ValueError(f"{path}: cannot read it ({error.strerror or error})") from None
    finally:
        os.close(handle)
    return b"".join(chunks)


def read_regular_text(path: str | Path, what: str, *, follow_links: bool = True) -> str:
    """`read_regular_bytes` decoded as UTF-8 (a byte-order mark is dropped); text in another encoding
    (UTF-16, Latin-1) is a ValueError naming the file."""
    data = read_regular_bytes(path, what, follow_links=follow_links)
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError as error:
        raise ValueError(
            f"{path}: not UTF-8 text (byte {error.start} is {data[error.start : error.start + 1]!r}); "
            f"{what} is UTF-8 text"
        ) from None


__all__ = ["read_regular_bytes", "read_regular_text"]
