"""What stops or breaks a run: the user (Ctrl-C, SIGTERM, SIGHUP, through the lab's own handlers), or
code that is not the lab's calling sys.exit, raising KeyboardInterrupt or failing. The lab's handlers
raise the marked exceptions below, so that a filter's own `sys.exit(0)` or `raise KeyboardInterrupt`
can be told apart from the user's stop and reported as the filter's error, not passed on as the
program's exit. The student's code failing during a run is reported by `student_code`, as a
`StudentCodeError` (see both)."""

from __future__ import annotations

import contextlib
import inspect
import os
import signal
import sys
import sysconfig
import threading
import traceback
import warnings
from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager
from pathlib import Path
from types import SimpleNamespace, TracebackType
from typing import Any

PACKAGE_DIR = Path(__file__).resolve().parent  # mazelab/: frames here are the lab's, not the student's
_LIBRARY_DIRS = tuple(
    Path(p).resolve() for p in {sysconfig.get_paths()[k] for k in ("stdlib", "platstdlib", "purelib", "platlib")}
)
STOP_SIGNALS = tuple(getattr(signal, name) for name in ("SIGINT", "SIGTERM", "SIGHUP") if hasattr(signal, name))


class StoppedBySignal(SystemExit):
    """SIGTERM or SIGHUP turned into an exit (code 128 + signal) by the lab's handler."""


class Interrupted(KeyboardInterrupt):
    """Ctrl-C (SIGINT), raised by the lab's handler (`mark_interrupts`)."""


_marking = False  # whether the lab's SIGINT handler is installed (else any KeyboardInterrupt may be the user's)


def _raise_interrupted(number: int, frame: Any) -> None:
    raise Interrupted


def mark_interrupts() -> Callable[[], None]:
    """Install the SIGINT handler that raises `Interrupted` (main thread only, and only over Python's
    default handler); returns the function that puts the previous one back."""
    global _marking
    if threading.current_thread() is not threading.main_thread():
        return lambda: None
    previous = signal.getsignal(signal.SIGINT)
    if previous is not signal.default_int_handler:
        return lambda: None
    signal.signal(signal.SIGINT, _raise_interrupted)
    _marking = True

    def restore() -> None:
        global _marking
        if signal.getsignal(signal.SIGINT) is _raise_interrupted:
            signal.signal(signal.SIGINT, previous)
        _marking = False

    return restore


@contextlib.contextmanager
def signal_handlers(signals: Iterable[int], handler: Any) -> Iterator[dict[int, Any]]:
    """`handler` (a function, or signal.SIG_IGN) for each of `signals` while the block runs, the previous
    handlers (what the block gets) put back after it; in a thread other than the main one (which cannot
    set handlers) nothing changes. The one place the lab sets and restores its stop handlers."""
    if threading.current_thread() is not threading.main_thread():
        yield {}
        return
    previous = {number: signal.signal(number, handler) for number in signals}
    try:
        yield previous
    finally:
        for number, old in previous.items():
            signal.signal(number, signal.SIG_DFL if old is None else old)  # None: set outside Python


def is_users_stop(error: BaseException) -> bool:
    """Whether a SystemExit or KeyboardInterrupt is the user's stop (a signal the lab turned into it),
    rather than code of a filter's calling sys.exit or raising KeyboardInterrupt itself."""
    if isinstance(error, (StoppedBySignal, Interrupted)):
        return True
    if isinstance(error, KeyboardInterrupt):
        return not _marking or type(error).__module__.startswith("mazelab")  # e.g. a study's StudyStopped
    return False


def describe_exit(error: BaseException) -> str:
    """What a filter's code did, in a few words: 'called sys.exit(3)', 'raised KeyboardInterrupt'."""
    if isinstance(error, SystemExit):
        return f"called sys.exit({error.code!r})" if error.code is not None else "called sys.exit()"
    return f"raised {type(error).__name__}"


def exit_without_strays(code: int, warn: Callable[[str], None]) -> None:
    """End the process with `code` now if threads that are not the lab's own would keep it alive (a
    plug-in's forgotten thread): one warning line naming them, the output flushed, then os._exit;
    without such threads, return (the caller exits as usual)."""
    strays = [t for t in threading.enumerate() if t.is_alive() and not t.daemon and t is not threading.main_thread()]
    if not strays:
        return
    names = ", ".join(t.name for t in strays[:3]) + (", ..." if len(strays) > 3 else "")
    warn(
        f"warning: {len(strays)} thread(s) that the lab did not start are still running ({names}); exiting without them"
    )
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(Exception):
            stream.flush()
    os._exit(code)


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


@contextmanager
def student_code(filter_class: type) -> Iterator[SimpleNamespace]:
    """Around the calls of a user's filter: an Exception inside (or its own sys.exit or KeyboardInterrupt)
    becomes a StudentCodeError naming the step (set `.number` on what this yields: 0 while the filter is
    built) and the user's frames, from the error; the working folder it changes is put back; a shipped
    filter's errors and the user's own stop pass as they are."""
    step = SimpleNamespace(number=0)
    try:  # the filter is the user's when its file lies outside the lab (not a shipped one)
        students = not is_lab_file(inspect.getfile(filter_class))
    except (TypeError, OSError):  # defined in a notebook cell or the interpreter: the user's
        students = True
    try:
        with working_folder_kept(filter_class.name) if students else contextlib.nullcontext():
            yield step
    except BaseException as error:  # the student's own sys.exit becomes their error too
        if not students or isinstance(error, StudentCodeError) or is_users_stop(error):
            raise
        when = "while being built" if step.number == 0 else f"at step {step.number}"
        frames = [  # the student's frames, one line each: file, line, function and code
            f"  {f.filename}, line {f.lineno}, in {f.name}" + (f": {f.line.strip()}" if f.line else "")
            for f in student_frames(error.__traceback__)
        ]
        if isinstance(error, (SystemExit, KeyboardInterrupt)):
            what = f"{filter_class.name} {describe_exit(error)} {when} (a filter must not end the program)"
            raise StudentCodeError("\n".join([what, *frames])) from None
        what = f"{filter_class.name} raised {type(error).__name__} {when}: {error}"
        raise StudentCodeError("\n".join([what, *frames])) from error


@contextmanager
def working_folder_kept(owner: str) -> Iterator[None]:
    """Put back the working folder if `owner`'s code changes it (outputs are written where the user
    asked), with a one-line warning."""
    before = os.getcwd()
    try:
        yield
    finally:
        after = None  # the folder it moved to may have been removed
        with contextlib.suppress(OSError):
            after = os.getcwd()
        if after != before:
            os.chdir(before)
            warnings.warn(f"{owner} changed the working folder to {after}; it was put back to {before}", stacklevel=3)


def student_line(tb: TracebackType | None, error: BaseException) -> str:
    """' (file.py, line 12)' for the innermost of the student's frames, or '' (a SyntaxError names its line)."""
    if isinstance(error, SyntaxError):
        return ""
    frames = student_frames(tb)
    return f" ({Path(frames[-1].filename).name}, line {frames[-1].lineno})" if frames else ""
