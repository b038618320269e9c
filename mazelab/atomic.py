"""Files written whole or not at all: a temporary file in the same folder, then a rename.

Every write of this program goes through here (scenarios, CSV, figures, recordings, mazes):
- the temporary name holds the writer's pid and a random part (`.NAME.PID-RANDOM.tmp`, NAME cut so
  the whole stays within the folder's name limit), so concurrent writers never share one, and a
  temporary whose writer is gone (killed mid-write) is removed by the next write to that folder;
- a new file follows the umask (0644 under umask 022), a replaced file keeps its mode, and a
  symlink is written through to its target;
- any failure (full disk, file size limit, read-only folder, a name too long) removes the temporary,
  leaves an older file intact and raises WriteError: one line naming the file and the cause.
"""

from __future__ import annotations

import contextlib
import errno
import os
import re
import secrets
import stat
from pathlib import Path

TEMPORARY_PATTERN = re.compile(r"^\..*\.(\d+)-[0-9a-f]{8}\.tmp$")  # .NAME.PID-RANDOM.tmp
DEFAULT_NAME_MAX = 255  # bytes in one file name on the usual file systems


class WriteError(OSError):
    """A file that could not be written; str() is one line naming the file and the cause."""

    def __str__(self) -> str:
        cause = self.strerror or (os.strerror(self.errno) if self.errno else "write failed")
        return f"cannot write {self.filename}: {cause}"


def write_text_atomically(path: str | Path, text: str) -> None:
    """Write `text` to `path` whole or not at all: a temporary file in the same folder, then rename."""
    write_bytes_atomically(path, text.encode("utf-8"))


def write_bytes_atomically(path: str | Path, data: bytes, *, replace: bool = True) -> Path:
    """Write `data` to `path` whole or not at all (see the module docstring); returns the path.
    `replace=False` never replaces an existing file (FileExistsError): a name is claimed only once."""
    path = Path(path)
    temporary = None
    try:
        target = Path(os.path.realpath(path)) if path.is_symlink() else path  # --force onto a link: its target
        remove_stale_temporaries(target.parent)
        temporary = target.parent / temporary_name(target)
        mode = stat.S_IMODE(os.stat(target).st_mode) if target.exists() else None
        handle = os.open(temporary, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)  # 0o666 & ~umask
        try:
            write_all(handle, data)
            if mode is not None and hasattr(os, "fchmod"):
                os.fchmod(handle, mode)
            os.fsync(handle)
            if os.fstat(handle).st_size != len(data):
                raise OSError(errno.EIO, "the file on disk is shorter than what was written")
        finally:
            os.close(handle)
        move_into_place(temporary, target, replace)
        sync_folder(target.parent)
    except BaseException as error:
        if temporary is not None:
            with contextlib.suppress(OSError):  # e.g. a read-only folder, where it was never made
                temporary.unlink(missing_ok=True)
        if isinstance(error, OSError) and (replace or not isinstance(error, FileExistsError)):
            raise WriteError(error.errno, error.strerror, str(path)) from None
        raise
    return path


def sync_folder(folder: Path) -> None:
    """Make the rename itself durable (best effort: not every system can fsync a folder)."""
    if os.name == "nt":
        return
    with contextlib.suppress(OSError):
        handle = os.open(folder, os.O_RDONLY)
        try:
            os.fsync(handle)
        finally:
            os.close(handle)


def write_all(handle: int, data: bytes) -> None:
    """os.write until every byte is written (a short write is retried, an error raised)."""
    view = memoryview(data)
    while view:
        view = view[os.write(handle, view) :]


def move_into_place(temporary: Path, target: Path, replace: bool) -> None:
    """Rename `temporary` to `target`; with replace=False only if `target` does not exist yet."""
    if replace:
        os.replace(temporary, target)
        return
    try:
        os.link(temporary, target)  # fails with FileExistsError if another writer claimed the name
    except OSError as error:
        if error.errno not in (errno.EPERM, errno.ENOTSUP, errno.EOPNOTSUPP):
            raise
        if target.exists():  # a file system without hard links: check, then rename
            raise FileExistsError(errno.EEXIST, "File exists", str(target)) from None
        os.replace(temporary, target)
        return
    temporary.unlink(missing_ok=True)


def temporary_name(target: Path) -> str:
    """`.NAME.PID-RANDOM.tmp` for `target`, NAME cut so the whole fits the folder's name limit."""
    suffix = f".{os.getpid()}-{secrets.token_hex(4)}.tmp"
    room = name_max(target.parent) - len(suffix.encode()) - 1
    name = target.name.encode()[: max(room, 1)].decode(errors="ignore")
    return f".{name}{suffix}"


def name_max(folder: Path) -> int:
    """The longest file name (bytes) the folder's file system takes."""
    try:
        return int(os.pathconf(folder, "PC_NAME_MAX"))
    except (OSError, ValueError, AttributeError):
        return DEFAULT_NAME_MAX


def remove_stale_temporaries(folder: Path) -> list[Path]:
    """Remove this program's temporaries in `folder` whose writing process is gone; the removed ones."""
    removed = []
    try:
        entries = list(os.scandir(folder))
    except OSError:
        return removed
    for entry in entries:
        match = TEMPORARY_PATTERN.match(entry.name)
        if match and not process_alive(int(match.group(1))):
            try:
                os.unlink(entry.path)
                removed.append(Path(entry.path))
            except OSError:
                pass
    return removed


def process_alive(pid: int) -> bool:
    """Whether a process with this pid exists (ours, or another user's)."""
    if pid == os.getpid() or os.name == "nt":  # Windows: os.kill cannot ask, so keep the file
        return True
    if pid <= 0:
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OverflowError:
        return False
    except PermissionError:
        return True
    return not zombie(pid)


def zombie(pid: int) -> bool:
    """Whether the process has ended but not yet been reaped (Linux /proc; elsewhere False)."""
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except (OSError, IndexError):
        return False
    return state in ("Z", "X")


__all__ = [
    "WriteError",
    "move_into_place",
    "process_alive",
    "remove_stale_temporaries",
    "sync_folder",
    "temporary_name",
    "write_all",
    "write_bytes_atomically",
    "write_text_atomically",
    "zombie",
]
