"""The grader's outputs, guarded before any grading: never inside the class folder (a submission
could see them, and an output would be graded as a submission or replace a student's file), and
claimed by one grader at a time (a second `exercise grade` with the same --csv or --gradescope is
refused at once, not after its grading).

A claim is an exclusive lock (flock) on a hidden file beside the output, `.NAME.grading`, held for
the whole grading and released by the system if the grader dies; the file is removed at the end.
"""

from __future__ import annotations

import contextlib
import os
from collections.abc import Iterator
from pathlib import Path

try:
    import fcntl
except ImportError:  # Windows: no claim, outputs are still written whole (mazelab.atomic)
    fcntl = None  # type: ignore[assignment]


class ClaimError(ValueError):
    """An output that cannot be used: one line naming it and the way out."""


def check_outside(output: Path, folder: Path, option: str) -> None:
    """Refuse an output path inside the class folder (or the folder itself)."""
    where, classes = output.resolve(), folder.resolve()
    if where == classes or where.is_relative_to(classes):
        raise ClaimError(
            f"{option} {output}: inside the class folder {folder}; write the grader's outputs outside it "
            "(a submission must not see them, nor be replaced by them)"
        )


def claim_file(output: Path) -> Path:
    """The hidden file whose lock claims `output` (a file or a folder)."""
    return output.parent / f".{output.name}.grading"


@contextlib.contextmanager
def claimed(outputs: list[tuple[Path, str]]) -> Iterator[None]:
    """Hold the claims of `outputs` ((path, option) each) while grading; ClaimError at once when another
    grader holds one."""
    held: list[tuple[int, Path]] = []
    try:
        for output, option in outputs:
            if fcntl is None:
                continue
            lock = claim_file(output)
            handle = os.open(lock, os.O_RDWR | os.O_CREAT | getattr(os, "O_NOFOLLOW", 0), 0o644)
            try:
                fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except OSError:
                os.close(handle)
                raise ClaimError(
                    f"{option} {output}: another grader is writing it now; wait for it or choose another name"
                ) from None
            os.ftruncate(handle, 0)
            os.write(handle, f"{os.getpid()}\n".encode())
            held.append((handle, lock))
        yield
    finally:
        for handle, lock in held:
            with contextlib.suppress(OSError):
                lock.unlink()
            os.close(handle)


__all__ = ["ClaimError", "check_outside", "claim_file", "claimed"]
