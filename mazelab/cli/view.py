"""`mazelab view FILE`: serve a saved recording in the web viewer on 127.0.0.1, for a machine without
a display (over ssh: forward the two ports, then open the printed address)."""

from __future__ import annotations

import signal
import warnings
from pathlib import Path
from typing import Annotated

import typer

from mazelab.cli.options import UserError
from mazelab.viz.processes import WebServer

RRD_MAGIC = b"RRF2"  # the first bytes of a Rerun recording file


def view(
    recording: Annotated[Path, typer.Argument(metavar="FILE", help="a saved recording (.rrd)", show_default=False)],
) -> None:
    """Serve a saved recording (.rrd) in the web viewer on 127.0.0.1 until Ctrl-C; needs no display."""
    if recording.is_dir():
        found = sorted(recording.glob("*.rrd"))
        which = f"e.g. {found[-1]}" if found else "it holds no .rrd file"
        raise UserError(f"{recording} is a folder, not a recording: name one .rrd file ({which})")
    if not recording.is_file():
        raise UserError(f"{recording}: no such recording file")
    if not is_recording(recording):
        raise UserError(f"{recording}: not a Rerun recording (.rrd)")
    try:
        server = WebServer.start([recording])
    except (RuntimeError, OSError) as error:
        raise UserError(f"{recording}: cannot serve it ({error})") from None
    print(f"Serving {recording}")
    stop_on_termination()
    server.serve_until_interrupted()


def stop_on_termination() -> None:
    """SIGTERM and SIGHUP (`timeout`, a closed terminal) stop serving as Ctrl-C does, so the server
    process ends with this one instead of holding its ports."""

    def interrupt(_signum: int, _frame: object) -> None:
        raise KeyboardInterrupt

    for name in ("SIGTERM", "SIGHUP"):
        if hasattr(signal, name):
            signal.signal(getattr(signal, name), interrupt)


def is_recording(path: Path) -> bool:
    """Whether the file is an .rrd recording: Rerun's 'RRF2' header, and Rerun's own reader finds a
    whole recording in it (a file that only starts like one, or is cut short, is not)."""
    try:
        with path.open("rb") as file:
            if file.read(4) != RRD_MAGIC:
                return False
    except OSError:
        return False
    from rerun.chunk import RrdReader

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # "no footer": a cut file is scanned, then refused below
            return any(store.kind == "recording" for store in RrdReader(path).recordings())
    except Exception:  # Rerun's reader refuses it: a bad frame, an unknown encoding, a cut file
        return False


__all__ = ["is_recording", "stop_on_termination", "view"]
