"""What one run draws: particles coloured by weight (or the EKF's covariance ellipse), the estimate's
circle, each mode's circle with its weight, the series; and the views that a run (open_view) or a
comparison of filters (open_comparison) draws into.

`visualize` (run_model's argument and the CLI's --viewer/--rrd/--web/--no-viz) takes:
  True or "auto"  the notebook viewer inside Jupyter, else the native viewer when a display
                  exists, else an .rrd file in recordings/ (the path is printed)
  "viewer"        spawn the native viewer (falls back to a file, saying so, without a display)
  "web"           serve the web viewer on 127.0.0.1 (and save a file); Ctrl-C stops serving
  "notebook"      the viewer inline in a Jupyter notebook (needs the `notebook` extra)
  a str/Path      save the recording to that .rrd file (any other string is a path)
  an rr.RecordingStream   log into the caller's own recording (it stays open)
  False / None    draw nothing                   a view object (has log_step/close): draw into it
  Visualization(target, max_drawn=...)  any of the above, drawing at most max_drawn particles
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from mazelab.contract import Density, Gaussian, NullView, Particles
from mazelab.kalman import covariance_ellipse
from mazelab.maze import Maze
from mazelab.model import CONFIDENCE_RADIUS
from mazelab.modes import Mode
from mazelab.registry import described
from mazelab.viz.recording import Recording, Visualization, heading_vectors
from mazelab.viz.style import (
    CELL_DOT_RADIUS,
    CONFIDENT_COLOR,
    COVARIANCE_LINE_RADIUS,
    COVARIANCE_SIGMAS,
    ESTIMATE_COLOR,
    INJECTED_COLOR,
    MAP,
    MODE_DRAWN_SHARE,
    MODE_LINE_RADIUS,
    MODE_MIN_RADIUS,
    PARTICLE_ARROW_LENGTH,
    PARTICLE_ARROW_RADIUS,
    SERIES,
    comparison_blueprint,
    entity_name,
    run_blueprint,
)


def open_recording(visualize: Any, world: Maze, blueprint: Callable[[], Any], label: str) -> tuple[Any, int]:
    """The Recording a `visualize` value asks for (None: nothing is drawn, or Rerun is switched off),
    laid out by `blueprint()` and named by `label`, and how many particles a step draws at most."""
    options = visualize if isinstance(visualize, Visualization) else Visualization(visualize)
    if options.target is None or options.target is False:
        return None, options.max_drawn
    return Recording.open(options.target, world, blueprint(), label=label, replace=options.replace), options.max_drawn


def open_view(visualize: Any, world: Maze, filter_name: str) -> Any:
    """The view one run draws to (see the `visualize` values above; a view itself is simulate's to pass on)."""
    layout = functools.partial(run_blueprint, world, filter_name)
    recording, max_drawn = open_recording(visualize, world, layout, entity_name(filter_name))
    return NullView() if recording is None else RunView(recording, filter_name, max_drawn, owns_recording=True)


def open_comparison(visualize: Any, world: Maze, filter_names: Sequence[str]) -> Comparison:
    """A recording for comparing `filter_names` side by side (see the `visualize` values above)."""
    names = list(dict.fromkeys(filter_names))
    if not names:
        raise ValueError("a comparison needs at least one filter")
    layout = functools.partial(comparison_blueprint, world, names)
    recording, max_drawn = open_recording(visualize, world, layout, "compare")
    return Comparison(recording, names, max_drawn)


class Comparison:
    """All filters of one scenario in one recording: one `RunView` per filter, the robot drawn once;
    without a recording (nothing drawn) a NullView per filter."""

    def __init__(self, recording: Recording | None, filter_names: Sequence[str], max_drawn: int):
        self.recording = recording
        self.views = {
            name: NullView() if recording is None else RunView(recording, name, max_drawn, owns_recording=False)
            for name in filter_names
        }

    def view_for(self, filter_name: str) -> Any:
        """The view that the run of `filter_name` draws to (one of the names the comparison was opened with)."""
        if filter_name not in self.views:
            raise ValueError(f"{filter_name!r} is not in this comparison ({', '.join(self.views)})")
        return self.views[filter_name]

    def close(self) -> None:
        """Finish the recording (file complete, viewer flushed, web viewer served until Ctrl-C)."""
        if self.recording is not None:
            self.recording.close()


# -- what one run draws ----------------------------------------------------------------------------
class RunView:
    """One filter's run drawn into a Rerun recording: its particles, estimate and time series."""

    def __init__(self, recording: Recording, filter_name: str, max_drawn: int, *, owns_recording: bool):
        import rerun as rr

        self.recording, self.name, self.max_drawn = recording, filter_name, max_drawn
        self.owns_recording = owns_recording
        self.metric = entity_name(filter_name)
        self.path = f"{MAP}/{self.metric}"
        self.color = described(filter_name).colour  # each filter in its registry colour, as in the figures
        self.count_series_styled = False
        style = rr.SeriesLines(names=filter_name, colors=self.color, widths=2)
        for series in SERIES:
            recording.stream.log(f"/metrics/{series}/{self.metric}", style, static=True)

    def expect_kidnapping(self, step: int, position: Sequence[float]) -> None:
        """The robot will be carried to `position` at step `step`: its recording draws the jump."""
        self.recording.kidnapping = (step, (float(position[0]), float(position[1])))

    def log_step(self, step: int, robot_position: Sequence[float], robot_heading: float | None, state: Any) -> None:
        """Draw step `step`: the robot (once per recording), the particles coloured by weight (the
        injected ones apart) or a Gaussian's covariance ellipse, the estimate's circle (green when
        confident), and the error, ESS and confidence series; with KLD-sampling, the particle count
        beside the ESS."""
        import rerun as rr

        stream = self.recording.stream
        stream.set_time("step", sequence=step)
        self.recording.log_robot(step, robot_position, robot_heading)
        belief = state.belief()
        if isinstance(belief, Gaussian):  # the EKF's: a polygon (rerun's Ellipses2D cannot be rotated)
            outline = covariance_ellipse(np.asarray(belief.mean), np.asarray(belief.covariance), COVARIANCE_SIGMAS)
            strip = rr.LineStrips2D([outline], colors=self.color, radii=COVARIANCE_LINE_RADIUS)
            stream.log(f"{self.path}/covariance", strip)
        else:
            self.log_particles(belief)
        estimate, confident = np.asarray(state.estimate, dtype=float), bool(state.is_confident)
        circle = rr.Ellipses2D(
            centers=[estimate],
            half_sizes=[[CONFIDENCE_RADIUS] * 2],
            colors=CONFIDENT_COLOR if confident else ESTIMATE_COLOR,
            line_radii=0.03,
        )
        stream.log(f"{self.path}/estimate", circle)
        if not isinstance(belief, Gaussian) and belief.modes is not None:
            self.log_modes(belief.modes)
        error = float(np.hypot(*(estimate - np.asarray(robot_position, dtype=float))))
        stream.log(f"/metrics/error/{self.metric}", rr.Scalars(error))
        ess = float(state.ess)
        if not math.isnan(ess):  # the grid filter is not a sample: no ESS
            stream.log(f"/metrics/ess/{self.metric}", rr.Scalars(ess))
        stream.log(f"/metrics/confident/{self.metric}", rr.Scalars(float(confident)))
        if isinstance(belief, Particles) and belief.count_varies:  # KLD-sampling: N in the ESS panel (ESS <= N)
            path = f"/metrics/ess/{self.metric}/particle_count"
            if not self.count_series_styled:
                self.count_series_styled = True
                stream.log(path, rr.SeriesLines(names=f"{self.name} N", colors=self.color, widths=1), static=True)
            stream.log(path, rr.Scalars(float(state.count)))

    def log_particles(self, belief: Particles | Density) -> None:
        """What is drawn of a filter's belief: arrows along the particles' headings (dots without), coloured
        by weight (blue to red), INJECTED_COLOR for the particles that recovery injected this step.

        Particles: all N when N <= max_drawn, else max_drawn of them at evenly spaced indices
        (deterministic: drawing never draws from the filter's random stream). A Density (the grid
        filter's cells, which are not a sample): the cells hit by a systematic pick of max_drawn points
        of its mass, each cell once, so the dots show where the probability is.
        """
        import rerun as rr

        weights, positions = np.asarray(belief.weights), np.asarray(belief.positions)
        picked: slice | np.ndarray = slice(None)
        headings = injected = None  # a Density has neither: its cells are drawn as dots
        if isinstance(belief, Density):
            cumulative = np.cumsum(weights)
            targets = (np.arange(self.max_drawn) + 0.5) / self.max_drawn * cumulative[-1]
            picked = np.unique(np.minimum(np.searchsorted(cumulative, targets), len(weights) - 1))
        else:
            headings, injected = belief.headings, belief.injected
            if len(positions) > self.max_drawn:
                picked = np.linspace(0, len(positions) - 1, self.max_drawn).round().astype(np.int64)
        shown = weights[picked]  # coloured from blue (weight 0) to red (the largest weight), linear in w / max w
        top = shown.max() if len(shown) else 0.0
        t = shown / top if top > 0 else np.zeros_like(shown)
        colors = np.column_stack([255 * t, np.zeros_like(t), 255 * (1 - t)]).astype(np.uint8)
        if injected is not None:  # a mask over all N particles
            colors[np.asarray(injected)[picked]] = INJECTED_COLOR
        if headings is None:
            drawn = rr.Points2D(positions[picked], colors=colors, radii=CELL_DOT_RADIUS)
        else:
            vectors = heading_vectors(np.asarray(headings)[picked], PARTICLE_ARROW_LENGTH)
            drawn = rr.Arrows2D(origins=positions[picked], vectors=vectors, colors=colors, radii=PARTICLE_ARROW_RADIUS)
        self.recording.stream.log(f"{self.path}/particles", drawn)

    def log_modes(self, modes: Sequence[Mode]) -> None:
        """Each mode holding more than MODE_DRAWN_SHARE of the weight: a circle in the filter's colour
        (radius its spread, at least MODE_MIN_RADIUS) labelled with its weight, so the hypotheses show."""
        import rerun as rr

        shown = [m for m in modes if m.weight > MODE_DRAWN_SHARE]
        circles = rr.Ellipses2D(
            centers=[m.mean for m in shown],
            half_sizes=[[max(m.spread, MODE_MIN_RADIUS)] * 2 for m in shown],
            colors=self.color,
            line_radii=MODE_LINE_RADIUS,
            labels=[f"{m.weight:.0%}" for m in shown],
            show_labels=True,
        )
        self.recording.stream.log(f"{self.path}/modes", circles)

    def close(self) -> None:
        """Finish the recording if this run owns it (a comparison's views leave it open)."""
        if self.owns_recording:
            self.recording.close()
        else:
            self.recording.stream.flush()
