"""The student's process: the one place a submission's code runs when it is graded.

The grader (mazelab.exercise.runner) starts this as a child process and sends it a request: the file
and class to load, the stages to run and their inputs (points, weights, angles, a maze's cells, the
scenarios' compass angles and measurements: what a filter is given, never the true path, the exact
posterior or a reference answer). The child loads the file under the reference-call monitor
(mazelab.exercise.monitor), builds a fresh filter for each part, calls the student's methods on the
inputs and sends back, stage by stage, only values: the arrays the student's code returned, its
errors as text, and the reference functions it called. Every verdict is made by the grader, from
these values. Before each stage it sends that stage's name, so that a child that ends mid-way (an
exit, a signal, a hang the grader kills) is reported at the stage where it happened.

`serve` is the same work in any process: the child's `main` calls it, and the notebook's checks call
it in their own process (a self-check, not a grade).
"""

from __future__ import annotations

import contextlib
import faulthandler
import os
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from mazelab.exercise.monitor import Monitor, preload_reference
from mazelab.exercise.student import StudentFilter
from mazelab.exercise.wire import Message, decode, encode
from mazelab.maze import Maze
from mazelab.plugins import StudentCodeError, load_plugin, student_code, student_frames
from mazelab.seeding import filter_rng
from mazelab.stops import describe_exit, mark_interrupts

preload_reference()  # once, in the fork server (its children start with them imported, none of their time)
STAGES = ("predict", "weigh", "resample", "estimate", "whole")
Emit = Callable[..., None]  # emit(meta, arrays=None): one message to the grader
Answer = tuple[dict[str, Any], dict[str, np.ndarray]]  # a stage's meta (its error, if any) and arrays
TEXT_LIMIT = 600  # characters of an error's text


# -- the student's calls ------------------------------------------------------------------------
def _text(error: BaseException) -> str:
    try:
        text = str(error)
    except BaseException:
        text = "(an error that cannot be printed)"
    return text if len(text) <= TEXT_LIMIT else text[: TEXT_LIMIT - 3] + "..."


def _where(error: BaseException) -> str:
    frames = student_frames(error.__traceback__)
    return f" ({Path(frames[-1].filename).name}, line {frames[-1].lineno})" if frames else ""


def student_call(function: Callable[..., Any], *args: Any) -> tuple[Any, dict[str, str] | None]:
    """(what the student's function returned, None), or (None, the error as values): not written
    (NotImplementedError), an exit (its own sys.exit or KeyboardInterrupt), or any other error."""
    try:
        return function(*args), None
    except NotImplementedError:
        return None, {"kind": "not written", "text": "not implemented"}
    except (SystemExit, KeyboardInterrupt) as error:
        return None, {"kind": "exit", "text": f"{describe_exit(error)}, which a part must not do{_where(error)}"}
    except BaseException as error:
        return None, {"kind": "error", "text": f"{type(error).__name__}: {_text(error)}{_where(error)}"}


def as_values(part: str, value: Any, shape: tuple[int, ...], whole_numbers: bool = False) -> tuple[Any, Any]:
    """(the answer as a float64 or int64 array of `shape`, None), or (None, an error naming what came)."""
    try:
        array = np.asarray(value)
        if whole_numbers:
            if not np.issubdtype(array.dtype, np.integer):
                return None, {
                    "kind": "answer",
                    "text": f"{part} returned {array.dtype} values, not whole-number indices",
                }
            array = array.astype(np.int64)
        else:
            array = array.astype(np.float64)
    except BaseException as error:
        return None, {"kind": "answer", "text": f"{part} returned {type(value).__name__}, not numbers ({_text(error)})"}
    if array.shape != shape:
        return None, {"kind": "answer", "text": f"{part} returned shape {array.shape}; expected {shape}"}
    return array, None


def _answered(part: str, function: Callable[..., Any], args: tuple, shape: tuple, whole: bool = False) -> tuple:
    value, error = student_call(function, *args)
    return (None, error) if error else as_values(part, value, shape, whole)


# -- the stages ---------------------------------------------------------------------------------
class Worlds:
    """The mazes of a request, each built once (its nearest-station table too); a filter gets a copy."""

    def __init__(self) -> None:
        self._built: dict[bytes, Maze] = {}

    def copy_of(self, grid: np.ndarray, name: str) -> Maze:
        key = np.ascontiguousarray(grid).tobytes() + str(grid.shape).encode()
        if key not in self._built:
            self._built[key] = Maze(np.array(grid), source=name).prepare()
        return self._built[key].copy()


def part_filter(cls: type, request: Message, worlds: Worlds) -> tuple[Any, dict | None]:
    """A fresh filter for one part check: the parts' maze, sigma and delta, prior and Generator."""
    parts = request.meta["parts"]
    world = worlds.copy_of(request.arrays["parts/grid"], parts["maze"])
    prior = request.arrays["parts/prior"].copy()
    return student_call(cls, world, parts["sigma"], parts["delta"], prior, np.random.default_rng(parts["filter_seed"]))


def predict_stage(cls: type, request: Message, worlds: Worlds, emit: Emit) -> Answer:
    """moved/j at each angle j (from default_rng(seed_j)); at angle 0 also `again` (the same
    Generator, continued) and `repeat` (an equally seeded one)."""
    filt, error = part_filter(cls, request, worlds)
    if error:
        return {"error": error}, {}
    spec, start = request.meta["parts"]["predict"], request.arrays["predict/start"]
    angles, seeds = spec["angles"], spec["seeds"]
    first = np.random.default_rng(seeds[0])
    calls = [("moved/0", 0, first), ("again", 0, first), ("repeat", 0, None)]
    calls += [(f"moved/{j}", j, None) for j in range(1, len(angles))]
    out: dict[str, np.ndarray] = {}
    for name, j, rng in calls:
        rng = rng if rng is not None else np.random.default_rng(seeds[j])
        moved, error = _answered("predict", filt.predict, (start.copy(), angles[j], rng), start.shape)
        if error:
            return {"error": error}, out
        out[name] = moved
    return {}, out


def weigh_stage(cls: type, request: Message, worlds: Worlds, emit: Emit) -> Answer:
    """log_w/j: weigh on the points for each measurement z_j."""
    filt, error = part_filter(cls, request, worlds)
    if error:
        return {"error": error}, {}
    points, out = request.arrays["weigh/points"], {}
    for j, z in enumerate(request.meta["parts"]["weigh"]["z"]):
        log_w, error = _answered("weigh", filt.weigh, (points.copy(), z), (len(points),))
        if error:
            return {"error": error}, out
        out[f"log_w/{j}"] = log_w
    return {}, out


def resample_stage(cls: type, request: Message, worlds: Worlds, emit: Emit) -> Answer:
    """ancestors/k (R, N): R calls on weight vector k from one Generator; repeat/k: the first call
    again from an equally seeded one."""
    filt, error = part_filter(cls, request, worlds)
    if error:
        return {"error": error}, {}
    spec, out = request.meta["parts"]["resample"], {}
    for k, seed in enumerate(spec["seeds"]):
        weights = request.arrays[f"resample/weights/{k}"]
        n, rng = len(weights), np.random.default_rng(seed)
        rows = np.empty((spec["draws"], n), dtype=np.int64)
        for r in range(spec["draws"]):
            ancestors, error = _answered("resample", filt.resample, (weights.copy(), rng), (n,), True)
            if error:
                return {"error": error}, out
            rows[r] = ancestors
        again, error = _answered("resample", filt.resample, (weights.copy(), np.random.default_rng(seed)), (n,), True)
        if error:
            return {"error": error}, out
        out[f"ancestors/{k}"], out[f"repeat/{k}"] = rows, again
    return {}, out


def estimate_stage(cls: type, request: Message, worlds: Worlds, emit: Emit) -> Answer:
    """point/k: estimate of the points under weight vector k."""
    filt, error = part_filter(cls, request, worlds)
    if error:
        return {"error": error}, {}
    points, out = request.arrays["estimate/points"], {}
    for k in range(len(request.meta["parts"]["estimate"]["kinds"])):
        weights = request.arrays[f"estimate/weights/{k}"]
        point, error = _answered("estimate", filt.estimate_part, (points.copy(), weights.copy()), (2,))
        if error:
            return {"error": error}, out
        out[f"point/{k}"] = point
    return {}, out


def whole_stage(cls: type, request: Message, worlds: Worlds, emit: Emit) -> Answer:
    """estimates/i (steps, 2): the filter stepped along scenario i's compass angles and measurements,
    its estimate read after each step; the first error ends the stage (naming scenario and step)."""
    out: dict[str, np.ndarray] = {}
    for i, scenario in enumerate(request.meta["scenarios"]):
        emit({"kind": "stage", "stage": "whole", "scenario": i})
        world = worlds.copy_of(request.arrays[f"scenario/{i}/grid"], scenario["maze"])
        compass, z = request.arrays[f"scenario/{i}/compass"], request.arrays[f"scenario/{i}/z"]
        estimates = np.empty((len(z), 2))
        try:
            with student_code(cls) as at:
                particles = request.arrays[f"scenario/{i}/particles"].copy()
                filt = cls(world, scenario["sigma"], scenario["delta"], particles, filter_rng(scenario["seed"]))
                for k in range(len(z)):
                    at.number = k + 1
                    filt.step(float(compass[k]), float(z[k]))
                    estimates[k] = _estimate_of(filt)
        except StudentCodeError as error:
            text = "; ".join(line.strip() for line in str(error).splitlines())  # one line: a table cell
            return {"error": {"kind": "error", "text": text}, "scenario": i, "step": at.number}, out
        except BaseException as error:
            return {"error": {"kind": "exit", "text": describe_exit(error)}, "scenario": i, "step": at.number}, out
        out[f"estimates/{i}"] = estimates
    return {}, out


def _estimate_of(filt: Any) -> np.ndarray:
    """The filter's estimate as (2,) floats (whatever they are: NaN is the grader's to judge)."""
    point = np.asarray(filt.estimate, dtype=float)
    if point.shape != (2,):
        raise ValueError(f"estimate has shape {point.shape}; expected (2,)")
    return point


STAGE_RUNNERS = {
    "predict": predict_stage,
    "weigh": weigh_stage,
    "resample": resample_stage,
    "estimate": estimate_stage,
    "whole": whole_stage,
}


# -- loading and serving ----------------------------------------------------------------------
def load(meta: dict[str, Any]) -> tuple[type | None, dict[str, Any]]:
    """The class the request names (loaded from its file), and what the grader is told about it."""
    spec = meta["file"] + (f":{meta['class']}" if meta.get("class") else "")
    try:
        cls = load_plugin(spec)
    except ValueError as error:
        return None, {"error": _text(error)}
    except BaseException as error:
        return None, {"error": f"{spec} does not import: {type(error).__name__}: {_text(error)}"}
    return cls, describe_class(cls)


def describe_class(cls: type) -> dict[str, Any]:
    """The class's name, whether it is a StudentFilter, and its first bases (for the one line)."""
    try:
        name = str(cls.name)
    except BaseException:
        name = cls.__name__
    bases = [f"{b.__module__}.{b.__qualname__}" for b in cls.__mro__[1:-1]][:3]
    return {"class": cls.__name__, "name": name[:80], "student_filter": issubclass(cls, StudentFilter), "bases": bases}


def serve(request: Message, emit: Emit, monitor: Monitor, filter_class: type | None = None) -> None:
    """Load the class (or take `filter_class`), then run the request's stages, each under the
    monitor, sending its start and its answer; then "done"."""
    with monitor.watching("import"):
        cls, loaded = (filter_class, describe_class(filter_class)) if filter_class else load(request.meta)
    emit({"kind": "loaded", **loaded, **monitor.seen("import")})
    if cls is None or not loaded["student_filter"]:
        emit({"kind": "done"})
        return
    worlds = Worlds()
    for stage in request.meta["stages"]:
        emit({"kind": "stage", "stage": stage})
        started = time.perf_counter()
        with monitor.watching(stage):
            meta, arrays = STAGE_RUNNERS[stage](cls, request, worlds, emit)
        _flush()
        emit(
            {**meta, "kind": "result", "stage": stage, "seconds": time.perf_counter() - started, **monitor.seen(stage)},
            arrays,
        )
    emit({"kind": "done"})


def _flush() -> None:
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(BaseException):  # the student may have replaced or closed them
            stream.flush()


def apply_limits(limits: dict[str, int]) -> None:
    """The child's own resource limits (POSIX): its processor time (SIGXCPU at the limit, SIGKILL two
    seconds later), its memory, no core file, a bounded file size."""
    try:
        import resource
    except ImportError:  # Windows: the grader's time limit is all there is
        return
    for name, value in (
        ("RLIMIT_CPU", limits["cpu_seconds"]),
        ("RLIMIT_AS", limits["memory_bytes"]),
        ("RLIMIT_CORE", 0),
        ("RLIMIT_FSIZE", limits["file_bytes"]),
    ):
        which = getattr(resource, name, None)
        if which is None:
            continue
        try:
            hard = resource.getrlimit(which)[1]
            value = value if hard == resource.RLIM_INFINITY else min(value, hard)
            resource.setrlimit(which, (value, value + 2 if name == "RLIMIT_CPU" else hard))
        except (ValueError, OSError):
            pass


def main(request: bytes, results: Any, output: Any) -> None:
    """The child process: its own session (the grader ends it and whatever it starts together), its
    prints into `output`, its limits, the monitor, then `serve`, answering through `results`."""
    with contextlib.suppress(AttributeError, OSError):
        os.setsid()
    for fd in (1, 2):
        os.dup2(output.fileno(), fd)
    faulthandler.enable(file=sys.stderr, all_threads=True)  # a crash in C names the student's line
    message = decode(request)
    apply_limits(message.meta["limits"])
    mark_interrupts()  # a KeyboardInterrupt raised by code is the student's, not a Ctrl-C
    preload_reference()
    monitor = Monitor()
    monitor.install()

    def emit(meta: dict[str, Any], arrays: dict[str, np.ndarray] | None = None) -> None:
        results.send_bytes(encode(meta, arrays))

    serve(message, emit, monitor)
    _flush()


__all__ = ["STAGES", "STAGE_RUNNERS", "as_values", "load", "main", "serve", "student_call"]
