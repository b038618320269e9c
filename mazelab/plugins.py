"""A student's own filter as a plug-in: `path/to/my_filter.py:MyFilter` wherever a filter name goes.

`load_plugin(spec)` imports the file under a module name of its own (one per file, so two files that
both define `MyFilter` never clash) and returns the class, refusing in one line that names the file,
the class and what is missing. `StudentCodeError` is what a run raises when the student's code fails:
the student's own frames (their file and line, none of the lab's) and the step at which it happened.
"""

from __future__ import annotations

import hashlib
import importlib.util
import inspect
import sys
import sysconfig
import traceback
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from types import ModuleType, TracebackType

from mazelab.contract import missing_parts

PACKAGE_DIR = Path(__file__).resolve().parent  # mazelab/: frames here are the lab's, not the student's
_LIBRARY_DIRS = tuple(
    Path(p).resolve() for p in {sysconfig.get_paths()[k] for k in ("stdlib", "platstdlib", "purelib", "platlib")}
)
_loaded: dict[tuple[str, int, str], type] = {}  # (file, modification time, class) -> the class
_by_name: dict[str, type] = {}  # the loaded plug-ins by their `name`, for the names results carry


def is_plugin_spec(text: str) -> bool:
    """Whether `text` names a file's class (`file.py:Class`) or a file (`file.py`), not a shipped filter."""
    path = text.rsplit(":", 1)[0] if ":" in text and not text.endswith(".py") else text
    return path.strip().endswith(".py")


def split_spec(spec: str) -> tuple[Path, str | None]:
    """`file.py:Class` -> (Path("file.py"), "Class"); `file.py` -> (Path("file.py"), None)."""
    spec = spec.strip()
    if spec.endswith(".py"):
        return Path(spec), None
    path, _, class_name = spec.rpartition(":")
    return Path(path), class_name.strip() or None


def canonical_spec(spec: str) -> str:
    """The spec with the file's absolute path and the class named: what a study hands its worker
    processes (they import the file again; the class object itself is never sent)."""
    cls = load_plugin(spec)
    return f"{Path(inspect.getfile(cls)).resolve()}:{cls.__name__}"


def load_plugin(spec: str) -> type:
    """The class of a plug-in spec `path/to/file.py:ClassName` (or `file.py` holding one filter class).

    Raises
    ------
    ValueError
        One line naming the file, the class and what is missing: no such file, an import that fails,
        no such class, or a class that misses part of the filter contract (mazelab.contract).
    """
    path, class_name = split_spec(spec)
    shown = f"{path}:{class_name}" if class_name else str(path)
    if not path.is_file():
        raise ValueError(f"{shown}: no such file {path}" + ("" if path.exists() else " (check the path)"))
    resolved = path.resolve()
    module = _import_file(resolved, path)
    if class_name is None:
        classes = [c for c in vars(module).values() if _defined_filter(c, module)]
        if len(classes) != 1:
            found = ", ".join(c.__name__ for c in classes) or "none"
            raise ValueError(f"{path}: name the filter class as {path}:ClassName (filter classes found: {found})")
        class_name = classes[0].__name__
        shown = f"{path}:{class_name}"
    key = (str(resolved), resolved.stat().st_mtime_ns, class_name)
    if key in _loaded:
        return _loaded[key]
    cls = getattr(module, class_name, None)
    if not isinstance(cls, type):
        defined = ", ".join(
            n for n, c in vars(module).items() if isinstance(c, type) and c.__module__ == module.__name__
        )
        raise ValueError(f"{shown}: {path} has no class {class_name!r} (it defines: {defined or 'no classes'})")
    missing = missing_parts(cls)
    if missing:
        raise ValueError(
            f"{shown}: class {class_name} does not meet the filter contract: it has no {', '.join(missing)}"
        )
    _loaded[key] = cls
    _by_name[cls.name] = cls
    return cls


def loaded_plugin(name: str) -> type | None:
    """A plug-in already loaded in this process, by its `name` (what results and tables carry)."""
    return _by_name.get(name)


def _defined_filter(value: object, module: ModuleType) -> bool:
    return isinstance(value, type) and value.__module__ == module.__name__ and not missing_parts(value)


def _import_file(resolved: Path, shown: Path) -> ModuleType:
    """Import the file as module `mazelab_plugin_<hash of its path>_<mtime>`: unique per file (and per
    version of it, so an edited file is read again), registered in sys.modules (pickle, dataclasses)."""
    stamp = resolved.stat().st_mtime_ns
    digest = hashlib.sha1(str(resolved).encode()).hexdigest()[:12]
    module_name = f"mazelab_plugin_{digest}_{stamp}"
    if module_name in sys.modules:
        return sys.modules[module_name]
    spec = importlib.util.spec_from_file_location(module_name, resolved)
    if spec is None or spec.loader is None:
        raise ValueError(f"{shown}: cannot be imported as a Python module")
    module = importlib.util.module_from_spec(spec)
    sys.modules[module_name] = module
    try:
        spec.loader.exec_module(module)
    except Exception as error:
        del sys.modules[module_name]
        line = _student_line(error.__traceback__, error)
        raise ValueError(f"{shown} does not import: {type(error).__name__}: {error}{line}") from None
    return module


def _student_line(tb: TracebackType | None, error: BaseException) -> str:
    """' (file.py, line 12)' for the innermost of the student's frames, or '' (a SyntaxError names its line)."""
    if isinstance(error, SyntaxError):
        return ""
    frames = student_frames(tb)
    return f" ({Path(frames[-1].filename).name}, line {frames[-1].lineno})" if frames else ""


# -- the student's code failing during a run ----------------------------------------------------------
class StudentCodeError(RuntimeError):
    """The student's filter raised during a run: the message names the filter, the step (0: while it was
    built), the error, and the student's own frames (file, line, code); the original is its __cause__."""


def is_lab_file(filename: str) -> bool:
    """Whether a frame's file is the lab's (mazelab/) or Python's or an installed library's."""
    path = Path(filename).resolve()
    return path.is_relative_to(PACKAGE_DIR) or any(path.is_relative_to(d) for d in _LIBRARY_DIRS)


def student_frames(tb: TracebackType | None) -> list[traceback.FrameSummary]:
    """The frames of a traceback outside the lab, Python and installed libraries: the student's."""
    return [frame for frame in traceback.extract_tb(tb) if not is_lab_file(frame.filename)]


def is_student_class(filter_class: type) -> bool:
    """Whether a filter class is the user's (its file lies outside the lab), not a shipped one."""
    try:
        return not is_lab_file(inspect.getfile(filter_class))
    except (TypeError, OSError):  # defined in a notebook cell or the interpreter: the user's
        return True


def describe_student_error(error: BaseException, filter_name: str, step: int) -> str:
    """`MyFilter raised ValueError at step 5: ...` and the student's frames, one line each."""
    when = "while being built" if step == 0 else f"at step {step}"
    lines = [f"{filter_name} raised {type(error).__name__} {when}: {error}"]
    for frame in student_frames(error.__traceback__):
        code = f": {frame.line.strip()}" if frame.line else ""
        lines.append(f"  {frame.filename}, line {frame.lineno}, in {frame.name}{code}")
    return "\n".join(lines)


class _Step:
    """The step a run is at (0 while the filter is built), for `student_code`."""

    number = 0


def raise_for_student(error: Exception, filter_class: type, step: int) -> None:
    """Raise `error` as it is for a shipped filter; for a user's, a StudentCodeError naming the step and
    the user's frames, from `error`."""
    if not is_student_class(filter_class) or isinstance(error, StudentCodeError):
        raise error
    raise StudentCodeError(describe_student_error(error, filter_class.name, step)) from error


@contextmanager
def student_code(filter_class: type) -> Iterator[_Step]:
    """Around the calls of a user's filter: an Exception inside becomes a StudentCodeError naming the
    step (set `.number` on what this yields) and the user's frames; a shipped filter's errors pass as they are."""
    step = _Step()
    try:
        yield step
    except Exception as error:
        raise_for_student(error, filter_class, step.number)


__all__ = [
    "StudentCodeError",
    "canonical_spec",
    "describe_student_error",
    "is_plugin_spec",
    "is_student_class",
    "load_plugin",
    "loaded_plugin",
    "raise_for_student",
    "split_spec",
    "student_code",
    "student_frames",
]
