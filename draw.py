"""The maze of the lab: its grid, free area, stations and distances, and drawing it.

Map frame (lab-spec.md): maze row 0 is the top row; the cell in row r, column c of an H x W maze
covers x in [c, c+1), y in [H-1-r, H-r), so the map spans [0, W] x [0, H] with y pointing up.
Cell values: 0 empty, 1 wall, 2 wall with a station at each of its four corners.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

EMPTY, WALL, STATION_WALL = 0, 1, 2
MAZE_FILE_LIMIT_BYTES = 1_000_000  # a maze file larger than this is refused, not read
# Points up to this many cells beyond the map's border use the fast nearest-station lookup;
# points farther out (rare: particles only drift out by a step length at a time) use brute force.
_LOOKUP_MARGIN_CELLS = 2


class MazeError(ValueError):
    """A maze map or maze file that cannot be used; the message names the problem (and file:line)."""


class Maze:
    """A rectangular maze of 0/1/2 cells: free area, walls, stations and nearest-station distances.

    `maze_map` is any rectangular nested sequence (tuple of tuples, list of lists, numpy array).
    """

    def __init__(self, maze_map: Sequence[Sequence[int]] | np.ndarray, *, source: str = "maze map"):
        self.grid = _validate_grid(maze_map, source)
        self.source = source
        self.height, self.width = self.grid.shape
        self.stations = _station_corners(self.grid)
        self.free_cells = _free_cell_origins(self.grid)
        self._lookup = _NearestStationLookup(self.stations, self.width, self.height)

    # -- loading ---------------------------------------------------------------------------------
    @classmethod
    def from_file(cls, path: str | Path) -> Maze:
        """Read a maze text file: one row per line, cells 0/1/2 (spaces optional), '#' comments."""
        path = Path(path)
        return cls(parse_maze_text(_read_maze_file(path), source=str(path)), source=str(path))

    def to_text(self) -> str:
        """The maze in the file format of `from_file` (one row per line, cells separated by spaces)."""
        return "".join(" ".join(str(v) for v in row) + "\n" for row in self.grid.tolist())

    def as_lists(self) -> list[list[int]]:
        """The grid as a list of lists of ints (for json)."""
        return self.grid.tolist()

    # -- geometry --------------------------------------------------------------------------------
    @property
    def free_area(self) -> float:
        """Area of the free space in square map units (each free cell is 1 x 1)."""
        return float(len(self.free_cells))

    def cell_of(self, x: Any, y: Any) -> tuple[np.ndarray, np.ndarray]:
        """(row, column) indices of the cells containing the points; may lie outside the grid."""
        col = np.floor(np.asarray(x, dtype=float)).astype(np.int64)
        row = self.height - 1 - np.floor(np.asarray(y, dtype=float)).astype(np.int64)
        return row, col

    def is_free(self, x: Any, y: Any) -> bool | np.ndarray:
        """True where (x, y) lies in [0, W) x [0, H) in a cell of type 0; vectorised over arrays."""
        x = np.asarray(x, dtype=float)
        y = np.asarray(y, dtype=float)
        inside = (x >= 0) & (x < self.width) & (y >= 0) & (y < self.height)
        row, col = self.cell_of(np.where(inside, x, 0.0), np.where(inside, y, 0.0))
        free = inside & (self.grid[row, col] == EMPTY)
        return bool(free) if free.ndim == 0 else free

    def random_free_place(self, rng: np.random.Generator | None = None) -> tuple[float, float]:
        """One point drawn uniformly from the free area, as (x, y)."""
        x, y = self.random_free_places(1, rng)[0]
        return float(x), float(y)

    def random_free_places(self, count: int, rng: np.random.Generator | None = None) -> np.ndarray:
        """`count` points drawn uniformly from the free area, shape (count, 2).

        Every free cell has area 1, so a uniform cell then a uniform offset inside it is uniform.
        """
        rng = np.random.default_rng() if rng is None else rng
        cells = self.free_cells[rng.integers(len(self.free_cells), size=count)]
        return cells + rng.random((count, 2))

    def distance_to_nearest_station(self, x: Any, y: Any | None = None) -> float | np.ndarray:
        """Euclidean distance from each point to its nearest station (map units).

        Call as `distance_to_nearest_station(x, y)` with scalars or arrays of one shape, or with a
        single array of points of shape (..., 2).
        """
        points = np.asarray(x, dtype=float) if y is None else np.stack(np.broadcast_arrays(x, y), -1)
        points = np.asarray(points, dtype=float)
        flat = points.reshape(-1, 2)
        distances = self._lookup.distances(flat).reshape(points.shape[:-1])
        return float(distances) if distances.ndim == 0 else distances

    def __repr__(self) -> str:
        return f"Maze({self.height}x{self.width}, {len(self.stations)} stations, source={self.source!r})"


# -- validation and parsing ----------------------------------------------------------------------
def _validate_grid(maze_map: Any, source: str) -> np.ndarray:
    """Check the map is rectangular, non-empty, of 0/1/2 with a free cell and a station."""
    if isinstance(maze_map, np.ndarray):
        rows = maze_map.tolist() if maze_map.ndim == 2 else None
        if rows is None:
            raise MazeError(f"{source}: a maze must be 2-D, got an array of {maze_map.ndim} dimension(s)")
    else:
        try:
            rows = [list(row) for row in maze_map]
        except TypeError:
            raise MazeError(f"{source}: a maze must be a nested sequence of rows of 0/1/2") from None
    if not rows or not rows[0]:
        raise MazeError(f"{source}: the maze is empty")
    width = len(rows[0])
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


def _read_maze_file(path: Path) -> str:
    """The text of a maze file, refusing missing, unreadable, binary or enormous files clearly."""
    try:
        size = path.stat().st_size
        if path.is_dir():
            raise MazeError(f"{path}: is a folder, not a maze file")
        if size > MAZE_FILE_LIMIT_BYTES:
            raise MazeError(f"{path}: {size} bytes is too large for a maze file (limit {MAZE_FILE_LIMIT_BYTES})")
        data = path.read_bytes()
    except FileNotFoundError:
        raise MazeError(f"{path}: no such maze file") from None
    except PermissionError:
        raise MazeError(f"{path}: not readable (permission denied)") from None
    except OSError as error:
        raise MazeError(f"{path}: cannot be read ({error.strerror or error})") from None
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError:
        raise MazeError(f"{path}: not a text file (not UTF-8)") from None


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
def _station_corners(grid: np.ndarray) -> np.ndarray:
    """The four corners of every type-2 cell in map coordinates, each point once, shape (B, 2)."""
    height = grid.shape[0]
    rows, cols = np.nonzero(grid == STATION_WALL)
    corners = {
        (int(c + dx), int(height - 1 - r + dy))
        for r, c in zip(rows, cols, strict=True)
        for dx in (0, 1)
        for dy in (0, 1)
    }
    return np.array(sorted(corners), dtype=float)


def _free_cell_origins(grid: np.ndarray) -> np.ndarray:
    """Lower-left corners (x, y) of the free cells, shape (F, 2)."""
    rows, cols = np.nonzero(grid == EMPTY)
    return np.column_stack([cols, grid.shape[0] - 1 - rows]).astype(float)


class _NearestStationLookup:
    """Nearest-station distances from per-cell candidate lists, so the cost does not grow with B.

    For each unit cell (of the map plus a margin) keep only the stations that can be nearest to some
    point of that cell: station s is kept when its least distance to the cell is at most the smallest,
    over all stations t, of the greatest distance from the cell to t. That superset is exact.
    """

    def __init__(self, stations: np.ndarray, width: int, height: int):
        self.stations = stations
        self.margin = _LOOKUP_MARGIN_CELLS
        self.x0 = self.y0 = -self.margin
        self.nx, self.ny = width + 2 * self.margin, height + 2 * self.margin
        self.candidates = self._candidate_table()  # (ny * nx, K) station indices, padded by repeats

    def _candidate_table(self) -> np.ndarray:
        ix, iy = np.meshgrid(np.arange(self.nx), np.arange(self.ny))
        lo = np.column_stack([ix.ravel() + self.x0, iy.ravel() + self.y0]).astype(float)  # (C, 2)
        hi = lo + 1.0
        s = self.stations[None, :, :]  # (1, B, 2)
        nearest_gap = np.maximum(np.maximum(lo[:, None] - s, s - hi[:, None]), 0.0)
        farthest_gap = np.maximum(np.abs(s - lo[:, None]), np.abs(s - hi[:, None]))
        d_min = np.hypot(nearest_gap[..., 0], nearest_gap[..., 1])  # (C, B)
        d_max = np.hypot(farthest_gap[..., 0], farthest_gap[..., 1])
        keep = d_min <= d_max.min(axis=1, keepdims=True) + 1e-9
        width = int(keep.sum(axis=1).max())
        # Sort each cell's kept stations first, then pad with its first candidate (harmless repeat).
        order = np.argsort(~keep, axis=1, kind="stable")[:, :width]
        counts = keep.sum(axis=1)
        pad = np.arange(width)[None, :] >= counts[:, None]
        return np.where(pad, order[:, :1], order)

    def distances(self, points: np.ndarray) -> np.ndarray:
        """Distance to the nearest station for points of shape (N, 2)."""
        cx = np.floor(points[:, 0]).astype(np.int64) - self.x0
        cy = np.floor(points[:, 1]).astype(np.int64) - self.y0
        near = (cx >= 0) & (cx < self.nx) & (cy >= 0) & (cy < self.ny)
        out = np.empty(len(points))
        if near.all():
            out[:] = self._near_distances(points, cy * self.nx + cx)
        else:
            out[near] = self._near_distances(points[near], (cy * self.nx + cx)[near])
            far = points[~near]
            out[~near] = np.sqrt(((far[:, None, :] - self.stations[None]) ** 2).sum(-1)).min(axis=1)
        return out

    def _near_distances(self, points: np.ndarray, cells: np.ndarray) -> np.ndarray:
        cand = self.stations[self.candidates[cells]]  # (N, K, 2)
        d2 = ((cand - points[:, None, :]) ** 2).sum(-1)
        return np.sqrt(d2.min(axis=1))


# -- drawing -------------------------------------------------------------------------------------
# `visualize` (run_model's argument and the CLI's --viewer/--rrd/--web/--no-viz) takes:
#   True or "auto"  the native viewer when a display exists, else an .rrd file (path printed)
#   "viewer"        spawn the native viewer        "web"  serve the web viewer on 127.0.0.1
#   a str/Path      save the recording to that .rrd file
#   False / None    draw nothing                   a view object (has log_step/close): draw into it
class NullView:
    """A view that draws nothing: what `run_model(..., visualize=False)` uses."""

    def log_step(self, step: int, robot_position: Sequence[float], robot_heading: float | None, state: Any) -> None:
        """Draw step `step`: the robot (position, heading) and the filter `state` (its particles,
        weights, headings, estimate, ESS, confidence)."""

    def close(self) -> None:
        """Finish drawing (flush and close the recording)."""


def open_view(visualize: Any, world: Maze, filter_name: str) -> Any:
    """The view one run draws to (see the `visualize` values above)."""
    if hasattr(visualize, "log_step"):
        return visualize
    return NullView()


class NullComparison:
    """All filters of one scenario in one recording (compare): one view per filter."""

    def view_for(self, filter_name: str) -> Any:
        """The view that the run of `filter_name` draws to."""
        return NullView()

    def close(self) -> None:
        """Finish the recording."""


def open_comparison(visualize: Any, world: Maze, filter_names: Sequence[str]) -> Any:
    """A recording for comparing `filter_names` side by side (see the `visualize` values above)."""
    return NullComparison()


def heading_vectors(angles: np.ndarray, length: float) -> np.ndarray:
    """Arrows of `length` along `angles` (radians, counter-clockwise from +x), shape (N, 2)."""
    return length * np.column_stack([np.cos(angles), np.sin(angles)])


__all__ = [
    "EMPTY",
    "STATION_WALL",
    "WALL",
    "Maze",
    "MazeError",
    "NullComparison",
    "NullView",
    "heading_vectors",
    "open_comparison",
    "open_view",
    "parse_maze_text",
]
