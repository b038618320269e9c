"""The maze of the lab: its grid, maze files, free area and stations, and the shipped mazes (the folder
mazes/ at the top of the repository), found by name or path.

Map frame (a convention the paper leaves open, fixed here): maze row 0 is the top row; the cell in
row r, column c of an H x W maze covers x in [c, c+1), y in [H-1-r, H-r), so the map spans
[0, W] x [0, H] with y pointing up.
Cell values: 0 empty, 1 wall, 2 wall with a station at each of its four corners.
"""

from __future__ import annotations

import copy
import math
from collections.abc import Sequence
from functools import cached_property
from pathlib import Path
from typing import Any

import numpy as np

from mazelab.checks import BYTES_PER_LOOKUP_CELL, BYTES_PER_MAZE_CELL, MAX_MAZE_SIDE, check_memory, read_text_file
from mazelab.lookup import NearestStationLookup, Progress, lookup_cell_count


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


def load_maze(name_or_path: str | Path) -> Maze:
    """The maze of a file, or of a shipped maze's name (`Maze.from_file`)."""
    return Maze.from_file(name_or_path)


def mazes_fitting(start: Sequence[float], particles: np.ndarray) -> list[str]:
    """The shipped mazes in whose free area the robot's start and every particle lie (a scenario
    that stores no maze was made on one of these)."""
    points = np.vstack([np.asarray(start, dtype=float).reshape(1, 2), np.asarray(particles, dtype=float)])
    return [name for name in shipped_mazes() if np.all(load_maze(name).is_free(points[:, 0], points[:, 1]))]


EMPTY, WALL, STATION_WALL = 0, 1, 2
# At most MAX_MAZE_SIDE rows and columns: the nearest-station table's flat cell indices stay exact in
# float32 ((4000 + 4)**2 < 2**24) and float32 particle positions resolve 2**-11 map units.
# A maze file larger than this is refused, not read: room for the largest maze written with ", "
# between cells (3 bytes a cell, 48 MB), comments included.
MAZE_FILE_LIMIT_BYTES = 64 * 2**20


BYTES_PER_DRAWN_POINT = 64  # random_free_places: the cell indices, the cells and the offsets per point


class Maze:
    """A rectangular maze of 0/1/2 cells: free area, walls, stations and nearest-station distances.

    `maze_map` is any rectangular nested sequence (tuple of tuples, list of lists, numpy array).
    A Maze does not change once built: its arrays are read-only and its attributes cannot be
    reassigned, so every filter handed one maze sees the same map (a plug-in gets its own `copy`).
    """

    def __init__(self, maze_map: Sequence[Sequence[int]] | np.ndarray, *, source: str = "maze map"):
        state = self.__dict__
        state["grid"] = _validate_grid(maze_map, source)
        state["source"] = source
        state["height"], state["width"] = self.grid.shape
        # the stations: the four corners of every station block, in map coordinates, each point once (B, 2)
        rows, columns = np.nonzero(self.grid == STATION_WALL)
        corners = {
            (int(c + dx), int(self.height - 1 - r + dy))
            for r, c in zip(rows, columns, strict=True)
            for dx in (0, 1)
            for dy in (0, 1)
        }
        state["stations"] = np.array(sorted(corners), dtype=float)
        rows, columns = np.nonzero(self.grid == EMPTY)  # the free cells' lower-left corners (x, y), (F, 2)
        state["free_cells"] = np.column_stack([columns, self.height - 1 - rows]).astype(float)
        _read_only(self)

    def __setattr__(self, name: str, value: Any) -> None:
        raise AttributeError(f"a Maze does not change once built: cannot set {name!r} (make a new Maze)")

    def __setstate__(self, state: dict[str, Any]) -> None:
        """Unpickled (a worker process's copy): read-only again (numpy unpickles arrays writeable)."""
        self.__dict__.update(state)
        _read_only(self)

    def __delattr__(self, name: str) -> None:
        raise AttributeError(f"a Maze does not change once built: cannot delete {name!r}")

    def copy(self) -> Maze:
        """A maze equal to this one that shares no array with it (its nearest-station table too, if
        built): what a filter that is not the lab's is handed, so that whatever it does to its maze
        cannot reach the others' (a read-only maze already refuses the writes of ordinary code)."""
        return copy.deepcopy(self)  # __setstate__ makes the copy read-only

    # -- loading ---------------------------------------------------------------------------------
    @classmethod
    def from_file(cls, path: str | Path) -> Maze:
        """Read a maze text file: one row per line, cells 0/1/2 (spaces optional), '#' comments; a
        shipped maze also by its name from any folder (`Maze.from_file("paper_5x5")`)."""
        path = find_maze(path)
        try:
            text = read_text_file(path, "maze", "text", MazeError, limit=MAZE_FILE_LIMIT_BYTES)
        except FileNotFoundError:
            raise MazeError(f"{path}: no such maze file") from None
        if text.lstrip().startswith("{"):
            raise MazeError(f"{path}: looks like a saved scenario (json), not a maze; replay it with run --scenario")
        return cls(parse_maze_text(text, source=str(path)), source=str(path))

    def to_text(self) -> str:
        """The maze in the file format of `from_file` (one row per line, cells separated by spaces)."""
        return "".join(" ".join(str(v) for v in row) + "\n" for row in self.grid.tolist())

    def as_lists(self) -> list[list[int]]:
        """The grid as a list of lists of ints (for json)."""
        return self.grid.tolist()

    @cached_property
    def _lookup(self) -> NearestStationLookup:
        """The nearest-station table, built on first use (a few ms; about a second for 100 x 100)."""
        return self.prepare().__dict__["_lookup"]

    def prepare(self, progress: Progress | None = None) -> Maze:
        """Build the nearest-station table now rather than on first use, calling `progress(done, total)`
        as it goes (a 1000 x 1000 maze takes tens of seconds), refused up front if it would not fit in
        memory. Returns the maze."""
        if not self.has_lookup:
            what = f"the nearest-station table of the {self.height}x{self.width} maze ({self.source})"
            check_memory(what, self.lookup_cells * BYTES_PER_LOOKUP_CELL)
            self.__dict__["_lookup"] = NearestStationLookup(self.stations, self.grid == EMPTY, progress)
            _read_only(self._lookup)
        return self

    @property
    def has_lookup(self) -> bool:
        """Whether the nearest-station table is built already."""
        return "_lookup" in self.__dict__

    @property
    def lookup_cells(self) -> int:
        """The size of the nearest-station table, in lookup cells (what its build time grows with)."""
        return lookup_cell_count(self.width, self.height)

    # -- geometry --------------------------------------------------------------------------------
    def is_free(self, x: Any, y: Any) -> bool | np.ndarray:
        """True where (x, y) lies in [0, W) x [0, H) in a cell of type 0; vectorised over arrays."""
        if _is_scalar(x) and _is_scalar(y):
            return self.free_at(float(x), float(y))
        x = np.asarray(x, dtype=float)
        y = np.asarray(y, dtype=float)
        inside = (x >= 0) & (x < self.width) & (y >= 0) & (y < self.height)
        col = np.floor(np.where(inside, x, 0.0)).astype(np.int64)  # the cell (row, col) of each point
        row = self.height - 1 - np.floor(np.where(inside, y, 0.0)).astype(np.int64)
        free = inside & (self.grid[row, col] == EMPTY)
        return bool(free) if free.ndim == 0 else free

    def free_at(self, x: float, y: float) -> bool:
        """`is_free` for one point in plain floats, without its dispatch (the robot's wall checks,
        several a step)."""
        if not (0 <= x < self.width and 0 <= y < self.height):
            return False
        return self._free_rows[self.height - 1 - math.floor(y)][math.floor(x)]

    @cached_property
    def _free_rows(self) -> list[list[bool]]:
        return (self.grid == EMPTY).tolist()

    def random_free_place(self, rng: np.random.Generator | None = None) -> tuple[float, float]:
        """One point drawn uniformly from the free area, as (x, y)."""
        x, y = self.random_free_places(1, rng)[0]
        return float(x), float(y)

    def random_free_places(self, count: int, rng: np.random.Generator | None = None) -> np.ndarray:
        """`count` points drawn uniformly from the free area, shape (count, 2).

        Every free cell has area 1, so a uniform cell then a uniform offset inside it is uniform.
        A count that is not a whole number >= 0 (1.5, True, -1) is a TypeError or ValueError, and one
        whose arrays would not fit in memory (10**12) a MemoryLimitError (a ValueError): one line each.
        """
        if isinstance(count, bool) or not isinstance(count, (int, np.integer)):
            raise TypeError(f"random_free_places: count must be a whole number, got {count!r}")
        if count < 0:
            raise ValueError(f"random_free_places: count must be >= 0, got {count}")
        check_memory(f"random_free_places({count})", int(count) * BYTES_PER_DRAWN_POINT)
        rng = np.random.default_rng() if rng is None else rng
        cells = self.free_cells[rng.integers(len(self.free_cells), size=count)]
        return cells + rng.random((count, 2))

    def distance_to_nearest_station(self, x: Any, y: Any | None = None) -> float | np.ndarray:
        """Euclidean distance from each point to its nearest station (map units).

        Call as `distance_to_nearest_station(x, y)` with scalars or arrays of one shape, or with a
        single array of points of shape (..., 2).
        """
        if y is not None and _is_scalar(x) and _is_scalar(y):
            return self.distance_at(float(x), float(y))
        points = _point_array(x) if y is None else np.stack(np.broadcast_arrays(x, y), -1).astype(float)
        flat = points.reshape(-1, 2)
        distances = self.station_distances_and_free(flat[:, 0], flat[:, 1])[0].reshape(points.shape[:-1])
        return float(distances) if distances.ndim == 0 else distances

    def distance_at(self, x: float, y: float) -> float:
        """`distance_to_nearest_station` of one point in plain floats, without its dispatch (the
        robot's measurement, once a step): the same value."""
        return self._lookup.station_at(x, y)[1]

    def nearest_station(self, points: Any) -> np.ndarray:
        """Coordinates of the station nearest each point: points (..., 2) -> (..., 2), map units.
        The station whose distance `distance_to_nearest_station` gives (the EKF's data association, one
        mean a step): each point's from the lookup in plain floats (`NearestStationLookup.station_at`)."""
        points = _point_array(points)
        nearest = [self._lookup.station_at(x, y)[0] for x, y in points.reshape(-1, 2).tolist()]
        return self.stations[nearest].reshape(points.shape)

    def station_distances_and_free(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Distance to the nearest station and the free flag of each point, both from one cell lookup:
        x, y of shape (N,) and one float dtype (float32 particles are computed in float32)."""
        return self._lookup.locate(x, y)

    def __repr__(self) -> str:
        return f"Maze({self.height}x{self.width}, {len(self.stations)} stations, source={self.source!r})"


# -- validation and parsing ----------------------------------------------------------------------
def check_maze_size(rows: int, columns: int, source: str | None = None) -> None:
    """Refuse, before anything is allocated, a maze beyond MAX_MAZE_SIDE or one whose grid and
    nearest-station table would not fit in memory (`source` names the file, if any)."""
    where = f"{source}: " if source else ""
    if rows > MAX_MAZE_SIDE or columns > MAX_MAZE_SIDE:
        raise MazeError(
            f"{where}a {rows}x{columns} maze is too large: at most {MAX_MAZE_SIDE} rows and {MAX_MAZE_SIDE} columns"
        )
    needed = rows * columns * BYTES_PER_MAZE_CELL + lookup_cell_count(columns, rows) * BYTES_PER_LOOKUP_CELL
    check_memory(f"{where}a {rows}x{columns} maze", needed)


def _validate_grid(maze_map: Any, source: str) -> np.ndarray:
    """Check the map is rectangular, non-empty, of 0/1/2 with a free cell and a station."""
    if isinstance(maze_map, np.ndarray):
        if maze_map.ndim != 2:
            raise MazeError(f"{source}: a maze must be 2-D, got an array of {maze_map.ndim} dimension(s)")
        check_maze_size(*maze_map.shape, source=source)
        rows = maze_map.tolist()
    else:
        try:
            rows = [list(row) for row in maze_map]
        except TypeError:
            raise MazeError(f"{source}: a maze must be a nested sequence of rows of 0/1/2") from None
    if not rows or not rows[0]:
        raise MazeError(f"{source}: the maze is empty")
    width = len(rows[0])
    check_maze_size(len(rows), width, source)
    for r, row in enumerate(rows):
        if len(row) != width:
            raise MazeError(f"{source}: row {r + 1} has {len(row)} cells, row 1 has {width}: not rectangular")
        for c, value in enumerate(row):
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value not in (0, 1, 2):
                raise MazeError(f"{source}: row {r + 1}, column {c + 1} is {value!r}; cells must be 0, 1 or 2")
    grid = np.array(rows, dtype=np.int8)
    if not (grid == EMPTY).any():
        raise MazeError(f"{source}: the maze has no free cell (0)")
    if not (grid == STATION_WALL).any():
        raise MazeError(f"{source}: the maze has no station block (2)")
    return grid


def parse_maze_text(text: str, source: str = "maze text") -> list[list[int]]:
    """Parse the maze file format: a row per line of 0/1/2, spaces or commas optional, '#' comments."""
    rows: list[list[int]] = []
    for number, line in enumerate(text.splitlines(), start=1):
        content = line.split("#", 1)[0].replace(",", " ")
        cells = "".join(content.split())
        if not cells:
            continue
        bad = next((ch for ch in cells if ch not in "012"), None)
        if bad is not None:
            raise MazeError(f"{source}:{number}: {bad!r} is not a maze cell; use 0 (free), 1 (wall), 2 (station)")
        if len(rows) >= MAX_MAZE_SIDE or len(cells) > MAX_MAZE_SIDE:  # refused at this line, not after the rest
            check_maze_size(len(rows) + 1, len(cells), f"{source}:{number}")
        row = [int(ch) for ch in cells]
        if rows and len(row) != len(rows[0]):
            raise MazeError(
                f"{source}:{number}: {len(row)} cells where the first row has {len(rows[0])}: not rectangular"
            )
        rows.append(row)
    if not rows:
        raise MazeError(f"{source}: the maze is empty (no rows of 0/1/2)")
    return rows


# -- derived geometry ----------------------------------------------------------------------------
def _point_array(points: Any) -> np.ndarray:
    """Points of shape (..., 2) as floats, or one line saying what the Maze's methods take."""
    array = np.asarray(points, dtype=float)
    if array.ndim == 0 or array.shape[-1] != 2:
        raise ValueError(
            f"points must have shape (N, 2), one (x, y) each, or give x and y apart; got shape {array.shape}"
        )
    return array


def _is_scalar(value: Any) -> bool:
    return isinstance(value, (float, int, np.floating, np.integer)) and not isinstance(value, bool)


def _read_only(holder: Any) -> None:
    """Make every array attribute of `holder` (a Maze, its nearest-station table) read-only: a write
    into the map raises at the line that tries it instead of changing it for everyone else."""
    for value in vars(holder).values():
        if isinstance(value, np.ndarray):
            value.flags.writeable = False
        elif isinstance(value, NearestStationLookup):
            _read_only(value)


def check_world(world: Any) -> Maze:
    """A maze for a filter or a run: a Maze, or a one-line ValueError."""
    if not isinstance(world, Maze):
        raise ValueError(f"world must be a Maze (mazelab.maze.Maze or load_maze), got {type(world).__name__}")
    return world


__all__ = [
    "DEFAULT_MAZE",
    "EMPTY",
    "LAB_MAZES",
    "MAX_MAZE_SIDE",
    "MAZES_DIR",
    "MAZE_FILE_LIMIT_BYTES",
    "STATION_WALL",
    "WALL",
    "Maze",
    "MazeError",
    "check_maze_size",
    "check_world",
    "find_maze",
    "find_shipped",
    "load_maze",
    "mazes_fitting",
    "parse_maze_text",
    "shipped_mazes",
]
