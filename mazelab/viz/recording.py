"""A Rerun recording of the lab: where it goes (the `visualize` values, the display check, recording
file names and the recordings folder), its stream and sinks, the maze and the robot drawn once per recording.

A file recording is kept in memory (Rerun's binary stream) and written at the end through
mazelab.atomic: whole or not at all, under its own temporary name, every write error reported.
"""

from __future__ import annotations

import difflib
import importlib.util
import itertools
import os
import re
import shlex
import sys
import time
import uuid
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from contextvars import ContextVar
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from mazelab.atomic import WriteError, write_atomically
from mazelab.checks import step_number
from mazelab.invocation import command_prefix
from mazelab.maze import EMPTY, Maze
from mazelab.viz.processes import WebServer, hold_stop_signals, native_viewer, release_stop_signals
from mazelab.viz.style import (
    APPLICATION_ID,
    DEFAULT_MAX_DRAWN,
    FREE_COLOR,
    KIDNAP_COLOR,
    MAP,
    ROBOT_ARROW_LENGTH,
    ROBOT_COLOR,
    ROBOT_RADIUS,
    STATION_COLOR,
    STATION_RADIUS,
    WALL_COLOR,
)

TARGET_WORDS = ("viewer", "web", "notebook")  # the visualize strings that are not file names
RECORDINGS_DIR = Path("recordings")  # where runs without a display are saved, relative to the cwd
CROWDED_BYTES = 100e6  # a save line beyond this size of RECORDINGS_DIR adds how to thin it (the example's run: 6 MB)
KEEP_HINT = 10  # the cleanup that line suggests: keep this many of the newest default recordings
RERUN_OFF_NOTE = "Rerun is switched off (RERUN=off in the environment): nothing is recorded"
NO_DISPLAY = "no display found (DISPLAY and WAYLAND_DISPLAY unset)"
# within deferred_to_the_end: the write errors and the web servers kept for the end of the block
_deferred: ContextVar[tuple[list[WriteError], list[WebServer]] | None] = ContextVar("deferred", default=None)


class Recording:
    """A Rerun recording of the lab: its stream, where it goes, and the robot and maze drawn once."""

    def __init__(
        self,
        stream: Any,
        *,
        path: Path | None = None,
        server: WebServer | None = None,
        owned: bool = True,
        sink: Any = None,
        claim_name: bool = False,
        replace: bool = True,
        why: str = "",
    ):
        self.stream, self.path, self.server, self.owned = stream, path, server, owned
        self.sink, self.claim_name = sink, claim_name  # the binary stream of a file; a default name: never replaced
        self.replace = replace and not claim_name  # a named file: replaced only if asked (--force)
        self.why = why  # why a file and not the viewer asked for, said where the file is
        if sink is not None:
            hold_stop_signals(self)  # SIGTERM/SIGHUP end the run as Ctrl-C does: the steps done are saved
        self.robot_steps: set[int] = set()
        self.last_robot_position: tuple[float, float] | None = None
        self.kidnapping: tuple[int, tuple[float, float]] | None = None  # (step, place), see expect_kidnapping
        self.closed = False

    @classmethod
    def open(cls, target: Any, world: Maze, blueprint: Any, *, label: str, replace: bool = True) -> Recording | None:
        """A recording going where `target` says (see the `visualize` values), with the static map logged:
        walls black and free cells white (an image, one pixel per cell), stations as cyan dots, all under
        MAP, whose transform turns the map frame (y up) into the view's (y down). None, after a line
        saying so, when Rerun is switched off (RERUN=off). A named file replaces an existing one only
        with `replace`."""
        import rerun as rr

        if isinstance(target, rr.RecordingStream):
            target.send_blueprint(blueprint, make_active=False, make_default=True)
            recording = cls(target, owned=False)
        else:
            if rerun_switched_off():
                print(RERUN_OFF_NOTE)
                return None
            stream = rr.RecordingStream(APPLICATION_ID, recording_id=str(uuid.uuid4()))
            recording = cls._to(stream, target, blueprint, label, replace)
        stream = recording.stream
        stream.log(MAP, rr.Transform3D(translation=[0, world.height, 0], scale=[1, -1, 1]), static=True)
        walls = world.grid[::-1] != EMPTY  # pixel (row j, column i): the cell over x in [i, i+1), y in [j, j+1)
        image = np.where(walls[..., None], np.uint8(WALL_COLOR), np.uint8(FREE_COLOR)).astype(np.uint8)
        stream.log(f"{MAP}/maze", rr.Image(image, draw_order=-10.0), static=True)
        stations = rr.Points2D(world.stations, colors=STATION_COLOR, radii=STATION_RADIUS)
        stream.log(f"{MAP}/stations", stations, static=True)
        return recording

    @classmethod
    def _to(cls, stream: Any, target: Any, blueprint: Any, label: str, replace: bool = True) -> Recording:
        """A recording of `stream` going to `target` (see Recording.open); the viewer asked for
        without a display, or one that cannot open, becomes a file of the lab's own name."""
        import rerun as rr

        place, why = resolve_target(target), ""
        if place == "viewer" and not has_display():
            place, why = None, NO_DISPLAY
        elif place == "viewer":
            try:
                stream.connect_grpc(native_viewer(), default_blueprint=blueprint)
                return cls(stream)
            except RuntimeError as error:  # e.g. a display that the viewer cannot open
                place, why = None, str(error)
        if place == "notebook":
            stream.notebook_show(blueprint=blueprint, height=700)
            return cls(stream)
        default, path = place in (None, "web"), place
        if default:  # recordings/<label>-<date>-<time>.rrd, claimed when written (save): if taken, the next free one
            try:
                RECORDINGS_DIR.mkdir(parents=True, exist_ok=True)
            except OSError as error:
                raise WriteError(error.errno, error.strerror, str(RECORDINGS_DIR)) from None
            path = RECORDINGS_DIR / f"{label}-{time.strftime('%Y%m%d-%H%M%S')}.rrd"
        sink = stream.binary_stream()  # kept in memory: written whole at close (see mazelab.atomic)
        server = WebServer.start() if place == "web" else None
        sinks = [sink] if server is None else [rr.GrpcSink(server.grpc_url), sink]
        stream.set_sinks(*sinks)
        # the layout made active as well as default: Rerun's web viewer reads a file's recording before
        # its layout and, with a default alone, shows its automatic grid (see mazelab.cli.recordings, `view`)
        stream.send_blueprint(blueprint, make_active=True, make_default=True)
        if server is not None:
            print(f"Serving the web viewer at {server.url}")
        return cls(stream, path=path, server=server, sink=sink, claim_name=default, replace=replace, why=why)

    def log_robot(self, step: int, position: Sequence[float], heading: float | None) -> None:
        """The robot (a green dot and its heading) and the step number, once per step of the recording:
        every filter of a comparison replays the same robot. At the step of its kidnapping, the jump: a
        line from where it was to where it was put down (drawn from that step on) and a ring there."""
        import rerun as rr

        if step in self.robot_steps:
            return
        self.robot_steps.add(step)
        self.stream.log(f"{MAP}/robot", rr.Points2D([position], colors=ROBOT_COLOR, radii=ROBOT_RADIUS))
        if heading is not None:
            vector = heading_vectors(np.array([heading]), ROBOT_ARROW_LENGTH)
            arrow = rr.Arrows2D(origins=[position], vectors=vector, colors=ROBOT_COLOR, radii=0.04)
            self.stream.log(f"{MAP}/robot/heading", arrow)
        title = f"### Step {step}"
        if self.kidnapping is not None and self.kidnapping[0] == step:
            place, label = self.kidnapping[1], f"kidnapped at step {step}"
            if self.last_robot_position is not None:
                jump = rr.LineStrips2D(
                    [[self.last_robot_position, place]], colors=KIDNAP_COLOR, radii=0.03, labels=label
                )
                self.stream.log(f"{MAP}/robot/kidnapping", jump)
            ring = rr.Ellipses2D(centers=[place], half_sizes=[[0.25, 0.25]], colors=KIDNAP_COLOR, line_radii=0.03)
            self.stream.log(f"{MAP}/robot/kidnapping/place", ring)
            title += ": the robot is kidnapped"
        self.stream.log("/title", rr.TextDocument(title, media_type=rr.MediaType.MARKDOWN))
        self.last_robot_position = (float(position[0]), float(position[1]))

    def close(self) -> None:
        """Flush; a file is written whole and its path printed (a write error is raised, or deferred,
        see deferred_to_the_end); a web viewer is served until Ctrl-C. A caller's own recording is
        only flushed."""
        if self.closed:
            return
        self.closed = True
        try:
            self.stream.flush()
        except RuntimeError as error:  # a viewer closed during the run: say so, do not crash the run
            print(f"The viewer did not receive the whole run ({error})")
        if not self.owned:
            return
        self.stream.disconnect()
        interrupted = sys.exc_info()[0] is not None
        try:
            if self.path is not None:
                self.save()
        finally:
            release_stop_signals(self)
            deferred = _deferred.get()
            if self.server is not None and deferred is not None and not interrupted:
                deferred[1].append(self.server)  # served once the command has printed its results
            elif self.server is not None:
                # close() runs in simulate's `finally`: a run being interrupted stops serving at once.
                self.server.serve_until_interrupted(announced=True, already_interrupted=interrupted)

    def save(self) -> None:
        """Write the recording to its file, whole or not at all, and say where; a default name that
        another run took meanwhile becomes the next free one. A write error is raised or deferred."""
        data = self.sink.read() or b""
        while True:
            try:
                write_atomically(self.path, data, replace=self.replace)
                break
            except WriteError as error:  # every error of write_atomically is one
                deferred = _deferred.get()
                if self.claim_name and isinstance(error, FileExistsError):  # a default name, taken meanwhile
                    self.path = next_free_name(self.path)
                elif deferred is None:
                    raise
                else:
                    deferred[0].append(error)  # raised when the block of deferred_to_the_end ends
                    return
        why = f"; {self.why}, so" if self.why else ";"
        command, quoted = command_prefix(), shlex.quote(str(self.path))
        # without a display: the web viewer that `view` serves on 127.0.0.1 (`rerun --web-viewer` listens everywhere)
        hint = f"rerun {quoted}" if has_display() else f"{command} view {quoted} (the web viewer, on 127.0.0.1)"
        print(f"Recording saved to {self.path}; {human_size(len(data))}{why} open it with: {hint}")
        folder = self.path.parent  # default names: runs without a display pile them up in RECORDINGS_DIR
        if self.claim_name and sum(saved.size for saved in saved_recordings(folder)) > CROWDED_BYTES:
            cleanup = f"{command} recordings --keep {KEEP_HINT} --clean"
            print(f"{folder_summary(folder)}; to keep only the {KEEP_HINT} newest: {cleanup}")


def rerun_switched_off() -> bool:
    """Whether Rerun's own switch, the environment variable RERUN, turns logging off (off, 0, false, no)."""
    return os.environ.get("RERUN", "").strip().lower() in ("off", "0", "false", "no")


@contextmanager
def deferred_to_the_end() -> Iterator[None]:
    """Within this block a command prints its results first: a recording that cannot be written does
    not end the run (the error is raised when the block ends), and a web viewer is served (until
    Ctrl-C) when the block ends, not when its run ends; an error in the block stops it at once."""
    errors: list[WriteError] = []
    servers: list[WebServer] = []
    token = _deferred.set((errors, servers))
    finished = False
    try:
        yield
        finished = True
    finally:
        _deferred.reset(token)
        for index, server in enumerate(servers):
            if finished and index == 0:
                server.serve_until_interrupted(announced=True)
            else:
                server.stop()
    if errors:
        raise errors[0]


def heading_vectors(angles: np.ndarray, length: float) -> np.ndarray:
    """Arrows of `length` along `angles` (radians, counter-clockwise from +x), shape (N, 2)."""
    return length * np.column_stack([np.cos(angles), np.sin(angles)])


# -- where a recording goes ------------------------------------------------------------------------
@dataclass(frozen=True)
class Visualization:
    """A `visualize` value with options: where to draw (`target`, see mazelab.viz.views) and how much."""

    target: Any = True
    max_drawn: int = DEFAULT_MAX_DRAWN
    replace: bool = True  # a recording file may replace an existing one (False: its name is created exclusively)

    def __post_init__(self) -> None:
        step_number("max_drawn", self.max_drawn, "a whole number")


def resolve_target(target: Any) -> str | Path:
    """The place a `visualize` value means (listed in mazelab.viz.views): "viewer", "web", "notebook" or a path."""
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


# -- the recordings folder -------------------------------------------------------------------------
LAB_NAME = re.compile(r"([^.].*-\d{8}-\d{6})(?:-(\d+))?\.rrd")  # default names: <label>-<date>-<time>[-N].rrd


def next_free_name(path: Path) -> Path:
    """The first of NAME-2.rrd, NAME-3.rrd, ... that does not exist for a default name NAME[-N].rrd."""
    base, number = LAB_NAME.fullmatch(path.name).groups()
    for n in itertools.count(int(number or 1) + 1):
        candidate = path.with_name(f"{base}-{n}.rrd")
        if not candidate.exists():
            return candidate


@dataclass(frozen=True)
class SavedRecording:
    """A recording file in a folder: its path, size (bytes), time last written (seconds since the
    epoch), and whether the lab named it (a default name, LAB_NAME)."""

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
