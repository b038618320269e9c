"""Files written whole or not at all: a temporary file in the same folder, then a rename.

Every write of this program goes through here (scenarios, CSV, figures, recordings, mazes):
- the temporary name holds the writer's host, pid and a random part (`.NAME.HOST.PID-RANDOM.tmp`, NAME
  cut so the whole stays within the folder's name limit), so concurrent writers never share one, and a
  temporary whose writer is gone (killed mid-write) is removed by the next write to that folder from the
  same host: on a folder shared between machines (NFS) a pid says nothing about another host's
  processes, so another host's temporaries (and those without a host, of older versions) are kept;
- only regular files are ever replaced: a folder, device, pipe, socket or symlink loop at the name is
  refused (NotRegularFileError), `replace` or not; a symlink to a regular file is written through to its
  target, a dangling one only with `replace`;
- without `replace` the final name is created exclusively (a hard link of the finished temporary
  onto it, which fails atomically if the name exists): of concurrent writers exactly one wins, the
  others get NameTakenError; with `replace` the last writer wins, and a writer whose file another process
  replaced before it could say "saved" gets ReplacedMeanwhileError instead;
- a new file follows the umask (0644 under umask 022), a replaced file keeps its mode;
- any failure (full disk, file size limit, read-only folder, a name too long) removes the temporary,
  leaves an older file intact and raises WriteError: one line naming the file and the cause.
"""

from __future__ import annotations

import contextlib
import errno
import hashlib
import os
import re
import secrets
import socket
import stat
from pathlib import Path

try:
    import fcntl
except ImportError:  # Windows: no advisory locks
    fcntl = None  # type: ignore[assignment]

TEMPORARY_PATTERN = re.compile(r"^\..*\.([A-Za-z0-9_-]+)\.(\d+)-[0-9a-f]{8}\.tmp$")  # .NAME.HOST.PID-RANDOM.tmp
HOST_TAG_LENGTH = 40  # characters of the host name a temporary's name keeps (a hash of the rest joins them)
DEFAULT_NAME_MAX = 255  # bytes in one file name on the usual file systems


class WriteError(OSError):
    """A file that could not be written; str() is one line naming the file and the cause."""

    def __str__(self) -> str:
        cause = self.strerror or (os.strerror(self.errno) if self.errno else "write failed")
        return f"cannot write {self.filename}: {cause}"


class NotRegularFileError(WriteError):
    """An output name held by a folder, device, pipe or socket: never replaced, --force or not."""

    def __init__(self, path: str | Path, what: str):
        super().__init__(errno.EEXIST, f"it is {what}, not a regular file; only regular files are replaced", str(path))


class NameTakenError(WriteError, FileExistsError):
    """An output name that exists (or was created by another process meanwhile) and may not be replaced."""

    def __init__(self, path: str | Path, how: str = "it exists"):
        super().__init__(errno.EEXIST, f"{how}; use --force to replace it", str(path))


class ReplacedMeanwhileError(WriteError):
    """A file that another writer replaced right after this one wrote it: it is not this writer's."""

    def __str__(self) -> str:
        return f"{self.filename} was replaced by another process meanwhile: the file there is not this run's"


def file_kind(mode: int) -> str:
    """'a folder', 'a device', ... for a stat mode that is not a regular file's."""
    if stat.S_ISDIR(mode):
        return "a folder"
    if stat.S_ISCHR(mode) or stat.S_ISBLK(mode):
        return "a device"
    if stat.S_ISFIFO(mode):
        return "a pipe"
    if stat.S_ISSOCK(mode):
        return "a socket"
    return "not a regular file"


def output_target(path: str | Path, replace: bool, follow_links: bool = True) -> Path:
    """The file a write to `path` creates or replaces: `path`, or a symlink's final target. Raises
    NotRegularFileError for a folder, device, pipe or socket (`replace` or not), and without `replace`
    NameTakenError for an existing name (a symlink too, dangling or not). With `follow_links` False
    (a program's own working file) a symlink at the name is NotRegularFileError too, never followed."""
    path = Path(path)
    if not follow_links and path.is_symlink():
        raise NotRegularFileError(path, "a symlink")
    target = Path(os.path.realpath(path)) if path.is_symlink() else path
    try:
        mode = os.stat(target).st_mode
    except FileNotFoundError:
        if target is not path and not replace:
            raise NameTakenError(path, "it is a symlink to a missing file") from None
        return target
    except OSError as error:
        if error.errno == errno.ELOOP:  # a link to itself, or a chain that comes back
            raise NotRegularFileError(path, "a symlink loop") from None
        raise
    if not stat.S_ISREG(mode):
        raise NotRegularFileError(path, file_kind(mode))
    if not replace:
        raise NameTakenError(path)
    return target


def write_atomically(path: str | Path, data: str | bytes, *, replace: bool = True, follow_links: bool = True) -> Path:
    """Write `data` (text: UTF-8) to `path` whole or not at all, claiming the name only once without
    `replace` (see the module docstring); returns the path. `follow_links=False` (a program's own working
    file, such as a study's partial record) refuses a symlink at the name, and the rename replaces a link
    put there meanwhile rather than writing through it."""
    path, data = Path(path), data.encode("utf-8") if isinstance(data, str) else data
    temporary = None
    try:
        target = output_target(path, replace, follow_links)  # --force onto a link: its target
        remove_stale_temporaries(target.parent)
        temporary = target.parent / temporary_name(target)
        mode = stat.S_IMODE(os.stat(target).st_mode) if target.exists() else None
        handle = os.open(temporary, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)  # 0o666 & ~umask
        try:
            write_all(handle, data)
            if mode is not None and hasattr(os, "fchmod"):
                os.fchmod(handle, mode)
            os.fsync(handle)
            written = os.fstat(handle)
            if written.st_size != len(data):
                raise OSError(errno.EIO, "the file on disk is shorter than what was written")
        finally:
            os.close(handle)
        if replace:
            output_target(path, replace, follow_links)  # a device or pipe put there meanwhile is still never replaced
        move_into_place(temporary, target, replace)
        sync_folder(target.parent)
    except BaseException as error:
        if temporary is not None:
            with contextlib.suppress(OSError):  # e.g. a read-only folder, where it was never made
                temporary.unlink(missing_ok=True)
        if isinstance(error, WriteError):
            raise
        if isinstance(error, FileExistsError) and not replace:
            raise NameTakenError(path, "another process created it meanwhile") from None
        if isinstance(error, OSError):
            raise WriteError(error.errno, error.strerror, str(path)) from None
        raise
    with contextlib.suppress(OSError):  # still the file written: no other writer replaced it since
        now = os.stat(target)
        if (now.st_ino, now.st_dev) == (written.st_ino, written.st_dev) or os.name == "nt":
            return path
    raise ReplacedMeanwhileError(errno.EEXIST, "replaced meanwhile", str(path))


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
    """Rename `temporary` to `target`; with replace=False only if `target` does not exist yet (a hard
    link fails atomically with FileExistsError when another writer holds the name)."""
    if replace:
        os.replace(temporary, target)
        return
    try:
        os.link(temporary, target)  # fails with FileExistsError if another writer claimed the name
    except OSError as error:
        if error.errno not in (errno.EPERM, errno.ENOTSUP, errno.EOPNOTSUPP):
            raise
        if os.path.lexists(target):  # a file system without hard links: check, then rename
            raise FileExistsError(errno.EEXIST, "File exists", str(target)) from None
        os.replace(temporary, target)
        return
    temporary.unlink(missing_ok=True)


def temporary_name(target: Path) -> str:
    """`.NAME.HOST.PID-RANDOM.tmp` for `target`, NAME cut so the whole fits the folder's name limit."""
    suffix = f".{host_tag()}.{os.getpid()}-{secrets.token_hex(4)}.tmp"
    name_max = DEFAULT_NAME_MAX  # the longest file name (bytes) the folder's file system takes
    with contextlib.suppress(OSError, ValueError, AttributeError):
        name_max = int(os.pathconf(target.parent, "PC_NAME_MAX"))
    room = name_max - len(suffix.encode()) - 1
    name = target.name.encode()[: max(room, 1)].decode(errors="ignore")
    return f".{name}{suffix}"


def host_tag(host: str | None = None) -> str:
    """This host's name as a temporary's name holds it: letters, digits, '-' and '_' only (a dot
    would split the name), at most HOST_TAG_LENGTH characters; a name that had to change gets a
    short hash of the whole, so that two hosts never share a tag."""
    host = socket.gethostname() if host is None else host
    tag = re.sub(r"[^A-Za-z0-9-]", "_", host)
    if tag != host or len(tag) > HOST_TAG_LENGTH or not tag:
        digest = hashlib.sha256(host.encode("utf-8", "surrogateescape")).hexdigest()[:8]
        tag = f"{tag[: HOST_TAG_LENGTH - 9]}_{digest}"
    return tag


def remove_stale_temporaries(folder: Path) -> list[Path]:
    """Remove this program's temporaries in `folder` written on this host by a process that is gone;
    the removed ones. Another host's are kept: its writer may be alive there (a shared folder)."""
    removed = []
    try:
        entries = list(os.scandir(folder))
    except OSError:
        return removed
    here = host_tag()
    for entry in entries:
        match = TEMPORARY_PATTERN.match(entry.name)
        if match and match.group(1) == here and not process_alive(int(match.group(2))):
            with contextlib.suppress(OSError):  # removed meanwhile, or not ours to remove
                os.unlink(entry.path)
                removed.append(Path(entry.path))
    return removed


def process_alive(pid: int) -> bool:
    """Whether a process with this pid exists (ours, or another user's)."""
    if pid == os.getpid() or os.name == "nt":  # Windows: os.kill cannot ask, so keep the file
        return True
    if pid <= 0:
        return False
    try:
        os.kill(pid, 0)
    except (ProcessLookupError, OverflowError):  # gone, or a number no process can have
        return False
    except PermissionError:
        return True
    try:  # a process that has ended but is not yet reaped is gone too (Linux /proc; elsewhere alive)
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except (OSError, IndexError):
        return True
    return state not in ("Z", "X")


def lock(handle: int) -> bool:
    """Lock an open file for this process (exclusive, without waiting: flock, released when the file is
    closed or the process ends); False if another process holds it. Where there is no flock (Windows),
    True (a study's journal is still claimed by its exclusive creation). The one lock of the program's
    own files (a study's journal, a grader's claims)."""
    if fcntl is None:
        return True
    try:
        fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        return False
    return True
