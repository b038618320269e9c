"""The maze and its drawing, as the paper names them: `from draw import Maze`.

Rerun replaces the paper's turtle window. This file only gathers the names; where the lines are:

    Maze (the grid, maze files, free area, stations)     mazelab/maze.py
    the nearest-station distance of every particle       mazelab/lookup.py
    what a run draws (particles, estimate, series)       mazelab/viz/views.py, RunView.log_step
    where a recording goes (viewer, file, web, notebook) mazelab/viz/recording.py
    the colours and the viewer's layouts                 mazelab/viz/style.py
"""

from mazelab.contract import NullView
from mazelab.maze import EMPTY, STATION_WALL, WALL, Maze, MazeError, parse_maze_text
from mazelab.viz.recording import Recording, Visualization, heading_vectors
from mazelab.viz.style import DEFAULT_MAX_DRAWN
from mazelab.viz.views import Comparison, RunView, open_comparison, open_view

__all__ = [
    "DEFAULT_MAX_DRAWN",
    "EMPTY",
    "STATION_WALL",
    "WALL",
    "Comparison",
    "Maze",
    "MazeError",
    "NullView",
    "Recording",
    "RunView",
    "Visualization",
    "heading_vectors",
    "open_comparison",
    "open_view",
    "parse_maze_text",
]
