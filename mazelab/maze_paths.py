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
    """A maze file path, or the name of a file in mazes/ (with or without .txt), from any folder
    (`find_shipped`); a bare name that is no shipped maze is refused, naming them."""
    return find_shipped(name_or_path, MAZES_DIR, ".txt", "maze", MazeError, bare_names=True)


def find_shipped(
    name_or_path: str | Path, folder: Path, suffix: str, what: str, error: type[ValueError], bare_names: bool = False
) -> Path:
    """A file's path, or the name of a shipped one in `folder` (with or without `suffix`), from any folder:
    a file in the current folder comes first. A path that does not exist but ends in a shipped file's name
    (`mazes/paper_5x5.txt` typed in another folder) is refused with the name that works everywhere
    (`paper_5x5`); with `bare_names`, so is a bare name that is no shipped file. Else the path as given
    (its reader reports it missing)."""
    path = Path(name_or_path)
    if path.exists():
        return path
    shipped = sorted(p.stem for p in folder.glob(f"*{suffix}"))
    if path.parent == Path("."):
        for candidate in (folder / path.name, folder / f"{path.name}{suffix}"):
            if candidate.is_file():
                return candidate
        if bare_names and shipped:
            raise error(f"{path}: no such {what} file, nor a {what} in {folder.name}/ ({', '.join(shipped)})")
    elif path.stem in shipped and path.suffix in ("", suffix):
        raise error(
            f"{path}: no such {what} file in {Path.cwd()}; {path.stem} is a shipped {what}: "
            f"name it {path.stem!r} (without a folder) to use it from any folder"
        )
    return path
