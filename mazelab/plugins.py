"""A student's own filter as a plug-in: `path/to/my_filter.py:MyFilter` wherever a filter name goes.

`load_plugin(spec)` imports the file under a module name of its own (one per file, so two files that
both define `MyFilter` never clash), with the file's folder importable while it loads (as `python
my_filter.py` has it), and returns the class, refusing in one line that names the file, the class and
what is missing. `plugin_reference` is how a saved run names it: the spec as written, the file's
sha256 and the class (a scenario never imports it: the user names the plug-in to replay it).
`PluginCode` is a plug-in as a study carries it: the file's bytes and their sha256, read once when the
study is planned, so that a worker process or a Dask worker on another machine runs the very code the
study was planned with (its own copy, by the hash, where the file is not there; a plug-in that imports
modules beside it needs them on the worker too: only its own file travels).
`StudentCodeError` is what a run raises when the student's code fails: the student's own frames (their
file and line, none of the lab's) and the step at which it happened; a filter that calls sys.exit,
raises KeyboardInterrupt or changes the working folder is reported the same way (mazelab.stops).
"""

from __future__ import annotations

import hashlib
import importlib.util
import inspect
import os
import sys
import sysconfig
import tempfile
import traceback
import warnings
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from types import ModuleType, TracebackType

from mazelab.atomic import write_bytes_atomically
from mazelab.contract import missing_parts
from mazelab.declaration import options_of
from mazelab.stops import describe_exit, is_users_stop

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


@dataclass(frozen=True)
class PluginReference:
    """How a saved run names a plug-in: the spec as the user wrote it, the file's sha256 and the class.
    A scenario stores it and never imports it; a replay needs the user to name the plug-in again."""

    spec: str
    sha256: str
    class_name: str
    path: str  # the file's absolute path when it was loaded (for the worker processes of a study)

    @property
    def canonical(self) -> str:
        """`/absolute/path/file.py:Class`: what worker processes import again."""
        return f"{self.path}:{self.class_name}"

    def as_json(self) -> dict[str, str]:
        """What a scenario stores (the absolute path is the machine's, so it is left out)."""
        return {"spec": self.spec, "sha256": self.sha256, "class": self.class_name}


def file_sha256(path: str | Path) -> str:
    """The sha256 of a file's bytes, hex (what `sha256sum FILE` prints)."""
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def plugin_reference(spec: str, filter_class: type) -> PluginReference:
    """The reference of a plug-in loaded from `spec` (its class already loaded)."""
    path = Path(inspect.getfile(filter_class)).resolve()
    written = split_spec(spec)[0]
    return PluginReference(f"{written}:{filter_class.__name__}", file_sha256(path), filter_class.__name__, str(path))


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
    defined = ", ".join(n for n, c in vars(module).items() if isinstance(c, type) and c.__module__ == module.__name__)
    if not isinstance(cls, type):
        raise ValueError(f"{shown}: {path} has no class {class_name!r} (it defines: {defined or 'no classes'})")
    if cls.__module__ != module.__name__ and is_lab_class(cls):
        raise ValueError(
            f"{shown}: {class_name} is the lab's own class, which {path.name} imports; name the class you wrote "
            f"(it defines: {defined or 'no classes'})"
        )
    missing = missing_parts(cls)
    if missing:
        raise ValueError(
            f"{shown}: class {class_name} does not meet the filter contract: it has no {', '.join(missing)}"
        )
    check_declared_defaults(cls, shown)
    _loaded[key] = cls
    _by_name[cls.name] = cls
    return cls


def check_declared_defaults(cls: type, shown: str) -> None:
    """A constructor that spells an option's default itself must spell the declared one (else the run
    would use one value and the scenario store another); one line naming the option."""
    try:
        parameters = inspect.signature(cls.__init__).parameters
        declared = options_of(cls)
    except (TypeError, ValueError) as error:
        raise ValueError(f"{shown}: {error}") from None
    for name, parameter in parameters.items():
        spelled = name in declared and parameter.default is not inspect.Parameter.empty
        if spelled and parameter.default != declared[name].default:
            raise ValueError(
                f"{shown}: the constructor's default {name}={parameter.default!r} is not the declared "
                f"default {declared[name].default!r}: take the default from the declaration (options)"
            )


def is_lab_class(cls: type) -> bool:
    """Whether a class is the lab's own (defined in mazelab/ or a face of the repo), not the student's."""
    module = getattr(cls, "__module__", "") or ""
    return module.split(".")[0] in ("mazelab", "particle_filter", "draw")


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
    folder = str(resolved.parent)
    added = folder not in sys.path
    if added:
        sys.path.insert(0, folder)  # its helper modules import, as with `python file.py`
    try:
        with working_folder_kept(shown.name):
            spec.loader.exec_module(module)
    except (SystemExit, KeyboardInterrupt) as error:
        del sys.modules[module_name]
        if is_users_stop(error):
            raise
        line = _student_line(error.__traceback__, error)
        raise ValueError(f"{shown} does not import: it {describe_exit(error)} while being imported{line}") from None
    except Exception as error:
        del sys.modules[module_name]
        line = _student_line(error.__traceback__, error)
        raise ValueError(f"{shown} does not import: {type(error).__name__}: {error}{line}") from None
    finally:
        if added and folder in sys.path:
            sys.path.remove(folder)
    return module


def _student_line(tb: TracebackType | None, error: BaseException) -> str:
    """' (file.py, line 12)' for the innermost of the student's frames, or '' (a SyntaxError names its line)."""
    if isinstance(error, SyntaxError):
        return ""
    frames = student_frames(tb)
    return f" ({Path(frames[-1].filename).name}, line {frames[-1].lineno})" if frames else ""


# -- a plug-in's code, sent with a study's runs ------------------------------------------------------
CODE_FOLDER = "mazelab-plugins"  # under the system's temporary folder: the shipped plug-ins, by sha256


@dataclass(frozen=True)
class PluginCode:
    """One plug-in of a study: the spec the runs name it by (`/absolute/path/file.py:Class`), the
    file's bytes and their sha256."""

    spec: str
    source: bytes
    sha256: str

    @classmethod
    def of(cls, spec: str) -> PluginCode:
        """The code of a plug-in spec with an absolute path (runs.filter_key), read now."""
        source = split_spec(spec)[0].read_bytes()
        return cls(spec, source, hashlib.sha256(source).hexdigest())

    @property
    def path(self) -> Path:
        return split_spec(self.spec)[0]

    @property
    def class_name(self) -> str:
        return split_spec(self.spec)[1] or ""

    def spec_here(self) -> str:
        """The spec that imports this code in this process: the file itself when it holds these bytes,
        else a copy written beside the other shipped plug-ins. Raises ValueError (one line) when the
        bytes do not have the recorded sha256."""
        if hashlib.sha256(self.source).hexdigest() != self.sha256:
            raise ValueError(f"{self.path.name}: the plug-in's code arrived damaged (its sha256 differs)")
        try:
            if file_sha256(self.path) == self.sha256:
                return self.spec
        except OSError:  # not on this machine
            pass
        copy = Path(tempfile.gettempdir()) / CODE_FOLDER / self.sha256 / self.path.name
        if not copy.is_file():
            copy.parent.mkdir(parents=True, exist_ok=True)
            write_bytes_atomically(copy, self.source)
        return f"{copy}:{self.class_name}"


def plugin_codes(filters: Sequence[object]) -> tuple[PluginCode, ...]:
    """The code of every plug-in among a study's filters (names and specs; classes from Python are
    sent as they are)."""
    return tuple(PluginCode.of(f) for f in filters if isinstance(f, str) and is_plugin_spec(f))


def filters_here(filters: Sequence[str], codes: Sequence[PluginCode]) -> tuple[str, ...]:
    """A run's filter names with each plug-in's spec replaced by the one that imports its shipped code
    in this process (`PluginCode.spec_here`)."""
    here = {code.spec: code.spec_here() for code in codes}
    return tuple(here.get(name, name) for name in filters)


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


def _frame_lines(tb: TracebackType | None) -> list[str]:
    """The student's frames of a traceback, one line each: file, line, function and code."""
    lines = []
    for frame in student_frames(tb):
        code = f": {frame.line.strip()}" if frame.line else ""
        lines.append(f"  {frame.filename}, line {frame.lineno}, in {frame.name}{code}")
    return lines


class _Step:
    """The step a run is at (0 while the filter is built), for `student_code`."""

    number = 0


def raise_for_student(error: BaseException, filter_class: type, step: int) -> None:
    """Raise `error` as it is for a shipped filter; for a user's, a StudentCodeError naming the step and
    the user's frames, from `error` (a sys.exit or KeyboardInterrupt of its own too; the user's stop
    passes as it is)."""
    if not is_student_class(filter_class) or isinstance(error, StudentCodeError):
        raise error
    when = "while being built" if step == 0 else f"at step {step}"
    frames = _frame_lines(error.__traceback__)
    if isinstance(error, (SystemExit, KeyboardInterrupt)):
        if is_users_stop(error):
            raise error
        what = f"{filter_class.name} {describe_exit(error)} {when} (a filter must not end the program)"
        raise StudentCodeError("\n".join([what, *frames])) from None
    what = f"{filter_class.name} raised {type(error).__name__} {when}: {error}"
    raise StudentCodeError("\n".join([what, *frames])) from error


@contextmanager
def student_code(filter_class: type) -> Iterator[_Step]:
    """Around the calls of a user's filter: an Exception inside (or its own sys.exit) becomes a
    StudentCodeError naming the step (set `.number` on what this yields) and the user's frames; the
    working folder it changes is put back; a shipped filter's errors pass as they are."""
    step = _Step()
    try:
        with working_folder_kept(filter_class.name if is_student_class(filter_class) else None):
            yield step
    except BaseException as error:  # the student's own sys.exit becomes their error too
        raise_for_student(error, filter_class, step.number)


@contextmanager
def working_folder_kept(owner: str | None) -> Iterator[None]:
    """Put back the working folder if `owner`'s code changes it (outputs are written where the user
    asked), with a one-line warning; None: nothing to watch (a shipped filter)."""
    if owner is None:
        yield
        return
    before = os.getcwd()
    try:
        yield
    finally:
        after = _cwd_or_none()
        if after != before:
            os.chdir(before)
            warnings.warn(f"{owner} changed the working folder to {after}; it was put back to {before}", stacklevel=3)


def _cwd_or_none() -> str | None:
    try:
        return os.getcwd()
    except OSError:  # the folder it moved to was removed
        return None


__all__ = [
    "PluginCode",
    "PluginReference",
    "StudentCodeError",
    "check_declared_defaults",
    "file_sha256",
    "filters_here",
    "is_lab_class",
    "is_plugin_spec",
    "is_student_class",
    "load_plugin",
    "loaded_plugin",
    "plugin_codes",
    "plugin_reference",
    "raise_for_student",
    "split_spec",
    "student_code",
    "student_frames",
    "working_folder_kept",
]
