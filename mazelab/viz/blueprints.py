"""The viewer layouts: one run, and the comparison of several filters side by side."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from mazelab.maze import Maze
from mazelab.viz.style import MAP, SERIES, entity_name

# The step panel stands for the paper's window title. Its share of the column's height: the panel's
# header and one line of heading text need about 110 pixels, and the viewer's default layout in a
# 1400 x 900 browser window leaves some 620 pixels for the column (checked on a screenshot of the
# web viewer in headless Chromium); 1 in 10 cut the text in half.
STEP_PANEL_SHARE = 0.18
# Where the legend of an error plot goes: the errors are large over the first steps, where the filters
# still search and their curves differ (the left, up to the top), then small; the top right corner is
# the part of the plot that no curve reaches once the robot is found (the default, top left, hid the
# search).
ERROR_LEGEND_CORNER = "RightTop"


# -- layouts ---------------------------------------------------------------------------------------
def map_view(world: Maze, filter_name: str) -> Any:
    """A 2-D view of the maze, the robot and one filter's particles and estimate, the whole map in sight."""
    import rerun.blueprint as rrb

    margin = 0.5
    return rrb.Spatial2DView(
        name=filter_name,
        origin="/",
        contents=[f"{MAP}/maze", f"{MAP}/stations", f"{MAP}/robot/**", f"{MAP}/{entity_name(filter_name)}/**"],
        visual_bounds=rrb.VisualBounds2D(
            x_range=[-margin, world.width + margin], y_range=[-margin, world.height + margin]
        ),
    )


def run_blueprint(world: Maze, filter_name: str) -> Any:
    """One run: the step number over the maze view; the error, ESS and confidence series beside it."""
    import rerun.blueprint as rrb

    series = [series_view(s) for s in SERIES]
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Vertical(
                rrb.TextDocumentView(name="step", origin="/title"),
                map_view(world, filter_name),
                row_shares=[STEP_PANEL_SHARE, 1 - STEP_PANEL_SHARE],
            ),
            rrb.Vertical(*series),
            column_shares=[3, 2],
        )
    )


def comparison_blueprint(world: Maze, filter_names: Sequence[str]) -> Any:
    """The lab's comparison: one maze view per filter side by side, every filter's error below."""
    import rerun.blueprint as rrb

    return rrb.Blueprint(
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
    return rrb.TimeSeriesView(name=SERIES_TITLES[series], origin=f"/metrics/{series}", plot_legend=legend)


SERIES_TITLES = {
    "error": "error |estimate - truth|",
    "ess": "effective sample size (and N with KLD-sampling)",
    "confident": "confident (95% within the circle)",
}


__all__ = [
    "ERROR_LEGEND_CORNER",
    "SERIES_TITLES",
    "STEP_PANEL_SHARE",
    "comparison_blueprint",
    "map_view",
    "run_blueprint",
    "series_view",
]
