"""The grader's side of the student's process: the request it is sent, the child started and bounded
in time, and what came back, read without trusting it.

The child is a multiprocessing process of the forkserver context (spawn where there is none): the
fork server is a fresh interpreter that has imported only the child's modules (numpy, the lab's
model, StudentFilter), so a child starts in milliseconds and shares nothing with the grader's memory:
not the exact runs, not the robot's path, not the reference answers. It runs in a session of its
own (ended with all it started), with its prints collected (the first and last few lines kept), and
answers through a pipe as messages of mazelab.exercise.wire (JSON and raw arrays, never pickle),
read by a thread as they come, so that a child that dies mid-way leaves the answers it gave.

How a child can end: it answers and says "done"; it exits (any code, os._exit too) or is killed by a
signal before that; it runs past the time limit (killed); or it sends what is not a message. Each is
`ChildRun.ended`, one phrase naming what happened, and where (the last stage it started).
"""

from __future__ import annotations

import contextlib
import math
import multiprocessing
import os
import signal
import threading
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from mazelab.exercise.inputs import PartInputs, ScenarioInputs
from mazelab.exercise.wire import MAX_MESSAGE_BYTES, Message, WireError, decode, encode

DEFAULT_TIMEOUT = 120.0  # processor seconds per child run: a vectorised filter needs 5-10, per-particle loops more
MEMORY_LIMIT = 4 << 30  # bytes of address space for the child
FILE_LIMIT = 64 << 20  # the largest file the child may write
OUTPUT_KEPT = 2000  # characters of the child's prints kept (its first and its last)
CHILD_ENVIRONMENT = {  # the fork server's (and so every child's): one thread each, a fixed str hash, no display
    "OMP_NUM_THREADS": "1",
    "OPENBLAS_NUM_THREADS": "1",
    "MKL_NUM_THREADS": "1",
    "PYTHONHASHSEED": "0",
    "MPLBACKEND": "Agg",
    "PYTHONDONTWRITEBYTECODE": "1",
}
_context_lock = threading.Lock()
_context: Any = None
_running: set[Any] = set()  # the children alive now (what `stop_children` ends)
_running_lock = threading.Lock()
_stopped = threading.Event()


class GradingStoppedError(Exception):
    """The grading was stopped (Ctrl-C): no new child is started, and the running ones are ended."""


def stop_children() -> None:
    """End every running child (and its session) and start no new one until `allow_children`."""
    _stopped.set()
    with _running_lock:
        running = list(_running)
    for process in running:
        _end_session(process)


def allow_children() -> None:
    _stopped.clear()


def child_request(
    file: str,
    class_name: str | None,
    stages: list[str],
    parts: PartInputs,
    scenarios: list[ScenarioInputs],
    timeout: float = DEFAULT_TIMEOUT,
) -> bytes:
    """The request: what to load, which stages, their inputs and the child's limits; only what a
    filter is given (the scenarios' compass angles, measurements and initial particles, never their
    true path)."""
    predict, weigh, resample, estimate = parts.predict, parts.weigh, parts.resample, parts.estimate
    meta = {
        "file": file,
        "class": class_name,
        "stages": stages,
        "limits": {"memory_bytes": MEMORY_LIMIT, "file_bytes": FILE_LIMIT, "cpu_seconds": math.ceil(timeout)},
        "parts": {
            "maze": parts.maze,
            "sigma": parts.sigma,
            "delta": parts.delta,
            "filter_seed": parts.filter_seed,
            "predict": {"angles": list(predict.angles), "seeds": list(predict.seeds)},
            "weigh": {"z": list(weigh.z)},
            "resample": {"kinds": list(resample.kinds), "seeds": list(resample.seeds), "draws": resample.draws},
            "estimate": {"kinds": list(estimate.kinds)},
        },
        "scenarios": [{"maze": s.maze, "sigma": s.sigma, "delta": s.delta, "seed": s.seed} for s in scenarios],
    }
    arrays: dict[str, np.ndarray] = {
        "parts/grid": parts.grid,
        "parts/prior": parts.prior,
        "predict/start": predict.start,
        "weigh/points": weigh.points,
        "estimate/points": estimate.points,
    }
    arrays.update({f"resample/weights/{k}": w for k, w in enumerate(resample.weights)})
    arrays.update({f"estimate/weights/{k}": w for k, w in enumerate(estimate.weights)})
    for i, s in enumerate(scenarios):
        arrays[f"scenario/{i}/grid"] = s.grid
        arrays[f"scenario/{i}/particles"] = s.particles
        arrays[f"scenario/{i}/compass"] = np.asarray(s.compass_angles)
        arrays[f"scenario/{i}/z"] = np.asarray(s.measurements)
    return encode(meta, arrays)


@dataclass
class ChildRun:
    """What one child run gave: what it said of the class it loaded, each stage's answer, the stages
    it started, how it ended (None: it said "done"), its prints, and how long it took."""

    loaded: dict[str, Any] | None = None
    results: dict[str, Message] = field(default_factory=dict)
    started: list[str] = field(default_factory=list)
    scenario: int | None = None  # the last whole-filter scenario it started
    ended: str | None = None
    output: str = ""
    seconds: float = 0.0

    @property
    def stage(self) -> str:
        """Where it was: the last stage it started ("import" before any)."""
        return self.started[-1] if self.started else "import"

    def where(self) -> str:
        """'while importing the file', 'in predict', 'in the whole filter (scenario 3)'."""
        if self.loaded is None:
            return "while importing the file"
        if self.stage == "whole":
            return "in the whole filter" + ("" if self.scenario is None else f" (scenario {self.scenario + 1})")
        return f"in {self.stage}"


def child_context() -> Any:
    """The multiprocessing context of the children: forkserver (started once, with the child's modules
    and CHILD_ENVIRONMENT) where there is one, else spawn."""
    global _context
    with _context_lock:
        if _context is None:
            try:
                context = multiprocessing.get_context("forkserver")
            except ValueError:
                _context = multiprocessing.get_context("spawn")
                return _context
            # the main module too: a child would import it again otherwise (multiprocessing's rule), each time
            context.set_forkserver_preload(["__main__", "mazelab.exercise.child"])
            with _environment(CHILD_ENVIRONMENT):
                from multiprocessing import forkserver

                forkserver.ensure_running()
            _context = context
        return _context


@contextlib.contextmanager
def _environment(values: dict[str, str]) -> Any:
    """os.environ with `values` while the fork server starts (it copies the environment), then as before."""
    before = {name: os.environ.get(name) for name in values}
    os.environ.update(values)
    try:
        yield
    finally:
        for name, value in before.items():
            if value is None:
                os.environ.pop(name, None)
            else:
                os.environ[name] = value


class _Reader(threading.Thread):
    """Reads the child's messages as they come (a daemon: a pipe kept open by an escaped grandchild
    cannot hold the grader); stops at the end of the pipe or the first unreadable message."""

    def __init__(self, connection: Any, run: ChildRun):
        super().__init__(daemon=True)
        self.connection, self.run_, self.problem = connection, run, None
        self.done = False

    def run(self) -> None:
        received = 0
        try:
            while True:
                data = self.connection.recv_bytes(MAX_MESSAGE_BYTES)
                received += len(data)
                if received > MAX_MESSAGE_BYTES:
                    raise WireError(f"more than {MAX_MESSAGE_BYTES >> 20} MB")
                self._take(decode(data))
        except EOFError:
            pass
        except (WireError, OSError, ValueError) as error:
            self.problem = f"sent output the grader cannot read ({error})"

    def _take(self, message: Message) -> None:
        meta, run = message.meta, self.run_
        kind = meta.get("kind")
        if kind == "loaded" and run.loaded is None:
            run.loaded = meta
        elif kind == "stage" and isinstance(meta.get("stage"), str):
            if meta["stage"] not in run.started:
                run.started.append(meta["stage"])
            scenario = meta.get("scenario")
            run.scenario = scenario if isinstance(scenario, int) and not isinstance(scenario, bool) else run.scenario
        elif kind == "result" and isinstance(meta.get("stage"), str) and meta["stage"] not in run.results:
            run.results[meta["stage"]] = message
        elif kind == "done":
            self.done = True
        else:
            raise WireError(f"an unexpected message {str(kind)[:40]!r}")


class _Output(threading.Thread):
    """Collects what the child prints, keeping its first and last OUTPUT_KEPT characters."""

    def __init__(self, fd: int):
        super().__init__(daemon=True)
        self.fd, self.head, self.tail, self.total = fd, b"", b"", 0

    def run(self) -> None:
        try:
            while chunk := os.read(self.fd, 1 << 16):
                self.total += len(chunk)
                if len(self.head) < OUTPUT_KEPT:
                    taken = OUTPUT_KEPT - len(self.head)
                    self.head, chunk = self.head + chunk[:taken], chunk[taken:]
                self.tail = (self.tail + chunk)[-OUTPUT_KEPT:]
        except OSError:
            pass

    def text(self) -> str:
        skipped = self.total - len(self.head) - len(self.tail)
        middle = f"\n[... {skipped} bytes not kept ...]\n".encode() if skipped > 0 else b""
        return (self.head + middle + self.tail).decode(errors="replace")


def wall_limit(timeout: float) -> float:
    """How long the grader waits for a child whose processor time is limited to `timeout` seconds
    (its own RLIMIT_CPU ends a busy one): a child that waits without working (a sleep, a lock) is
    stopped after this; where there is no processor limit (Windows), `timeout` itself."""
    return 4 * timeout + 10 if _has_cpu_limit() else timeout


def _has_cpu_limit() -> bool:
    try:
        import resource
    except ImportError:
        return False
    return hasattr(resource, "RLIMIT_CPU")


def run_child(request: bytes, timeout: float = DEFAULT_TIMEOUT) -> ChildRun:
    """Start a child on `request` (whose processor time the child limits to `timeout` seconds),
    wait at most `wall_limit(timeout)`, and return what it gave."""
    from mazelab.exercise import child  # the target, by name: the fork server has it imported

    if _stopped.is_set():
        raise GradingStoppedError("the grading was stopped")
    context = child_context()
    results_in, results_out = context.Pipe(duplex=False)
    output_in, output_out = context.Pipe(duplex=False)
    run = ChildRun()
    process = context.Process(target=child.main, args=(request, results_out, output_out), daemon=True)
    started = time.perf_counter()
    with _running_lock:
        process.start()
        _running.add(process)
    results_out.close()
    output_out.close()
    reader, printed = _Reader(results_in, run), _Output(output_in.fileno())
    reader.start()
    printed.start()
    try:
        process.join(wall_limit(timeout))
        timed_out = process.exitcode is None
    finally:
        _end_session(process)
        process.join(5)
        with _running_lock:
            _running.discard(process)
    if _stopped.is_set():
        raise GradingStoppedError("the grading was stopped")
    run.seconds = time.perf_counter() - started
    reader.join(5)
    printed.join(2)
    run.output = printed.text()
    run.ended = _how_it_ended(run, reader, process.exitcode, timed_out, timeout)
    for connection in (results_in, output_in):
        with contextlib.suppress(OSError):
            connection.close()
    return run


def _end_session(process: Any) -> None:
    """Kill the child and everything in its session (it is the session's leader)."""
    for kill in (lambda: os.killpg(process.pid, signal.SIGKILL), process.kill):
        with contextlib.suppress(ProcessLookupError, PermissionError, AttributeError, OSError):
            kill()


def _how_it_ended(run: ChildRun, reader: _Reader, exitcode: int | None, timed_out: bool, timeout: float) -> str | None:
    where = run.where()
    if timed_out:
        return f"waited past the time limit ({wall_limit(timeout):g} s) {where} and was stopped"
    if exitcode is not None and exitcode == -getattr(signal, "SIGXCPU", 0):
        return f"ran past the time limit ({timeout:g} s of processor time) {where} and was stopped"
    if reader.problem:
        return f"{reader.problem} {where}"
    if reader.is_alive():
        return f"kept its answer pipe open after it ended {where}"
    if reader.done and exitcode == 0:
        return None
    if exitcode is not None and exitcode < 0:
        return f"was killed by signal {-exitcode} ({_signal_name(-exitcode)}) {where}"
    return f"exited with code {exitcode} {where}, before answering"


def _signal_name(number: int) -> str:
    try:
        return signal.Signals(number).name
    except ValueError:
        return "unknown"


__all__ = [
    "DEFAULT_TIMEOUT",
    "ChildRun",
    "GradingStoppedError",
    "allow_children",
    "child_context",
    "child_request",
    "run_child",
    "stop_children",
    "wall_limit",
]
