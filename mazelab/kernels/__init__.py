"""Compiled kernels (numba, the `fast` extra) for the hot parts of the particle filters: the model's
equations (mazelab.kernels.model: the move, the nearest station and the likelihood in one pass, the
RPF's jitter), the resampler (mazelab.kernels.resampling: systematic resampling by counting) and the
weighted reads (mazelab.kernels.weights: normalisation, mean, ESS and the confidence share in two
passes). mazelab.kernels.compiled.CompiledKernels calls them for a filter, with reused buffers.

The filters do not change: their steps call the cloud's methods (mazelab.cloud), which call these
kernels or the numpy functions, whichever backend runs (mazelab.backend). Each kernel takes the run
axis (R runs in one call), works on float32 particles and keeps the numpy path's float32 arithmetic
where it has some (the likelihood and the resampling are the numpy path's to the bit, given the same
inputs); cos and sin are the C library's, exact to rounding over the whole float32 range.

Importing this package imports numba. Each kernel is compiled on its first call and cached on disk
(numba's cache=True), so the compile time is paid once per machine: in `__pycache__` beside these
files, else in the folder NUMBA_CACHE_DIR names, else in the user's cache folder (numba's rules). Where
none of them can be written, the kernels are compiled in memory in each process (a few seconds at
its first step) and a warning says so once.
"""

from __future__ import annotations

import warnings
from collections.abc import Callable
from typing import Any

import numba

_warned: list[bool] = []


def jit(function: Callable[..., Any] | None = None, *, inline: bool = False) -> Any:
    """`function` compiled by numba in nopython mode, cached on disk where a cache folder can be
    written (see the module's docstring), else compiled in memory (with one warning per process).

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
    try:
        return numba.njit(cache=True, **options)(function)
    except RuntimeError:  # numba found no writable cache folder ("cannot cache function ...")
        if not _warned:
            _warned.append(True)
            warnings.warn(
                "mazelab's compiled kernels cannot be cached (no writable cache folder; set NUMBA_CACHE_DIR): "
                "they are compiled again in each process",
                stacklevel=2,
            )
        return numba.njit(cache=False, **options)(function)


__all__ = ["jit"]
