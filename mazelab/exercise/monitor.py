"""Who calls the lab's reference implementation: a profile hook in the student's process that records
each function of the reference modules (the model, the resampling schemes, the weights' helpers, the
shipped filters and their cloud, the grid filter, the simulation) entered on behalf of the student.

Which caller counts: walking out from the reference function past reference and library frames
(numpy, Python's own), the first other frame decides. A frame of the student's files: recorded. The
lab's own wiring (StudentFilter's step, `self.ess`, the maze's methods, this harness): not recorded,
since that is the exercise's skeleton. No such frame at all (a thread or a callback of the student's):
recorded. A function object copied, rebuilt from its code or reloaded still runs the reference file's
code, so it is seen; code copied out of the lab's files as text is the student's own, as far as this
can tell.

The hook also covers threads started later, and `sys.setprofile`/`threading.setprofile` are guarded:
replacing the hook is refused and recorded, and a stage that ends without the hook in place is
reported as the monitor removed (`Monitor.intact`).
"""

from __future__ import annotations

import importlib
import importlib.util
import sys
import sysconfig
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from types import FrameType
from typing import Any

PACKAGE_DIR = Path(__file__).resolve().parent.parent  # mazelab/
REFERENCE_MODULES = (
    "mazelab.model",
    "mazelab.resampling",
    "mazelab.weights",
    "mazelab.cloud",
    "mazelab.filters",
    "mazelab.grid_filter",
    "mazelab.kalman",
    "mazelab.regularisation",
    "mazelab.recovery",
    "mazelab.modes",
    "mazelab.robot",
    "mazelab.collect",
    "mazelab.simulation",
    "mazelab.lab",
)
REFERENCE_FOLDERS = ("experiments",)  # every module of mazelab.experiments (the studies run filters)
REFERENCE_FACES = ("particle_filter.py", "draw.py")  # the repository's faces, beside mazelab/
MAX_NAMES = 20  # names kept per stage
_LIBRARY_DIRS = tuple(
    str(Path(p).resolve()) for p in {sysconfig.get_paths()[k] for k in ("stdlib", "platstdlib", "purelib", "platlib")}
)


def reference_files() -> dict[str, str]:
    """The reference implementation's files (absolute paths) and the module name each stands for."""
    files = {}
    for name in REFERENCE_MODULES:
        spec = importlib.util.find_spec(name)
        if spec is not None and spec.origin:
            files[str(Path(spec.origin).resolve())] = name
    for folder in REFERENCE_FOLDERS:
        for path in sorted((PACKAGE_DIR / folder).glob("*.py")):
            files[str(path.resolve())] = f"mazelab.{folder}.{path.stem}"
    for face in REFERENCE_FACES:
        path = PACKAGE_DIR.parent / face
        if path.is_file():
            files[str(path.resolve())] = path.stem
    return files


def preload_reference() -> None:
    """Import the reference modules now, before the student's code runs: their module bodies then
    never run on the student's behalf (that would read as a call)."""
    for name in REFERENCE_MODULES:
        importlib.import_module(name)


class Monitor:
    """The profile hook and what it saw, per stage ("import", "predict", ..., "whole")."""

    def __init__(self) -> None:
        self.files = reference_files()
        self.stage = "import"
        self.calls: dict[str, list[str]] = {}
        self.refused: dict[str, int] = {}
        self._kinds: dict[str, str] = {}
        self._modules: dict[str, str] = {}
        self._real_setprofile = sys.setprofile
        self._real_thread_setprofile = threading.setprofile
        self.hook = self._make_hook()

    # -- what a frame's file is -----------------------------------------------------------------
    def kind(self, filename: str) -> str:
        """'reference', 'library' (Python's, an installed package's, frozen), 'lab' or 'student'."""
        known = self._kinds.get(filename)
        if known is not None:
            return known
        if filename.startswith("<frozen "):
            kind = "library"
        elif filename.startswith("<"):
            kind = "student"  # exec'd text, a notebook cell
        else:
            path = str(Path(filename).resolve())
            if path in self.files:
                kind = "reference"
                self._modules[filename] = self.files[path]
            elif path.startswith(str(PACKAGE_DIR) + "/"):
                kind = "lab"
            elif path.startswith(_LIBRARY_DIRS):
                kind = "library"
            else:
                kind = "student"
        self._kinds[filename] = kind
        return kind

    def on_behalf_of_student(self, frame: FrameType | None) -> bool:
        """Whether the first frame outside the reference and library code, walking out from `frame`,
        is the student's (or there is none)."""
        while frame is not None:
            kind = self.kind(frame.f_code.co_filename)
            if kind == "reference" and frame.f_code.co_name == "<module>":
                return False  # a reference module being imported (its own top-level code)
            if kind == "student":
                return True
            if kind == "lab":
                return False
            frame = frame.f_back
        return True

    def _make_hook(self) -> Any:
        kinds, classify, modules = self._kinds, self.kind, self._modules

        def hook(frame: FrameType, event: str, arg: Any) -> None:
            if event != "call":
                return
            code = frame.f_code
            if (kinds.get(code.co_filename) or classify(code.co_filename)) != "reference" or code.co_name == "<module>":
                return
            if self.on_behalf_of_student(frame.f_back):
                self.record(f"{modules[code.co_filename]}.{getattr(code, 'co_qualname', code.co_name)}")

        return hook

    def record(self, name: str) -> None:
        names = self.calls.setdefault(self.stage, [])
        if name not in names and len(names) < MAX_NAMES:
            names.append(name)

    # -- installing and guarding ---------------------------------------------------------------
    def install(self) -> None:
        """The hook on this thread and every thread started later; the setters guarded."""
        self._real_setprofile(self.hook)
        self._real_thread_setprofile(self.hook)
        sys.setprofile = self._guarded_setprofile
        threading.setprofile = self._guarded_thread_setprofile

    def _guarded_setprofile(self, function: Any) -> None:
        if function is self.hook:  # threading's bootstrap installing it on a new thread
            self._real_setprofile(function)
            return
        self.refused[self.stage] = self.refused.get(self.stage, 0) + 1
        raise PermissionError("the grader watches this process's calls: sys.setprofile is not for the filter")

    def _guarded_thread_setprofile(self, function: Any) -> None:
        self.refused[self.stage] = self.refused.get(self.stage, 0) + 1
        raise PermissionError("the grader watches this process's calls: threading.setprofile is not for the filter")

    def uninstall(self, previous: Any = None, previous_threads: Any = None) -> None:
        """The setters as they were, and `previous` as the profile function (this and new threads)."""
        sys.setprofile, threading.setprofile = self._real_setprofile, self._real_thread_setprofile
        self._real_setprofile(previous)
        self._real_thread_setprofile(previous_threads)

    @contextmanager
    def installed(self) -> Iterator[Monitor]:
        """Installed for a `with` block, then everything as it was (a check in the student's own
        process: the notebook's)."""
        previous, previous_threads = sys.getprofile(), getattr(threading, "_profile_hook", None)
        self.install()
        try:
            yield self
        finally:
            self.uninstall(previous, previous_threads)

    @property
    def intact(self) -> bool:
        """Whether the hook is still this thread's profile function."""
        return sys.getprofile() is self.hook

    @contextmanager
    def watching(self, stage: str) -> Iterator[None]:
        """Attribute what is seen meanwhile to `stage`; put the hook back if it was removed."""
        self.stage = stage
        try:
            yield
        finally:
            if not self.intact:
                self.refused[stage] = self.refused.get(stage, 0) + 1
                self._real_setprofile(self.hook)

    def seen(self, stage: str) -> dict[str, Any]:
        """What a stage's result reports: the reference functions called, and whether the monitor
        was tampered with."""
        return {"reference_calls": list(self.calls.get(stage, [])), "monitor_refused": self.refused.get(stage, 0)}


__all__ = ["REFERENCE_MODULES", "Monitor", "preload_reference", "reference_files"]
