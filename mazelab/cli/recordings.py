"""`mazelab recordings [FOLDER]`: the recordings that runs without a display saved (recordings/ in the
current folder), with their sizes; `--keep N`, `--older-than AGE` and `--max-size SIZE` choose old
ones to remove, shown first, removed with `--clean`.

Only recordings the lab named (`<label>-<date>-<time>.rrd`, regular files) are ever removed: a file
you saved there under a name of your own, a link or a folder stays.
"""

from __future__ import annotations

import os
import re
import stat
import time
from datetime import datetime
from pathlib import Path
from typing import Annotated

import numpy as np
import typer

from mazelab.cli.options import UserError
from mazelab.invocation import command_prefix
from mazelab.viz import targets
from mazelab.viz.targets import SavedRecording, folder_summary, human_size, saved_recordings

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
    folder: Annotated[
        Path | None,
        typer.Argument(metavar="FOLDER", help="where (default: recordings/ here)", show_default=False),
    ] = None,
    keep: Annotated[
        int | None, typer.Option("--keep", metavar="N", min=0, help="remove all but the N newest", show_default=False)
    ] = None,
    older_than: Annotated[
        str | None, typer.Option("--older-than", metavar="AGE", help="remove older ones: 30m, 12h, 7d, 2w")
    ] = None,
    max_size: Annotated[
        str | None, typer.Option("--max-size", metavar="SIZE", help="keep the newest within SIZE: 500MB, 2GB")
    ] = None,
    clean: Annotated[
        bool, typer.Option("--clean", help="remove the recordings chosen (without: only show them)")
    ] = False,
) -> None:
    """List the recordings of runs without a display, with their sizes; remove old ones with --clean."""
    folder = targets.RECORDINGS_DIR if folder is None else folder
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
    show(found, doomed, folder, rules)


def show(found: list[SavedRecording], doomed: list[SavedRecording], folder: Path, rules: str) -> None:
    """The listing: each recording (when written, its size, its path), marked when the `rules` remove
    it or when it is kept as one of your own names; then the command that removes what they chose."""
    typer.echo(f"{folder_summary(folder)}:")
    for saved in found:
        when = datetime.fromtimestamp(saved.modified).strftime("%Y-%m-%d %H:%M")
        mark = "  (would be removed)" if saved in doomed else "" if saved.lab_named else "  (your name: kept)"
        typer.echo(f"  {when}  {human_size(saved.size):>8}  {saved.path}{mark}")
    command = f"{command_prefix()} recordings" + ("" if folder == targets.RECORDINGS_DIR else f" {folder}")
    if rules:
        size = human_size(sum(saved.size for saved in doomed))
        typer.echo(f"{len(doomed)} would be removed ({size}): {command} {rules} --clean")
    else:
        typer.echo(f"To remove old ones: {command} --keep {targets.KEEP_HINT} (shows them), then add --clean")


__all__ = ["chosen", "parse_amount", "recordings", "remove"]
