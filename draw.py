"""The maze of the lab: its grid, free area, stations and distances, and drawing it.

Map frame (lab-spec.md): maze row 0 is the top row; the cell in row r, column c of an H x W maze
covers x in [c, c+1), y in [H-1-r, H-r), so the map spans [0, W] x [0, H] with y pointing up.
Cell values: 0 empty, 1 wall, 2 wall with a station at each of its four corners.
"""

from __future__ import annotations

import importlib.util
import math
import os
import re
import shlex
import shutil
import socket
import subprocess
import sys
import time
import urllib.parse
import uuid
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
        if _is_scalar(x) and _is_scalar(y):  # the robot's wall checks, several a step
            return self._free_at(float(x), float(y))
        x = np.asarray(x, dtype=float)
        y = np.asarray(y, dtype=float)
        inside = (x >= 0) & (x < self.width) & (y >= 0) & (y < self.height)
        row, col = self.cell_of(np.where(inside, x, 0.0), np.where(inside, y, 0.0))
        free = inside & (self.grid[row, col] == EMPTY)
        return bool(free) if free.ndim == 0 else free

    def _free_at(self, x: float, y: float) -> bool:
        """`is_free` for one point, in plain floats."""
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
        """
        rng = np.random.default_rng() if rng is None else rng
        cells = self.free_cells[rng.integers(len(self.free_cells), size=count)]
        return cells + rng.random((count, 2))

    def distance_to_nearest_station(self, x: Any, y: Any | None = None) -> float | np.ndarray:
        """Euclidean distance from each point to its nearest station (map units).

        Call as `distance_to_nearest_station(x, y)` with scalars or arrays of one shape, or with a
        single array of points of shape (..., 2).
        """
        if y is not None and _is_scalar(x) and _is_scalar(y):  # the robot's measurement, once a step
            return self._lookup.distance_at(float(x), float(y))
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
    regions, a padded row of all its candidates. Per point, two gathers do the common work: the
    first candidate's (x, y) pair from one packed table, and the cell's kind (free? ambiguous?), one byte.
    Queries run in the points' float dtype (float32 particles, float64 for the exact public API).
    """

    def __init__(self, stations: np.ndarray, grid: np.ndarray):
        height, width = grid.shape
        self.scale = _lookup_subdivisions(width, height)
        self.offset = _LOOKUP_MARGIN * self.scale  # lookup-cell index of x = 0 (and of y = 0)
        self.nx = (width + 2 * _LOOKUP_MARGIN) * self.scale
        self.ny = (height + 2 * _LOOKUP_MARGIN) * self.scale
        self.stations = stations
        free = _lookup_cells_free(grid, self.scale, _LOOKUP_MARGIN).ravel()  # (C,) bool
        candidates, counts = _candidate_stations(stations, self.nx, self.ny, self.offset, self.scale)
        ambiguous = np.flatnonzero(counts > 1)
        self.kind = _cell_kinds(free, counts > 1)  # (C,) int8
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
        first = tables.first.take(cells, axis=0)  # (N, 2): one gather for both coordinates
        d2 = _squared_distances(first[:, 0], first[:, 1], x, y)
        del first
        kinds = self.kind.take(cells)
        ambiguous = np.flatnonzero(kinds >= _AMBIGUOUS)
        if len(ambiguous):
            rows = self.row.take(cells.take(ambiguous))
            d2[ambiguous] = _nearest_candidate(tables, rows, x.take(ambiguous), y.take(ambiguous))
        free = np.bitwise_and(kinds, _FREE, out=kinds).view(bool)
        if len(beyond):
            d2[beyond] = _brute_force_squared_distances(tables.border, x[beyond], y[beyond])
            free[beyond] = False
        return np.sqrt(d2, out=d2), free

    def distance_at(self, x: float, y: float) -> float:
        """`locate`'s distance for one float64 point, in plain floats (the same IEEE operations, so the
        same value), without the cost of numpy calls on arrays of one."""
        ix, iy = math.floor(x * self.scale) + self.offset, math.floor(y * self.scale) + self.offset
        if not (0 <= ix < self.nx and 0 <= iy < self.ny):
            return float(self.distances(np.array([[x, y]]))[0])
        cell = iy * self.nx + ix
        row = self.row[cell]
        candidates = self._all[row] if row >= 0 else self._first[cell : cell + 1]
        nearest = min(_squared_distance(self.stations[i], x, y) for i in candidates.tolist())
        return math.sqrt(nearest)

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
            every = xy[self._all]
            columns_x, columns_y = every[..., 0].T.copy(), every[..., 1].T.copy()  # (K, A): candidate k of each row
            self._tables[dtype] = _StationTables(xy[self._first], columns_x, columns_y, xy[self._border])
        return self._tables[dtype]


_NO_POINTS = np.empty(0, dtype=np.intp)
_FREE, _AMBIGUOUS = 1, 2  # bits of a lookup cell's kind


def _cell_kinds(free: np.ndarray, ambiguous: np.ndarray) -> np.ndarray:
    """Each lookup cell's kind, int8 (C,): _FREE if free, plus _AMBIGUOUS if it has several candidates."""
    return (free * _FREE + ambiguous * _AMBIGUOUS).astype(np.int8)


@dataclass(frozen=True)
class _StationTables:
    """Coordinates of each lookup cell's first candidate (C, 2), of the ambiguous cells' candidates
    (K, A: row k holds every ambiguous cell's k-th candidate), and of the border cells' candidates (b, 2)."""

    first: np.ndarray
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


def _squared_distance(station: np.ndarray, x: float, y: float) -> float:
    """(sx - x)^2 + (sy - y)^2 in plain floats, in `_squared_distances`' order of operations."""
    sx, sy = station.tolist()
    dx, dy = sx - x, sy - y
    return dx * dx + dy * dy


def _is_scalar(value: Any) -> bool:
    return isinstance(value, (float, int, np.floating, np.integer)) and not isinstance(value, bool)


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
#   True or "auto"  the notebook viewer inside Jupyter, else the native viewer when a display
#                   exists, else an .rrd file in recordings/ (the path is printed)
#   "viewer"        spawn the native viewer (falls back to a file, saying so, without a display)
#   "web"           serve the web viewer on 127.0.0.1 (and save a file); Ctrl-C stops serving
#   "notebook"      the viewer inline in a Jupyter notebook (needs the `notebook` extra)
#   a str/Path      save the recording to that .rrd file (any other string is a path)
#   an rr.RecordingStream   log into the caller's own recording (it stays open)
#   False / None    draw nothing                   a view object (has log_step/close): draw into it
#   Visualization(target, max_drawn=...)  any of the above, drawing at most max_drawn particles
DEFAULT_MAX_DRAWN = 5000  # particles drawn per step at most; the filter keeps all of them
VIEWER_PORT = 9876  # the native viewer's gRPC port, rerun's default: later runs reuse its window
RECORDINGS_DIR = Path("recordings")  # where runs without a display are saved, relative to the cwd
APPLICATION_ID = "maze_particle_filter_lab"
MAP = "/map"  # everything drawn in the map frame lives under this entity
FREE_COLOR, WALL_COLOR = (255, 255, 255), (0, 0, 0)
STATION_COLOR, ROBOT_COLOR = (0, 200, 255), (0, 170, 0)
ESTIMATE_COLOR, CONFIDENT_COLOR = (128, 128, 128), (0, 200, 0)
INJECTED_COLOR = (255, 190, 0)  # particles injected by recovery this step (weights are drawn blue..red)
KIDNAP_COLOR = (230, 0, 200)  # the jump of a kidnapped robot
FILTER_COLORS = ((214, 39, 40), (31, 119, 180), (255, 127, 14), (44, 160, 44), (148, 103, 189), (140, 86, 75))
PARTICLE_ARROW_LENGTH, ROBOT_ARROW_LENGTH = 0.15, 0.5  # map units
STATION_RADIUS, ROBOT_RADIUS, PARTICLE_ARROW_RADIUS, CELL_DOT_RADIUS = 0.08, 0.12, 0.008, 0.03
SERIES = ("error", "ess", "confident")  # the time series under /metrics/<series>/<filter>


@dataclass(frozen=True)
class Visualization:
    """A `visualize` value with options: where to draw (`target`, see above) and how much."""

    target: Any = True
    max_drawn: int = DEFAULT_MAX_DRAWN

    def __post_init__(self) -> None:
        if isinstance(self.max_drawn, bool) or not isinstance(self.max_drawn, (int, np.integer)) or self.max_drawn < 1:
            raise ValueError(f"max_drawn must be a whole number >= 1, got {self.max_drawn!r}")


class NullView:
    """A view that draws nothing: what `run_model(..., visualize=False)` uses."""

    def log_step(self, step: int, robot_position: Sequence[float], robot_heading: float | None, state: Any) -> None:
        """Draw step `step`: the robot (position, heading) and the filter `state` (its particles,
        weights, headings, estimate, ESS, confidence)."""

    def close(self) -> None:
        """Finish drawing (flush and close the recording)."""

    def expect_kidnapping(self, step: int, position: Sequence[float]) -> None:
        """The robot will be carried to `position` at step `step`: draw the jump then."""


def expect_kidnapping(view: Any, step: int | None, position: Sequence[float] | None) -> None:
    """Tell `view` of a planned kidnapping, if there is one and the view draws it (a caller's own
    view need not)."""
    if step is not None and position is not None and hasattr(view, "expect_kidnapping"):
        view.expect_kidnapping(step, position)


def open_view(visualize: Any, world: Maze, filter_name: str) -> Any:
    """The view one run draws to (see the `visualize` values above)."""
    if hasattr(visualize, "log_step"):
        return visualize
    options = visualize if isinstance(visualize, Visualization) else Visualization(visualize)
    if options.target is None or options.target is False:
        return NullView()
    blueprint = run_blueprint(world, filter_name)
    recording = Recording.open(options.target, world, blueprint, label=entity_name(filter_name))
    return RunView(recording, filter_name, FILTER_COLORS[0], options.max_drawn, owns_recording=True)


class NullComparison:
    """All filters of one scenario in one recording (compare): one view per filter."""

    def view_for(self, filter_name: str) -> Any:
        """The view that the run of `filter_name` draws to."""
        return NullView()

    def close(self) -> None:
        """Finish the recording."""


def open_comparison(visualize: Any, world: Maze, filter_names: Sequence[str]) -> Any:
    """A recording for comparing `filter_names` side by side (see the `visualize` values above)."""
    options = visualize if isinstance(visualize, Visualization) else Visualization(visualize)
    if options.target is None or options.target is False:
        return NullComparison()
    names = list(dict.fromkeys(filter_names))
    if not names:
        raise ValueError("a comparison needs at least one filter")
    recording = Recording.open(options.target, world, comparison_blueprint(world, names), label="compare")
    return Comparison(recording, names, options.max_drawn)


class Comparison:
    """All filters of one scenario in one recording: one `RunView` per filter, the robot drawn once."""

    def __init__(self, recording: Recording, filter_names: Sequence[str], max_drawn: int):
        self.recording = recording
        self.views = {
            name: RunView(recording, name, FILTER_COLORS[i % len(FILTER_COLORS)], max_drawn, owns_recording=False)
            for i, name in enumerate(filter_names)
        }

    def view_for(self, filter_name: str) -> RunView:
        """The view that the run of `filter_name` draws to (one of the names the comparison was opened with)."""
        if filter_name not in self.views:
            raise ValueError(f"{filter_name!r} is not in this comparison ({', '.join(self.views)})")
        return self.views[filter_name]

    def close(self) -> None:
        """Finish the recording (file complete, viewer flushed, web viewer served until Ctrl-C)."""
        self.recording.close()


# -- what one run draws ----------------------------------------------------------------------------
def entity_name(filter_name: str) -> str:
    """A filter's name as an entity-path part: "SIRParticleFilter" -> "sir_particle_filter"."""
    spaced = re.sub(r"(?<=[a-z0-9])(?=[A-Z])|(?<=[A-Z])(?=[A-Z][a-z])", "_", str(filter_name).strip())
    return re.sub(r"[^a-z0-9]+", "_", spaced.lower()).strip("_") or "filter"


def weight_colors(weights: np.ndarray) -> np.ndarray:
    """RGB colours from blue (weight 0) to red (the largest weight), linear in w / max w, shape (N, 3)."""
    top = weights.max() if len(weights) else 0.0
    t = weights / top if top > 0 else np.zeros_like(weights)
    return np.column_stack([255 * t, np.zeros_like(t), 255 * (1 - t)]).astype(np.uint8)


def drawn_particles(state: Any, max_drawn: int) -> tuple[np.ndarray, np.ndarray | None, np.ndarray]:
    """What is drawn of a filter's posterior: positions (M, 2), headings (M,) or None, weights (M,).

    A particle filter: all N particles when N <= max_drawn, else max_drawn of them at evenly spaced
    indices (deterministic: drawing never draws from the filter's random stream). A grid density
    (GridBayesFilter, whose cells are not a sample): the cells hit by a systematic pick of max_drawn
    points of its mass, each cell once, so the dots show where the probability is.
    """
    weights = np.asarray(state.weights)
    positions = np.asarray(state.positions)
    if hasattr(state, "density"):
        cumulative = np.cumsum(weights)
        targets = (np.arange(max_drawn) + 0.5) / max_drawn * cumulative[-1]
        cells = np.unique(np.minimum(np.searchsorted(cumulative, targets), len(weights) - 1))
        return positions[cells], None, weights[cells]
    picked = drawn_indices(len(positions), max_drawn)
    return positions[picked], np.asarray(state.headings)[picked], weights[picked]


def drawn_indices(count: int, max_drawn: int) -> slice | np.ndarray:
    """Which of `count` particles are drawn: all, or max_drawn at evenly spaced indices."""
    if count <= max_drawn:
        return slice(None)
    return np.linspace(0, count - 1, max_drawn).round().astype(np.int64)


def particle_colors(state: Any, weights: np.ndarray, max_drawn: int) -> np.ndarray:
    """The drawn particles' colours (M, 3): by weight (`weight_colors`), and INJECTED_COLOR for those
    that recovery injected this step (`state.injected`, a mask over all N particles, or None)."""
    colors = weight_colors(weights)
    injected = getattr(state, "injected", None)
    if injected is not None:
        colors[np.asarray(injected)[drawn_indices(len(injected), max_drawn)]] = INJECTED_COLOR
    return colors


class RunView:
    """One filter's run drawn into a Rerun recording: its particles, estimate and time series."""

    def __init__(
        self, recording: Recording, filter_name: str, color: Sequence[int], max_drawn: int, *, owns_recording: bool
    ):
        import rerun as rr

        from particle_filter import CONFIDENCE_RADIUS  # imported here: particle_filter imports this module

        self.recording, self.name, self.max_drawn = recording, filter_name, max_drawn
        self.owns_recording = owns_recording
        self.path = f"{MAP}/{entity_name(filter_name)}"
        self.metric = entity_name(filter_name)
        self.confidence_radius = CONFIDENCE_RADIUS
        self.color = color
        self.count_series_styled = False
        for series in SERIES:
            recording.stream.log(
                f"/metrics/{series}/{self.metric}",
                rr.SeriesLines(names=filter_name, colors=color, widths=2),
                static=True,
            )

    def expect_kidnapping(self, step: int, position: Sequence[float]) -> None:
        """The robot will be carried to `position` at step `step`: its recording draws the jump."""
        self.recording.kidnapping = (step, (float(position[0]), float(position[1])))

    def log_step(self, step: int, robot_position: Sequence[float], robot_heading: float | None, state: Any) -> None:
        """Draw step `step`: the robot (once per recording), the particles coloured by weight (the
        injected ones apart), the estimate's circle (green when confident), and the error, ESS and
        confidence series; with KLD-sampling, the particle count beside the ESS."""
        import rerun as rr

        stream = self.recording.stream
        stream.set_time("step", sequence=step)
        self.recording.log_robot(step, robot_position, robot_heading)
        positions, headings, weights = drawn_particles(state, self.max_drawn)
        colors = particle_colors(state, weights, self.max_drawn)
        if headings is None:
            stream.log(f"{self.path}/particles", rr.Points2D(positions, colors=colors, radii=CELL_DOT_RADIUS))
        else:
            vectors = heading_vectors(headings, PARTICLE_ARROW_LENGTH)
            arrows = rr.Arrows2D(origins=positions, vectors=vectors, colors=colors, radii=PARTICLE_ARROW_RADIUS)
            stream.log(f"{self.path}/particles", arrows)
        estimate, confident = np.asarray(state.estimate, dtype=float), bool(state.is_confident)
        circle = rr.Ellipses2D(
            centers=[estimate],
            half_sizes=[[self.confidence_radius] * 2],
            colors=CONFIDENT_COLOR if confident else ESTIMATE_COLOR,
            line_radii=0.03,
        )
        stream.log(f"{self.path}/estimate", circle)
        error = float(np.hypot(*(estimate - np.asarray(robot_position, dtype=float))))
        stream.log(f"/metrics/error/{self.metric}", rr.Scalars(error))
        ess = float(state.ess)
        if not math.isnan(ess):  # the grid filter is not a sample: no ESS
            stream.log(f"/metrics/ess/{self.metric}", rr.Scalars(ess))
        stream.log(f"/metrics/confident/{self.metric}", rr.Scalars(float(confident)))
        if getattr(state, "kld", None) is not None:
            self.log_particle_count(int(state.count))

    def log_particle_count(self, count: int) -> None:
        """The particle count N of this step (KLD-sampling varies it), in the ESS panel: ESS <= N."""
        import rerun as rr

        path = f"/metrics/ess/{self.metric}/particle_count"
        if not self.count_series_styled:
            self.count_series_styled = True
            style = rr.SeriesLines(names=f"{self.name} N", colors=self.color, widths=1)
            self.recording.stream.log(path, style, static=True)
        self.recording.stream.log(path, rr.Scalars(float(count)))

    def close(self) -> None:
        """Finish the recording if this run owns it (a comparison's views leave it open)."""
        if self.owns_recording:
            self.recording.close()
        else:
            self.recording.stream.flush()


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

    series = [rrb.TimeSeriesView(name=SERIES_TITLES[s], origin=f"/metrics/{s}") for s in SERIES]
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Vertical(
                rrb.TextDocumentView(name="step", origin="/title"), map_view(world, filter_name), row_shares=[1, 9]
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
            rrb.TimeSeriesView(name=SERIES_TITLES["error"], origin="/metrics/error"),
            row_shares=[1.5, 8, 4],
        )
    )


SERIES_TITLES = {
    "error": "error |estimate - truth|",
    "ess": "effective sample size (and N with KLD-sampling)",
    "confident": "confident (95% within the circle)",
}


# -- recordings and where they go ------------------------------------------------------------------
class Recording:
    """A Rerun recording of the lab: its stream, where it goes, and the robot and maze drawn once."""

    def __init__(self, stream: Any, *, path: Path | None = None, server: WebServer | None = None, owned: bool = True):
        self.stream, self.path, self.server, self.owned = stream, path, server, owned
        self.robot_steps: set[int] = set()
        self.last_robot_position: tuple[float, float] | None = None
        self.kidnapping: tuple[int, tuple[float, float]] | None = None  # (step, place), see expect_kidnapping
        self.closed = False

    @classmethod
    def open(cls, target: Any, world: Maze, blueprint: Any, *, label: str) -> Recording:
        """A recording going where `target` says (see the `visualize` values), with the maze logged."""
        import rerun as rr

        if isinstance(target, rr.RecordingStream):
            target.send_blueprint(blueprint, make_active=False, make_default=True)
            recording = cls(target, owned=False)
        else:
            recording = cls._to(resolve_target(target, label), blueprint, label)
        log_maze(recording.stream, world)
        return recording

    @classmethod
    def _to(cls, target: str | Path, blueprint: Any, label: str) -> Recording:
        import rerun as rr

        stream = rr.RecordingStream(APPLICATION_ID, recording_id=str(uuid.uuid4()))
        if target == "viewer":
            try:
                stream.connect_grpc(native_viewer(), default_blueprint=blueprint)
                return cls(stream)
            except RuntimeError as error:  # e.g. a display that the viewer cannot open
                target = default_recording_path(label)
                print(f"{error}: the recording goes to {target} instead")
        if target == "notebook":
            stream.notebook_show(blueprint=blueprint, height=700)
            return cls(stream)
        path = default_recording_path(label) if target == "web" else Path(target)
        partial = partial_path(path)
        if target == "web":
            server = WebServer.start()
            stream.set_sinks(rr.GrpcSink(server.grpc_url), rr.FileSink(partial), default_blueprint=blueprint)
            print(f"Serving the web viewer at {server.url}")
            return cls(stream, path=path, server=server)
        stream.save(partial, default_blueprint=blueprint)
        return cls(stream, path=path)

    def log_robot(self, step: int, position: Sequence[float], heading: float | None) -> None:
        """The robot (a green dot and its heading) and the step number, once per step of the recording:
        every filter of a comparison replays the same robot."""
        import rerun as rr

        if step in self.robot_steps:
            return
        self.robot_steps.add(step)
        self.stream.log(f"{MAP}/robot", rr.Points2D([position], colors=ROBOT_COLOR, radii=ROBOT_RADIUS))
        if heading is not None:
            vector = heading_vectors(np.array([heading]), ROBOT_ARROW_LENGTH)
            arrow = rr.Arrows2D(origins=[position], vectors=vector, colors=ROBOT_COLOR, radii=0.04)
            self.stream.log(f"{MAP}/robot/heading", arrow)
        title = f"### Step {step}"
        if self.kidnapping is not None and self.kidnapping[0] == step:
            self.log_kidnapping(step, self.kidnapping[1])
            title += ": the robot is kidnapped"
        self.stream.log("/title", rr.TextDocument(title, media_type=rr.MediaType.MARKDOWN))
        self.last_robot_position = (float(position[0]), float(position[1]))

    def log_kidnapping(self, step: int, place: tuple[float, float]) -> None:
        """The jump of step `step`: a line from where the robot was to `place`, where it was put down
        (it stays drawn from that step on), and a ring at `place`."""
        import rerun as rr

        label = f"kidnapped at step {step}"
        if self.last_robot_position is not None:
            jump = rr.LineStrips2D([[self.last_robot_position, place]], colors=KIDNAP_COLOR, radii=0.03, labels=label)
            self.stream.log(f"{MAP}/robot/kidnapping", jump)
        ring = rr.Ellipses2D(centers=[place], half_sizes=[[0.25, 0.25]], colors=KIDNAP_COLOR, line_radii=0.03)
        self.stream.log(f"{MAP}/robot/kidnapping/place", ring)

    def close(self) -> None:
        """Flush; a file is completed and moved into place and its path printed; a web viewer is
        served until Ctrl-C. A caller's own recording is only flushed."""
        if self.closed:
            return
        self.closed = True
        try:
            self.stream.flush()
        except RuntimeError as error:  # a viewer closed during the run: say so, do not crash the run
            print(f"The viewer did not receive the whole run ({error})")
        if not self.owned:
            return
        self.stream.disconnect()
        if self.path is not None:
            os.replace(partial_path(self.path), self.path)
            print(f"Recording saved to {self.path}; open it with: rerun {shlex.quote(str(self.path))}")
        if self.server is not None:
            # close() runs in simulate's `finally`: a run being interrupted stops serving at once.
            self.server.serve_until_interrupted(already_interrupted=sys.exc_info()[0] is not None)


def resolve_target(target: Any, label: str = "run") -> str | Path:
    """The place a `visualize` value means: "viewer", "web", "notebook" or a file path; without a
    display, a file named after `label` in RECORDINGS_DIR (and a line saying so)."""
    if target is True or target == "auto":
        if in_jupyter() and notebook_viewer_installed():
            return "notebook"
        if has_display():
            return "viewer"
        path = default_recording_path(label)
        print(f"No display found (DISPLAY and WAYLAND_DISPLAY unset): the recording goes to {path}")
        return path
    if target == "viewer" and not has_display():
        path = default_recording_path(label)
        print(f"No display found (DISPLAY and WAYLAND_DISPLAY unset): saving to {path} instead of opening the viewer")
        return path
    if target == "notebook" and not notebook_viewer_installed():
        raise ValueError("visualize='notebook' needs rerun's notebook viewer: pip install -e '.[notebook]'")
    if target in ("viewer", "web", "notebook"):
        return target
    if isinstance(target, (str, Path)):
        path = Path(target)
        if path.is_dir():
            raise ValueError(f"{path} is a folder, not an .rrd file")
        if not path.parent.is_dir():
            raise ValueError(f"{path.parent} does not exist: cannot write {path.name} there")
        return path
    raise ValueError(
        f"visualize must be True, False, 'viewer', 'web', 'notebook', an .rrd path or a view, got {target!r}"
    )


def log_maze(stream: Any, world: Maze) -> None:
    """The static map: walls black and free cells white (an image, one pixel per cell), stations as
    cyan dots, all under MAP, whose transform turns the map frame (y up) into the view's (y down)."""
    import rerun as rr

    stream.log(MAP, rr.Transform3D(translation=[0, world.height, 0], scale=[1, -1, 1]), static=True)
    stream.log(f"{MAP}/maze", rr.Image(maze_image(world), draw_order=-10.0), static=True)
    stream.log(f"{MAP}/stations", rr.Points2D(world.stations, colors=STATION_COLOR, radii=STATION_RADIUS), static=True)


def maze_image(world: Maze) -> np.ndarray:
    """RGB image of the maze, shape (H, W, 3): pixel (row j, column i) is the cell covering
    x in [i, i+1), y in [j, j+1) of the map frame, so grid row H-1-j."""
    walls = world.grid[::-1] != EMPTY
    return np.where(walls[..., None], np.uint8(WALL_COLOR), np.uint8(FREE_COLOR)).astype(np.uint8)


def default_recording_path(label: str) -> Path:
    """recordings/<label>-<date>-<time>.rrd in the current folder, made unique; the folder is created."""
    RECORDINGS_DIR.mkdir(parents=True, exist_ok=True)
    stem = f"{label}-{time.strftime('%Y%m%d-%H%M%S')}"
    path, n = RECORDINGS_DIR / f"{stem}.rrd", 1
    while path.exists() or partial_path(path).exists():
        n += 1
        path = RECORDINGS_DIR / f"{stem}-{n}.rrd"
    return path


def partial_path(path: Path) -> Path:
    """Where a recording is written until it is complete (then renamed to `path`: never half a file)."""
    return path.with_name(f".{path.name}.partial")


def has_display() -> bool:
    """Whether a native viewer window can open: always on macOS and Windows, else DISPLAY or WAYLAND_DISPLAY."""
    return sys.platform in ("darwin", "win32") or bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


def in_jupyter() -> bool:
    """Whether this runs in a Jupyter kernel (where the viewer can be shown inline)."""
    ipython = sys.modules.get("IPython")
    shell = ipython.get_ipython() if ipython is not None else None
    return type(shell).__name__ == "ZMQInteractiveShell"


def notebook_viewer_installed() -> bool:
    """Whether rerun's notebook viewer (the `notebook` extra) is installed."""
    return importlib.util.find_spec("rerun_notebook") is not None


def viewer_executable() -> str:
    """The `rerun` viewer shipped in the rerun-sdk wheel, found without PATH (an unactivated venv works)."""
    spec = importlib.util.find_spec("rerun_cli")
    if spec is not None and spec.origin is not None:
        binary = Path(spec.origin).with_name("rerun.exe" if os.name == "nt" else "rerun")
        if binary.exists():
            return str(binary)
    found = shutil.which("rerun")
    if found is None:
        raise RuntimeError("the Rerun viewer (shipped with rerun-sdk) was not found; reinstall rerun-sdk")
    return found


def rerun_environment() -> dict[str, str]:
    """The environment of the Rerun processes this program starts: ours plus CI, the variable that
    makes Rerun's viewer and server turn their usage analytics off (its only other switch is a
    config file, `rerun analytics disable`). Our own environment is left as it is."""
    return {**os.environ, "CI": os.environ.get("CI", "1")}


def start_rerun(
    arguments: list[str], ports: Sequence[int], *, detached: bool, settle: float = 0.0, timeout: float = 15.0
) -> Any:
    """Start the `rerun` binary with `arguments` and wait until it listens on every port of `ports`
    (127.0.0.1) and is still running `settle` seconds later (a viewer serves before it opens its
    window); a process that exits or stays silent raises RuntimeError at once, not after minutes."""
    process = subprocess.Popen(
        [viewer_executable(), *arguments],
        env=rerun_environment(),
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        start_new_session=detached,  # a detached viewer outlives this program (and its Ctrl-C)
    )
    deadline = time.monotonic() + timeout
    while not all(listening(port) for port in ports):
        if process.poll() is not None or time.monotonic() > deadline:
            stop_process(process)
            raise RuntimeError(f"the Rerun viewer did not start (exit code {process.returncode})")
        time.sleep(0.05)
    time.sleep(settle)
    if process.poll() is not None:
        raise RuntimeError(f"the Rerun viewer did not start (exit code {process.returncode})")
    return process


def native_viewer() -> str:
    """The gRPC address of a native viewer on 127.0.0.1:VIEWER_PORT: the one already running there
    (as rerun's own spawn does, runs share its window), else a new detached one."""
    if not listening(VIEWER_PORT):
        start_rerun(["--bind", "127.0.0.1", "--port", str(VIEWER_PORT), "--expect-data-soon"], [VIEWER_PORT],
                    detached=True, settle=1.0)  # fmt: skip
    return f"rerun+http://127.0.0.1:{VIEWER_PORT}/proxy"


def stop_process(process: Any) -> None:
    """End a process we started: politely, then for sure."""
    if process.poll() is None:
        process.terminate()
        try:
            process.wait(timeout=5)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait()


class WebServer:
    """The web viewer and its gRPC proxy, served by the `rerun` binary on 127.0.0.1 only."""

    def __init__(self, process: Any, grpc_port: int, web_port: int):
        self.process, self.grpc_port, self.web_port = process, grpc_port, web_port
        self.grpc_url = f"rerun+http://127.0.0.1:{grpc_port}/proxy"
        self.url = f"http://127.0.0.1:{web_port}/?url={urllib.parse.quote(self.grpc_url, safe='')}"

    @classmethod
    def start(cls) -> WebServer:
        """Start `rerun --serve-web` bound to 127.0.0.1 on two free ports; return once it listens."""
        grpc_port, web_port = free_port(), free_port()
        arguments = ["--serve-web", "--bind", "127.0.0.1", "--port", str(grpc_port), "--web-viewer-port", str(web_port)]
        return cls(start_rerun(arguments, [grpc_port, web_port], detached=False), grpc_port, web_port)

    def serve_until_interrupted(self, already_interrupted: bool = False) -> None:
        """Keep serving (the server holds the recording) until Ctrl-C, then stop cleanly."""
        try:
            if not already_interrupted:
                print(f"The web viewer is at {self.url}; press Ctrl-C to stop serving.")
                self.process.wait()
        except KeyboardInterrupt:
            print("Stopped serving the web viewer.")
        finally:
            self.stop()

    def stop(self) -> None:
        """End the server process."""
        stop_process(self.process)


def free_port() -> int:
    """A TCP port that is free on 127.0.0.1 right now."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


def listening(port: int) -> bool:
    """Whether something accepts connections on 127.0.0.1:`port`."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as probe:
        probe.settimeout(0.2)
        return probe.connect_ex(("127.0.0.1", port)) == 0


def heading_vectors(angles: np.ndarray, length: float) -> np.ndarray:
    """Arrows of `length` along `angles` (radians, counter-clockwise from +x), shape (N, 2)."""
    return length * np.column_stack([np.cos(angles), np.sin(angles)])


__all__ = [
    "DEFAULT_MAX_DRAWN",
    "EMPTY",
    "STATION_WALL",
    "WALL",
    "Comparison",
    "Maze",
    "MazeError",
    "NullComparison",
    "NullView",
    "Recording",
    "RunView",
    "Visualization",
    "heading_vectors",
    "open_comparison",
    "open_view",
    "parse_maze_text",
]
