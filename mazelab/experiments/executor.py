"""How a study's runs are executed: in this process, on a local process pool, or on a Dask cluster
through its Client's executor (`Client.get_executor`): one loop (`Units`) hands out units of runs to
either and collects them as they finish, with a progress bar; on one backend for the whole study
(`study_backend`). Stopping keeps every finished run (`Units.run`); a pool's workers end with their parent
(`worker_setup`) and a dead one restarts the pool (`Units`); a Dask cluster (`study --dask ADDRESS`, the
optional extra `pip install -e ".[dask]"`) is connected in one line or refused (`connect`), its workers
asked once, before any run (`open_cluster`).
"""

from __future__ import annotations

import ctypes
import dataclasses
import functools
import logging
import math
import os
import signal
import socket
import sys
import threading
import time
import warnings
from collections import deque
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import FIRST_COMPLETED, CancelledError, Future, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from contextlib import contextmanager, suppress
from dataclasses import dataclass, field
from typing import Any

from mazelab.backend import backend_for_work, chosen_backend, cores, shared_threads, use_backend, use_threads
from mazelab.experiments.journal import dependency_versions
from mazelab.experiments.runs import take_startup_seconds
from mazelab.experiments.study import (
    MAX_BATCH,
    RunFailure,
    RunRecord,
    RunTask,
    run_task_safely,
    run_unit_safely,
    study_order,
    study_units,
)
from mazelab.stops import STOP_SIGNALS, signal_handlers

REPORTED_PACKAGES = ("numpy", "numba", "llvmlite")  # the versions a worker reports with its backend
MAX_POOL_RESTARTS = 3  # a pool whose workers die more often than this stops the study (rows kept)
PR_SET_PDEATHSIG = 1  # linux/prctl.h: the signal a process gets when its parent dies
WATCHDOG_SECONDS = 0.5


# -- what a study produced, and what each process says of itself ----------------------------------------
@dataclass
class WorkerReport:
    """What a process that ran a study's runs says of itself with its results: where it ran, its
    backend and package versions (a study refuses workers that disagree), and the start-up it spent."""

    worker: str  # host:pid
    backend: str
    packages: dict[str, str | None] = field(default_factory=dict)
    startup_seconds: float = 0.0

    def describe(self) -> str:
        versions = ", ".join(f"{name} {v or 'none'}" for name, v in self.packages.items())
        return f"{self.worker}: backend {self.backend} ({versions})"


def worker_report(startup_seconds: float = 0.0) -> WorkerReport:
    """This process's report (mazelab.backend.chosen_backend, the installed versions)."""
    return WorkerReport(
        f"{socket.gethostname()}:{os.getpid()}",
        chosen_backend(),
        dependency_versions(REPORTED_PACKAGES),
        startup_seconds,
    )


@dataclass
class StudyOutcome:
    """What a study produced: a record per finished run and filter, the failed runs, and whether
    the user interrupted it (then the records are the runs that finished before)."""

    records: list[RunRecord] = field(default_factory=list)
    failures: list[RunFailure] = field(default_factory=list)
    interrupted: bool = False
    stopped_by: int | None = None  # the signal that stopped it (2: Ctrl-C), None if it ran to the end
    lost: str | None = None  # why the study stopped early without a signal (a lost cluster or pool), one line
    workers: dict[str, WorkerReport] = field(default_factory=dict)  # each process's report, start-up summed
    backend: str = ""  # the one backend the study's runs ran on (mazelab.experiments.executor.study_backend)

    def collector(self, on_records: Any = None) -> Any:
        """The function that takes a unit's outcomes into this one, each run's records also handed to
        `on_records` as they come (the study's journal appends them)."""

        def collect(outcomes: list[list[RunRecord] | RunFailure | WorkerReport]) -> None:
            for outcome in outcomes:
                if isinstance(outcome, RunFailure):
                    self.failures.append(outcome)
                elif isinstance(outcome, WorkerReport):
                    known = self.workers.setdefault(outcome.worker, dataclasses.replace(outcome, startup_seconds=0.0))
                    known.startup_seconds += outcome.startup_seconds
                else:
                    self.records.extend(outcome)
                    if on_records is not None:
                        on_records(outcome)

        return collect

    @property
    def status(self) -> str:
        """A study that ran to its end: "finished", or "finished with failures" (a run raised)."""
        return "finished" if not self.failures else "finished with failures"

    @property
    def startup_seconds(self) -> float:
        """The start-up of every process that ran runs (numba's load, first-call warm-ups), summed."""
        return sum(report.startup_seconds for report in self.workers.values())


UnitOutcome = list[RunRecord] | RunFailure | WorkerReport

# -- an existing Dask cluster ---------------------------------------------------------------------------
CONNECT_SECONDS = 3  # a scheduler that does not answer within this is reported unreachable
DASK_TIMEOUT = 300.0  # seconds without any finished run after which a study on Dask gives up (--dask-timeout)
SCHEMES = ("tcp",)  # what --dask takes: tls, ucx and others need a security or transport setup of their own
# The loggers silenced while a study runs on Dask: distributed's configuration gives some of their
# children a level and a handler of their own (distributed.client: warning), so each is set, not
# only the parents.
QUIET_LOGGERS = ("distributed", "tornado", "asyncio", "bokeh")


def connect(address: str, timeout: float = CONNECT_SECONDS) -> Any:
    """A dask.distributed Client of the scheduler at `address` (e.g. tcp://10.0.0.5:8786), or a
    ValueError of one line: dask missing, another scheme than tcp://, or the scheduler unreachable
    within `timeout` seconds (probed with a plain socket first, so no half-made Client lingers)."""
    try:
        from distributed import Client
    except ImportError:
        raise ValueError('--dask needs dask.distributed: pip install -e ".[dask]"') from None
    host, port = parse_scheduler_address(address)
    quiet_distributed()
    try:
        with socket.create_connection((host, port), timeout=timeout):
            pass
    except OSError as error:
        reason = error.strerror or type(error).__name__ if not isinstance(error, TimeoutError) else "no answer"
        raise ValueError(f"cannot reach the Dask scheduler at {address!r}: {reason} within {timeout:g} s") from None
    try:
        return Client(address, timeout=timeout, set_as_default=False)
    except MemoryError:  # something answers there, but not Dask's protocol (a frame of exabytes)
        raise ValueError(f"cannot reach the Dask scheduler at {address!r}: what answers there is not one") from None
    except Exception as error:  # OSError, TimeoutError, ValueError (not a scheduler there), ...
        reason = str(error).splitlines()[0] if str(error) else type(error).__name__
        raise ValueError(f"cannot reach the Dask scheduler at {address!r}: {reason}") from None


def parse_scheduler_address(address: str) -> tuple[str, int]:
    """(host, port) of tcp://HOST:PORT, or a one-line ValueError naming --dask."""
    from distributed.comm import parse_address
    from distributed.comm.addressing import parse_host_port

    usage = f"--dask {address!r} is not a scheduler address like tcp://HOST:8786"
    try:  # a malformed address is refused here: a Client that fails to parse it lingers at exit
        scheme, location = parse_address(address)
        if scheme not in SCHEMES:
            raise ValueError(f"{usage} (only tcp:// is supported, not {scheme}://)")
        host, port = parse_host_port(location)
    except ValueError as error:
        raise ValueError(str(error) if str(error).startswith(usage) else f"{usage} ({error})") from None
    except TypeError as error:
        raise ValueError(f"{usage} ({error})") from None
    if not port or not 0 < int(port) < 65536:
        raise ValueError(f"{usage} (no port)")
    return host, int(port)


def quiet_distributed() -> None:
    """distributed's own logging (retries, lost connections, tracebacks) off, and the noise of a
    Client collected late ("Exception ignored in Client.__del__") dropped: this program says in one
    line what went wrong."""
    names = [n for n in list(logging.Logger.manager.loggerDict) if n.split(".")[0] in QUIET_LOGGERS]
    for name in dict.fromkeys([*QUIET_LOGGERS, *names]):
        logging.getLogger(name).setLevel(logging.CRITICAL + 1)
    previous = sys.unraisablehook
    if getattr(previous, "_mazelab_quiet", False):
        return

    def hook(unraisable: Any) -> None:
        where = " ".join(
            str(getattr(thing, "__module__", "") or "") for thing in (unraisable.object, type(unraisable.object))
        )
        if "distributed" not in where and "tornado" not in where:
            previous(unraisable)

    hook._mazelab_quiet = True  # type: ignore[attr-defined]
    sys.unraisablehook = hook


def check_workers(client: Any, backend: str) -> list[WorkerReport]:
    """Each Dask worker's report (`worker_report`), asked before any run: a worker that cannot
    run the study's `backend` (compiled without numba) or whose package versions differ from the
    others' would make rows that do not belong together, so it is refused in one line naming it."""
    try:
        reports = client.run(worker_report)
    except Exception as error:  # a worker without mazelab, or gone
        reason = str(error).splitlines()[0] if str(error) else type(error).__name__
        raise ValueError(f"the Dask workers cannot say their backend: {reason}") from None
    reports = [reports[address] for address in sorted(reports)]
    for report in reports:
        if backend == "compiled" and report.packages.get("numba") is None:
            raise ValueError(
                f"the Dask worker {report.describe()} cannot run the compiled backend: install numba "
                "there, or give --backend numpy"
            )
        if report.packages != reports[0].packages:
            raise ValueError(
                f"the Dask workers disagree ({reports[0].describe()}; {report.describe()}): start every worker "
                "with the same packages"
            )
    return reports


def close_client(client: Any) -> None:
    """Close the connection (the cluster itself goes on); quietly, also when the cluster is gone."""
    with suppress(Exception):
        client.close(timeout=CONNECT_SECONDS)


def describe_workers(client: Any) -> str:
    """'no worker is left' or 'N worker(s) connected', for the timeout's message."""
    try:
        count = len(client.scheduler_info(n_workers=-1).get("workers", {}))
    except TypeError:  # an older distributed without n_workers
        count = len(client.scheduler_info().get("workers", {}))
    except Exception:
        return "the scheduler does not answer"
    return "no worker is left" if count == 0 else f"{count} worker(s) connected, none finishing"


# -- the runs --------------------------------------------------------------------------------------------
class StudyStopped(KeyboardInterrupt):
    """SIGTERM or SIGHUP stopped the study (raised in the main thread, as Ctrl-C raises KeyboardInterrupt)."""

    def __init__(self, signum: int):
        super().__init__(signal.Signals(signum).name)
        self.signum = signum


class StudyLost(RuntimeError):  # noqa: N818 (a state, as KeyboardInterrupt)
    """The cluster went away (its scheduler died, no worker finishes) or the pool's workers keep dying:
    str() is one line saying which; the finished runs are kept."""


def study_backend(tasks: Sequence[RunTask], processes: int) -> str:
    """The one backend of a study's runs: MAZELAB_BACKEND's (--backend sets it), else the compiled one
    where its start-up in each of `processes` pays for the study's work (mazelab.backend.backend_for_work:
    the particles the filters' steps move, and the calls of `step`, the runs of a setting advancing
    together up to MAX_BATCH), else numpy."""
    particle_steps = sum(t.setting.particles * t.steps * len(t.filters) for t in tasks)
    calls = sum(t.steps * len(t.filters) for t in tasks) / min(max((t.run for t in tasks), default=1), MAX_BATCH)
    return backend_for_work(particle_steps, calls, processes=max(1, min(processes, len(tasks))))


def run_unit_timed(
    unit: Sequence[RunTask], backend: str, visualize: Any = False, threads: int = 1
) -> list[UnitOutcome]:
    """A unit of runs on `backend` and `threads` threads at most (`run_unit_safely`; with `visualize`, its one
    run drawn, in this process where the viewer is), each finished run's records given run_seconds (the unit's
    wall time less the start-up spent in it, divided by its runs), then this process's WorkerReport. Each
    plug-in's spec is the one that imports its shipped code here (RunTask.here)."""
    with use_backend(backend), use_threads(min(threads, cores())):
        started = time.perf_counter()
        tasks = [task.here() for task in unit]
        outcomes: list[UnitOutcome] = [run_task_safely(tasks[0], visualize)] if visualize else run_unit_safely(tasks)
        startup = take_startup_seconds()
        share = (time.perf_counter() - started - startup) / max(len(unit), 1)
        for outcome in outcomes:
            for record in outcome if isinstance(outcome, list) else ():
                record.run_seconds = share
        return [*outcomes, worker_report(startup)]


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
    backend: str | None = None,
) -> StudyOutcome:
    """Run every task, on `workers` processes (default: all cores) or on a Dask cluster (`dask`: its
    scheduler's address, opened (`open_cluster`) and closed here, or the Client `open_cluster` gave), on one
    backend (`backend`, default `study_backend`'s choice); with `visualize`, the first run drawn in this
    process. A run that raises becomes a RunFailure, the others go on; `on_records` is handed each finished
    run's records as they come (the journal appends them). A stop (`ignore_signals_after_stop`: the next
    ones ignored), a lost cluster (`dask_timeout` seconds without a finished unit) or a pool whose workers
    keep dying ends the study early, its finished runs kept (`run_units`)."""
    workers = worker_count(workers)
    backend = backend or study_backend(tasks, workers if dask is None else 1)
    client = open_cluster(dask, backend) if isinstance(dask, str) else dask  # a bad address: one line
    outcome = StudyOutcome(backend=backend)
    drawn, rest = (list(tasks[:1]), list(tasks[1:])) if visualize else ([], list(tasks))
    threads = shared_threads(workers, client)  # the runs at once x their threads <= cores
    work = functools.partial(run_unit_timed, backend=backend, threads=threads)
    units = Units(study_units(rest, 1 if client is not None else workers), work, workers, client, dask_timeout)
    collect = outcome.collector(on_records)

    def here(advance: Callable[..., None]) -> None:  # the drawn run, in this process where the viewer is
        for task in drawn:
            collect(run_unit_timed((task,), backend, visualize, threads))
            advance()

    try:
        run_units(outcome, units, collect, len(tasks), progress, here=here, ignore_after_stop=ignore_signals_after_stop)
    finally:
        if isinstance(dask, str):
            close_client(client)
    outcome.records = study_order(outcome.records, tasks)  # whatever order the workers finished in
    outcome.failures.sort(key=lambda f: (f.task.setting_index, f.task.run))
    return outcome


def worker_count(workers: int | None) -> int:
    """The processes of a study: `workers`, or all cores for None; fewer than one is one line."""
    if workers is not None and workers < 1:
        raise ValueError(f"workers must be >= 1 (or None: all cores), got {workers}")
    return cores() if workers is None else workers


def open_cluster(dask: Any, backend: str) -> Any:
    """The Dask client of `dask` (an address, connected here, or a distributed.Client), its workers asked
    once, before any run, whether they can run the study's `backend` (`check_workers`); None without
    `dask`; anything else is a TypeError. A client connected here is closed again when its workers are refused."""
    if dask is None:
        return None
    client_class = getattr(sys.modules.get("distributed"), "Client", None)  # none before distributed is imported
    if not isinstance(dask, str) and (client_class is None or not isinstance(dask, client_class)):
        raise TypeError(
            f"dask must be a scheduler address like 'tcp://HOST:8786' or a distributed.Client, got "
            f"{dask!r} ({type(dask).__name__})"
        )
    client = connect(dask) if isinstance(dask, str) else dask  # a bad address: one line, before anything runs
    try:
        check_workers(client, backend)  # workers that cannot run it, or of other versions: one line
    except BaseException:
        if isinstance(dask, str):
            close_client(client)
        raise
    return client


def run_units(
    outcome: StudyOutcome,
    units: Units,
    collect: Callable[[list], None],
    total: int,
    progress: bool,
    what: str = "runs",
    here: Callable[..., None] = lambda advance: None,
    ignore_after_stop: bool = False,
) -> None:
    """Run the units (`Units.run`, `here(advance)` in this process meanwhile) with a progress bar over
    `total` `what`. Meanwhile SIGTERM and SIGHUP raise StudyStopped in the main thread, so that they stop the
    study as Ctrl-C does: a stop sets outcome.interrupted and outcome.stopped_by, a lost cluster or pool
    outcome.lost (the finished units collected either way). Afterwards the previous handlers come back; with
    `ignore_after_stop`, the stop signals stay ignored after a stop."""

    def stop(signum: int, _frame: Any) -> None:
        raise StudyStopped(signum)

    with progress_bar(total, progress, what) as advance:
        with signal_handlers([sig for sig in STOP_SIGNALS if sig != signal.SIGINT], stop):
            try:
                units.run(collect, advance, functools.partial(here, advance))
            except StudyLost as lost:
                outcome.lost = str(lost)
            except KeyboardInterrupt as stopped:
                if ignore_after_stop:  # until signal_handlers puts the previous handlers back, then for good
                    _ignore(STOP_SIGNALS)
                outcome.interrupted, outcome.stopped_by = True, getattr(stopped, "signum", signal.SIGINT)
        if ignore_after_stop and outcome.interrupted:
            _ignore(STOP_SIGNALS)


class Units:
    """Units of runs, each `work(unit)` (picklable), handed out to a local process pool (at most two per
    worker at a time) or to a Dask cluster (all at once, through `Client.get_executor`), collected as
    they finish. A unit whose worker died is reported as a RunFailure of each of its tasks."""

    def __init__(
        self,
        units: Sequence[tuple[Any, ...]],
        work: Callable[[Any], list],
        workers: int,
        client: Any = None,
        timeout: float | None = None,
    ) -> None:
        self.waiting = deque(units)
        self.running: dict[Future, tuple[Any, ...]] = {}
        self.work, self.client, self.timeout = work, client, timeout
        self.size = min(workers, len(units))
        self.limit = len(units) if client is not None else 2 * workers
        self.restarts = 0
        self.pool: Any = None

    def _executor(self) -> Any:
        if self.client is not None:
            return self.client.get_executor(pure=False)
        return ProcessPoolExecutor(max_workers=self.size, initializer=worker_setup)

    def run(
        self, collect: Callable[[list], None], advance: Callable[..., None], here: Callable[[], None] = lambda: None
    ) -> None:
        """Hand out the units, run `here()` (the drawn run) meanwhile, and collect every unit as it
        finishes. The first Ctrl-C hands out no more units and lets the running ones finish (on Dask:
        cancels the rest), a second Ctrl-C, SIGTERM or SIGHUP ends the workers at once; the stop, a lost
        cluster or pool, is raised again once the finished units are collected and the workers ended."""
        self.collect, self.advance = collect, advance
        if self.client is None and self.size <= 1:  # one worker, or one unit: in this process, in order
            here()
            while self.waiting:
                unit = self.waiting.popleft()
                collect(self.work(unit))
                advance(len(unit))
            return
        self.pool = self._executor()
        try:
            handed = self._hand_out()
            here()
            while self.running or self.waiting:
                done, broken = self._wait() if handed else (set(), True)
                self._take(self._restart() if broken else done)
                handed = self._hand_out()
        except (StudyLost, KeyboardInterrupt) as stop:
            if self.client is None and not isinstance(stop, (StudyLost, StudyStopped)):
                try:  # the pool's workers ignore Ctrl-C and finish what they were handed
                    while self.running:
                        self._take(wait(self.running, timeout=0.2, return_when=FIRST_COMPLETED)[0])
                except KeyboardInterrupt as second:
                    stop = second
            with signal_handlers(STOP_SIGNALS, signal.SIG_IGN):  # a third Ctrl-C changes nothing
                self._take(self._finished())
                if self.client is None:
                    end_workers(self.pool)  # the unfinished runs are dropped
                else:
                    with suppress(Exception):  # on Dask: the rest cancelled
                        self.pool.shutdown(wait=False)
            raise stop from None
        self.pool.shutdown(wait=True)

    def _wait(self) -> tuple[set[Future], bool]:
        """The units finished next, and whether the pool is broken: a worker died, whether its future
        says so or not (killed while it wrote a unit's rows, the pool's thread waits for the rest of the
        message; end_workers frees it). A lost cluster raises StudyLost: its scheduler gone, or `timeout`
        seconds without a finished unit (no worker left); a local pool has no deadline."""
        deadline = time.monotonic() + (self.timeout if self.client is not None else math.inf)
        while True:
            left = deadline - time.monotonic()
            done = wait(self.running, timeout=max(0.0, min(1.0, left)), return_when=FIRST_COMPLETED)[0]
            processes = (getattr(self.pool, "_processes", None) or {}).values()  # a local pool's (no public API)
            broken = any(isinstance(f.exception(), BrokenProcessPool) for f in done if not f.cancelled())
            if done or broken or not all(process.is_alive() for process in processes):
                return done, broken or not done
            if self.client is not None and self.client.status not in ("running", "connecting"):
                raise StudyLost(f"lost the connection to the Dask scheduler ({self.client.status})")
            if left <= 1.0:
                raise StudyLost(
                    f"no run finished on the Dask cluster within {self.timeout:g} s (--dask-timeout): "
                    f"{describe_workers(self.client)}"
                )

    def _finished(self) -> set[Future]:
        """The units that finished well (what a stop keeps)."""
        return {f for f in self.running if f.done() and not f.cancelled() and f.exception() is None}

    def _hand_out(self) -> bool:
        """Submit units up to the limit; False if the pool is broken (the unit stays queued)."""
        while self.waiting and len(self.running) < self.limit:
            try:
                future = self.pool.submit(self.work, self.waiting[0])
            except BrokenProcessPool:  # a worker died since the last wait
                return False
            self.running[future] = self.waiting.popleft()
        return True

    def _take(self, done: set[Future]) -> None:
        for future in done:
            unit = self.running.pop(future)
            try:
                results = future.result()
            except BrokenProcessPool:
                results = [RunFailure(task, "its worker process died (out of memory?)") for task in unit]
            except CancelledError:  # the scheduler went away with it: not the run's fault
                raise StudyLost("lost the Dask scheduler (it cancelled the runs not finished)") from None
            except OSError as error:
                raise StudyLost(f"lost the connection to the Dask cluster ({type(error).__name__})") from None
            except Exception as error:  # the unit itself raised on the worker (e.g. mazelab missing there)
                where = "on the Dask cluster" if self.client is not None else "in a worker process"
                results = [RunFailure(task, f"{where}: {type(error).__name__}: {error}") for task in unit]
            self.collect(results)
            self.advance(len(unit))

    def _restart(self) -> set[Future]:
        """A new pool: the unfinished units go back in the queue, the finished futures are returned (to
        take), at most MAX_POOL_RESTARTS times."""
        self.restarts += 1
        if self.restarts > MAX_POOL_RESTARTS:
            raise StudyLost(f"worker processes died {self.restarts} times (killed, or out of memory?)")
        finished = self._finished()
        for future in [f for f in self.running if f not in finished]:
            self.waiting.appendleft(self.running.pop(future))
        warnings.warn(
            "a worker process died (killed, or out of memory?): its runs start again on a new pool", stacklevel=3
        )
        end_workers(self.pool)
        self.pool = self._executor()
        return finished


def end_workers(pool: ProcessPoolExecutor) -> None:
    """Kill the pool's worker processes now and reap them (their unfinished runs are dropped).

    A worker killed while it wrote a unit's rows (SIGTERM to the process group, kill -9) leaves a message
    cut short in the result pipe, and the pool's thread waits for its rest for ever: this process closes
    its own end of the pipe too, once the workers are gone, so that the thread reads the end of the pipe,
    and `shutdown` returns."""
    kill_workers = getattr(pool, "kill_workers", None)  # Python 3.14
    processes = list((getattr(pool, "_processes", None) or {}).values())  # no public API before 3.14
    if kill_workers is not None:
        kill_workers()
    for process in processes:
        if process.is_alive():
            process.kill()
    for process in processes:
        process.join(timeout=5)
    writer = getattr(getattr(pool, "_result_queue", None), "_writer", None)  # no public API either
    if writer is not None and not any(process.is_alive() for process in processes):
        writer.close()
    pool.shutdown(wait=True)  # the pool's thread sees the workers gone and ends


def worker_setup() -> None:
    """In each pool worker: leave Ctrl-C to the main process (it stops the study and keeps what
    finished), and end with the parent, however it ends: SIGKILL from the kernel on Linux
    (PR_SET_PDEATHSIG), and on every system a daemon thread that polls os.getppid()."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)  # not the parent's handler, which a fork inherits
    if hasattr(signal, "SIGHUP"):  # a terminal's hangup reaches the whole group: the parent ends the workers
        signal.signal(signal.SIGHUP, signal.SIG_IGN)
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


def _ignore(signals: Sequence[int]) -> None:
    """Ignore these signals from now on (in the main thread; elsewhere nothing to do)."""
    if threading.current_thread() is threading.main_thread():
        for sig in signals:
            signal.signal(sig, signal.SIG_IGN)


@contextmanager
def progress_bar(total: int, show: bool, what: str = "runs") -> Iterator[Callable[..., None]]:
    """A rich progress bar on stderr (typer brings rich) over `total` `what` when stderr is a terminal,
    else one plain line at the end ("runs 120/120 in 4.1 s": a log file gets the count, not a redrawn
    bar, and a study run by a script does not import rich); yields the function that advances it."""
    if not show:
        yield lambda count=1: None
        return
    if not sys.stderr.isatty():
        done, started = [0], time.perf_counter()
        try:
            yield lambda count=1: done.__setitem__(0, done[0] + count)
        finally:
            print(f"{what} {done[0]}/{total} in {time.perf_counter() - started:.1f} s", file=sys.stderr, flush=True)
        return
    from rich import progress as rich
    from rich.console import Console

    columns = (rich.BarColumn(), rich.MofNCompleteColumn(), rich.TimeElapsedColumn(), rich.TextColumn("left"))
    columns = (rich.TextColumn(what), *columns, rich.TimeRemainingColumn())
    with rich.Progress(*columns, console=Console(stderr=True), transient=False) as bar:
        task = bar.add_task(what, total=total)
        yield lambda count=1: bar.advance(task, count)
