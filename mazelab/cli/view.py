"""`mazelab view FILE`: serve saved recordings in the web viewer on 127.0.0.1, for a machine without
a display (over ssh: forward the port, then open the printed address)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from mazelab.cli.options import UserError
from mazelab.viz.processes import WebServer


def view(
    recordings: Annotated[
        list[Path], typer.Argument(metavar="FILE", help="saved recordings (.rrd)", show_default=False)
    ],
) -> None:
    """Serve saved recordings (.rrd) in the web viewer on 127.0.0.1 until Ctrl-C; needs no display."""
    for path in recordings:
        if not path.is_file():
            raise UserError(f"{path}: no such recording file")
    server = WebServer.start(recordings)
    print(f"Serving {', '.join(str(path) for path in recordings)}")
    server.serve_until_interrupted()


__all__ = ["view"]
