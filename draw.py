"""The maze of the lab: its grid, free area, stations and distances, and drawing it.

Map frame (lab-spec.md): maze row 0 is the top row; the cell in row r, column c of an H x W maze
covers x in [c, c+1), y in [H-1-r, H-r), so the map spans [0, W] x [0, H] with y pointing up.
Cell values: 0 empty, 1 wall, 2 wall with a station at each of its four corners.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path
from typing import Any

import numpy as np

EMPTY, WALL, STATION_WALL = 0, 1, 2
MAZE_FILE_LIMIT_BYTES = 1_000_000  # a maze file larger than this is refused, not read
# Points up to this many map units beyond the map's border use the fast nearest-station lookup;
# points farther out (rare: particles only drift out by a step length at a time) use brute force.
_LOOKUP_MARGIN = 2
# Lookup cells per map unit, a power of two (so x * scale and its floor are exact): the finer the
# cells, the fewer have more than one candidate station (at 4, about one in five on the shipped mazes).
_LOOKUP_SUBDIVISIONS = 4
_LOOKUP_MAX_CELLS = 2**22  # a larger map gets coarser lookup cells (flat indices stay exact in float32)
_LOOKUP_TILE = 8  # the table is built in square tiles of this many lookup cells a side
_LOOKUP_TOLERANCE = 1e-9  # map units: candidate tests keep near-ties (rounding cannot drop the nearest)


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

    @cached_property
    def _lookup(self) -> _NearestStationLookup:
        """The nearest-station table, built on first use (a few ms; about a second for 100 x 100)."""
        return _NearestStationLookup(self.stations, self.grid)

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

    def station_distances_and_free(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Distance to the nearest station and the free flag of each point, both from one cell lookup:
        x, y of shape (N,) and one float dtype (float32 particles are computed in float32)."""
        return self._lookup.locate(x, y)

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
    """Nearest-station distances and free flags from one table lookup per point: cost flat in B.

    The map plus a margin is cut into square lookup cells of side 1/scale. Each cell keeps the
    stations that can be nearest to some point of it (`_candidate_stations`): the first candidate,
    used for every point, and, for the minority of cells near a boundary between two stations'
    regions, a padded row of all its candidates. The same cell index gives the point's free flag.
    Queries run in the points' float dtype (float32 particles, float64 for the exact public API).
    """

    def __init__(self, stations: np.ndarray, grid: np.ndarray):
        height, width = grid.shape
        self.scale = _lookup_subdivisions(width, height)
        self.offset = _LOOKUP_MARGIN * self.scale  # lookup-cell index of x = 0 (and of y = 0)
        self.nx = (width + 2 * _LOOKUP_MARGIN) * self.scale
        self.ny = (height + 2 * _LOOKUP_MARGIN) * self.scale
        self.stations = stations
        self.free = _lookup_cells_free(grid, self.scale, _LOOKUP_MARGIN).ravel()  # (C,) bool
        candidates, counts = _candidate_stations(stations, self.nx, self.ny, self.offset, self.scale)
        ambiguous = np.flatnonzero(counts > 1)
        self.row = np.full(len(counts), -1, dtype=np.int32)  # each cell's row of `_all`, -1: one candidate
        self.row[ambiguous] = np.arange(len(ambiguous))
        # The nearest station to a point beyond the table is the nearest to the point where the segment
        # between them crosses the table's border, so it is a candidate of a border cell.
        self._border = np.unique(candidates.reshape(self.ny, self.nx, -1)[_border_of(self.ny, self.nx)])
        self._first = candidates[:, 0]  # (C,) station indices
        self._all = candidates[ambiguous]  # (A, K) station indices, padded by repeats
        self._tables: dict[np.dtype, _StationTables] = {}

    def locate(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(distance to the nearest station, free flag) for points x, y of shape (N,), in x's dtype."""
        tables = self._station_tables(x.dtype)
        cells, beyond = self._cells(x, y)
        d2 = _squared_distances(tables.first_x.take(cells), tables.first_y.take(cells), x, y)
        rows = self.row.take(cells)
        ambiguous = np.flatnonzero(rows >= 0)
        if len(ambiguous):
            d2[ambiguous] = _nearest_candidate(tables, rows[ambiguous], x[ambiguous], y[ambiguous])
        free = self.free.take(cells)
        if len(beyond):
            d2[beyond] = _brute_force_squared_distances(tables.border, x[beyond], y[beyond])
            free[beyond] = False
        return np.sqrt(d2, out=d2), free

    def distances(self, points: np.ndarray) -> np.ndarray:
        """Distance to the nearest station for points of shape (N, 2)."""
        return self.locate(points[:, 0], points[:, 1])[0]

    def _cells(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Each point's flat lookup-cell index (N,), and the indices of the points beyond the table."""
        ix = np.floor(x * self.scale)  # exact: the scale is a power of two
        iy = np.floor(y * self.scale)
        ix += self.offset
        iy += self.offset
        inside = ix.min() >= 0 and iy.min() >= 0 and ix.max() < self.nx and iy.max() < self.ny
        beyond = _NO_POINTS if inside else np.flatnonzero((ix < 0) | (ix >= self.nx) | (iy < 0) | (iy >= self.ny))
        ix[beyond] = iy[beyond] = 0  # any cell: their answers are replaced
        iy *= self.nx
        iy += ix  # whole numbers below 2**24 (see _lookup_subdivisions), exact even in float32
        return iy.astype(np.intp), beyond

    def _station_tables(self, dtype: np.dtype) -> _StationTables:
        """The candidates' coordinates in `dtype`, made once per dtype."""
        if dtype not in self._tables:
            xy = self.stations.astype(dtype)
            first, every = xy[self._first], xy[self._all]
            columns_x, columns_y = every[..., 0].T.copy(), every[..., 1].T.copy()  # (K, A): candidate k of each row
            self._tables[dtype] = _StationTables(first[:, 0], first[:, 1], columns_x, columns_y, xy[self._border])
        return self._tables[dtype]


_NO_POINTS = np.empty(0, dtype=np.intp)


@dataclass(frozen=True)
class _StationTables:
    """Coordinates of each lookup cell's first candidate (C,), of the ambiguous cells' candidates
    (K, A: row k holds every ambiguous cell's k-th candidate), and of the border cells' candidates (b, 2)."""

    first_x: np.ndarray
    first_y: np.ndarray
    all_x: np.ndarray
    all_y: np.ndarray
    border: np.ndarray


def _border_of(ny: int, nx: int) -> np.ndarray:
    """(ny, nx) mask of the outermost ring of cells."""
    ring = np.ones((ny, nx), dtype=bool)
    ring[1:-1, 1:-1] = False
    return ring


def _lookup_subdivisions(width: int, height: int) -> int:
    """Lookup cells per map unit: _LOOKUP_SUBDIVISIONS, halved while the table would exceed
    _LOOKUP_MAX_CELLS (which keeps flat cell indices exact in float32)."""
    scale = _LOOKUP_SUBDIVISIONS
    while scale > 1 and (width + 2 * _LOOKUP_MARGIN) * (height + 2 * _LOOKUP_MARGIN) * scale**2 > _LOOKUP_MAX_CELLS:
        scale //= 2
    return scale


def _lookup_cells_free(grid: np.ndarray, scale: int, margin: int) -> np.ndarray:
    """Free flags of the lookup cells, shape (ny, nx), row j covering y in [j/scale - margin, ...)."""
    free_up = np.pad(grid[::-1] == EMPTY, margin, constant_values=False)  # row 0 is y in [-margin, ...)
    return np.repeat(np.repeat(free_up, scale, axis=0), scale, axis=1)


def _nearest_candidate(tables: _StationTables, rows: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Squared distance from each point to the nearest candidate of its ambiguous cell (row of the table)."""
    nearest = _squared_distances(tables.all_x[0].take(rows), tables.all_y[0].take(rows), x, y)
    for candidate_x, candidate_y in zip(tables.all_x[1:], tables.all_y[1:], strict=True):
        np.minimum(nearest, _squared_distances(candidate_x.take(rows), candidate_y.take(rows), x, y), out=nearest)
    return nearest


def _squared_distances(sx: np.ndarray, sy: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """(sx - x)^2 + (sy - y)^2, broadcast, in as few temporary arrays as possible."""
    dx = sx - x
    dx *= dx
    dy = sy - y
    dy *= dy
    dx += dy
    return dx


def _brute_force_squared_distances(stations: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Squared distance to the nearest of `stations` (b, 2), for the rare points beyond the table."""
    out = np.empty(len(x), dtype=x.dtype)
    for start in range(0, len(x), 1024):  # chunks bound the (chunk, B) temporary
        part = slice(start, start + 1024)
        out[part] = _squared_distances(stations[:, 0], stations[:, 1], x[part, None], y[part, None]).min(axis=1)
    return out


def _candidate_stations(
    stations: np.ndarray, nx: int, ny: int, offset: int, scale: int
) -> tuple[np.ndarray, np.ndarray]:
    """For every lookup cell (flat index j * nx + i), the stations that can be nearest to a point of it,
    nearest to the cell's centre first: (C, K) station indices padded by repeating the first, and the
    counts (C,). Built tile by tile, each tile's cells choosing among the tile's own candidates."""
    size = 1 / scale
    tiles = []
    for j0 in range(0, ny, _LOOKUP_TILE):
        for i0 in range(0, nx, _LOOKUP_TILE):
            ii, jj = np.meshgrid(np.arange(i0, min(i0 + _LOOKUP_TILE, nx)), np.arange(j0, min(j0 + _LOOKUP_TILE, ny)))
            lo_x, lo_y = (ii.ravel() - offset) * size, (jj.ravel() - offset) * size
            tile = (lo_x[:1], lo_y[:1], lo_x[-1:] + size - lo_x[:1], lo_y[-1:] + size - lo_y[:1])
            near = np.flatnonzero(_possibly_nearest(stations, *tile)[0])
            order, counts = _cell_candidates(stations[near], lo_x, lo_y, size)
            tiles.append(((jj * nx + ii).ravel(), near[order], counts))
    width = max(int(counts.max()) for _, _, counts in tiles)
    table = np.empty((nx * ny, width), dtype=np.intp)
    all_counts = np.empty(nx * ny, dtype=np.intp)
    for cells, candidates, counts in tiles:
        candidates = candidates[:, :width]
        candidates = np.where(np.arange(candidates.shape[1]) < counts[:, None], candidates, candidates[:, :1])
        table[cells] = np.pad(candidates, ((0, 0), (0, width - candidates.shape[1])), mode="edge")
        all_counts[cells] = counts
    return table, all_counts


def _cell_candidates(
    stations: np.ndarray, lo_x: np.ndarray, lo_y: np.ndarray, size: float
) -> tuple[np.ndarray, np.ndarray]:
    """Which of `stations` (K, 2) can be nearest to some point of each square cell (lower-left corner
    lo_x, lo_y, side `size`): each row of the (c, K) order lists them first, nearest the centre first.

    A station is dropped when it is farther from the whole cell than another station can ever be
    (`_possibly_nearest`), or when one other station is nearer at all four corners: the points nearer
    to that one form a half-plane, so it is then nearer on the whole (convex) cell.
    """
    possible = _possibly_nearest(stations, lo_x, lo_y, size, size)  # (c, K)
    counts = possible.sum(axis=1)
    shortlist = np.argsort(~possible, axis=1, kind="stable")[:, : counts.max()]  # (c, w), possible ones first
    real = np.arange(shortlist.shape[1]) < counts[:, None]
    shortlist = np.where(real, shortlist, shortlist[:, :1])  # pad with a real candidate: it beats no one wrongly
    sx, sy = stations[shortlist, 0][:, None, :], stations[shortlist, 1][:, None, :]  # (c, 1, w)
    corners_x = lo_x[:, None, None] + np.array([0, size, 0, size])[:, None]  # (c, 4, 1)
    corners_y = lo_y[:, None, None] + np.array([0, 0, size, size])[:, None]
    d = np.hypot(corners_x - sx, corners_y - sy)  # (c, 4, w)
    # beaten[c, s, t]: candidate t is nearer than candidate s at every corner of cell c
    beaten = (d[:, :, None, :] < d[:, :, :, None] - _LOOKUP_TOLERANCE).all(axis=1)
    keep = real & ~beaten.any(axis=2)
    centre = np.hypot(lo_x[:, None] + size / 2 - sx[:, 0], lo_y[:, None] + size / 2 - sy[:, 0])
    order = np.lexsort((centre, ~keep))  # along the last axis: kept first, then by distance to the centre
    return np.take_along_axis(shortlist, order, axis=1), keep.sum(axis=1)


def _possibly_nearest(
    stations: np.ndarray, lo_x: np.ndarray, lo_y: np.ndarray, size_x: np.ndarray | float, size_y: np.ndarray | float
) -> np.ndarray:
    """(c, K) mask: station k's least distance to box c is at most the smallest, over all stations,
    greatest distance to box c (otherwise that other station is nearer everywhere in the box)."""
    lo_x, lo_y = lo_x[:, None], lo_y[:, None]
    hi_x, hi_y = lo_x + np.asarray(size_x)[..., None], lo_y + np.asarray(size_y)[..., None]
    sx, sy = stations[:, 0], stations[:, 1]
    least = np.hypot(np.maximum(np.maximum(lo_x - sx, sx - hi_x), 0), np.maximum(np.maximum(lo_y - sy, sy - hi_y), 0))
    greatest = np.hypot(
        np.maximum(np.abs(sx - lo_x), np.abs(sx - hi_x)), np.maximum(np.abs(sy - lo_y), np.abs(sy - hi_y))
    )
    return least <= greatest.min(axis=1, keepdims=True) + _LOOKUP_TOLERANCE


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
