"""A Rerun recording of the lab: its stream and sinks, the maze and the robot drawn once per recording."""

from __future__ import annotations

import os
import sys
import uuid
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from mazelab.maze import EMPTY, Maze
from mazelab.viz.processes import WebServer, native_viewer, open_hint
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
from mazelab.viz.targets import default_recording_path, has_display, partial_path, resolve_target


class Recording:
    """A Rerun recording of the lab: its stream, where it goes, and the robot and maze drawn once."""

    def __init__(self, stream: Any, *, path: Path | None = None, server: WebServer | None = None, owned: bool = True):
        self.stream, self.path, self.server, self.owned = stream, path, server, owned
        self.robot_steps: set[int] = set()
        self.last_robot_position: tuple[float, float] | None = None
        self.kidnapping: tuple[int, tuple[float, float]] | None = None  # (step, place), see expect_kidnapping
        self.closed = False

    @classmethod
    def open(cls, target: Any, world: Maze, blueprint: Any, *, label: str) -> Recording:
        """A recording going where `target` says (see the `visualize` values), with the maze logged."""
        import rerun as rr

        if isinstance(target, rr.RecordingStream):
            target.send_blueprint(blueprint, make_active=False, make_default=True)
            recording = cls(target, owned=False)
        else:
            recording = cls._to(resolve_target(target, label), blueprint, label)
        log_maze(recording.stream, world)
        return recording

    @classmethod
    def _to(cls, target: str | Path, blueprint: Any, label: str) -> Recording:
        import rerun as rr

        stream = rr.RecordingStream(APPLICATION_ID, recording_id=str(uuid.uuid4()))
        if target == "viewer":
            try:
                stream.connect_grpc(native_viewer(), default_blueprint=blueprint)
                return cls(stream)
            except RuntimeError as error:  # e.g. a display that the viewer cannot open
                target = default_recording_path(label)
                print(f"{error}: the recording goes to {target} instead")
        if target == "notebook":
            stream.notebook_show(blueprint=blueprint, height=700)
            return cls(stream)
        path = default_recording_path(label) if target == "web" else Path(target)
        partial = partial_path(path)
        if target == "web":
            server = WebServer.start()
            stream.set_sinks(rr.GrpcSink(server.grpc_url), rr.FileSink(partial), default_blueprint=blueprint)
            print(f"Serving the web viewer at {server.url}")
            return cls(stream, path=path, server=server)
        stream.save(partial, default_blueprint=blueprint)
        return cls(stream, path=path)

    def log_robot(self, step: int, position: Sequence[float], heading: float | None) -> None:
        """The robot (a green dot and its heading) and the step number, once per step of the recording:
        every filter of a comparison replays the same robot."""
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
            self.log_kidnapping(step, self.kidnapping[1])
            title += ": the robot is kidnapped"
        self.stream.log("/title", rr.TextDocument(title, media_type=rr.MediaType.MARKDOWN))
        self.last_robot_position = (float(position[0]), float(position[1]))

    def log_kidnapping(self, step: int, place: tuple[float, float]) -> None:
        """The jump of step `step`: a line from where the robot was to `place`, where it was put down
        (it stays drawn from that step on), and a ring at `place`."""
        import rerun as rr

        label = f"kidnapped at step {step}"
        if self.last_robot_position is not None:
            jump = rr.LineStrips2D([[self.last_robot_position, place]], colors=KIDNAP_COLOR, radii=0.03, labels=label)
            self.stream.log(f"{MAP}/robot/kidnapping", jump)
        ring = rr.Ellipses2D(centers=[place], half_sizes=[[0.25, 0.25]], colors=KIDNAP_COLOR, line_radii=0.03)
        self.stream.log(f"{MAP}/robot/kidnapping/place", ring)

    def close(self) -> None:
        """Flush; a file is completed and moved into place and its path printed; a web viewer is
        served until Ctrl-C. A caller's own recording is only flushed."""
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
        if self.path is not None:
            os.replace(partial_path(self.path), self.path)
            print(f"Recording saved to {self.path}; open it with: {open_hint(self.path, has_display())}")
        if self.server is not None:
            # close() runs in simulate's `finally`: a run being interrupted stops serving at once.
            self.server.serve_until_interrupted(already_interrupted=sys.exc_info()[0] is not None)


def log_maze(stream: Any, world: Maze) -> None:
    """The static map: walls black and free cells white (an image, one pixel per cell), stations as
    cyan dots, all under MAP, whose transform turns the map frame (y up) into the view's (y down)."""
    import rerun as rr

    stream.log(MAP, rr.Transform3D(translation=[0, world.height, 0], scale=[1, -1, 1]), static=True)
    stream.log(f"{MAP}/maze", rr.Image(maze_image(world), draw_order=-10.0), static=True)
    stream.log(f"{MAP}/stations", rr.Points2D(world.stations, colors=STATION_COLOR, radii=STATION_RADIUS), static=True)


def maze_image(world: Maze) -> np.ndarray:
    """RGB image of the maze, shape (H, W, 3): pixel (row j, column i) is the cell covering
    x in [i, i+1), y in [j, j+1) of the map frame, so grid row H-1-j."""
    walls = world.grid[::-1] != EMPTY
    return np.where(walls[..., None], np.uint8(WALL_COLOR), np.uint8(FREE_COLOR)).astype(np.uint8)


def heading_vectors(angles: np.ndarray, length: float) -> np.ndarray:
    """Arrows of `length` along `angles` (radians, counter-clockwise from +x), shape (N, 2)."""
    return length * np.column_stack([np.cos(angles), np.sin(angles)])


__all__ = [
    "Recording",
    "heading_vectors",
    "log_maze",
    "maze_image",
]
