"""The Rerun processes this program starts (native viewer, web viewer), on 127.0.0.1 only.

A process that belongs to this run (the web viewer's server) ends with it: on Ctrl-C, and on SIGTERM
or SIGHUP (a closed terminal, `timeout`, a stopped notebook kernel), which stop it and end the program
through its `finally` clauses (as Ctrl-C does, so a recording keeps the steps done). A detached
native viewer outlives the program on purpose.
"""

from __future__ import annotations

import atexit
import contextlib
import importlib.util
import os
import shutil
import signal
import socket
import subprocess
import threading
import time
import urllib.parse
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from mazelab.stops import STOP_SIGNALS, StoppedBySignal, signal_handlers

VIEWER_PORT = 9876  # the native viewer's gRPC port, rerun's default: later runs reuse its window

_holders: set[object] = set()  # while any: SIGTERM/SIGHUP handled by us; the processes among them end with us
_handlers = contextlib.ExitStack()  # ours, while installed (stops.signal_handlers)
_previous_handlers: dict[int, Any] = {}  # the handlers before ours


def viewer_executable() -> str:
    """The `rerun` viewer shipped in the rerun-sdk wheel, found without PATH (an unactivated venv works)."""
    spec = importlib.util.find_spec("rerun_cli")
    if spec is not None and spec.origin is not None:
        binary = Path(spec.origin).with_name("rerun.exe" if os.name == "nt" else "rerun")
        if binary.exists():
            return str(binary)
    found = shutil.which("rerun")
    if found is None:
        raise RuntimeError("the Rerun viewer (shipped with rerun-sdk) was not found; reinstall rerun-sdk")
    return found


def rerun_environment() -> dict[str, str]:
    """The environment of the Rerun processes this program starts: ours plus CI, the variable that
    makes Rerun's viewer and server turn their usage analytics off (its only other switch is a
    config file, `rerun analytics disable`). Our own environment is left as it is."""
    return {**os.environ, "CI": os.environ.get("CI", "1")}


def start_rerun(
    arguments: list[str], ports: Sequence[int], *, detached: bool, settle: float = 0.0, timeout: float = 15.0
) -> Any:
    """Start the `rerun` binary with `arguments` and wait until it listens on every port of `ports`
    (127.0.0.1) and is still running `settle` seconds later (a viewer serves before it opens its
    window); a process that exits or stays silent raises RuntimeError at once, not after minutes."""
    process = subprocess.Popen(
        [viewer_executable(), *arguments],
        env=rerun_environment(),
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        start_new_session=detached,  # a detached viewer outlives this program (and its Ctrl-C)
    )
    if not detached:
        hold_stop_signals(process)  # it ends with this program
    deadline = time.monotonic() + timeout
    while process.poll() is None and time.monotonic() <= deadline:
        if all(listening(port) for port in ports):
            time.sleep(settle)
            if process.poll() is None:
                return process
        time.sleep(0.05)
    stop_process(process)
    raise RuntimeError(f"the Rerun viewer did not start (exit code {process.returncode})")


def native_viewer() -> str:
    """The gRPC address of a native viewer on 127.0.0.1:VIEWER_PORT: the one already running there
    (as rerun's own spawn does, runs share its window), else a new detached one."""
    if not listening(VIEWER_PORT):
        start_rerun(
            ["--bind", "127.0.0.1", "--port", str(VIEWER_PORT), "--expect-data-soon"],
            [VIEWER_PORT],
            detached=True,
            settle=1.0,
        )
    return f"rerun+http://127.0.0.1:{VIEWER_PORT}/proxy"


def stop_process(process: Any) -> None:
    """End a process we started: politely, then for sure."""
    if process.poll() is None:
        process.terminate()
        try:
            process.wait(timeout=5)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait()
    release_stop_signals(process)


def hold_stop_signals(holder: object) -> None:
    """While `holder` (a child process, which then ends with this program, or an open recording) is held,
    SIGTERM and SIGHUP end this program as the module docstring says; Ctrl-C is handled where it waits,
    a signal ignored (nohup) stays so."""
    _holders.add(holder)
    if not _previous_handlers and threading.current_thread() is threading.main_thread():
        ours = [n for n in STOP_SIGNALS if n != signal.SIGINT and signal.getsignal(n) != signal.SIG_IGN]
        _previous_handlers.update(_handlers.enter_context(signal_handlers(ours, _stop_children_then_go_on)))


def release_stop_signals(holder: object) -> None:
    """`holder` is done; with none left, SIGTERM and SIGHUP do what they did before we set ours."""
    _holders.discard(holder)
    if not _holders and threading.current_thread() is threading.main_thread():
        _handlers.close()
        _previous_handlers.clear()


def _stop_children_then_go_on(number: int, frame: Any) -> None:
    """SIGTERM/SIGHUP: with no handler of its own before us, the program exits (code 128 + signal)
    through its `finally` clauses, which save the recording (an exit hook stops any child left);
    else the previous handler runs. Our children are sent SIGTERM first in either case."""
    for process in [holder for holder in _holders if isinstance(holder, subprocess.Popen)]:
        with contextlib.suppress(OSError):
            os.kill(process.pid, signal.SIGTERM)  # not Popen's methods: the interrupted code may hold its lock
    previous = _previous_handlers.get(number)
    if not callable(previous):
        raise StoppedBySignal(128 + number)
    previous(number, frame)


@atexit.register
def _stop_children_at_exit() -> None:
    """No child of this run outlives it."""
    for process in [holder for holder in _holders if isinstance(holder, subprocess.Popen)]:
        stop_process(process)


class WebServer:
    """The web viewer and its gRPC proxy, served by the `rerun` binary on 127.0.0.1 only."""

    def __init__(self, process: Any, grpc_port: int, web_port: int):
        self.process, self.grpc_port, self.web_port = process, grpc_port, web_port
        self.grpc_url = f"rerun+http://127.0.0.1:{grpc_port}/proxy"
        self.url = f"http://127.0.0.1:{web_port}/?url={urllib.parse.quote(self.grpc_url, safe='')}"

    @classmethod
    def start(cls) -> WebServer:
        """Start `rerun --serve-web` bound to 127.0.0.1 on two free ports; return once it listens."""
        grpc_port, web_port = free_port(), free_port()
        arguments = ["--serve-web", "--bind", "127.0.0.1", "--port", str(grpc_port), "--web-viewer-port", str(web_port)]
        return cls(start_rerun(arguments, [grpc_port, web_port], detached=False), grpc_port, web_port)

    def serve_until_interrupted(self, announced: bool = False, already_interrupted: bool = False) -> None:
        """Keep serving (the server holds the recording) until Ctrl-C, then stop cleanly; `announced`:
        its address was printed already (a run prints it as it starts)."""
        try:
            if not already_interrupted:  # the address alone on its line: copied whole, with nothing glued on
                shown = "the address above" if announced else "this address"
                print(f"Open {shown} in a browser (press Ctrl-C to stop serving)", end="", flush=True)
                print("." if announced else f":\n{self.url}", flush=True)
                self.process.wait()
        except KeyboardInterrupt:
            print("Stopped serving the web viewer.")
        finally:
            self.stop()

    def stop(self) -> None:
        """End the server process."""
        stop_process(self.process)


def free_port() -> int:
    """A TCP port that is free on 127.0.0.1 right now."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


def listening(port: int) -> bool:
    """Whether something accepts connections on 127.0.0.1:`port`."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as probe:
        probe.settimeout(0.2)
        return probe.connect_ex(("127.0.0.1", port)) == 0
