"""Where a recording goes: the `visualize` values, the display check, and recording file names."""

from __future__ import annotations

import difflib
import importlib.util
import os
import re
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from mazelab.atomic import WriteError
from mazelab.viz.style import DEFAULT_MAX_DRAWN

TARGET_WORDS = ("viewer", "web", "notebook")  # the visualize strings that are not file names
RECORDINGS_DIR = Path("recordings")  # where runs without a display are saved, relative to the cwd
CROWDED_BYTES = 100e6  # a save line beyond this size of RECORDINGS_DIR adds how to thin it (the example's run: 6 MB)
KEEP_HINT = 10  # the cleanup that line suggests: keep this many of the newest default recordings


@dataclass(frozen=True)
class Visualization:
    """A `visualize` value with options: where to draw (`target`, see above) and how much."""

    target: Any = True
    max_drawn: int = DEFAULT_MAX_DRAWN
    replace: bool = True  # a recording file may replace an existing one (False: its name is created exclusively)

    def __post_init__(self) -> None:
        if isinstance(self.max_drawn, bool) or not isinstance(self.max_drawn, (int, np.integer)) or self.max_drawn < 1:
            raise ValueError(f"max_drawn must be a whole number >= 1, got {self.max_drawn!r}")


def resolve_target(target: Any) -> str | Path:
    """The place a `visualize` value means: "viewer" (True or "auto" outside Jupyter; a file instead when
    the viewer cannot open, see Recording.open), "web", "notebook" or a file path."""
    if target is True or target == "auto":
        return "notebook" if in_jupyter() and notebook_viewer_installed() else "viewer"
    if target == "notebook" and not notebook_viewer_installed():
        raise ValueError("visualize='notebook' needs rerun's notebook viewer: pip install -e '.[notebook]'")
    if target in TARGET_WORDS:
        return target
    if isinstance(target, (str, Path)):
        path = Path(target)
        # a file has a folder or a suffix (.rrd); any other string is a word: a mistyped "viwer" is no file
        if isinstance(target, str) and not path.suffix and path.parent == Path(".") and target.strip():
            close = difflib.get_close_matches(target, TARGET_WORDS, n=1)
            hint = f"; did you mean {close[0]!r}?" if close else "; a file needs a suffix such as .rrd"
            words = ", ".join(map(repr, TARGET_WORDS))
            raise ValueError(f"visualize={target!r} is not one of {words} nor a file name{hint}")
        if path.is_dir():
            raise ValueError(f"{path} is a folder, not an .rrd file")
        if not path.parent.is_dir():
            raise ValueError(f"{path.parent} does not exist: cannot write {path.name} there")
        return path
    raise ValueError(
        f"visualize must be True, False, 'viewer', 'web', 'notebook', an .rrd path or a view, got {target!r}"
    )


def default_recording_path(label: str) -> Path:
    """recordings/<label>-<date>-<time>.rrd in the current folder; the folder is created. The name is
    claimed when the file is written (Recording.save): taken by then, the next free one is."""
    try:
        RECORDINGS_DIR.mkdir(parents=True, exist_ok=True)
    except OSError as error:
        raise WriteError(error.errno, error.strerror, str(RECORDINGS_DIR)) from None
    return RECORDINGS_DIR / f"{label}-{time.strftime('%Y%m%d-%H%M%S')}.rrd"


def next_free_name(path: Path) -> Path:
    """The first of NAME-2.rrd, NAME-3.rrd, ... that does not exist (NAME-2 follows NAME-1 or NAME)."""
    match = re.fullmatch(r"(.*-\d{8}-\d{6})(?:-(\d+))?", path.stem) or re.fullmatch(r"(.*?)(?:-(\d+))?", path.stem)
    base, n = match.group(1), int(match.group(2) or 1)
    while True:
        n += 1
        candidate = path.with_name(f"{base}-{n}{path.suffix}")
        if not candidate.exists():
            return candidate


# -- the recordings folder -------------------------------------------------------------------------
LAB_NAME = re.compile(r"[^.].*-\d{8}-\d{6}(-\d+)?\.rrd")  # default names: <label>-<date>-<time>[-N].rrd


@dataclass(frozen=True)
class SavedRecording:
    """A recording file in a folder: its path, size (bytes), time last written (seconds since the
    epoch), and whether the lab named it (a default name, see default_recording_path)."""

    path: Path
    size: int
    modified: float

    @property
    def lab_named(self) -> bool:
        return LAB_NAME.fullmatch(self.path.name) is not None


def saved_recordings(folder: Path) -> list[SavedRecording]:
    """The .rrd files in `folder` that are regular files (a symbolic link or a folder is not one of
    them), oldest first; none when the folder does not exist."""
    found = []
    try:
        entries = list(os.scandir(folder))
    except (FileNotFoundError, NotADirectoryError):
        return []
    for entry in entries:
        if entry.name.startswith(".") or not entry.name.endswith(".rrd"):
            continue
        try:
            if not entry.is_file(follow_symlinks=False):
                continue
            info = entry.stat(follow_symlinks=False)
        except FileNotFoundError:  # removed meanwhile (another cleanup, a run's rename)
            continue
        found.append(SavedRecording(Path(folder) / entry.name, info.st_size, info.st_mtime))
    return sorted(found, key=lambda saved: (saved.modified, saved.path.name))


def human_size(size: float) -> str:
    """A size in bytes as people write it, in powers of 1000: 532 B, 12.4 kB, 3.1 MB, 1.25 GB."""
    for unit, scale in (("GB", 1e9), ("MB", 1e6), ("kB", 1e3)):
        if size >= scale:
            value = size / scale
            return f"{value:.3g} {unit}" if value < 100 else f"{value:.0f} {unit}"
    return f"{int(size)} B"


def folder_summary(folder: Path) -> str:
    """What a folder of recordings holds now, e.g. "recordings/ holds 7 recordings, 140 MB"."""
    found = saved_recordings(folder)
    count = f"{len(found)} recording{'s' if len(found) != 1 else ''}"
    return f"{folder}{os.sep} holds {count}, {human_size(sum(saved.size for saved in found))}"


def crowded_folder_hint(folder: Path, command: str) -> str | None:
    """Once a folder of default recordings holds more than CROWDED_BYTES: what it holds and the
    `command` prefix's cleanup that keeps the KEEP_HINT newest; else None."""
    if sum(saved.size for saved in saved_recordings(folder)) <= CROWDED_BYTES:
        return None
    cleanup = f"{command} recordings --keep {KEEP_HINT} --clean"
    return f"{folder_summary(folder)}; to keep only the {KEEP_HINT} newest: {cleanup}"


def has_display() -> bool:
    """Whether a native viewer window can open: always on macOS and Windows, else DISPLAY or WAYLAND_DISPLAY."""
    return sys.platform in ("darwin", "win32") or bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


def in_jupyter() -> bool:
    """Whether this runs in a Jupyter kernel (where the viewer can be shown inline)."""
    ipython = sys.modules.get("IPython")
    shell = ipython.get_ipython() if ipython is not None else None
    return type(shell).__name__ == "ZMQInteractiveShell"


def notebook_viewer_installed() -> bool:
    """Whether rerun's notebook viewer (the `notebook` extra) is installed."""
    return importlib.util.find_spec("rerun_notebook") is not None
