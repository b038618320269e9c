"""How a study's runs are executed: in this process or on a process pool, with a progress bar;
Ctrl-C keeps the finished runs."""

from __future__ import annotations

import os
import signal
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from contextlib import contextmanager
from typing import Any

from mazelab.experiments.study import RunFailure, RunRecord, RunTask, StudyOutcome, run_task, run_task_safely

QUEUED_PER_WORKER = 4  # tasks queued per worker process at a time


def default_workers() -> int:
    """All the cores this process may use."""
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1


def run_study(
    tasks: Sequence[RunTask], workers: int | None = None, *, visualize: Any = False, progress: bool = False
) -> StudyOutcome:
    """Run every task, on `workers` processes (default: all cores); Ctrl-C keeps the finished runs.

    With `visualize`, the first run is drawn (all its filters, as compare draws them) in this process.
    A run that raises becomes a RunFailure; the others go on.
    """
    workers = default_workers() if workers is None else workers
    if workers < 1:
        raise ValueError(f"--workers must be >= 1, got {workers}")
    outcome = StudyOutcome(tasks=len(tasks))
    with _progress_bar(len(tasks), progress) as advance:
        try:
            drawn, rest = (list(tasks[:1]), list(tasks[1:])) if visualize else ([], list(tasks))
            if workers == 1 or len(rest) <= 1:
                for task in drawn:
                    outcome.add(_draw_task(task, visualize))
                    advance()
                for task in rest:
                    outcome.add(run_task_safely(task))
                    advance()
            else:
                _run_in_pool(rest, drawn, workers, visualize, outcome, advance)
        except KeyboardInterrupt:
            outcome.interrupted = True
    outcome.sort()
    return outcome


def _draw_task(task: RunTask, visualize: Any) -> list[RunRecord] | RunFailure:
    try:
        return run_task(task, visualize)
    except Exception as error:
        return RunFailure(task, f"{type(error).__name__}: {error}")


def _run_in_pool(
    tasks: list[RunTask],
    drawn: list[RunTask],
    workers: int,
    visualize: Any,
    outcome: StudyOutcome,
    advance: Callable[[], None],
) -> None:
    """Tasks on a process pool (the drawn ones here meanwhile); on Ctrl-C, cancel what has not
    started, let the running tasks finish, and keep every finished result. A few tasks per worker are
    queued at a time, so that a large study starts at once and Ctrl-C never meets a long submission."""
    pool = ProcessPoolExecutor(max_workers=min(workers, len(tasks)), initializer=_ignore_sigint)
    pending: dict[Future, RunTask] = {}
    queue = iter(tasks)

    def submit_next() -> None:
        task = next(queue, None)
        if task is not None:
            pending[pool.submit(run_task_safely, task)] = task

    try:
        for _ in range(QUEUED_PER_WORKER * workers):
            submit_next()
        for task in drawn:
            outcome.add(_draw_task(task, visualize))
            advance()
        while pending:
            done, _ = wait(pending, return_when=FIRST_COMPLETED)
            for future in done:
                outcome.add(_result_of(future, pending.pop(future)))
                advance()
                submit_next()
    finally:  # also on Ctrl-C: the workers ignore it and finish their current run
        pool.shutdown(wait=True, cancel_futures=True)
        for future, task in pending.items():
            if future.done() and not future.cancelled():
                outcome.add(_result_of(future, task))
                advance()


def _result_of(future: Future, task: RunTask) -> list[RunRecord] | RunFailure:
    try:
        return future.result()
    except BrokenProcessPool:
        return RunFailure(task, "its worker process died (out of memory?)")


def _ignore_sigint() -> None:
    """Workers leave Ctrl-C to the main process, which stops the study and saves what finished."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)


@contextmanager
def _progress_bar(total: int, show: bool) -> Iterator[Callable[[], None]]:
    """A rich progress bar on stderr (typer brings rich); yields the function that advances it."""
    if not show:
        yield lambda: None
        return
    from rich.console import Console
    from rich.progress import (
        BarColumn,
        MofNCompleteColumn,
        Progress,
        TextColumn,
        TimeElapsedColumn,
        TimeRemainingColumn,
    )

    columns = (
        TextColumn("runs"),
        BarColumn(),
        MofNCompleteColumn(),
        TimeElapsedColumn(),
        TextColumn("left"),
        TimeRemainingColumn(),
    )
    with Progress(*columns, console=Console(stderr=True), transient=False) as bar:
        task = bar.add_task("runs", total=total)
        yield lambda: bar.advance(task)


__all__ = [
    "default_workers",
    "run_study",
]
