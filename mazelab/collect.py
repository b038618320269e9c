"""The one recording loop: a filter stepped along a walk, each step's values read where the contract
says, checked, and kept per step, for one run (simulate) and for R runs advanced together (a batched
study) alike. A filter's own figures (`diagnostics`: the RPF's regularisation, recovery's injection
probability) are kept the same way, so they reach RunResult and a study's traces with no code of their
own.

    steps = record_steps(filt, 200, observe=lambda k: robot.step(world))
    steps.estimates   # (steps, 2) for one run, (R, steps, 2) for R runs
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from mazelab.contract import ContractError, check_step_values

Observe = Callable[[int], tuple[Any, Any]]  # step index k (0-based) -> (compass angle, z) of every run
AfterStep = Callable[[int, Any], None]  # (step number k (1-based), the filter) after each step


@dataclass
class Recorded:
    """Per step k = 1..steps, for R runs: the estimate (R, steps, 2), ESS, green circle, particle count
    and log evidence log p(z_1:k) (R, steps; NaN for a filter that keeps none), the filter's own time
    per step (steps,), and its diagnostics by name (R, steps)."""

    estimates: np.ndarray
    ess: np.ndarray
    confident: np.ndarray
    counts: np.ndarray
    log_evidence: np.ndarray
    seconds: np.ndarray
    diagnostics: dict[str, np.ndarray] = field(default_factory=dict)


def record_steps(
    filt: Any,
    steps: int,
    observe: Observe,
    *,
    runs: int | None = None,
    after: AfterStep | None = None,
    at: Any = None,
) -> Recorded:
    """Step `filt` `steps` times and keep what each step reads.

    Parameters
    ----------
    filt : a filter (mazelab.contract)
    steps : int
    observe : callable
        k (0-based) -> (compass angle th0_k, measurement z_k): numbers for one run, arrays (R,) for R runs.
    runs : int, optional
        R for a filter advancing R runs together (None: one run, the paper's shapes).
    after : callable, optional
        (k, filt) after step k (1-based): the viewer, a progress line.
    at : object with a `number` attribute, optional
        Set to the step being run (for the error that names it, mazelab.stops.student_code).

    Returns
    -------
    Recorded
        Arrays with a run axis of length R (1 for one run). The time per step is the filter's step
        and its reads (estimate, ESS, confidence), divided among the R runs.
    """
    count = 1 if runs is None else runs
    recorded = _unfilled(count, steps)
    diagnostics: dict[str, list[Any]] = {}
    for k in range(steps):
        if at is not None:
            at.number = k + 1
        compass_angle, z = observe(k)
        started = time.perf_counter()
        filt.step(compass_angle, z)
        values = filt.estimate, filt.ess, filt.is_confident, filt.count
        recorded.seconds[k] = (time.perf_counter() - started) / count
        _keep_step(recorded, k, check_step_values(type(filt), values, runs), filt)
        _keep_diagnostics(diagnostics, getattr(filt, "diagnostics", None), k, type(filt))
        if after is not None:
            after(k + 1, filt)
    recorded.diagnostics = {name: _per_run(values, count) for name, values in diagnostics.items()}
    return recorded


def _unfilled(count: int, steps: int) -> Recorded:
    """Recorded's arrays for `count` runs of `steps` steps, filled step by step by record_steps."""
    shape = (count, steps)
    return Recorded(
        np.empty((*shape, 2)),
        np.empty(shape),
        np.empty(shape, dtype=bool),
        np.empty(shape, dtype=np.int64),
        np.empty(shape),
        np.empty(steps),
    )


def _keep_step(recorded: Recorded, k: int, values: tuple[Any, Any, Any, Any], filt: Any) -> None:
    """Step k's checked reads (estimate, ESS, green circle, particle count) into column k of every run."""
    estimate, ess, confident, particles = values
    recorded.estimates[:, k], recorded.ess[:, k], recorded.confident[:, k] = estimate, ess, confident
    recorded.counts[:, k] = particles
    recorded.log_evidence[:, k] = getattr(filt, "log_evidence", np.nan)  # optional in the contract


def _keep_diagnostics(kept: dict[str, list[Any]], now: Any, k: int, filter_class: type) -> None:
    """Append this step's diagnostics; a name missing at a step is NaN there."""
    if not now:
        for values in kept.values():
            values.append(np.nan)
        return
    if not isinstance(now, dict):
        raise ContractError(f"{filter_class.name}.diagnostics must be a dict of this step's figures, got {now!r}")
    for name in kept.keys() - now.keys():
        kept[name].append(np.nan)
    for name, value in now.items():
        kept.setdefault(name, [np.nan] * k).append(value)


def _per_run(values: list[Any], runs: int) -> np.ndarray:
    """A diagnostic's steps as (R, steps): one value a step for one run, (R,) a step for R runs (a
    number, or one per run, is spread over the runs as numpy broadcasts it)."""
    array = np.empty((runs, len(values)))
    try:
        for k, value in enumerate(values):
            value = np.asarray(value, dtype=float)
            if value.ndim > 1:  # a column takes (1, R) too; a step's diagnostic is not a table
                raise ValueError
            array[:, k] = value
    except (TypeError, ValueError):
        raise ContractError("a diagnostic must be a number (or one per run) at every step") from None
    return array


__all__ = ["Recorded", "record_steps"]
