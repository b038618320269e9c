"""How the lab is drawn: colours, sizes and entity paths shared by every view, and the viewer's layouts
(one run; the comparison of several filters side by side)."""

from __future__ import annotations

import re
from collections.abc import Sequence
from typing import Any

from mazelab.maze import Maze
from mazelab.model import CONFIDENCE_RADIUS

DEFAULT_MAX_DRAWN = 5000  # particles drawn per step at most; the filter keeps all of them
APPLICATION_ID = "maze_particle_filter_lab"
MAP = "/map"  # everything drawn in the map frame lives under this entity
FREE_COLOR, WALL_COLOR = (255, 255, 255), (0, 0, 0)
STATION_COLOR, ROBOT_COLOR = (0, 200, 255), (0, 170, 0)
ESTIMATE_COLOR, CONFIDENT_COLOR = (128, 128, 128), (0, 200, 0)
INJECTED_COLOR = (255, 190, 0)  # particles injected by recovery this step (weights are drawn blue..red)
KIDNAP_COLOR = (230, 0, 200)  # the jump of a kidnapped robot
PARTICLE_ARROW_LENGTH, ROBOT_ARROW_LENGTH = 0.15, 0.5  # map units
STATION_RADIUS, ROBOT_RADIUS, PARTICLE_ARROW_RADIUS, CELL_DOT_RADIUS = 0.08, 0.12, 0.008, 0.03
COVARIANCE_SIGMAS, COVARIANCE_LINE_RADIUS = 2.0, 0.02  # the EKF's ellipse: 2-sigma (86% of a 2-D Gaussian)
MODE_DRAWN_SHARE = 0.05  # modes holding more than this share of the weight are drawn, each a labelled circle
MODE_MIN_RADIUS, MODE_LINE_RADIUS = 0.25, 0.02  # a mode's circle: its spread, at least this (map units)
SERIES = {  # the time series under /metrics/<series>/<filter>, and their panels' titles
    "error": "error |estimate - truth|",
    "ess": "effective sample size (and N with KLD-sampling)",
    "confident": "confident (95% within the circle)",
}
# The map views show the map and around it room for the estimate's circle (radius CONFIDENCE_RADIUS)
# and its line when the estimate lies on the map's edge; a mode's label ("100%") sits above its circle.
MAP_MARGIN = CONFIDENCE_RADIUS + 0.25
# The step panel stands for the paper's window title. Its share of the column's height: the panel's
# header and one line of heading text need about 110 pixels, and the layout in a 1400 x 900 browser
# window leaves some 620 pixels for the column (checked on a screenshot of the web viewer in headless
# Chromium); 1 in 10 cut the text in half.
STEP_PANEL_SHARE = 0.18
# Where the legend of an error plot goes: the errors are large over the first steps, where the filters
# still search and their curves differ (the left, up to the top), then small; the top right corner is
# the part of the plot that no curve reaches once the robot is found (the default, top left, hid the search).
ERROR_LEGEND_CORNER = "RightTop"


def entity_name(filter_name: str) -> str:
    """A filter's name as an entity-path part: "SIRParticleFilter" -> "sir_particle_filter"."""
    spaced = re.sub(r"(?<=[a-z0-9])(?=[A-Z])|(?<=[A-Z])(?=[A-Z][a-z])", "_", str(filter_name).strip())
    return re.sub(r"[^a-z0-9]+", "_", spaced.lower()).strip("_") or "filter"


# -- layouts ---------------------------------------------------------------------------------------
def lab_blueprint(root: Any) -> Any:
    """The viewer with the lab's panels only: Rerun's own side panels (the blueprint tree, the
    selection) collapsed, which at 1400 x 900 took about 45% of the window from the maps, and the time
    panel reduced to its play button and slider on the step timeline."""
    import rerun.blueprint as rrb

    return rrb.Blueprint(root, rrb.TimePanel(state="collapsed", timeline="step"), collapse_panels=True)


def map_view(world: Maze, filter_name: str) -> Any:
    """A 2-D view of the maze, the robot and one filter's particles and estimate, the whole map in sight
    with MAP_MARGIN around it."""
    import rerun.blueprint as rrb

    return rrb.Spatial2DView(
        name=filter_name,
        origin="/",
        contents=[f"{MAP}/maze", f"{MAP}/stations", f"{MAP}/robot/**", f"{MAP}/{entity_name(filter_name)}/**"],
        visual_bounds=rrb.VisualBounds2D(
            x_range=[-MAP_MARGIN, world.width + MAP_MARGIN], y_range=[-MAP_MARGIN, world.height + MAP_MARGIN]
        ),
    )


def run_blueprint(world: Maze, filter_name: str) -> Any:
    """One run: the step number over the maze view; the error, ESS and confidence series beside it."""
    import rerun.blueprint as rrb

    return lab_blueprint(
        rrb.Horizontal(
            rrb.Vertical(
                rrb.TextDocumentView(name="step", origin="/title"),
                map_view(world, filter_name),
                row_shares=[STEP_PANEL_SHARE, 1 - STEP_PANEL_SHARE],
            ),
            rrb.Vertical(*[series_view(series) for series in SERIES]),
            column_shares=[3, 2],
        )
    )


def comparison_blueprint(world: Maze, filter_names: Sequence[str]) -> Any:
    """The lab's comparison: one maze view per filter side by side, every filter's error below."""
    import rerun.blueprint as rrb

    return lab_blueprint(
        rrb.Vertical(
            rrb.TextDocumentView(name="step", origin="/title"),
            rrb.Horizontal(*[map_view(world, name) for name in filter_names]),
            series_view("error"),
            row_shares=[STEP_PANEL_SHARE, (1 - STEP_PANEL_SHARE) * 2 / 3, (1 - STEP_PANEL_SHARE) / 3],
        )
    )


def series_view(series: str) -> Any:
    """The plot of one series over the steps (every filter's curve in it); the error's legend out of the
    way of the first steps (ERROR_LEGEND_CORNER)."""
    import rerun.blueprint as rrb

    legend = getattr(rrb.Corner2D, ERROR_LEGEND_CORNER) if series == "error" else None
    return rrb.TimeSeriesView(name=SERIES[series], origin=f"/metrics/{series}", plot_legend=legend)
