"""A study's journal: one JSON line per finished run, appended as the runs finish, from which the CSV,
the traces and `--resume` are derived (NAME.runs.jsonl beside NAME.csv; `accuracy` keeps one too).

Its lines: {"session": {...}} when a session starts (its command, its start, the parameters that
--resume compares), {"run": [setting, run], "records": [...]} per finished run (each filter's row, with
its per-step trace when the study keeps traces), {"closed": {...}} when a session ends (its status, its
end, the runs finished). What a stopped study keeps there and how `--resume` goes on from it (a larger
--runs extends the study): docs/studies.md.

The journal is the program's own file, never followed through a link nor read from a pipe or a device
(`check_own_file`), created exclusively and locked while its study runs (`Journal`), read back whole
(`read_journal`); the other outputs of a study are claimed by a locked NAME.lock beside each (`claim_outputs`).

The record of how a result was made (`Recorder`): NAME.record.json beside a study's CSV (and beside
compare's and accuracy's outputs), what it holds in docs/studies.md (The record).
"""

from __future__ import annotations

import contextlib
import datetime as dt
import errno
import functools
import json
import os
import platform
import stat
import subprocess
import sys
import time
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from mazelab.atomic import file_kind, lock, write_all, write_atomically
from mazelab.backend import backend_versions
from mazelab.checks import check_memory, check_seed
from mazelab.experiments.study import RunRecord, RunTask, option_cells
from mazelab.experiments.summary import CONFIDENCE_LEVEL, INTERVAL_METHODS
from mazelab.experiments.tables import beside

journal_path = functools.partial(beside, suffix=".runs.jsonl")  # a study's journal: study.csv -> study.runs.jsonl
CLAIM_SUFFIX = ".lock"
MEMORY_PER_BYTE = 12  # what reading a journal takes per byte of it: the text, its lines, the records (generous)
_NOFOLLOW = getattr(os, "O_NOFOLLOW", 0)  # a symlink at the name: ELOOP, never its target
_NONBLOCK = getattr(os, "O_NONBLOCK", 0)  # a pipe at the name: no wait for its other end


class JournalError(ValueError):
    """A journal (or a claimed output) that is in the way or cannot be used: one line naming it."""


def _not_ours(path: Path, what: str) -> str:
    return (
        f"{path} is {what}; a journal is a regular file the program creates itself (it never writes "
        "through a link): move it away or give another --csv"
    )


def check_own_file(path: Path, status: os.stat_result | None = None) -> None:
    """Refuse, in one line, a name of the program's own files held by anything but a regular file of one
    name: a symlink (dangling or not), a hard link, a folder, pipe, device or socket. Nothing there is fine."""
    try:
        status = status or os.lstat(path)
    except FileNotFoundError:
        return
    except OSError as error:
        raise JournalError(f"{path}: cannot look at it ({error.strerror or error})") from None
    if stat.S_ISLNK(status.st_mode):
        raise JournalError(_not_ours(path, "a symlink"))
    if not stat.S_ISREG(status.st_mode):
        raise JournalError(_not_ours(path, file_kind(status.st_mode)))
    if status.st_nlink > 1:
        raise JournalError(_not_ours(path, "a second name of another file (a hard link)"))


def open_own(path: Path, flags: int, doing: str = "open") -> int:
    """The program's own file at `path`, opened with `flags` without following a link or waiting on a
    pipe, and checked again on the open file (should the name have changed meanwhile): a JournalError of
    one line for anything else at the name, or for a file it cannot `doing` (FileNotFoundError as it is)."""
    check_own_file(path)
    try:
        handle = os.open(path, flags | _NOFOLLOW | _NONBLOCK | getattr(os, "O_CLOEXEC", 0))
    except FileNotFoundError:
        raise
    except OSError as error:
        if error.errno in (errno.ELOOP, errno.EMLINK, errno.ENXIO):  # a symlink; a pipe with no reader
            check_own_file(path)
            raise JournalError(_not_ours(path, "not a regular file")) from None
        raise JournalError(f"{path}: cannot {doing} it ({error.strerror or error})") from None
    try:
        check_own_file(path, os.fstat(handle))
    except JournalError:
        os.close(handle)
        raise
    return handle


def journal_state(path: Path) -> str | None:
    """What holds a journal's name: None (nothing), "busy" (another study writing it), "left" (one left
    by an earlier study); one line for anything but the program's own regular file."""
    check_own_file(path)
    if not path.exists():
        return None
    handle = open_own(path, os.O_RDONLY)
    try:
        return "left" if lock(handle) else "busy"
    finally:
        os.close(handle)  # and with it the lock


class Journal:
    """A journal open for appending, locked by this process: created exclusively, or an earlier one
    taken over, either to go on with it (`adopt`: a last line cut short is dropped) or, with `replace`,
    emptied. A write error stops the appending (the study goes on, and the CSV is still written at the end
    from the runs in memory)."""

    def __init__(self, path: str | Path, *, adopt: bool = False, replace: bool = False):
        self.path = Path(path)
        check_own_file(self.path)
        try:
            self._handle: int | None = os.open(self.path, os.O_WRONLY | os.O_CREAT | os.O_EXCL | _NOFOLLOW, 0o666)
            left = False
        except FileExistsError:
            self._handle, left = open_own(self.path, os.O_WRONLY), True
        if not lock(self._handle):
            self.close()
            raise JournalError(f"another study is writing {self.path}: give this one another --csv")
        if left and not (adopt or replace):
            self.close()
            raise JournalError(left_over(self.path))
        size = os.fstat(self._handle).st_size
        os.ftruncate(self._handle, 0 if not adopt else _whole_lines(self.path, size))
        os.lseek(self._handle, 0, os.SEEK_END)

    def write(self, line: dict[str, Any]) -> None:
        """Append one line (JSON; numbers in full, NaN as NaN); after a write error nothing more."""
        if self._handle is None:
            return
        size = os.lseek(self._handle, 0, os.SEEK_END)
        try:
            write_all(self._handle, (json.dumps(line, separators=(",", ":")) + "\n").encode("utf-8"))
        except OSError:  # a full disk, a file size limit: the journal cut back to its whole lines
            with contextlib.suppress(OSError):
                os.ftruncate(self._handle, size)
            self.close()

    def append_run(self, records: Sequence[RunRecord]) -> None:
        """One finished run's rows (and traces), as `read_journal` reads them back."""
        self.write({"run": [records[0].setting, records[0].run], "records": [r.to_json() for r in records]})

    def end_session(self, status: str, **closing: Any) -> None:
        """A session's last line (its `status`, and what it says of itself), then the journal released."""
        self.write({"closed": {"status": status, **closing}})
        self.close()

    def close(self) -> None:
        """Stop appending and release the journal (it stays where it is)."""
        if self._handle is not None:
            with contextlib.suppress(OSError):
                os.close(self._handle)
            self._handle = None

    def kept(self) -> str:
        """Where the finished runs are, for a message."""
        return f"the finished rows are in {self.path}"


def left_over(path: Path) -> str:
    return (
        f"{path} holds the runs of an earlier study: add --resume to the same command to go on with it, "
        "or use --force to discard it"
    )


def _whole_lines(path: Path, size: int) -> int:
    """The bytes of a journal up to its last whole line (a line cut short by a kill is dropped)."""
    with path.open("rb") as handle:
        handle.seek(max(0, size - 1))
        if size == 0 or handle.read(1) == b"\n":
            return size
        handle.seek(0)
        return handle.read(size).rfind(b"\n") + 1


def read_journal(path: str | Path) -> list[dict[str, Any]]:
    """A journal's lines, read only from a regular file of one name (never a link, a pipe or a device),
    as UTF-8 text that fits in memory; a last line cut short is left out, any other line that is not a
    JSON object is a JournalError of one line naming the file and line."""
    path = Path(path)
    handle = open_own(path, os.O_RDONLY, "read")
    try:
        size = os.fstat(handle).st_size
        check_memory(f"reading {path} ({size} bytes)", size * MEMORY_PER_BYTE)
        with os.fdopen(os.dup(handle), "rb") as stream:
            data = stream.read()
    finally:
        os.close(handle)
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as error:
        raise JournalError(f"{path}: not UTF-8 text (byte {error.start}); a journal is UTF-8 text") from None
    lines = text.split("\n")
    parsed = []
    for number, line in enumerate(lines[:-1], start=1):  # the text after the last newline: cut short
        try:
            value = json.loads(line)
        except (ValueError, RecursionError) as error:
            raise JournalError(f"{path} line {number}: not a journal line ({str(error).splitlines()[0]})") from None
        if not isinstance(value, dict):
            raise JournalError(f"{path} line {number}: not a journal line (a JSON object)")
        parsed.append(value)
    return parsed


def claim_outputs(outputs: Sequence[tuple[str, Path | None]]) -> Callable[[], None]:
    """Claim each output (flag, path) by a locked lock file beside it, NAME.lock: a second study given
    the same output while this one runs is refused at once, naming it; returns the function that
    removes and releases the lock files (a lock file left by a killed study holds no lock: taken over)."""
    held: list[tuple[Path, int]] = []

    def release() -> None:
        for claim, handle in held:
            with contextlib.suppress(OSError):
                claim.unlink()
            with contextlib.suppress(OSError):
                os.close(handle)
        held.clear()

    try:
        for flag, path in outputs:
            if path is None:
                continue
            claim = Path(path).with_name(Path(path).name + CLAIM_SUFFIX)
            check_own_file(claim)  # a link, folder or device at its name: refused, never followed
            handle = os.open(claim, os.O_WRONLY | os.O_CREAT | _NOFOLLOW, 0o666)
            held.append((claim, handle))
            if not lock(handle):
                held.pop()
                os.close(handle)
                raise JournalError(f"another study is writing {path} now ({flag}): give this one another {flag}")
    except BaseException:
        release()
        raise
    return release


# -- the record of how a result was made ------------------------------------------------------------
RECORD_FORMAT = 1
record_path = functools.partial(beside, suffix=".record.json")  # an output's record: study.csv -> study.record.json
PACKAGE = "maze-particle-filter-lab"
GIT_SECONDS = 5  # a git that does not answer within this is left out


def package_version() -> str:
    """The installed package's version (`dependency_versions`; the source's when it is not installed)."""
    from mazelab import __version__

    return dependency_versions([PACKAGE])[PACKAGE] or __version__


def git_commit() -> str | None:
    """The commit of the source the package runs from (with '-dirty' if it has changes), or None
    without git, outside a repository, or when git does not answer: never an error."""
    git = ["git", "-C", str(Path(__file__).resolve().parents[2])]
    run = functools.partial(subprocess.run, capture_output=True, text=True, timeout=GIT_SECONDS, check=True)
    try:
        commit = run([*git, "rev-parse", "HEAD"]).stdout.strip()
        dirty = bool(run([*git, "status", "--porcelain", "--untracked-files=no"]).stdout.strip())
    except (OSError, subprocess.SubprocessError, ValueError):
        return None
    return f"{commit}-dirty" if dirty else commit


# the distributions a result can depend on: the project's dependencies and extras (None: not installed)
DEPENDENCIES = (
    "numpy",
    "rerun-sdk",
    "pydantic",
    "typer",
    "rich",
    "matplotlib",
    "dask",
    "distributed",
    "numba",
    "llvmlite",
    "pyarrow",
    "scipy",
)


def dependency_versions(names: Sequence[str] = DEPENDENCIES) -> dict[str, str | None]:
    """The installed version of each of `names` (default DEPENDENCIES), None for one that is not
    installed; read from the distributions' metadata, without importing them."""
    from importlib.metadata import PackageNotFoundError, version

    versions: dict[str, str | None] = {}
    for name in names:
        try:
            versions[name] = version(name)
        except PackageNotFoundError:
            versions[name] = None
    return versions


def program_versions() -> dict[str, Any]:
    """The versions a result depends on: this program (and its git commit, if any), numpy, the filters'
    backend (numpy or compiled, mazelab.backend) and numba's version (None without it), Python, and
    every dependency's (`packages`)."""
    return {
        "mazelab": package_version(),
        "git_commit": git_commit(),
        "numpy": np.__version__,
        **backend_versions(),
        "python": platform.python_version(),
        "implementation": platform.python_implementation(),
        "system": f"{platform.system()} {platform.machine()}",
        "packages": dependency_versions(),
    }


def now() -> str:
    """The current time, UTC, ISO 8601 to the second."""
    return dt.datetime.now(dt.UTC).isoformat(timespec="seconds")


def peak_memory() -> dict[str, int | None]:
    """Peak resident memory in bytes of this process and of its largest finished worker (None where
    the system does not say)."""
    try:
        import resource
    except ImportError:  # Windows
        return {"this_process": None, "largest_worker": None}
    scale = 1 if sys.platform == "darwin" else 1024  # ru_maxrss: bytes on macOS, kilobytes on Linux
    own = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * scale
    children = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss * scale
    return {"this_process": int(own), "largest_worker": int(children) or None}


def jsonable(value: Any) -> Any:
    """Tuples, ranges and arrays as lists, numpy numbers as Python ones, paths as text, NaN as None: what
    json.dumps writes and reads back."""
    if isinstance(value, Mapping):
        return {str(k): jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple, range)):
        return [jsonable(v) for v in value]
    if isinstance(value, os.PathLike):
        return os.fspath(value)
    if isinstance(value, (np.generic, np.ndarray)):
        return jsonable(value.tolist())  # Python numbers, or lists of them
    if isinstance(value, float) and value != value:
        return None
    return value


class Recorder:
    """A record being made: started when the work starts, written at its end (an interrupted study's
    parameters, for --resume, are in its journal's session line)."""

    def __init__(self, kind: str, command: Sequence[str], parameters: Mapping[str, Any], **extra: Any):
        self.started_clock = time.perf_counter()
        self.data: dict[str, Any] = {
            "record_format": RECORD_FORMAT,
            "kind": kind,
            "command": list(command),
            "program": program_versions(),
            "started": now(),
            "ended": None,
            "duration_seconds": None,
            "status": "running",
            "working_folder": os.getcwd(),  # where relative paths of the command and the mazes start
            "parameters": jsonable(parameters),
            "intervals": {"level": CONFIDENCE_LEVEL, **INTERVAL_METHODS},
            **jsonable(extra),
        }

    def finish(self, status: str, **extra: Any) -> dict[str, Any]:
        """Close the record: end time, duration, status, peak memory and the given items (summary, ...)."""
        self.data.update(
            ended=now(),
            duration_seconds=round(time.perf_counter() - self.started_clock, 3),
            status=status,
            peak_memory_bytes=peak_memory(),
            **jsonable(extra),
        )
        return self.data

    def write(self, path: str | Path) -> None:
        """Write the record, whole (mazelab.atomic)."""
        write_atomically(path, json.dumps(self.data, indent=2, allow_nan=False) + "\n")


def differences(recorded: Mapping[str, Any], given: Mapping[str, Any], ignore: Sequence[str] = ()) -> list[str]:
    """The parameters that differ between a record's and the given ones, as 'name: recorded -> given'."""
    given = jsonable(given)
    names = [k for k in dict.fromkeys([*recorded, *given]) if k not in ignore]
    return [f"{k}: {recorded.get(k)!r} -> {given.get(k)!r}" for k in names if recorded.get(k) != given.get(k)]


# -- a study's journal: --resume ------------------------------------------------------------------------
def journal_parameters(path: Path, lines: Sequence[dict[str, Any]]) -> dict[str, Any]:
    """The parameters of a study's journal (its last session's): a mapping with a root seed and a run
    count; a JournalError of one line naming the file otherwise."""
    sessions = [line["session"] for line in lines if isinstance(line.get("session"), dict)]
    if not sessions:
        raise JournalError(f"{path}: not a study's journal (no session line)")
    parameters = sessions[-1].get("parameters")
    if not isinstance(parameters, dict):
        raise JournalError(f"{path}: its parameters are {type(parameters).__name__}, not a mapping of names to values")
    try:
        check_seed("its parameters' root_seed", parameters.get("root_seed"))
    except ValueError as error:
        raise JournalError(f"{path}: {error}") from None
    runs = parameters.get("runs")
    if isinstance(runs, bool) or not isinstance(runs, int) or runs < 1:
        raise JournalError(f"{path}: its parameters' runs must be a whole number >= 1, got {runs!r}")
    return parameters


def resume_study(
    path: Path, lines: Sequence[dict[str, Any]], plan: Any, backend: str
) -> tuple[list[RunTask], list[RunRecord], list[dict[str, Any]]]:
    """(the runs still to go, the rows to keep, the earlier sessions) of a study resumed from its journal:
    the study checked against its parameters (a larger --runs extends it), a plug-in's code against its
    sha256, each kept row against the plan (another study's rows are refused) and its backend against
    this session's (rows of two backends never mix); with traces, a run kept only with its traces."""
    recorded = journal_parameters(path, lines)
    check_plugin_code(recorded, plan, path)  # before the parameters: its line names the file and both hashes
    changed = differences(recorded, plan.parameters(), ignore=("runs",))
    if changed:
        raise JournalError(f"--resume: the study differs from its journal ({changed[0]}); give the same parameters")
    if plan.runs < recorded["runs"]:
        raise JournalError(f"--resume: --runs {plan.runs} is fewer than the study's {recorded['runs']}")
    runs: dict[tuple[int, int], list[RunRecord]] = {}
    for number, line in enumerate(lines, start=1):
        if "run" in line:
            try:
                runs[tuple(line["run"])] = [RunRecord.from_json(row) for row in line["records"]]
            except (TypeError, KeyError, ValueError) as error:
                raise JournalError(f"--resume: {path} line {number}: not a run's rows ({error})") from None
    records, tasks = [r for rows in runs.values() for r in rows], plan.tasks
    found = foreign_row(tasks, records)
    if found is not None:
        raise JournalError(
            f"--resume: {path} holds another study's rows ({found}); rows of another study are "
            "never kept: give this study's own --csv and parameters, or another --csv"
        )
    other = sorted({r.backend for r in records} - {backend})
    if other:
        raise JournalError(
            f"--resume: {path} holds runs made on the {other[0]} backend and this session runs on "
            f"{backend}: give --backend {other[0]} to go on with them (or --force to start again)"
        )
    if plan.traces:  # a run is kept with its traces only: one without them runs again
        records = [r for r in records if r.trace is not None]
    todo, kept = missing_tasks(tasks, records)
    return todo, kept, earlier_sessions(lines)


def earlier_sessions(lines: Sequence[dict[str, Any]]) -> list[dict[str, Any]]:
    """The sessions a journal tells of, for the record: command, start, end, status, runs finished (a
    session killed outright has no end: its status stays "running")."""
    sessions: list[dict[str, Any]] = []
    for line in lines:
        if isinstance(line.get("session"), dict):
            started = {k: line["session"].get(k) for k in ("command", "started")}
            sessions.append({**started, "ended": None, "status": "running", "runs_finished": None})
        elif isinstance(line.get("closed"), dict) and sessions:
            sessions[-1].update({k: line["closed"].get(k) for k in ("ended", "status", "runs_finished")})
    return sessions


def check_plugin_code(recorded: dict[str, Any], plan: Any, path: Path) -> None:
    """--resume keeps rows made by the same code only: a plug-in whose file's sha256 is not the one in
    the journal is refused in one line naming the file and both hashes."""
    before = {p.get("filter"): p for p in recorded.get("plugins") or [] if isinstance(p, dict)}
    for now in plan.parameters().get("plugins", []):
        old = before.get(now["filter"])
        if old is not None and old.get("sha256") != now["sha256"]:
            raise JournalError(
                f"--resume: {now['file']} is not the code that made the rows (sha256 {old.get('sha256')} in "
                f"{path}, {now['sha256']} now); restore it, or start the study again with --force"
            )


def foreign_row(tasks: Sequence[RunTask], records: Sequence[RunRecord]) -> str | None:
    """Why the first record that is not one of `tasks`' rows is another study's (None when every record
    is: a (setting, run) the tasks have, one of its filters, the cells the task fixes (RunTask.cells) and the
    options its filter runs with in the task's setting)."""
    planned = {(t.setting_index, t.run): t for t in tasks}
    for record in records:
        task = planned.get((record.setting, record.run))
        where = f"run {record.run} of setting {record.setting}"
        if task is None:
            return f"{where} is not in this study"
        if record.filter not in task.row_filters():
            return f"{where}: its filter {record.filter} is not one this study runs in setting {record.setting}"
        options = option_cells(task.setting, task.row_filters()[record.filter])
        for name in record.options.keys() - options.keys():
            return f"{where}: its {name} is {record.options[name]}, an option {record.filter} does not take"
        found = {**{column: getattr(record, column) for column in task.cells()}, **record.options}
        for column, value in {**task.cells(), **options}.items():  # seed and maze first, then the parameters
            if not _same(found.get(column), value):
                return f"{where}: its {column} is {_shown(found.get(column))}, where this study has {_shown(value)}"
    return None


def _same(a: Any, b: Any) -> bool:
    return a == b or (isinstance(a, float) and isinstance(b, float) and a != a and b != b)


def _shown(value: Any) -> str:
    return "none" if value is None else str(value)


def missing_tasks(tasks: Sequence[RunTask], records: Sequence[RunRecord]) -> tuple[list[RunTask], list[RunRecord]]:
    """(the tasks whose rows are missing, the rows to keep): a run's rows are kept when every filter the
    task runs has one (a run with some of them runs again whole, its rows the same bit for bit)."""
    present: dict[tuple[int, int], dict[str, RunRecord]] = {}
    for r in records:
        present.setdefault((r.setting, r.run), {})[r.filter] = r
    todo, kept = [], []
    for task in tasks:
        have = present.get((task.setting_index, task.run), {})
        if set(task.row_filters()) <= set(have):
            kept += [have[name] for name in task.row_filters()]
        else:
            todo.append(task)
    return todo, kept
