"""A unit of a study's runs, timed: each run's record gets its share of the unit's wall time
(`run_seconds`; the runs of a setting advanced together share one unit, see batch_runs)."""

from __future__ import annotations

import time
from collections.abc import Sequence

from mazelab.experiments.batch_runs import run_unit_safely
from mazelab.experiments.study import RunFailure, RunRecord, RunTask


def run_unit_timed(unit: Sequence[RunTask]) -> list[list[RunRecord] | RunFailure]:
    """`run_unit_safely`, with each finished run's records given run_seconds, the unit's wall time
    divided by its runs."""
    started = time.perf_counter()
    outcomes = run_unit_safely(_here(unit))
    share = (time.perf_counter() - started) / max(len(unit), 1)
    for outcome in outcomes:
        if not isinstance(outcome, RunFailure):
            for record in outcome:
                record.run_seconds = share
    return outcomes


def _here(unit: Sequence[RunTask]) -> list[RunTask]:
    """The unit's runs with the plug-ins' shipped code (RunTask.here); its sha256 checked."""
    return [task.here() for task in unit]


__all__ = ["run_unit_timed"]
