"""The run axis of a filter that advances R runs together (mazelab.engine): run r's particles are the
block of rows r*N..(r+1)*N, its draws come from its own Generator. What a filter's constructor reads
of it: the particles as (R, N, 2), one Generator per run."""

from __future__ import annotations

from typing import Any

import numpy as np

from mazelab.checks import as_points


def as_runs(particles: Any) -> np.ndarray:
    """Initial particles as (R, N, 2): (N, 2) is one run.

    Parameters
    ----------
    particles : array-like (N, 2) or (R, N, 2)

    Returns
    -------
    array (R, N, 2)
    """
    array = np.asarray(particles)
    if array.ndim == 3:
        if array.shape[2] != 2 or array.shape[1] < 1:
            raise ValueError(f"particles of R runs must have shape (R, N, 2), got {array.shape}")
        return np.stack([as_points("particles", run) for run in array])
    return as_points("particles", particles)[None]


def generators(rng: Any, runs: int) -> list[np.random.Generator]:
    """One Generator per run: `rng` itself for one run, or the sequence given (None: fresh ones).

    Parameters
    ----------
    rng : numpy.random.Generator, a sequence of R of them, or None
    runs : int

    Returns
    -------
    list of numpy.random.Generator
    """
    if rng is None:
        return [np.random.default_rng() for _ in range(runs)]
    if isinstance(rng, np.random.Generator):
        if runs != 1:
            raise ValueError(f"{runs} runs need {runs} generators, one each, got one")
        return [rng]
    rngs = list(rng)
    if len(rngs) != runs or not all(isinstance(g, np.random.Generator) for g in rngs):
        raise ValueError(f"{runs} runs need {runs} numpy Generators, got {len(rngs)}")
    return rngs


__all__ = ["as_runs", "generators"]
