"""`mazelab view FILE`: serve a saved recording in the web viewer on 127.0.0.1, with the lab's layout,
for a machine without a display (over ssh: forward the two ports, then open the printed address).

Why the layout is sent, not only the file (rerun-sdk 0.41): a file written with `default_blueprint=`
marks its blueprint as the application's default only, and the SDK writes the recording's own store
before the blueprint. The web viewer, fed such a file by `rerun --serve-web FILE`, activates the
recording first, finds no active layout and builds its automatic grid; a default that arrives later
stays a default. So the lab writes its recordings with their layout active (mazelab.viz.recording), and
`view` sends a file's layout first and active, which also opens older files and a caller's own
`rr.RecordingStream` with the lab's layout.
"""

from __future__ import annotations

import collections
import os
import signal
import warnings
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Annotated, Any

import typer

from mazelab.cli.options import UserError
from mazelab.stops import STOP_SIGNALS
from mazelab.viz.processes import WebServer
from mazelab.viz.recording import rerun_switched_off

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
        replay_with_layout(recording, lambda stream: stream.connect_grpc(server.grpc_url))
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
    process ends with this one instead of holding its ports, and the command ends cleanly (exit 0)."""

    def interrupt(_signum: int, _frame: object) -> None:
        raise KeyboardInterrupt

    for number in STOP_SIGNALS:
        if number != signal.SIGINT:
            signal.signal(number, interrupt)


def recording_problem(path: Path) -> str | None:
    """Why `path` is not a whole Rerun recording, or None when it is one: Rerun's "RRF2" header, a
    recording its reader finds, Rerun's end marker at the very end of the file (rerun 0.41 ends
    every file it writes with a footer that indexes its chunks; a file with bytes appended, or cut
    short, has none where the reader looks), and every chunk decoded (a frame damaged in the middle
    would otherwise fail only while it is sent, with Rerun's own log lines)."""
    try:
        with path.open("rb") as file:
            if file.read(4) != RRD_MAGIC:
                return "not a Rerun recording (.rrd)"
    except OSError as error:
        return f"cannot be read ({error.strerror})"
    from rerun.chunk import RrdReader

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # "no footer/manifest": a file without an end marker, refused below
            reader = RrdReader(path)
            recordings = reader.recordings()
            if not recordings:
                return "not a Rerun recording (.rrd): it holds no recording"
    except Exception:  # Rerun's reader refuses it: a bad frame, an unknown encoding, a file cut in a frame
        return "not a Rerun recording (.rrd), or a damaged one: Rerun cannot read it (cut short?)"
    try:
        reader.store(store=recordings[0])  # needs the footer: refused by rerun when the file does not end with it
    except Exception:
        return "not a whole Rerun recording: something follows the end of the recording, or it was cut short"
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            for entry in [*recordings, *reader.blueprints()]:  # every chunk decoded, as sending it will
                collections.deque(reader.stream(store=entry), maxlen=0)
    except Exception:  # a frame damaged in the middle: its checksum or its compressed data does not decode
        return "a damaged Rerun recording: part of it cannot be decoded (changed on disk?)"
    return None


class SavedBlueprint:
    """A blueprint read back from a file, in the form `RecordingStream.send_blueprint` takes: rerun 0.41
    turns a BlueprintLike into a blueprint stream by `to_blueprint()._log_to_stream(stream)`; here that
    sends the file's blueprint chunks as they are (containers, views, shares, visual bounds, panels)."""

    def __init__(self, chunks: Iterable[Any]):
        self.chunks = list(chunks)

    def to_blueprint(self) -> SavedBlueprint:
        """The blueprint itself (the BlueprintLike protocol)."""
        return self

    def _log_to_stream(self, stream: Any) -> None:
        """Send the saved chunks to the blueprint stream that rerun prepared."""
        stream.send_chunks(self.chunks)


def replay_with_layout(path: Path, connect: Callable[[Any], None]) -> None:
    """Replay the saved recording `path` (checked by recording_problem) into new streams, each given
    its sink by `connect`: for each recording in the file, its application's blueprint first, made the
    active layout, then the recording's chunks (its properties among them), under the file's own
    application and recording ids. Each stream is flushed and closed before this returns."""
    import rerun as rr
    from rerun.chunk import RrdReader

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        reader = RrdReader(path)
        blueprints = {entry.application_id: entry for entry in reader.blueprints()}  # the last of each application
        for entry in reader.recordings():
            stream = rr.RecordingStream(entry.application_id, recording_id=entry.recording_id, send_properties=False)
            connect(stream)
            if entry.application_id in blueprints:
                layout = SavedBlueprint(reader.stream(store=blueprints[entry.application_id]))
                stream.send_blueprint(layout, make_active=True, make_default=True)
            stream.send_chunks(reader.stream(store=entry))
            stream.flush()
            stream.disconnect()


__all__ = ["recording_problem", "replay_with_layout", "view"]
