"""A unit of a study's runs, timed: each run's record gets its share of the unit's wall time
(`run_seconds`; the runs of a setting advanced together share one unit, see batch_runs), the process's
start-up (mazelab.experiments.warmup) left out of it and reported apart, with the backend and package
versions the process runs with (a WorkerReport after the unit's outcomes)."""

from __future__ import annotations

import time
from collections.abc import Sequence

from mazelab.experiments.batch_runs import run_unit_safely
from mazelab.experiments.study import RunFailure, RunRecord, RunTask
from mazelab.experiments.warmup import WorkerReport, take_startup_seconds, worker_report

UnitOutcome = list[RunRecord] | RunFailure | WorkerReport


def run_unit_timed(unit: Sequence[RunTask]) -> list[UnitOutcome]:
    """`run_unit_safely`, with each finished run's records given run_seconds (the unit's wall time less
    the start-up spent in it, divided by its runs), then this process's WorkerReport."""
    started = time.perf_counter()
    outcomes: list[UnitOutcome] = list(run_unit_safely(_here(unit)))
    startup = take_startup_seconds()
    share = (time.perf_counter() - started - startup) / max(len(unit), 1)
    for outcome in outcomes:
        if isinstance(outcome, list):
            for record in outcome:
                record.run_seconds = share
    return [*outcomes, worker_report(startup)]


def _here(unit: Sequence[RunTask]) -> list[RunTask]:
    """The unit's runs with the plug-ins' shipped code (RunTask.here); its sha256 checked."""
    return [task.here() for task in unit]


__all__ = ["UnitOutcome", "run_unit_timed"]
