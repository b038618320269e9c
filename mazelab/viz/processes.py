"""The Rerun processes this program starts (native viewer, web viewer), on 127.0.0.1 only."""

from __future__ import annotations

import importlib.util
import os
import shlex
import shutil
import socket
import subprocess
import time
import urllib.parse
from collections.abc import Sequence
from pathlib import Path
from typing import Any

VIEWER_PORT = 9876  # the native viewer's gRPC port, rerun's default: later runs reuse its window


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
    deadline = time.monotonic() + timeout
    while not all(listening(port) for port in ports):
        if process.poll() is not None or time.monotonic() > deadline:
            stop_process(process)
            raise RuntimeError(f"the Rerun viewer did not start (exit code {process.returncode})")
        time.sleep(0.05)
    time.sleep(settle)
    if process.poll() is not None:
        raise RuntimeError(f"the Rerun viewer did not start (exit code {process.returncode})")
    return process


def native_viewer() -> str:
    """The gRPC address of a native viewer on 127.0.0.1:VIEWER_PORT: the one already running there
    (as rerun's own spawn does, runs share its window), else a new detached one."""
    if not listening(VIEWER_PORT):
        start_rerun(["--bind", "127.0.0.1", "--port", str(VIEWER_PORT), "--expect-data-soon"], [VIEWER_PORT],
                    detached=True, settle=1.0)  # fmt: skip
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


class WebServer:
    """The web viewer and its gRPC proxy, served by the `rerun` binary on 127.0.0.1 only."""

    def __init__(self, process: Any, grpc_port: int, web_port: int):
        self.process, self.grpc_port, self.web_port = process, grpc_port, web_port
        self.grpc_url = f"rerun+http://127.0.0.1:{grpc_port}/proxy"
        self.url = f"http://127.0.0.1:{web_port}/?url={urllib.parse.quote(self.grpc_url, safe='')}"

    @classmethod
    def start(cls, recordings: Sequence[Path] = ()) -> WebServer:
        """Start `rerun --serve-web` bound to 127.0.0.1 on two free ports; return once it listens.
        With `recordings` (saved .rrd files) it serves those instead of waiting for a run."""
        grpc_port, web_port = free_port(), free_port()
        arguments = ["--serve-web", "--bind", "127.0.0.1", "--port", str(grpc_port), "--web-viewer-port", str(web_port)]
        arguments += [str(path) for path in recordings]
        return cls(start_rerun(arguments, [grpc_port, web_port], detached=False), grpc_port, web_port)

    def serve_until_interrupted(self, already_interrupted: bool = False) -> None:
        """Keep serving (the server holds the recording) until Ctrl-C, then stop cleanly."""
        try:
            if not already_interrupted:
                print(f"The web viewer is at {self.url}; press Ctrl-C to stop serving.")
                self.process.wait()
        except KeyboardInterrupt:
            print("Stopped serving the web viewer.")
        finally:
            self.stop()

    def stop(self) -> None:
        """End the server process."""
        stop_process(self.process)


def open_hint(path: Path, display: bool) -> str:
    """How to look at a saved recording: the native viewer with a display, else the web viewer that
    `mazelab view` serves on 127.0.0.1 (plain `rerun --web-viewer` would listen on every interface)."""
    quoted = shlex.quote(str(path))
    return f"rerun {quoted}" if display else f"mazelab view {quoted} (the web viewer, on 127.0.0.1)"


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


__all__ = [
    "VIEWER_PORT",
    "WebServer",
    "free_port",
    "listening",
    "native_viewer",
    "open_hint",
    "rerun_environment",
    "start_rerun",
    "stop_process",
    "viewer_executable",
]
