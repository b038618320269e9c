"""The shipped mazes (the folder mazes/ at the top of the repository), found by name or path."""

from __future__ import annotations

from pathlib import Path

from mazelab.maze import Maze

MAZES_DIR = Path(__file__).resolve().parent.parent / "mazes"  # the repository's mazes/ (an editable install)
DEFAULT_MAZE = "maze_10x10"


def find_maze(name_or_path: str) -> Path:
    """A maze file path, or the name of a file in mazes/ (with or without .txt)."""
    path = Path(name_or_path)
    if path.exists():
        return path
    for candidate in (MAZES_DIR / name_or_path, MAZES_DIR / f"{name_or_path}.txt"):
        if candidate.exists():
            return candidate
    return path  # Maze.from_file reports it missing


def load_maze(name_or_path: str) -> Maze:
    return Maze.from_file(find_maze(name_or_path))


__all__ = [
    "DEFAULT_MAZE",
    "MAZES_DIR",
    "find_maze",
    "load_maze",
]
