"""The shipped mazes (the folder mazes/ at the top of the repository), found by name or path."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from mazelab.maze import Maze, MazeError

MAZES_DIR = Path(__file__).resolve().parent.parent / "mazes"  # the repository's mazes/ (an editable install)
DEFAULT_MAZE = "maze_10x10"
# The mazes the lab ships, named: what `accuracy` runs on by default (a maze a student adds to mazes/
# is found by its name too, but does not change the lab's default set).
LAB_MAZES = ("maze_10x10", "maze_20x20", "paper_5x5", "twin_rooms_6x12")


def shipped_mazes() -> list[str]:
    """The names of the mazes in mazes/ (file names without .txt), sorted."""
    return sorted(path.stem for path in MAZES_DIR.glob("*.txt"))


def find_maze(name_or_path: str | Path) -> Path:
    """A maze file path, or the name of a file in mazes/ (with or without .txt), from any folder.

    A path that does not exist but ends in a shipped maze's file name (`mazes/paper_5x5.txt` typed in
    another folder) is refused with the name that works everywhere (`paper_5x5`)."""
    path = Path(name_or_path)
    if path.exists():
        return path
    if path.parent == Path("."):
        for candidate in (MAZES_DIR / path.name, MAZES_DIR / f"{path.name}.txt"):
            if candidate.is_file():
                return candidate
    if path.stem in shipped_mazes() and path.suffix in ("", ".txt"):
        raise MazeError(
            f"{path}: no such maze file in {Path.cwd()}; {path.stem} is a shipped maze: "
            f"name it {path.stem!r} (without a folder) to use it from any folder"
        )
    if path.parent == Path(".") and shipped_mazes():  # a bare name: perhaps a mistyped shipped maze
        raise MazeError(f"{path}: no such maze file, nor a maze in mazes/ ({', '.join(shipped_mazes())})")
    return path  # Maze.from_file reports it missing


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
