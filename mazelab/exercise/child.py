"""The student's process: the one place a submission's code runs when it is graded (in its sandbox,
where of the lab there is only the student kit), and the messages it exchanges with the grader
(docs/exercise.md, "Values only"). It reads the request on its standard input, says "hello" before any
of the student's code runs, installs the audit hook (`guard`, "Only the files run"), loads the file,
and sends back, stage by stage, only values: the arrays the student's code returned and its errors
as text. Both ways a message is MAGIC, the length of a JSON header (`meta` and each array's name, dtype
and shape), the header, then the arrays' bytes: written by `encode`, read by `messages`, which checks
each whole before any array is made (never pickle: unpickling what the student's process sends would
run its code in the grader).
"""

from __future__ import annotations

import collections
import contextlib
import faulthandler
import importlib.util
import itertools
import json
import math
import os
import sys
import sysconfig
import time
import traceback
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from mazelab.exercise.student import PartError, StudentFilter, answer_array
from mazelab.maze import Maze
from mazelab.seeding import run_streams
from mazelab.stops import describe_exit

MAGIC = b"MZL1"
MAX_HEADER_BYTES = 1 << 20
MAX_MESSAGE_BYTES = 1 << 28  # 256 MB: the most a child may send in all (the grader reads no more)
DTYPES = ("<f8", "<i8", "|b1")  # float64, int64, bool: all the checks exchange
TEXT_LIMIT = 600  # characters of an error's text
Emit = Callable[..., None]  # emit(meta, arrays=None): one message to the grader
_LIBRARIES = tuple(
    str(Path(p).resolve()) for p in {sys.prefix, sys.base_prefix, Path(np.__file__).parent, Path(__file__).parents[1]}
)


# -- the messages ---------------------------------------------------------------------------------
class WireError(ValueError):
    """A message that is not one of ours, or an answer in it not of the form the grader asked for
    (mazelab.exercise.parts.take): what is wrong with it, in one line."""


@dataclass
class Message:
    """A decoded message: its JSON `meta` and its arrays by name."""

    meta: dict[str, Any]
    arrays: dict[str, np.ndarray] = field(default_factory=dict)


def _wire_array(array: Any) -> np.ndarray:
    array = np.asarray(array)
    kind = "|b1" if array.dtype == bool else "<i8" if np.issubdtype(array.dtype, np.integer) else "<f8"
    return np.ascontiguousarray(array, dtype=np.dtype(kind))


def encode(meta: dict[str, Any], arrays: dict[str, Any] | None = None) -> bytes:
    """One message: `meta` (JSON; finite floats only) and the arrays (as float64, int64 or bool)."""
    wired = {name: _wire_array(value) for name, value in (arrays or {}).items()}
    entries = [{"name": name, "dtype": a.dtype.str, "shape": list(a.shape)} for name, a in wired.items()]
    text = json.dumps({"meta": meta, "arrays": entries}, allow_nan=False, separators=(",", ":")).encode()
    return b"".join([MAGIC, len(text).to_bytes(4, "big"), text, *(a.tobytes() for a in wired.values())])


def messages(stream: Any) -> Iterator[Message]:
    """The messages on `stream` until its end, each checked whole (the module docstring) before any of
    its arrays is made; WireError at the first that is not one of ours, or past MAX_MESSAGE_BYTES in all."""
    received = 0
    while start := stream.read(8):
        size = int.from_bytes(start[4:], "big")
        if len(start) < 8 or start[:4] != MAGIC:
            raise WireError("not a message of the grader's (no header)")
        if size > MAX_HEADER_BYTES:
            raise WireError(f"a header of {size} bytes")
        text = _exactly(stream, size)
        try:
            header = json.loads(text, parse_constant=_no_constant)
        except (ValueError, RecursionError) as error:
            raise WireError(f"a header that is not JSON ({error})") from None
        if not isinstance(header, dict) or set(header) != {"meta", "arrays"} or not isinstance(header["meta"], dict):
            raise WireError("a header without meta and arrays")
        entries = [_array_entry(entry) for entry in header["arrays"]] if isinstance(header["arrays"], list) else None
        if entries is None or len({name for name, _, _ in entries}) < len(entries):
            raise WireError("a header whose arrays are not a list of names each given once")
        sizes = [math.prod(shape) * dtype.itemsize for _, dtype, shape in entries]
        received += 8 + size + sum(sizes)
        if received > MAX_MESSAGE_BYTES:
            raise WireError(f"more than {MAX_MESSAGE_BYTES >> 20} MB")
        data, offsets = _exactly(stream, sum(sizes)), itertools.accumulate(sizes, initial=0)
        arrays = {}
        for (name, dtype, shape), offset in zip(entries, offsets, strict=False):  # the offsets: one more
            arrays[name] = np.frombuffer(data, dtype=dtype, count=math.prod(shape), offset=offset).reshape(shape)
        yield Message(header["meta"], arrays)


def _exactly(stream: Any, size: int) -> bytes:
    data = stream.read(size)
    if len(data) < size:
        raise WireError("a message cut short")
    return data


def _no_constant(name: str) -> None:
    raise ValueError(f"{name} is not JSON")


def _array_entry(entry: Any) -> tuple[str, np.dtype, tuple[int, ...]]:
    """(name, dtype, shape) of a header's array entry, checked."""
    if not isinstance(entry, dict) or set(entry) != {"name", "dtype", "shape"}:
        raise WireError("an array entry without name, dtype and shape")
    name, dtype, shape = entry["name"], entry["dtype"], entry["shape"]
    if not isinstance(name, str) or len(name) > 200 or dtype not in DTYPES:
        raise WireError(f"an array entry {str(name)[:40]!r} of dtype {str(dtype)[:10]!r} (one of {', '.join(DTYPES)})")
    whole = all(isinstance(n, int) and not isinstance(n, bool) and 0 <= n <= MAX_MESSAGE_BYTES for n in shape)
    if not isinstance(shape, list) or len(shape) > 4 or not whole:
        raise WireError(f"the array {name!r} has shape {shape!r}")
    return name, np.dtype(dtype), tuple(shape)


# -- the student's calls ------------------------------------------------------------------------
def _text(error: BaseException) -> str:
    try:
        text = str(error)
    except BaseException:
        text = "(an error that cannot be printed)"
    return text if len(text) <= TEXT_LIMIT else text[: TEXT_LIMIT - 3] + "..."


def _where(error: BaseException) -> str:
    """' (my_filter.py, line 12)': the student's last frame of the error's traceback, if any."""
    frames = traceback.extract_tb(error.__traceback__)
    mine = [f for f in frames if not str(Path(f.filename).resolve()).startswith(_LIBRARIES)]
    return f" ({Path(mine[-1].filename).name}, line {mine[-1].lineno})" if mine else ""


def _past_limit(error: BaseException) -> str:
    """' (past the memory limit of 4 GB)' for a MemoryError under the grader's limit, else ''."""
    try:
        import resource

        limit = resource.getrlimit(resource.RLIMIT_AS)[0]
    except (ImportError, OSError, ValueError):
        return ""
    unlimited = not isinstance(error, MemoryError) or limit == resource.RLIM_INFINITY
    return "" if unlimited else f" (past the memory limit of {limit / 2**30:g} GB)"


def student_call(function: Callable[..., Any], *args: Any) -> tuple[Any, dict[str, str] | None]:
    """(what the student's function returned, None), or (None, the error as values): not written
    (NotImplementedError), an answer not of the form asked for (PartError), an exit (its own sys.exit
    or KeyboardInterrupt), or any other error."""
    try:
        return function(*args), None
    except NotImplementedError:
        return None, {"kind": "not written", "text": "not implemented"}
    except PartError as error:  # an answer not of the form asked for (answer_array)
        return None, {"kind": "answer", "text": _text(error)}
    except (SystemExit, KeyboardInterrupt) as error:
        return None, {"kind": "exit", "text": f"{describe_exit(error)}, which a part must not do{_where(error)}"}
    except BaseException as error:
        text = f"{type(error).__name__}: {_text(error)}{_where(error)}{_past_limit(error)}"
        return None, {"kind": "error", "text": text}


# -- the stages ---------------------------------------------------------------------------------
class Inputs(dict):
    """A request's inputs by name (mazelab.exercise.inputs.request: scalars and arrays), its mazes built
    once each (the nearest-station table too); a filter gets a copy."""

    def of(self, prefix: str) -> dict[str, Any]:
        """The inputs under `prefix.`, by the rest of their names."""
        return {name.removeprefix(prefix + "."): v for name, v in self.items() if name.startswith(prefix + ".")}

    def world(self, prefix: str) -> Maze:
        key = f"{prefix}.built"
        if key not in self:
            self[key] = Maze(np.array(self[f"{prefix}.grid"]), source=self[f"{prefix}.maze"]).prepare()
        return self[key].copy()


Call = tuple[str, str, tuple, tuple, bool, int]  # (answer, method, arguments, shape, whole numbers, calls stacked)


def part_calls(stage: str, inputs: Inputs) -> list[Call]:
    """One part's calls, named as the grader's judges read them (mazelab.exercise.parts). predict:
    moved/j at each angle j (from default_rng(seed_j)), at angle 0 also `again` (the same Generator,
    continued) and `repeat` (an equally seeded one); weigh: log_w/j for each measurement z_j; resample:
    ancestors/k, R calls on weight vector k from one Generator stacked (R, N), and repeat/k from an
    equally seeded one; estimate: point/k under weight vector k."""
    given = inputs.of(f"parts.{stage}")
    if stage == "predict":
        start, angles, seeds = given["start"], given["angles"], given["seeds"]
        first = np.random.default_rng(seeds[0])
        order = [("moved/0", 0, first), ("again", 0, first), ("repeat", 0, None)]
        order += [(f"moved/{j}", j, None) for j in range(1, len(angles))]
        rngs = [(name, j, rng or np.random.default_rng(seeds[j])) for name, j, rng in order]
        return [(name, stage, (start, angles[j], rng), start.shape, False, 0) for name, j, rng in rngs]
    if stage == "weigh":
        points = given["points"]
        return [(f"log_w/{j}", stage, (points, z), (len(points),), False, 0) for j, z in enumerate(given["z"])]
    if stage == "estimate":
        points, count = given["points"], len(given["kinds"])
        return [(f"point/{k}", "estimate_part", (points, given[f"weights.{k}"]), (2,), False, 0) for k in range(count)]
    calls = []
    for k, seed in enumerate(given["seeds"]):
        weights = given[f"weights.{k}"]
        for name, stacked in ((f"ancestors/{k}", given["draws"]), (f"repeat/{k}", 0)):
            calls.append((name, stage, (weights, np.random.default_rng(seed)), weights.shape, True, stacked))
    return calls


def part_stage(cls: type, stage: str, inputs: Inputs) -> tuple[dict, dict]:
    """One part's answers: a fresh filter (the parts' maze, sigma, delta, prior and Generator), then
    each call on copies of its inputs; the first error ends the stage."""
    given = inputs.of("parts")
    rng = np.random.default_rng(given["filter_seed"])
    filt, error = student_call(cls, inputs.world("parts"), given["sigma"], given["delta"], given["prior"].copy(), rng)
    out: dict[str, Any] = {}
    for name, method, args, shape, whole, stacked in [] if error else part_calls(stage, inputs):
        values = []
        for _ in range(stacked or 1):
            copies = tuple(a.copy() if isinstance(a, np.ndarray) else a for a in args)
            value, error = student_call(getattr(filt, method), *copies)
            value, error = (None, error) if error else student_call(answer_array, stage, value, shape, whole)
            if error:
                return {"error": error}, out
            values.append(value)
        out[name] = np.stack(values) if stacked else values[0]
    return ({"error": error} if error else {}), out


def whole_stage(cls: type, inputs: Inputs, emit: Emit) -> tuple[dict, dict]:
    """estimates/i (steps, 2): the filter stepped along scenario i's compass angles and measurements,
    its estimate read after each step; the first error ends the stage (naming scenario and step)."""
    out: dict[str, np.ndarray] = {}
    for i in range(inputs["whole.count"]):
        emit({"kind": "stage", "stage": "whole", "scenario": i})
        given = inputs.of(f"whole.{i}")
        compass, z = given["compass_angles"], given["measurements"]
        estimates, step = np.empty((len(z), 2)), 0
        try:
            noise = (given["sigma"], given["delta"], given["particles"].copy())
            filt = cls(inputs.world(f"whole.{i}"), *noise, run_streams(given["seed"]).filter)
            for step in range(1, len(z) + 1):
                filt.step(float(compass[step - 1]), float(z[step - 1]))
                estimates[step - 1] = answer_array("estimate", filt.estimate, (2,))  # a property of its own too
        except BaseException as error:
            when = " while being built" if step == 0 else f" at step {step}"
            exited = isinstance(error, (SystemExit, KeyboardInterrupt))
            said = describe_exit(error) if exited else f"raised {type(error).__name__}"
            text = f"{cls.__name__} {said}{when}{'' if exited else ': ' + _text(error)}{_where(error)}"
            text = "; ".join(line.strip() for line in (text + _past_limit(error)).splitlines())  # one table cell
            return {"error": {"kind": "exit" if exited else "error", "text": text}, "scenario": i, "step": step}, out
        out[f"estimates/{i}"] = estimates
    return {}, out


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
    defined = [c for c in vars(module).values() if isinstance(c, type) and c.__module__ == module.__name__]
    if class_name is None:
        students = [c for c in defined if issubclass(c, StudentFilter)]
        if len(students) == 1:
            return students[0], describe_class(students[0], shown)
        found = ", ".join(c.__name__ for c in students) or "none"
        return None, {"error": f"{shown}: name the class as {shown}:ClassName (StudentFilter classes: {found})"}
    cls = getattr(module, class_name, None)
    if not isinstance(cls, type) or cls not in defined:
        names = ", ".join(c.__name__ for c in defined) or "no classes"
        return None, {"error": f"{shown}: no class {class_name!r} of its own (it defines: {names})"}
    return cls, describe_class(cls, shown)


def describe_class(cls: type, shown: str) -> dict[str, Any]:
    """The class's names (its own and its `name`), or the one line why it cannot be graded: it is not a
    StudentFilter (naming its first bases)."""
    if not issubclass(cls, StudentFilter):
        bases = ", ".join(f"{b.__module__}.{b.__qualname__}" for b in cls.__mro__[1:-1][:3]) or "object"
        return {
            "error": f"{shown}: {cls.__name__} is not a StudentFilter (it subclasses {bases}); the exercise grades "
            "a subclass of mazelab.exercise.StudentFilter with your own predict, weigh, resample and estimate"
        }
    try:
        name = str(cls.name)
    except BaseException:
        name = cls.__name__
    return {"class": cls.__name__, "name": name[:80]}


def serve(request: Message, emit: Emit, filter_class: type | None = None) -> None:
    """Load the class (or take `filter_class`), then run the request's stages, sending each one's
    start and its answer; then "done"."""
    shown = request.meta.get("shown") or getattr(filter_class, "__name__", "")
    cls, loaded = (filter_class, describe_class(filter_class, shown)) if filter_class else load(request.meta)
    emit({"kind": "loaded", **loaded})
    if cls is not None and "error" not in loaded:
        inputs = Inputs({**request.meta["inputs"], **request.arrays})
        for stage in request.meta["stages"]:
            emit({"kind": "stage", "stage": stage})
            started = time.perf_counter()
            meta, arrays = whole_stage(cls, inputs, emit) if stage == "whole" else part_stage(cls, stage, inputs)
            _flush()
            emit({**meta, "kind": "result", "stage": stage, "seconds": time.perf_counter() - started}, arrays)
    emit({"kind": "done"})


def _flush() -> None:
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(BaseException):  # the student may have replaced or closed them
            stream.flush()


# -- the guard ---------------------------------------------------------------------------------------
def guard(folder: str) -> None:
    """Install the audit hook (docs/exercise.md, "Only the files run") for a submission in `folder`:
    the files under the kit, numpy, the standard library and `folder` may be compiled or unmarshalled,
    modules outside them and the submission's own files may not be imported."""
    import numpy
    import numpy.ma

    site = os.path.dirname(os.path.dirname(numpy.__file__))
    paths = sysconfig.get_paths()
    roots = (sys.path[0], f"{site}/numpy/", f"{site}/numpy.libs/", paths["stdlib"], paths["platstdlib"], folder)
    roots = tuple(r.rstrip("/") + "/" for r in roots)
    own = {p.stem for p in Path(folder).glob("*.py")}
    names = frozenset(sys.stdlib_module_names - {"ctypes", "_ctypes"} | {"numpy", "mazelab"} | own)
    paths = frozenset([*sys.path, folder])
    finders = (tuple(map(id, sys.meta_path)), tuple(map(id, sys.path_hooks)))
    sys.addaudithook(_hook_with(roots, names, paths, finders, collections.namedtuple.__code__))


def _hook_with(roots: tuple[str, ...], names: frozenset, paths: frozenset, finders: tuple, named: Any) -> Callable:
    """The audit hook; its one default holds all it reads, the real builtins bound once (a patched builtin
    or module changes nothing in it, and the default cannot be replaced: `object.__setattr__` on the hook
    is refused). `named` is namedtuple's code, which compiles a text of identifiers only (checked with the
    real `type` and `str`: the standard library makes namedtuples as it is imported)."""
    held = (roots, names, paths, finders, named, sys._getframe, open, type, str, bytes, tuple, map, id, all, range)

    def hook(event, args, held=held):
        roots, names, paths, finders, named, frame, read, type, str, bytes, tuple, map, id, all, range = held

        def namedtuple(caller):  # namedtuple's own code, run with the real builtins (its checks hold)
            real = caller.f_builtins.get("type") is type and caller.f_builtins.get("str") is str
            return caller.f_code is named and real

        def own(path, data, skip=0):  # the bytes of a file under the roots, reached without ".."
            if type(path) is not str or type(data) is not bytes or "/.." in path or not path.startswith(roots):
                return False
            with read(path, "rb") as file:
                return file.read()[skip:] == data

        if event == "compile" and not own(args[1], args[0]) and not namedtuple(frame(1)):
            raise PermissionError("a submission may not compile text (nor use dataclasses or namedtuple, which do)")
        if event in ("marshal.loads", "marshal.load"):
            for depth in range(1, 6):  # importlib's own reading of a .pyc under the roots
                try:
                    if own(frame(depth).f_locals.get("bytecode_path"), args[0], 16):
                        return
                except ValueError:  # no frame that deep
                    break
            raise PermissionError("a submission may not unmarshal code")
        if (
            event == "code.__new__"
            or event.startswith("ctypes.")
            or (event == "object.__setattr__" and args[0] is hook)
        ):
            raise PermissionError(f"a submission may not use {event}")
        if event == "import" and args[2] is not None:
            where = all(type(p) is str and p in paths for p in args[2])
            same = where and (tuple(map(id, args[3])), tuple(map(id, args[4]))) == finders
            if str.partition(args[0], ".")[0] not in names or not same:
                raise ImportError(f"{args[0]}: a submission imports only numpy, the standard library and its own files")

    return hook


def main(answer_fd: int) -> None:
    """The child process: read the request, set the process limit, guard, say hello, serve the request
    answering on the descriptor `answer_fd`, then end (the student's threads with it)."""
    faulthandler.enable(file=sys.stderr, all_threads=True)  # a crash in C names the student's line
    message = next(messages(sys.stdin.buffer))
    os.close(0)
    os.open(os.devnull, os.O_RDONLY)  # the student's code reads nothing there
    answers = os.fdopen(answer_fd, "wb", buffering=0)

    def emit(meta: dict[str, Any], arrays: dict[str, Any] | None = None) -> None:
        answers.write(encode(meta, arrays))

    processes = message.meta.get("processes")
    if processes:  # counted in the sandbox's own user namespace: its processes and threads only
        import resource

        resource.setrlimit(resource.RLIMIT_NPROC, (processes, processes))
    guard(str(Path(message.meta["file"]).parent))
    emit({"kind": "hello"})  # the limits and the guard hold: the student's code may run now
    serve(message, emit)
    _flush()
    os._exit(0)
