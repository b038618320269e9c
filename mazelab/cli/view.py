"""`mazelab view FILE`: serve a saved recording in the web viewer on 127.0.0.1, with the lab's layout,
for a machine without a display (over ssh: forward the two ports, then open the printed address)."""

from __future__ import annotations

import os
import signal
from pathlib import Path
from typing import Annotated

import typer

from mazelab.cli.options import UserError
from mazelab.viz.processes import WebServer
from mazelab.viz.recording import rerun_switched_off
from mazelab.viz.saved import recording_problem, send_with_layout


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
    if rerun_switched_off():
        switch = f"RERUN={os.environ['RERUN']}"
        raise UserError(f"{recording}: viewing needs Rerun, which {switch} switches off: unset RERUN")
    problem = recording_problem(recording)
    if problem is not None:
        raise UserError(f"{recording}: {problem}")
    try:
        server = WebServer.start()
    except (RuntimeError, OSError) as error:
        raise UserError(f"{recording}: cannot serve it ({error})") from None
    stop_on_termination()
    try:
        # sent by us, not by `rerun --serve-web FILE`: the lab's layout goes first and active (see mazelab.viz.saved)
        send_with_layout(recording, server.grpc_url)
    except RuntimeError as error:  # rerun could not read or send it after all
        server.stop()
        typer.echo(f"error: {recording}: could not send it to the web viewer ({error})", err=True)
        raise typer.Exit(1) from None
    except BaseException:
        server.stop()
        raise
    print(f"Serving {recording}")
    server.serve_until_interrupted()


def stop_on_termination() -> None:
    """SIGTERM and SIGHUP (`timeout`, a closed terminal) stop serving as Ctrl-C does, so the server
    process ends with this one instead of holding its ports."""

    def interrupt(_signum: int, _frame: object) -> None:
        raise KeyboardInterrupt

    for name in ("SIGTERM", "SIGHUP"):
        if hasattr(signal, name):
            signal.signal(getattr(signal, name), interrupt)


__all__ = ["stop_on_termination", "view"]
