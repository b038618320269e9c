"""What stops a run: the user (Ctrl-C, SIGTERM, SIGHUP, through the lab's own handlers), or code that
is not the lab's calling sys.exit or raising KeyboardInterrupt. The lab's handlers raise the marked
exceptions below, so that a filter's own `sys.exit(0)` or `raise KeyboardInterrupt` can be told apart
from the user's stop and reported as the filter's error, not passed on as the program's exit."""

from __future__ import annotations

import contextlib
import os
import signal
import sys
import threading
from collections.abc import Callable, Iterable, Iterator
from typing import Any

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
def signal_handlers(signals: Iterable[int], handler: Any) -> Iterator[None]:
    """`handler` (a function, or signal.SIG_IGN) for each of `signals` while the block runs, the previous
    handlers put back after it; in a thread other than the main one (which cannot set handlers) nothing
    changes. The one place the lab's commands set and restore their stop handlers."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = {number: signal.signal(number, handler) for number in signals}
    try:
        yield
    finally:
        for number, old in previous.items():
            signal.signal(number, old)


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


def stray_threads() -> list[threading.Thread]:
    """Threads that would keep the process alive at its exit (not daemons, still running), but the main one."""
    return [t for t in threading.enumerate() if t.is_alive() and not t.daemon and t is not threading.main_thread()]


def exit_without_strays(code: int, warn: Callable[[str], None]) -> None:
    """End the process with `code` now if threads that are not the lab's own would keep it alive (a
    plug-in's forgotten thread): one warning line naming them, the output flushed, then os._exit;
    without such threads, return (the caller exits as usual)."""
    strays = stray_threads()
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
