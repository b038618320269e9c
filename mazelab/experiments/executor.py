"""How a study's runs are executed: in this process or on a process pool, with a progress bar.

Stopping keeps every finished run: the first Ctrl-C cancels the runs not started and lets the running
ones finish; a second Ctrl-C, SIGTERM or SIGHUP ends the workers at once. Workers also end with their
parent when it is killed outright (kill -9): a parent-death signal on Linux, a watchdog thread elsewhere.
"""

from __future__ import annotations

import ctypes
import os
import signal
import sys
import threading
import time
import warnings
from collections import deque
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from contextlib import contextmanager, suppress
from typing import Any

from mazelab.experiments.batch_runs import study_units
from mazelab.experiments.dask_runner import (
    DASK_TIMEOUT,
    ClusterLost,
    check_workers,
    close_client,
    connect,
    run_on_dask,
)
from mazelab.experiments.study import (
    RunFailure,
    RunRecord,
    RunTask,
    StudyOutcome,
    run_task,
)
from mazelab.experiments.units import UnitOutcome, run_unit_timed
from mazelab.experiments.warmup import take_startup_seconds, worker_report


def default_workers() -> int:
    """All the cores this process may use."""
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1


class StudyStopped(KeyboardInterrupt):
    """SIGTERM or SIGHUP stopped the study (raised in the main thread, as Ctrl-C raises KeyboardInterrupt)."""

    def __init__(self, signum: int):
        super().__init__(signal.Signals(signum).name)
        self.signum = signum


def run_study(
    tasks: Sequence[RunTask],
    workers: int | None = None,
    *,
    visualize: Any = False,
    progress: bool = False,
    on_records: Callable[[list[RunRecord]], None] | None = None,
    dask: Any = None,
    ignore_signals_after_stop: bool = False,
    dask_timeout: float = DASK_TIMEOUT,
) -> StudyOutcome:
    """Run every task, on `workers` processes (default: all cores) or on a Dask cluster: `dask` is its
    scheduler's address (connected and closed here) or a dask.distributed Client; any stop keeps the
    finished runs.

    With `visualize`, the first run is drawn (all its filters, as compare draws them) in this process.
    A run that raises becomes a RunFailure; the others go on. `on_records` is handed each finished
    run's records as they come (the study's CSV appends them). A stop sets outcome.interrupted and
    outcome.stopped_by (the signal's number: SIGINT for Ctrl-C); with `ignore_signals_after_stop` (a
    command about to exit), further Ctrl-C, SIGTERM and SIGHUP are ignored from then on. A lost Dask
    cluster (its scheduler gone, or `dask_timeout` seconds without a finished run) or a local pool
    whose workers keep dying ends the study early: outcome.lost says why, in one line.
    """
    workers = default_workers() if workers is None else workers
    if workers < 1:
        raise ValueError(f"--workers must be >= 1, got {workers}")
    client = connect(dask) if isinstance(dask, str) else dask  # a bad address: one line, before anything runs
    if client is not None:
        try:
            check_workers(client)  # workers of different backends or versions: one line, before anything runs
        except ValueError:
            if isinstance(dask, str):
                close_client(client)
            raise
    outcome = StudyOutcome(tasks=len(tasks))

    def collect(results: list[list[RunRecord] | RunFailure]) -> None:
        for result in results:
            outcome.add(result)
            if on_records is not None and isinstance(result, list):
                on_records(result)

    try:

        def keep_ignoring() -> bool:
            return ignore_signals_after_stop and outcome.interrupted

        with progress_bar(len(tasks), progress) as advance, stop_signals(keep_ignoring):
            try:
                drawn, rest = (list(tasks[:1]), list(tasks[1:])) if visualize else ([], list(tasks))
                units = study_units(rest, 1 if client is not None else workers)
                if client is not None:
                    here = lambda: _run_drawn(drawn, visualize, collect, advance)  # noqa: E731
                    run_on_dask(client, units, here, collect, advance, dask_timeout)
                elif workers == 1 or len(units) <= 1:
                    _run_drawn(drawn, visualize, collect, advance)
                    for unit in units:
                        collect(run_unit_timed(unit))
                        advance(len(unit))
                else:
                    _run_in_pool(units, drawn, workers, visualize, collect, advance)
            except (ClusterLost, PoolLost) as lost:
                outcome.lost = str(lost)
            except KeyboardInterrupt as stop:
                if ignore_signals_after_stop:
                    _ignore(STOP_SIGNALS)
                outcome.interrupted = True
                outcome.stopped_by = getattr(stop, "signum", signal.SIGINT)
    finally:
        if isinstance(dask, str):
            close_client(client)
    outcome.sort()
    return outcome


def _run_drawn(
    drawn: list[RunTask], visualize: Any, collect: Callable[[list], None], advance: Callable[..., None]
) -> None:
    """The drawn run(s), in this process (the viewer is here)."""
    for task in drawn:
        collect(_draw_task(task, visualize))
        advance()


def _draw_task(task: RunTask, visualize: Any) -> list[UnitOutcome]:
    """The drawn run's records (or its failure), then this process's WorkerReport."""
    started = time.perf_counter()
    try:
        records = run_task(task.here(), visualize)
    except Exception as error:
        return [RunFailure(task, f"{type(error).__name__}: {error}"), worker_report(take_startup_seconds())]
    startup = take_startup_seconds()
    for record in records:
        record.run_seconds = time.perf_counter() - started - startup
    return [records, worker_report(startup)]


def _run_in_pool(
    units: list[tuple[RunTask, ...]],
    drawn: list[RunTask],
    workers: int,
    visualize: Any,
    collect: Callable[[list], None],
    advance: Callable[..., None],
) -> None:
    """Units of runs on a process pool (the drawn ones here meanwhile), at most two per worker handed
    out at a time. On Ctrl-C, hand out no more and let the running units finish; on a second Ctrl-C,
    SIGTERM or SIGHUP end the workers at once. Every finished result is kept; the stop is raised again.

    A worker that dies (kill -9, out of memory) breaks the pool. That shows either as a unit's future
    failing with BrokenProcessPool, or, when the worker died after the last wait returned (another
    unit had just finished), as `submit` raising BrokenProcessPool while more units are handed out:
    both restart the pool, at most MAX_POOL_RESTARTS times, with the units not finished handed out
    again and the finished ones kept."""
    size = min(workers, len(units))
    pool = ProcessPoolExecutor(max_workers=size, initializer=worker_setup)
    waiting = deque(units)
    running: dict[Future, tuple[RunTask, ...]] = {}
    restarts = 0

    def hand_out() -> bool:
        """Submit units until two per worker run; False if the pool is broken (the unit stays queued)."""
        while waiting and len(running) < 2 * workers:
            unit = waiting[0]
            try:
                future = pool.submit(run_unit_timed, unit)
            except BrokenProcessPool:  # a worker died since the last wait
                return False
            running[future] = waiting.popleft()
        return True

    def take(done: set[Future], finished_only: bool = False) -> None:
        for future in done:
            unit = running.pop(future)
            if not finished_only or future.exception() is None:
                collect(_result_of(future, unit))
                advance(len(unit))

    def restart() -> set[Future]:
        """A new pool: the unfinished units go back in the queue, the finished futures are returned
        (to take), at most MAX_POOL_RESTARTS times."""
        nonlocal pool, restarts
        restarts += 1
        if restarts > MAX_POOL_RESTARTS:
            raise PoolLost(f"worker processes died {restarts} times (killed, or out of memory?)")
        finished = {f for f in running if f.done() and f.exception() is None}
        for future in [f for f in running if f not in finished]:
            waiting.appendleft(running.pop(future))
        warnings.warn("a worker process died (killed, or out of memory?): its runs start again on a new pool",
                      stacklevel=3)  # fmt: skip
        end_workers(pool)
        pool = ProcessPoolExecutor(max_workers=size, initializer=worker_setup)
        return finished

    def broken(done: set[Future]) -> bool:
        return any(isinstance(f.exception(), BrokenProcessPool) for f in done)

    try:
        handed = hand_out()
        _run_drawn(drawn, visualize, collect, advance)
        while running or waiting:
            if not handed:
                take(restart())
            else:
                done = wait(running, return_when=FIRST_COMPLETED)[0]
                take(restart() if broken(done) else done)
            handed = hand_out()
    except PoolLost:
        with signals_ignored():
            take({future for future in running if future.done() and future.exception() is None})
            end_workers(pool)
        raise
    except KeyboardInterrupt as stop:
        if not isinstance(stop, StudyStopped):
            try:  # the workers ignore Ctrl-C and finish what they were handed
                while running:
                    take(wait(running, timeout=0.2, return_when=FIRST_COMPLETED)[0])
            except KeyboardInterrupt as second:
                stop = second
        with signals_ignored():
            take({future for future in running if future.done()}, finished_only=True)
            end_workers(pool)
        raise stop from None
    pool.shutdown(wait=True)


def end_workers(pool: ProcessPoolExecutor) -> None:
    """Kill the pool's worker processes now and reap them (their unfinished runs are dropped)."""
    kill_workers = getattr(pool, "kill_workers", None)  # Python 3.14
    processes = list((getattr(pool, "_processes", None) or {}).values())  # no public API before 3.14
    if kill_workers is not None:
        kill_workers()
    for process in processes:
        if process.is_alive():
            process.kill()
    for process in processes:
        process.join(timeout=5)
    pool.shutdown(wait=True)  # the pool's thread sees the workers gone and ends


def _result_of(future: Future, unit: tuple[RunTask, ...]) -> list[list[RunRecord] | RunFailure]:
    try:
        return future.result()
    except BrokenProcessPool:
        return [RunFailure(task, "its worker process died (out of memory?)") for task in unit]


MAX_POOL_RESTARTS = 3  # a pool whose workers die more often than this stops the study (rows kept)


class PoolLost(RuntimeError):  # noqa: N818 (a state, as ClusterLost)
    """The local pool's workers keep dying: str() is one line; the finished runs are kept."""


PR_SET_PDEATHSIG = 1  # linux/prctl.h: the signal a process gets when its parent dies
WATCHDOG_SECONDS = 0.5


def worker_setup() -> None:
    """In each worker: leave Ctrl-C to the main process (it stops the study and keeps what finished),
    and end with the parent, however it ends."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)  # not the parent's handler, which a fork inherits
    if hasattr(signal, "SIGHUP"):  # a terminal's hangup reaches the whole group: the parent ends the workers
        signal.signal(signal.SIGHUP, signal.SIG_IGN)
    die_with_parent()


def die_with_parent() -> None:
    """End this process when its parent ends: SIGKILL from the kernel on Linux (PR_SET_PDEATHSIG),
    and on every system a daemon thread that polls os.getppid() (a reparented process has another)."""
    parent = os.getppid()
    if sys.platform.startswith("linux"):
        with suppress(OSError, AttributeError):
            ctypes.CDLL(None, use_errno=True).prctl(PR_SET_PDEATHSIG, signal.SIGKILL, 0, 0, 0)
    if parent == 1:  # the parent died before the check was set
        os._exit(1)
    threading.Thread(target=_watch_parent, args=(parent,), daemon=True, name="parent-watchdog").start()


def _watch_parent(parent: int) -> None:
    while os.getppid() == parent:
        time.sleep(WATCHDOG_SECONDS)
    os._exit(1)


@contextmanager
def stop_signals(keep_ignoring: Callable[[], bool] = lambda: False) -> Iterator[None]:
    """While the study runs: SIGTERM and SIGHUP raise StudyStopped in the main thread (as Ctrl-C raises
    KeyboardInterrupt), so that they too keep the finished runs and end the workers. Afterwards the
    previous handlers come back, unless `keep_ignoring()` (the stop signals stay ignored then)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def stop(signum: int, _frame: Any) -> None:
        raise StudyStopped(signum)

    previous = {sig: signal.signal(sig, stop) for sig in STOP_SIGNALS if sig != signal.SIGINT}
    try:
        yield
    finally:
        if keep_ignoring():
            _ignore(STOP_SIGNALS)
        else:
            for sig, handler in previous.items():
                signal.signal(sig, handler)


def _ignore(signals: Sequence[int]) -> None:
    """Ignore these signals from now on (in the main thread; elsewhere nothing to do)."""
    if threading.current_thread() is threading.main_thread():
        for sig in signals:
            signal.signal(sig, signal.SIG_IGN)


STOP_SIGNALS = tuple(getattr(signal, name) for name in ("SIGINT", "SIGTERM", "SIGHUP") if hasattr(signal, name))


@contextmanager
def signals_ignored() -> Iterator[None]:
    """Ctrl-C, SIGTERM and SIGHUP ignored while the workers are ended (a third Ctrl-C changes nothing)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = {sig: signal.signal(sig, signal.SIG_IGN) for sig in STOP_SIGNALS}
    try:
        yield
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)


@contextmanager
def progress_bar(total: int, show: bool, what: str = "runs") -> Iterator[Callable[..., None]]:
    """A rich progress bar on stderr (typer brings rich) over `total` `what` when stderr is a terminal,
    else one plain line at the end (a log file gets the count, not a redrawn bar, and a study run by a
    script does not import rich); yields the function that advances it (by one, or by the count given)."""
    if not show:
        yield lambda count=1: None
        return
    if not sys.stderr.isatty():
        with _final_line(total, what) as advance:
            yield advance
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
        TextColumn(what),
        BarColumn(),
        MofNCompleteColumn(),
        TimeElapsedColumn(),
        TextColumn("left"),
        TimeRemainingColumn(),
    )
    with Progress(*columns, console=Console(stderr=True), transient=False) as bar:
        task = bar.add_task(what, total=total)
        yield lambda count=1: bar.advance(task, count)


@contextmanager
def _final_line(total: int, what: str) -> Iterator[Callable[..., None]]:
    """progress_bar off a terminal: "runs 120/120 in 4.1 s" on stderr when the runs end (or stop)."""
    done, started = [0], time.perf_counter()

    def advance(count: int = 1) -> None:
        done[0] += count

    try:
        yield advance
    finally:
        print(f"{what} {done[0]}/{total} in {time.perf_counter() - started:.1f} s", file=sys.stderr, flush=True)


__all__ = [
    "MAX_POOL_RESTARTS",
    "STOP_SIGNALS",
    "PoolLost",
    "StudyStopped",
    "default_workers",
    "die_with_parent",
    "end_workers",
    "progress_bar",
    "run_study",
    "signals_ignored",
    "stop_signals",
    "worker_setup",
]
