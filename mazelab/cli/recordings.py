"""`mazelab recordings [FOLDER]`: the recordings that runs without a display saved (recordings/ in the
current folder), with their sizes; `--keep N`, `--older-than AGE` and `--max-size SIZE` choose old
ones to remove, shown first, removed with `--clean`.

Only recordings the lab named (`<label>-<date>-<time>.rrd`, regular files) are ever removed: a file
you saved there under a name of your own, a link or a folder stays.

`mazelab view FILE`: serve a saved recording in the web viewer on 127.0.0.1, with the lab's layout,
for a machine without a display (over ssh: forward the two ports, then open the printed address).

`view` sends a file's layout ahead of its recording and makes it active: rerun-sdk 0.41's web viewer
reads a recording before its layout and, with a default layout alone, builds its automatic grid (see
docs/viewer.md). So older files and a caller's own `rr.RecordingStream` open with the lab's layout too.
"""

from __future__ import annotations

import collections
import os
import re
import signal
import stat
import time
import warnings
from collections.abc import Callable, Iterable
from datetime import datetime
from pathlib import Path
from typing import Any

import numpy as np
import typer

from mazelab.cli.options import UserError, arg, opt
from mazelab.invocation import command_prefix
from mazelab.stops import STOP_SIGNALS
from mazelab.viz import recording as viz_recording
from mazelab.viz.processes import WebServer
from mazelab.viz.recording import SavedRecording, folder_summary, human_size, rerun_switched_off, saved_recordings

AGE_UNITS = {"m": 60.0, "h": 3600.0, "d": 86400.0, "w": 7 * 86400.0}  # --older-than: 30m, 12h, 7d, 2w
# --max-size: 500kB, 100MB, 100M or 1.5GB (powers of 1000; bytes without a unit)
SIZE_UNITS = {"": 1.0, "b": 1.0, "k": 1e3, "kb": 1e3, "m": 1e6, "mb": 1e6, "g": 1e9, "gb": 1e9, "t": 1e12, "tb": 1e12}


def parse_amount(text: str, option: str, units: dict[str, float], examples: str) -> float:
    """A number and one of `units` (written as `examples` show), in the units' base: seconds, bytes.
    Anything else is one line naming `option`."""
    match = re.fullmatch(r"\s*(\d+(?:\.\d+)?)\s*([a-z]*)\s*", text.lower())
    if match is None or match.group(2) not in units:
        raise UserError(f"{option} {text!r}: write a number and a unit: {examples}")
    return float(match.group(1)) * units[match.group(2)]


def chosen(
    found: list[SavedRecording], keep: int | None, older_than: float | None, max_size: float | None, now: float
) -> list[SavedRecording]:
    """The lab-named recordings of `found` (oldest first) that a rule removes: beyond the `keep`
    newest, older than `older_than` seconds, or beyond `max_size` bytes counted from the newest.
    Together, a recording goes when any rule says so."""
    named = [saved for saved in found if saved.lab_named]
    newest_first = named[::-1]
    doomed: set[SavedRecording] = set(newest_first[keep:]) if keep is not None else set()
    if older_than is not None:
        doomed |= {saved for saved in named if now - saved.modified > older_than}
    if max_size is not None:
        sizes = np.cumsum([saved.size for saved in newest_first])
        doomed |= {saved for saved, total in zip(newest_first, sizes, strict=True) if total > max_size}
    return [saved for saved in named if saved in doomed]


def remove(doomed: list[SavedRecording]) -> list[SavedRecording]:
    """Remove each file that is still the regular file listed (one replaced by a link meanwhile, or
    gone, is left alone); the ones removed. The first error (permissions) ends it, raised."""
    removed = []
    for saved in doomed:
        try:
            info = os.lstat(saved.path)
        except FileNotFoundError:
            continue
        if not stat.S_ISREG(info.st_mode) or info.st_size != saved.size:
            continue  # no longer the recording listed: a run rewrote the name, or it is a link now
        os.unlink(saved.path)
        removed.append(saved)
    return removed


def recordings(
    folder: arg(Path | None, "FOLDER", "where (default: recordings/ here)") = None,
    keep: opt(int | None, "--keep", metavar="N", min=0, help="remove all but the N newest", show_default=False) = None,
    older_than: opt(str | None, "--older-than", metavar="AGE", help="remove older ones: 30m, 12h, 7d, 2w") = None,
    max_size: opt(str | None, "--max-size", metavar="SIZE", help="keep the newest within SIZE: 500MB, 2GB") = None,
    clean: opt(bool, "--clean", help="remove the recordings chosen (without: only show them)") = False,
) -> None:
    """List the recordings of runs without a display, with their sizes; remove old ones with --clean."""
    folder = viz_recording.RECORDINGS_DIR if folder is None else folder
    if folder.exists() and not folder.is_dir():
        raise UserError(f"{folder} is not a folder: name the folder of recordings (default: recordings/)")
    ages = None if older_than is None else parse_amount(older_than, "--older-than", AGE_UNITS, "30m, 12h, 7d or 2w")
    cap = None if max_size is None else parse_amount(max_size, "--max-size", SIZE_UNITS, "500kB, 100MB or 1.5GB")
    given = {"--keep": keep, "--older-than": older_than, "--max-size": max_size}
    rules = " ".join(f"{flag} {value}" for flag, value in given.items() if value is not None)  # as typed
    if clean and not rules:
        raise UserError(
            "--clean needs what to remove: --keep N (all but the N newest), --older-than 7d or --max-size 500MB"
        )
    found = saved_recordings(folder)
    if not found:
        typer.echo(f"No recordings in {folder}{os.sep}" + ("" if folder.is_dir() else " (no such folder)"))
        return
    doomed = chosen(found, keep, ages, cap, time.time()) if rules else []
    if clean:
        removed = remove(doomed)
        freed = human_size(sum(saved.size for saved in removed))
        plural = "s" if len(removed) != 1 else ""
        typer.echo(f"Removed {len(removed)} recording{plural} ({freed}); {folder_summary(folder)}")
        return
    typer.echo(f"{folder_summary(folder)}:")  # each one, marked when the rules remove it or when it is your name
    for saved in found:
        when = datetime.fromtimestamp(saved.modified).strftime("%Y-%m-%d %H:%M")
        mark = "  (would be removed)" if saved in doomed else "" if saved.lab_named else "  (your name: kept)"
        typer.echo(f"  {when}  {human_size(saved.size):>8}  {saved.path}{mark}")
    command = f"{command_prefix()} recordings" + ("" if folder == viz_recording.RECORDINGS_DIR else f" {folder}")
    if rules:
        size = human_size(sum(saved.size for saved in doomed))
        typer.echo(f"{len(doomed)} would be removed ({size}): {command} {rules} --clean")
    else:
        typer.echo(f"To remove old ones: {command} --keep {viz_recording.KEEP_HINT} (shows them), then add --clean")


# -- `mazelab view FILE` ---------------------------------------------------------------------------------
RRD_MAGIC = b"RRF2"  # the first bytes of a Rerun recording file


def view(recording: arg(Path, "FILE", "a saved recording (.rrd)")) -> None:
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
    for number in set(STOP_SIGNALS) - {signal.SIGINT}:  # SIGTERM, SIGHUP (`timeout`, a closed terminal) stop
        signal.signal(number, signal.default_int_handler)  # serving as Ctrl-C does: the server ends, exit 0
    try:
        replay_with_layout(recording, lambda stream: stream.connect_grpc(server.grpc_url))
    except BaseException as error:  # the server ends with the command, whatever stopped it
        server.stop()
        if not isinstance(error, RuntimeError):  # a RuntimeError: rerun could not read or send it after all
            raise
        typer.echo(f"error: {recording}: could not send it to the web viewer ({error})", err=True)
        raise typer.Exit(1) from None
    print(f"Serving {recording}")
    server.serve_until_interrupted()


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

    problem = "not a Rerun recording (.rrd), or a damaged one: Rerun cannot read it (cut short?)"  # a bad frame
    try:
        with warnings.catch_warnings(action="ignore"):  # "no footer/manifest": no end marker, refused below
            reader = RrdReader(path)
            recordings = reader.recordings()
            if not recordings:
                return "not a Rerun recording (.rrd): it holds no recording"
            problem = "not a whole Rerun recording: something follows the end of the recording, or it was cut short"
            reader.store(store=recordings[0])  # needs the footer: refused by rerun when the file does not end with it
            problem = "a damaged Rerun recording: part of it cannot be decoded (changed on disk?)"
            for entry in [*recordings, *reader.blueprints()]:  # every chunk decoded, as sending it will
                collections.deque(reader.stream(store=entry), maxlen=0)
    except Exception:  # Rerun refuses it at the stage `problem` names (a frame's checksum, its compressed data)
        return problem
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

    with warnings.catch_warnings(action="ignore"):
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
