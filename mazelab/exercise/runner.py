"""The grader's side of the student's process: the request it is sent, the child started in the
submission's sandbox (mazelab.exercise.sandbox) with its limits, and what came back, read without
trusting it.

The child is a fresh interpreter (`python -P -S -s`) running mazelab.exercise.child on the student
kit (the lab itself is not there); it is sent the request on its standard input and answers on a pipe as messages of
mazelab.exercise.wire (JSON and raw arrays, never pickle), each after its length, read by a thread as
they come, so that a child that dies mid-way leaves the answers it gave. Its processor time, memory
and file sizes are limited by the grader before it starts (setrlimit, inherited by all it starts);
its waiting by the grader's clock. It runs in a session of its own, ended with all it started.

How a child can end: it answers and says "done"; it exits (any code, os._exit too) or is killed by a
signal before that; it runs past the time limit (killed); or it sends what is not a message. Each is
`ChildRun.ended`, one phrase naming what happened, and where (the last stage it started).
"""

from __future__ import annotations

import atexit
import contextlib
import math
import os
import shutil
import signal
import subprocess
import tempfile
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from mazelab.exercise.inputs import PartInputs, ScenarioInputs
from mazelab.exercise.kit import build_kit
from mazelab.exercise.sandbox import Sandbox, numpy_folders, sandbox
from mazelab.exercise.wire import MAX_MESSAGE_BYTES, Message, WireError, decode, encode

DEFAULT_TIMEOUT = 120.0  # processor seconds per child run: a vectorised filter needs 5-10, per-particle loops more
MAX_TIMEOUT = 86_400.0  # a day: the largest --timeout (a processor-time limit must be a finite whole number)
MEMORY_LIMIT = 4 << 30  # bytes of address space for the child
FILE_LIMIT = 64 << 20  # the largest file the child may write
OUTPUT_KEPT = 2000  # characters of the child's prints kept (its first and its last)
_running: set[subprocess.Popen] = set()  # the children alive now (what `stop_children` ends)
_running_lock = threading.Lock()
_stopped = threading.Event()
_kit_lock = threading.Lock()
_kit: tuple[Path, str] | None = None


class GradingStoppedError(Exception):
    """The grading was stopped (Ctrl-C, SIGTERM): no new child is started, and the running ones are ended."""


def stop_children() -> None:
    """End every running child (and its sandbox) and start no new one until `allow_children`."""
    _stopped.set()
    with _running_lock:
        running = list(_running)
    for process in running:
        _end_session(process)


def allow_children() -> None:
    _stopped.clear()


def kit() -> tuple[Path, str]:
    """The student kit of this process (built once, in a temporary folder removed at exit) and its sha256."""
    global _kit
    with _kit_lock:
        if _kit is None:
            folder = Path(tempfile.mkdtemp(prefix="mazelab-kit-"))
            atexit.register(_remove, folder)
            _kit = (folder, build_kit(folder / "kit"))
        return _kit[0] / "kit", _kit[1]


def _remove(folder: Path) -> None:
    """Remove a folder of read-only files and folders."""
    for path in [folder, *folder.rglob("*")]:
        with contextlib.suppress(OSError):
            path.chmod(0o755 if path.is_dir() else 0o644)
    shutil.rmtree(folder, ignore_errors=True)


COMPANIONS_KEPT = 50  # at most this many Python files beside a submission are copied with it


@contextlib.contextmanager
def submission_copy(path: Path, companions: bool = True) -> Any:
    """A folder holding only read-only copies of the submission (`submission/NAME`) and, with
    `companions`, the Python files beside it (its helper modules: a submission folder's own files),
    and for a plain child `site/` with links to numpy; removed afterwards. Yields the folder."""
    run = Path(tempfile.mkdtemp(prefix="mazelab-run-"))
    try:
        (run / "submission").mkdir()
        beside = [p for p in path.parent.glob("*.py") if p.name != path.name and p.is_file() and not p.is_symlink()]
        for source in [path, *sorted(beside)[:COMPANIONS_KEPT]] if companions else [path]:
            copy = run / "submission" / source.name
            shutil.copyfile(source, copy)
            copy.chmod(0o444)
        (run / "site").mkdir()
        for folder in numpy_folders():
            (run / "site" / folder.name).symlink_to(folder)
        for folder in (run / "submission", run / "site", run):
            folder.chmod(0o555)
        yield run
    finally:
        _remove(run)


def child_request(
    file: str,
    class_name: str | None,
    stages: list[str],
    parts: PartInputs,
    scenarios: list[ScenarioInputs],
    shown: str = "",
) -> bytes:
    """The request: what to load, which stages, their inputs and the child's limits; only what a
    filter is given (the scenarios' compass angles, measurements and initial particles, never their
    true path); `file` is the submission's path as the child sees it, `shown` its name in messages."""
    predict, weigh, resample, estimate = parts.predict, parts.weigh, parts.resample, parts.estimate
    meta = {
        "file": file,
        "class": class_name,
        "shown": shown,
        "stages": stages,
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


class _Reader(threading.Thread):
    """Reads the child's messages as they come (a daemon: a pipe kept open by an escaped grandchild
    cannot hold the grader); stops at the end of the pipe or the first unreadable message."""

    def __init__(self, stream: Any, run: ChildRun):
        super().__init__(daemon=True)
        self.stream, self.run_, self.problem = stream, run, None
        self.done = False

    def run(self) -> None:
        received = 0
        try:
            while header := self.stream.read(8):
                size = int.from_bytes(header, "big")
                received += size
                if len(header) < 8 or received > MAX_MESSAGE_BYTES:
                    raise WireError(f"more than {MAX_MESSAGE_BYTES >> 20} MB" if len(header) == 8 else "a cut header")
                data = self.stream.read(size)
                if len(data) < size:
                    raise WireError("a message cut short")
                self._take(decode(data))
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
    (its RLIMIT_CPU ends a busy one): a child that waits without working (a sleep, a lock) is
    stopped after this; where there is no processor limit (Windows), `timeout` itself."""
    return 4 * timeout + 10 if _has_cpu_limit() else timeout


def _has_cpu_limit() -> bool:
    try:
        import resource
    except ImportError:
        return False
    return hasattr(resource, "RLIMIT_CPU")


def _limits(timeout: float) -> Any:
    """The function run in the child before it starts (after fork, before exec): its processor time
    (SIGXCPU at the limit, SIGKILL two seconds later), memory, no core file, a bounded file size."""
    try:
        import resource
    except ImportError:  # Windows: the grader's clock is all there is
        return None
    cpu = math.ceil(min(timeout, MAX_TIMEOUT))
    wanted = [
        (resource.RLIMIT_CPU, cpu, cpu + 2),
        (resource.RLIMIT_AS, MEMORY_LIMIT, MEMORY_LIMIT),
        (resource.RLIMIT_CORE, 0, 0),
        (resource.RLIMIT_FSIZE, FILE_LIMIT, FILE_LIMIT),
    ]
    current = [resource.getrlimit(which)[1] for which, _, _ in wanted]
    settings = [
        (
            which,
            min(soft, hard) if hard != resource.RLIM_INFINITY else soft,
            min(top, hard) if hard != resource.RLIM_INFINITY else top,
        )
        for (which, soft, top), hard in zip(wanted, current, strict=True)
    ]

    def apply() -> None:
        for which, soft, hard in settings:
            resource.setrlimit(which, (soft, hard))

    return apply


def run_child(
    request: bytes, run_folder: Path, timeout: float = DEFAULT_TIMEOUT, made: Sandbox | None = None
) -> ChildRun:
    """Start a child on `request` in its sandbox (the submission's copy in `run_folder`), its processor
    time limited to `timeout` seconds; wait at most `wall_limit(timeout)` and return what it gave."""
    if _stopped.is_set():
        raise GradingStoppedError("the grading was stopped")
    made = made or sandbox()
    kit_folder, _ = kit()
    answers_in, answers_out = os.pipe()
    run = ChildRun()
    started = time.perf_counter()
    with _running_lock:
        try:
            process = _start(made.command(kit_folder, run_folder, answers_out), answers_out, timeout, made, run_folder)
        except OSError as error:  # bwrap gone since the probe, no memory to fork: this run's failure only
            os.close(answers_in)
            os.close(answers_out)
            run.ended = f"could not be started ({error.strerror or error})"
            return run
        _running.add(process)
    os.close(answers_out)
    reader = _Reader(os.fdopen(answers_in, "rb"), run)
    printed = _Output(process.stdout.fileno())
    reader.start()
    printed.start()
    try:
        threading.Thread(target=_send, args=(process, request), daemon=True).start()
        process.wait(wall_limit(timeout))
        timed_out = False
    except subprocess.TimeoutExpired:
        timed_out = True
    finally:
        _end_session(process)
        with contextlib.suppress(subprocess.TimeoutExpired):
            process.wait(5)
        with _running_lock:
            _running.discard(process)
    if _stopped.is_set():
        raise GradingStoppedError("the grading was stopped")
    run.seconds = time.perf_counter() - started
    reader.join(5)
    printed.join(2)
    run.output = printed.text()
    run.ended = _how_it_ended(run, reader, _signal_of(process.returncode, made), process.returncode, timed_out, timeout)
    return run


def _start(command: list[str], answers: int, timeout: float, made: Sandbox, run_folder: Path) -> subprocess.Popen:
    """The child's process: the request on its standard input, its prints merged on one pipe, the
    answer pipe kept open, its limits, a session of its own."""
    return subprocess.Popen(
        command,
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        pass_fds=(answers,),
        preexec_fn=_limits(timeout),
        start_new_session=True,
        env=_plain_environment(made),
        cwd=run_folder,
    )


def _send(process: subprocess.Popen, request: bytes) -> None:
    """Write the request to the child's standard input and close it (a child that reads none is its own)."""
    with contextlib.suppress(OSError):
        process.stdin.write(request)
    with contextlib.suppress(OSError):
        process.stdin.close()


def _plain_environment(made: Sandbox) -> dict[str, str] | None:
    """A plain child's environment: the sandbox's few variables, and PATH (bwrap sets its own)."""
    from mazelab.exercise.sandbox import CHILD_ENVIRONMENT

    return {"PATH": os.environ.get("PATH", ""), **CHILD_ENVIRONMENT} if not made.sandboxed else None


def _signal_of(code: int | None, made: Sandbox) -> int | None:
    """The signal that ended the child: a negative return code, or bwrap's 128 + the signal of its child."""
    if code is None:
        return None
    if code < 0:
        return -code
    return code - 128 if made.sandboxed and 128 < code < 128 + 65 else None


def _end_session(process: subprocess.Popen) -> None:
    """Kill the child's session (bwrap and so its whole sandbox; a plain child and what it started)."""
    for kill in (lambda: os.killpg(process.pid, signal.SIGKILL), process.kill):
        with contextlib.suppress(ProcessLookupError, PermissionError, OSError):
            kill()


def _how_it_ended(
    run: ChildRun, reader: _Reader, signal_number: int | None, code: int | None, timed_out: bool, timeout: float
) -> str | None:
    where = run.where()
    if timed_out:
        return f"waited past the time limit ({wall_limit(timeout):g} s) {where} and was stopped"
    if signal_number == getattr(signal, "SIGXCPU", 0):
        return f"ran past the time limit ({timeout:g} s of processor time) {where} and was stopped"
    if reader.problem:
        return f"{reader.problem} {where}"
    if reader.is_alive():
        return f"kept its answer pipe open after it ended {where}"
    if reader.done and code == 0:
        return None
    if signal_number is not None:
        return f"was killed by signal {signal_number} ({_signal_name(signal_number)}) {where}"
    return f"exited with code {code} {where}, before answering"


def _signal_name(number: int) -> str:
    try:
        return signal.Signals(number).name
    except ValueError:
        return "unknown"


__all__ = [
    "DEFAULT_TIMEOUT",
    "MAX_TIMEOUT",
    "MEMORY_LIMIT",
    "ChildRun",
    "GradingStoppedError",
    "allow_children",
    "child_request",
    "kit",
    "run_child",
    "stop_children",
    "submission_copy",
    "wall_limit",
]
