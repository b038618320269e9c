"""A study's outputs claimed before its runs: each output file (the summary CSV, the record, the figure,
the traces) gets a lock file beside it, `NAME.lock`, locked while the study runs, so that a second study
given the same output while the first runs is refused at once, in one line, rather than finding out
after its runs. The CSV itself is claimed by its partial file (mazelab.experiments.rowlog). The lock
files go when the study ends; one left by a killed study holds no lock and is taken over."""

from __future__ import annotations

import contextlib
import os
from collections.abc import Sequence
from pathlib import Path

from mazelab.experiments.rowlog import PartialFileError, check_partial_name, lock

CLAIM_SUFFIX = ".lock"
_NOFOLLOW = getattr(os, "O_NOFOLLOW", 0)


def claim_path(path: str | Path) -> Path:
    """The lock file of an output: study.png -> study.png.lock, beside it."""
    path = Path(path)
    return path.with_name(path.name + CLAIM_SUFFIX)


class OutputClaims:
    """The outputs a study holds: (flag, path) pairs, each claimed by its locked lock file."""

    def __init__(self, outputs: Sequence[tuple[str, Path | None]]):
        self._held: list[tuple[Path, int]] = []
        try:
            for flag, path in outputs:
                if path is not None:
                    self._claim(flag, Path(path))
        except BaseException:
            self.release()
            raise

    def _claim(self, flag: str, path: Path) -> None:
        claim = claim_path(path)
        check_partial_name(claim)  # a link, folder or device at its name: refused, never followed
        handle = os.open(claim, os.O_WRONLY | os.O_CREAT | _NOFOLLOW, 0o666)
        if not lock(handle):
            os.close(handle)
            raise PartialFileError(f"another study is writing {path} now ({flag}): give this one another {flag}")
        self._held.append((claim, handle))

    def release(self) -> None:
        """Remove the lock files and release them (the outputs are written, or the study ends)."""
        for claim, handle in self._held:
            with contextlib.suppress(OSError):
                claim.unlink()
            with contextlib.suppress(OSError):
                os.close(handle)
        self._held = []


__all__ = ["CLAIM_SUFFIX", "OutputClaims", "claim_path"]
