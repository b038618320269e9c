"""The student's process: the one place a submission's code runs when it is graded.

It runs in the submission's sandbox (mazelab.exercise.sandbox), where the lab is not installed: this
module imports only numpy and the student kit (mazelab.exercise.kit), so that it runs there as it is.
The grader (mazelab.exercise.runner) starts it in `python -P -S -s` (mazelab.exercise.sandbox), writes
the request on its standard input (the file and class to load, the stages and their inputs: points,
weights, angles, a maze's cells, the scenarios' compass angles and measurements; never the true path,
the exact posterior or a reference answer) and reads its answers on a pipe whose descriptor it names, as messages
of mazelab.exercise.wire, each preceded by its length. The child loads the file, builds a fresh
filter for each part, calls the student's methods on the inputs and sends back, stage by stage, only
values: the arrays the student's code returned and its errors as text. Nothing it says about itself
is believed: every verdict is the grader's, from these values. Before each stage it sends that
stage's name, so that a child that ends mid-way is reported at the stage where it happened.

`serve` is the same work in any process: `main` calls it, and the notebook's checks call it in their
own process (a self-check, not a grade).
"""

from __future__ import annotations

import contextlib
import faulthandler
import importlib.util
import os
import sys
import time
import traceback
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from mazelab.exercise.student import StudentFilter
from mazelab.exercise.wire import Message, decode, encode
from mazelab.maze import Maze
from mazelab.seeding import filter_rng

STAGES = ("predict", "weigh", "resample", "estimate", "whole")
Emit = Callable[..., None]  # emit(meta, arrays=None): one message to the grader
Answer = tuple[dict[str, Any], dict[str, np.ndarray]]  # a stage's meta (its error, if any) and arrays
TEXT_LIMIT = 600  # characters of an error's text
_LIBRARIES = tuple(
    str(Path(p).resolve()) for p in {sys.prefix, sys.base_prefix, Path(np.__file__).parent, Path(__file__).parents[1]}
)


# -- the student's calls ------------------------------------------------------------------------
def _text(error: BaseException) -> str:
    try:
        text = str(error)
    except BaseException:
        text = "(an error that cannot be printed)"
    return text if len(text) <= TEXT_LIMIT else text[: TEXT_LIMIT - 3] + "..."


def student_frames(tb: Any) -> list[traceback.FrameSummary]:
    """The frames of a traceback outside the kit, Python and numpy: the student's."""
    return [f for f in traceback.extract_tb(tb) if not str(Path(f.filename).resolve()).startswith(_LIBRARIES)]


def _where(error: BaseException) -> str:
    frames = student_frames(error.__traceback__)
    return f" ({Path(frames[-1].filename).name}, line {frames[-1].lineno})" if frames else ""


def describe_exit(error: BaseException) -> str:
    """What the student's code did, in a few words: 'called sys.exit(3)', 'raised KeyboardInterrupt'."""
    if isinstance(error, SystemExit):
        return f"called sys.exit({error.code!r})" if error.code is not None else "called sys.exit()"
    return f"raised {type(error).__name__}"


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
        text = f"{type(error).__name__}: {_text(error)}{_where(error)}{_past_limit(error)}"
        return None, {"kind": "error", "text": text}


def _past_limit(error: BaseException) -> str:
    """' (past the memory limit of 4 GB)' for a MemoryError under the grader's limit, else ''."""
    if not isinstance(error, MemoryError):
        return ""
    try:
        import resource

        limit = resource.getrlimit(resource.RLIMIT_AS)[0]
    except (ImportError, OSError, ValueError):
        return ""
    return "" if limit == resource.RLIM_INFINITY else f" (past the memory limit of {limit / 2**30:g} GB)"


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
        estimates, step = np.empty((len(z), 2)), 0
        try:
            particles = request.arrays[f"scenario/{i}/particles"].copy()
            filt = cls(world, scenario["sigma"], scenario["delta"], particles, filter_rng(scenario["seed"]))
            for step in range(1, len(z) + 1):
                filt.step(float(compass[step - 1]), float(z[step - 1]))
                estimates[step - 1] = _estimate_of(filt)
        except (SystemExit, KeyboardInterrupt) as error:
            text = f"{cls.__name__} {describe_exit(error)}{_when(step)}{_where(error)}"
            return {"error": {"kind": "exit", "text": text}, "scenario": i, "step": step}, out
        except BaseException as error:
            text = f"{cls.__name__} raised {type(error).__name__}{_when(step)}: {_text(error)}{_where(error)}"
            text += _past_limit(error)
            text = "; ".join(line.strip() for line in text.splitlines())  # one line: a table cell
            return {"error": {"kind": "error", "text": text}, "scenario": i, "step": step}, out
        out[f"estimates/{i}"] = estimates
    return {}, out


def _when(step: int) -> str:
    return " while being built" if step == 0 else f" at step {step}"


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
    """The class the request names, loaded from its file (its folder importable while it loads), and
    what the grader is told about it (the grader checks it again from the values it gets)."""
    path, class_name = Path(meta["file"]), meta.get("class")
    shown = meta.get("shown") or path.name
    spec = importlib.util.spec_from_file_location("submission", path)
    if spec is None or spec.loader is None:
        return None, {"error": f"{shown}: cannot be imported as a Python module"}
    module = importlib.util.module_from_spec(spec)
    sys.modules["submission"] = module
    sys.path.insert(0, str(path.parent))
    try:
        spec.loader.exec_module(module)
    except (SystemExit, KeyboardInterrupt) as error:
        return None, {
            "error": f"{shown} does not import: it {describe_exit(error)} while being imported{_where(error)}"
        }
    except BaseException as error:
        line = "" if isinstance(error, SyntaxError) else _where(error)
        lab = isinstance(error, ModuleNotFoundError) and (error.name or "").startswith("mazelab")
        why = " (the lab's own code is not there for a submission: write the part yourself)" if lab else ""
        return None, {"error": f"{shown} does not import: {type(error).__name__}: {_text(error)}{line}{why}"}
    finally:
        with contextlib.suppress(ValueError):
            sys.path.remove(str(path.parent))
    return _chosen_class(module, class_name, shown)


def _chosen_class(module: Any, class_name: str | None, shown: str) -> tuple[type | None, dict[str, Any]]:
    """The named class, or the one class the file defines that subclasses StudentFilter."""
    defined = [c for c in vars(module).values() if isinstance(c, type) and c.__module__ == module.__name__]
    if class_name is None:
        students = [c for c in defined if issubclass(c, StudentFilter)]
        if len(students) != 1:
            found = ", ".join(c.__name__ for c in students) or "none"
            return None, {"error": f"{shown}: name the class as {shown}:ClassName (StudentFilter classes: {found})"}
        return students[0], describe_class(students[0])
    cls = getattr(module, class_name, None)
    if not isinstance(cls, type) or cls not in defined:
        names = ", ".join(c.__name__ for c in defined) or "no classes"
        return None, {"error": f"{shown}: no class {class_name!r} of its own (it defines: {names})"}
    return cls, describe_class(cls)


def describe_class(cls: type) -> dict[str, Any]:
    """The class's name, whether it is a StudentFilter, and its first bases (for the one line)."""
    try:
        name = str(cls.name)
    except BaseException:
        name = cls.__name__
    bases = [f"{b.__module__}.{b.__qualname__}" for b in cls.__mro__[1:-1]][:3]
    return {"class": cls.__name__, "name": name[:80], "student_filter": issubclass(cls, StudentFilter), "bases": bases}


def serve(request: Message, emit: Emit, filter_class: type | None = None) -> None:
    """Load the class (or take `filter_class`), then run the request's stages, sending each one's
    start and its answer; then "done"."""
    cls, loaded = (filter_class, describe_class(filter_class)) if filter_class else load(request.meta)
    emit({"kind": "loaded", **loaded})
    if cls is None or not loaded["student_filter"]:
        emit({"kind": "done"})
        return
    worlds = Worlds()
    for stage in request.meta["stages"]:
        emit({"kind": "stage", "stage": stage})
        started = time.perf_counter()
        meta, arrays = STAGE_RUNNERS[stage](cls, request, worlds, emit)
        _flush()
        emit({**meta, "kind": "result", "stage": stage, "seconds": time.perf_counter() - started}, arrays)
    emit({"kind": "done"})


def _flush() -> None:
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(BaseException):  # the student may have replaced or closed them
            stream.flush()


def _read_request() -> Message:
    """The request, whole, from standard input (then closed: the student's code reads nothing there)."""
    data = sys.stdin.buffer.read()
    os.close(0)
    os.open(os.devnull, os.O_RDONLY)
    return decode(data)


def main(answer_fd: int) -> None:
    """The child process: read the request, serve it, answering on the descriptor `answer_fd`."""
    faulthandler.enable(file=sys.stderr, all_threads=True)  # a crash in C names the student's line
    message = _read_request()
    answers = os.fdopen(answer_fd, "wb", buffering=0)

    def emit(meta: dict[str, Any], arrays: dict[str, np.ndarray] | None = None) -> None:
        data = encode(meta, arrays)
        answers.write(len(data).to_bytes(8, "big") + data)

    serve(message, emit)
    _flush()
    os._exit(0)  # the student's threads, daemons or not, end with the process


__all__ = ["STAGES", "STAGE_RUNNERS", "as_values", "describe_exit", "load", "main", "serve", "student_call"]
