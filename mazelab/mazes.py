"""The shipped mazes (the folder mazes/ at the top of the repository), loaded by name or path."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from mazelab.maze import Maze
from mazelab.maze_paths import DEFAULT_MAZE, LAB_MAZES, MAZES_DIR, find_maze, shipped_mazes


def load_maze(name_or_path: str) -> Maze:
    """The maze of a file, or of a shipped maze's name."""
    return Maze.from_file(find_maze(name_or_path))


def mazes_fitting(start: Sequence[float], particles: np.ndarray) -> list[str]:
    """The shipped mazes in whose free area the robot's start and every particle lie (a scenario
    that stores no maze was made on one of these)."""
    points = np.vstack([np.asarray(start, dtype=float).reshape(1, 2), np.asarray(particles, dtype=float)])
    return [name for name in shipped_mazes() if np.all(load_maze(name).is_free(points[:, 0], points[:, 1]))]


__all__ = [
    "DEFAULT_MAZE",
    "LAB_MAZES",
    "MAZES_DIR",
    "find_maze",
    "load_maze",
    "mazes_fitting",
    "shipped_mazes",
]
