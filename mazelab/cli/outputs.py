"""One file per output: two outputs of one command (study's --csv, its partial file, --plot, --traces,
--record and --rrd; accuracy's --csv and --record) that name one file are refused up front, before any
run, in one line naming both. One file: the same path once links are resolved (a symlink to another
output, `./s.csv` and `s.csv`), or two names of one existing file (a hard link)."""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path

from mazelab.cli.options import UserError


def file_identity(path: Path) -> tuple[str, tuple[int, int] | None]:
    """(the path with every link resolved, (device, inode) of the file if it exists)."""
    resolved = os.path.realpath(path)
    try:
        status = os.stat(resolved)
    except OSError:  # missing (the usual case for a new output), a loop, no permission
        return resolved, None
    return resolved, (status.st_dev, status.st_ino)


def one_file(first: Path, second: Path) -> bool:
    """Whether two output names are one file (see the module docstring)."""
    (path_a, inode_a), (path_b, inode_b) = file_identity(first), file_identity(second)
    return path_a == path_b or (inode_a is not None and inode_a == inode_b)


def check_one_file_each(outputs: Sequence[tuple[str, Path | None]]) -> None:
    """Refuse (UserError, one line) the first two of `outputs` that are one file. `outputs` holds
    (what the user calls it, e.g. "--csv" or "the record (beside --csv)", its path or None)."""
    given = [(name, Path(path)) for name, path in outputs if path is not None]
    for i, (name_a, path_a) in enumerate(given):
        for name_b, path_b in given[i + 1 :]:
            if one_file(path_a, path_b):
                same = f"{path_a}" if str(path_a) == str(path_b) else f"{path_a} and {path_b}"
                raise UserError(f"{name_a} and {name_b} are one file ({same}): give each output a name of its own")


__all__ = ["check_one_file_each", "file_identity", "one_file"]
