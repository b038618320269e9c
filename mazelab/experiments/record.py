"""The record of how a result was made: a JSON file beside a study's CSV (and beside compare's and
accuracy's outputs) with the exact command, every parameter as parsed, the root seed, the program's
version and commit, numpy's and Python's versions, the maze files with their sha256, when it ran and
for how long, the peak memory, the summary table and the intervals' methods. (`study --resume` checks a
study's parameters against its journal's, mazelab.experiments.journal.)"""

from __future__ import annotations

import datetime as dt
import json
import os
import platform
import subprocess
import sys
import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from mazelab.atomic import write_text_atomically
from mazelab.backend import backend_versions
from mazelab.experiments.summary import CONFIDENCE_LEVEL, INTERVAL_METHODS

RECORD_FORMAT = 1
RECORD_SUFFIX = ".record.json"
PACKAGE = "maze-particle-filter-lab"
GIT_SECONDS = 5  # a git that does not answer within this is left out


def record_path(output: str | Path) -> Path:
    """Where the record of an output goes: study.csv -> study.record.json, beside it."""
    output = Path(output)
    return output.with_name(output.stem + RECORD_SUFFIX)


def package_version() -> str:
    """The installed package's version (the source's when it is not installed)."""
    try:
        from importlib.metadata import PackageNotFoundError, version

        return version(PACKAGE)
    except (ImportError, PackageNotFoundError):
        from mazelab import __version__

        return __version__


def git_commit(folder: Path | None = None) -> str | None:
    """The commit of the source the package runs from (with '-dirty' if it has changes), or None
    without git, outside a repository, or when git does not answer: never an error."""
    folder = folder or Path(__file__).resolve().parents[2]
    try:

        def git(*args: str) -> str:
            done = subprocess.run(
                ["git", "-C", str(folder), *args], capture_output=True, text=True, timeout=GIT_SECONDS, check=True
            )
            return done.stdout.strip()

        commit = git("rev-parse", "HEAD")
        dirty = bool(git("status", "--porcelain", "--untracked-files=no"))
    except (OSError, subprocess.SubprocessError, ValueError):
        return None
    return f"{commit}-dirty" if dirty else commit


# the distributions a result can depend on: the project's dependencies and extras (None: not installed)
DEPENDENCIES = (
    "numpy", "rerun-sdk", "pydantic", "typer", "rich", "matplotlib", "dask", "distributed", "numba", "llvmlite",
    "pyarrow", "scipy",
)  # fmt: skip


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
    """A record being made: started when the work starts, written at the start (so that an interrupted
    study has its parameters for --resume) and again at the end."""

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

    def write(self, path: str | Path, follow_links: bool = True) -> None:
        """Write the record, whole (mazelab.atomic); `follow_links=False` for a partial record, which
        is the program's own file (a symlink at its name is refused, never written through)."""
        text = json.dumps(self.data, indent=2, allow_nan=False) + "\n"
        write_text_atomically(path, text, follow_links=follow_links)


def differences(recorded: Mapping[str, Any], given: Mapping[str, Any], ignore: Sequence[str] = ()) -> list[str]:
    """The parameters that differ between a record's and the given ones, as 'name: recorded -> given'."""
    given = jsonable(given)
    names = [k for k in dict.fromkeys([*recorded, *given]) if k not in ignore]
    return [f"{k}: {recorded.get(k)!r} -> {given.get(k)!r}" for k in names if recorded.get(k) != given.get(k)]
