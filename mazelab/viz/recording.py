"""A Rerun recording of the lab: its stream and sinks, the maze and the robot drawn once per recording.

A file recording is kept in memory (Rerun's binary stream) and written at the end through
mazelab.atomic: whole or not at all, under its own temporary name, every write error reported.
"""

from __future__ import annotations

import os
import sys
import uuid
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from contextvars import ContextVar
from pathlib import Path
from typing import Any

import numpy as np

from mazelab.atomic import WriteError, write_bytes_atomically
from mazelab.invocation import command_prefix
from mazelab.maze import EMPTY, Maze
from mazelab.viz import targets
from mazelab.viz.processes import WebServer, hold_stop_signals, native_viewer, open_hint, release_stop_signals
from mazelab.viz.style import (
    APPLICATION_ID,
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
from mazelab.viz.targets import crowded_folder_hint, default_recording_path, human_size, next_free_name

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

        place, why = targets.resolve_target(target), ""
        if place == "viewer" and not targets.has_display():
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
        default = place in (None, "web")
        path = default_recording_path(label) if default else place
        sink = stream.binary_stream()  # kept in memory: written whole at close (see mazelab.atomic)
        server = WebServer.start() if place == "web" else None
        sinks = [sink] if server is None else [rr.GrpcSink(server.grpc_url), sink]
        stream.set_sinks(*sinks)
        # the layout made active as well as default: Rerun's web viewer reads a file's recording before
        # its layout and, with a default alone, shows its automatic grid (see mazelab.cli.recordings, `view`)
        stream.send_blueprint(blueprint, make_active=True, make_default=True)
        if server is not None:
            print(f"Serving the web viewer at {server.url}")
            server.announced = True
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
                self.server.serve_until_interrupted(already_interrupted=interrupted)

    def save(self) -> None:
        """Write the recording to its file, whole or not at all, and say where; a default name that
        another run took meanwhile becomes the next free one. A write error is raised or deferred."""
        data = self.sink.read() or b""
        while True:
            try:
                write_bytes_atomically(self.path, data, replace=self.replace)
                break
            except WriteError as error:  # every error of write_bytes_atomically is one
                deferred = _deferred.get()
                if self.claim_name and isinstance(error, FileExistsError):  # a default name, taken meanwhile
                    self.path = next_free_name(self.path)
                elif deferred is None:
                    raise
                else:
                    deferred[0].append(error)  # raised when the block of deferred_to_the_end ends
                    return
        why = f"; {self.why}, so" if self.why else ";"
        hint = open_hint(self.path, targets.has_display())
        print(f"Recording saved to {self.path}; {human_size(len(data))}{why} open it with: {hint}")
        crowded = crowded_folder_hint(self.path.parent, command_prefix()) if self.claim_name else None
        if crowded is not None:  # default names: runs without a display pile them up in RECORDINGS_DIR
            print(crowded)


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
                server.serve_until_interrupted()
            else:
                server.stop()
    if errors:
        raise errors[0]


def heading_vectors(angles: np.ndarray, length: float) -> np.ndarray:
    """Arrows of `length` along `angles` (radians, counter-clockwise from +x), shape (N, 2)."""
    return length * np.column_stack([np.cos(angles), np.sin(angles)])
