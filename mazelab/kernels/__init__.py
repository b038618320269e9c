"""Compiled kernels (numba, the `fast` extra) for the hot parts of the particle filters: the model's
equations (mazelab.kernels.model: the move, the nearest station and the likelihood in one pass, the
RPF's jitter), the resampler (mazelab.kernels.resampling: systematic resampling by counting) and the
weighted reads (mazelab.kernels.weights: the top, then the float32 exponentials and their sums, then
the weights and the confidence share, three passes). mazelab.kernels.compiled.CompiledKernels calls
them for a filter, and its CompiledWeights keeps what the normalisation read.

The filters do not change: the model (mazelab.model.LostRobot) and the weights value call these
kernels or the numpy functions, whichever backend runs (mazelab.backend). Each kernel takes the run
axis (R runs in one call), works on float32 particles and keeps the numpy path's float32 arithmetic
where it has some (the likelihood and the resampling are the numpy path's to the bit, given the same
inputs); cos and sin are polynomials the compiler vectorises (mazelab.kernels.vector_math, within
0.501 float32 ulp of the exact values), the exponentials float32 ones (within one ulp).

Importing this package imports numba, and a process's first kernel call sets numba's compiler up (its
registries) even when the kernel comes from the cache: together 0.35 s of CPU with Python's bytecode
cached, 1.1 s without; each further kernel then loads in a few milliseconds. A command whose work does
not pay that back runs on numpy (mazelab.backend.backend_for_work).

Each kernel is compiled on its first call and cached on disk (numba's cache), so the compile time is
paid once per machine: in `__pycache__` beside these files,
else in the folder NUMBA_CACHE_DIR names, else in the user's cache folder (numba's rules). Where none
of them can be written, the kernels are compiled in memory in each process (a few seconds at its
first step) and a warning says so once. A damaged cache file (a cut-off copy, a full disk earlier) is
compiled over; a cache folder that cannot take the file (a full disk, a read-only mount) leaves the
kernel compiled in memory, with one warning naming the folder and the way out.
"""

from __future__ import annotations

import contextlib
import hashlib
import os
import warnings
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numba
from numba.core.caching import FunctionCache

_warned: set[str] = set()


def _warn_once(message: str) -> None:
    """One warning per process for each message (the CLI prints it as one line)."""
    if message not in _warned:
        _warned.add(message)
        warnings.warn(message, stacklevel=3)


def sources_digest(folder: Path) -> str:
    """A digest of the kernels' sources (every .py file in `folder`).

    numba keeps a cached kernel while its own file's time stamp and size are unchanged, but a kernel
    inlines helpers from the package's other modules (vector_math's cos and sin, weights' exponentials):
    an edit there alone (a `git pull`) would leave the old machine code running. Each kernel's cache
    entry is stamped with this digest too, so that any change to these files compiles them again.

    Parameters
    ----------
    folder : pathlib.Path

    Returns
    -------
    str
        16 hex digits.
    """
    digest = hashlib.sha256()
    for path in sorted(folder.glob("*.py")):
        digest.update(path.name.encode() + b"\0" + path.read_bytes())
    return digest.hexdigest()[:16]


_SOURCES = sources_digest(Path(__file__).parent)


class _MendingCache(FunctionCache):
    """numba's on-disk cache of one kernel, fresh only while the kernels' sources are all unchanged
    (sources_digest), that a damaged file does not stop: a file that does not load is dropped and the
    kernel compiled again (and saved over it), and a folder that cannot take the file leaves the
    kernel compiled in memory, with one warning naming the folder."""

    def __init__(self, py_func: Callable[..., Any]):
        super().__init__(py_func)
        cache_file = self._cache_file
        cache_file._source_stamp = (cache_file._source_stamp, _SOURCES)  # numba's (time, size), and ours

    def load_overload(self, sig: Any, target_context: Any) -> Any:
        try:
            return super().load_overload(sig, target_context)
        except Exception:  # a damaged index or data file: pickle, EOF, value errors; compile again
            self._drop_index()
            return None

    def save_overload(self, sig: Any, data: Any) -> None:
        try:
            try:
                super().save_overload(sig, data)
            except OSError:
                raise
            except Exception:  # the index it adds to does not load: start it again
                self._drop_index()
                super().save_overload(sig, data)
        except OSError as error:
            _warn_once(
                f"mazelab's compiled kernels cannot be saved in {self.cache_path} ({error.strerror or error}): "
                "they are compiled again in each process; free space there, or set NUMBA_CACHE_DIR to a "
                "writable folder"
            )

    def _drop_index(self) -> None:
        """Remove this kernel's index file (its data files are then written afresh)."""
        with contextlib.suppress(OSError):
            os.unlink(self._cache_file._index_path)


def jit(function: Callable[..., Any] | None = None, *, inline: bool = False) -> Any:
    """`function` compiled by numba in nopython mode (releasing the GIL), cached on disk where a cache
    folder can be written (see the module's docstring), else compiled in memory (with one warning per
    process).

    Parameters
    ----------
    function : callable
        A function of numbers and numpy arrays that numba compiles (`@jit` or `@jit(inline=True)`).
    inline : bool
        Inline it into the kernels that call it (numba's inline="always"): a helper called per
        particle, whose call would otherwise count the references of every array it is passed.

    Returns
    -------
    callable
        The numba dispatcher: compiled on its first call for its argument types.
    """
    if function is None:
        return lambda f: jit(f, inline=inline)
    options: dict[str, Any] = {"nogil": True, "error_model": "numpy"}  # numpy's: x / 0 is inf, no check
    if inline:
        options["inline"] = "always"
    dispatcher = numba.njit(**options)(function)
    try:
        dispatcher._cache = _MendingCache(function)  # what numba's cache=True sets, with the mending above
    except RuntimeError:  # numba found no writable cache folder ("cannot cache function ...")
        _warn_once(
            "mazelab's compiled kernels cannot be cached (no writable cache folder; set NUMBA_CACHE_DIR): "
            "they are compiled again in each process"
        )
    return dispatcher


__all__ = ["jit", "sources_digest"]
