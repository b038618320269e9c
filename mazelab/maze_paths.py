"""Where the shipped mazes are (the folder mazes/ at the top of the repository), by name or path,
and the error a maze that cannot be used raises. Below mazelab.maze, which reads the files."""

from __future__ import annotations

from pathlib import Path


class MazeError(ValueError):
    """A maze map or maze file that cannot be used; the message names the problem (and file:line)."""


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


__all__ = ["DEFAULT_MAZE", "LAB_MAZES", "MAZES_DIR", "MazeError", "find_maze", "shipped_mazes"]
