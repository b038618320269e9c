"""The nearest station and the free flag of any point, from one table lookup per point (cost flat in
the station count): what the likelihood of every particle needs each step."""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

# Points up to this many map units beyond the map's border use the fast nearest-station lookup;
# points farther out (rare: particles only drift out by a step length at a time) use brute force.
_LOOKUP_MARGIN = 2
# Lookup cells per map unit, a power of two (so x * scale and its floor are exact): the finer the
# cells, the fewer have more than one candidate station (at 4, about one in five on the shipped mazes;
# each halving of the side halves that share, so a small maze takes up to 16, its table still built in ms).
_LOOKUP_SUBDIVISIONS = 4
_LOOKUP_FINEST, _LOOKUP_FINE_CELLS = 16, 2**14  # a map whose table stays within this many cells at 8 or 16 takes it
_LOOKUP_MAX_CELLS = 2**22  # a larger map gets coarser lookup cells (flat indices stay exact in float32)
_LOOKUP_TILE = 16  # the table is built in square tiles of this many lookup cells a side
_LOOKUP_TOLERANCE = 1e-9  # map units: candidate tests keep near-ties (rounding cannot drop the nearest)
Progress = Callable[[int, int], None]  # progress(done, total): how far a long build has come


class NearestStationLookup:
    """Nearest-station distances and free flags from one table lookup per point: cost flat in B.

    The map plus a margin is cut into square lookup cells of side 1/scale. Each cell keeps the
    stations that can be nearest to some point of it (`_candidate_stations`): the first candidate,
    used for every point, and, for the minority of cells near a boundary between two stations'
    regions, a padded row of all its candidates. Per point, two gathers do the common work: the
    first candidate's (x, y) pair from one packed table, and the cell's kind (free? ambiguous?), one byte.
    Queries run in the points' float dtype (float32 particles, float64 for the exact public API).
    """

    def __init__(self, stations: np.ndarray, free_grid: np.ndarray, progress: Progress | None = None):
        """stations (B, 2) in map coordinates; free_grid (H, W) bool, the maze's free cells, row 0 on top;
        `progress(done, total)` is called as the table's tiles are built (a large maze takes seconds)."""
        height, width = free_grid.shape
        self.scale = _lookup_subdivisions(width, height)
        self.offset = _LOOKUP_MARGIN * self.scale  # lookup-cell index of x = 0 (and of y = 0)
        self.nx = (width + 2 * _LOOKUP_MARGIN) * self.scale
        self.ny = (height + 2 * _LOOKUP_MARGIN) * self.scale
        self.stations = stations
        free_up = np.pad(free_grid[::-1], _LOOKUP_MARGIN, constant_values=False)  # row 0: y in [-margin, ...)
        free = np.repeat(np.repeat(free_up, self.scale, axis=0), self.scale, axis=1).ravel()  # (C,) bool
        candidates, counts = _candidate_stations(stations, self.nx, self.ny, self.offset, self.scale, progress)
        ambiguous = np.flatnonzero(counts > 1)
        self.kind = (free * _FREE + (counts > 1) * _AMBIGUOUS).astype(np.int8)  # (C,) each cell's bits
        self.row = np.full(len(counts), -1, dtype=np.int32)  # each cell's row of `_all`, -1: one candidate
        self.row[ambiguous] = np.arange(len(ambiguous))
        # The nearest station to a point beyond the table is the nearest to the point where the segment
        # between them crosses the table's border, so it is a candidate of a border cell.
        grid = candidates.reshape(self.ny, self.nx, -1)  # the outermost ring of cells' candidates, sorted:
        border = np.concatenate([grid[0], grid[-1], grid[:, 0], grid[:, -1]]).ravel()
        self._border = np.flatnonzero(np.bincount(border, minlength=len(stations)))
        self._first = candidates[:, 0]  # (C,) station indices
        self._all = candidates[ambiguous]  # (A, K) station indices, padded by repeats
        self._tables: dict[np.dtype, tuple[np.ndarray, np.ndarray, np.ndarray]] = {}  # `_station_tables`
        self._near: dict[int, tuple[tuple[int, float, float], ...]] = {}  # `station_at`'s, cell by cell

    def locate(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(distance to the nearest station, free flag) for points x, y of shape (N,), in x's dtype."""
        first_xy, others, border = self._station_tables(x.dtype)
        cells, beyond = self._cells(x, y)
        first = first_xy.take(cells, axis=0)  # (N, 2): one gather for both coordinates
        d2 = _squared_distances(first[:, 0], first[:, 1], x, y)
        del first
        kinds = self.kind.take(cells)
        ambiguous = np.flatnonzero(kinds >= _AMBIGUOUS)
        if len(ambiguous):  # the nearest of the other candidates of each ambiguous cell (its row of `others`)
            near, xs, ys = d2.take(ambiguous), x.take(ambiguous), y.take(ambiguous)
            candidates = others.take(self.row.take(cells.take(ambiguous)), axis=0)  # (n, 2 (K - 1))
            for k in range(0, candidates.shape[1], 2):
                np.minimum(near, _squared_distances(candidates[:, k], candidates[:, k + 1], xs, ys), out=near)
            d2[ambiguous] = near
        free = np.bitwise_and(kinds, _FREE, out=kinds).view(bool)
        # the rare points beyond the table: brute force over the border cells' candidates (b), in chunks that
        # bound the (chunk, b) temporary
        for start in range(0, len(beyond), 1024):
            part = beyond[start : start + 1024]
            d2[part] = _squared_distances(border[:, 0], border[:, 1], x[part, None], y[part, None]).min(axis=1)
        free[beyond] = False
        return np.sqrt(d2, out=d2), free

    def station_at(self, x: float, y: float) -> tuple[int, float]:
        """The nearest station's index and distance for one float64 point, in plain floats: `locate`'s
        distance (the same IEEE operations, so the same values; ties go to the earlier candidate),
        without the cost of numpy calls on arrays of one. A lookup cell's
        candidates are made once, as (station index, sx, sy) without repeats: the robot's walk
        revisits its cells."""
        ix, iy = math.floor(x * self.scale) + self.offset, math.floor(y * self.scale) + self.offset
        if not (0 <= ix < self.nx and 0 <= iy < self.ny):  # beyond the table: every station, as `locate`'s border
            d2 = _squared_distances(self.stations[:, 0], self.stations[:, 1], x, y)
            best = int(d2.argmin())
            return best, math.sqrt(d2[best])
        cell = iy * self.nx + ix
        near = self._near.get(cell)
        if near is None:
            row = int(self.row[cell])
            candidates = dict.fromkeys((self._all[row] if row >= 0 else self._first[cell : cell + 1]).tolist())
            near = self._near[cell] = tuple((i, *self.stations[i].tolist()) for i in candidates)
        best, nearest = -1, math.inf
        for index, sx, sy in near:  # `_squared_distances`' order of operations, in plain floats
            dx, dy = sx - x, sy - y
            d2 = dx * dx + dy * dy
            if d2 < nearest:
                best, nearest = index, d2
        return best, math.sqrt(nearest)

    def _cells(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Each point's flat lookup-cell index (N,), and the indices of the points beyond the table (a NaN
        point among them: its distance comes out NaN, which the filter's step reports)."""
        ix = np.floor(x * self.scale)  # exact: the scale is a power of two
        iy = np.floor(y * self.scale)
        ix += self.offset
        iy += self.offset
        inside = ix.min() >= 0 and iy.min() >= 0 and ix.max() < self.nx and iy.max() < self.ny
        beyond = _NO_POINTS if inside else np.flatnonzero(~((ix >= 0) & (ix < self.nx) & (iy >= 0) & (iy < self.ny)))
        ix[beyond] = iy[beyond] = 0  # any cell: their answers are replaced
        iy *= self.nx
        iy += ix  # whole numbers below 2**24 (see _lookup_subdivisions), exact even in float32
        return iy.astype(np.intp), beyond

    def _station_tables(self, dtype: np.dtype) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The candidates' coordinates in `dtype`, made once per dtype: each lookup cell's first candidate's
        (C, 2), the ambiguous cells' other candidates' (A, 2 (K - 1): a row's x1, y1, x2, y2, ..., one
        gather a point), and the border cells' candidates' (b, 2)."""
        if dtype not in self._tables:
            xy = self.stations.astype(dtype)
            others = xy[self._all[:, 1:]].reshape(len(self._all), -1)
            self._tables[dtype] = xy[self._first], others, xy[self._border]
        return self._tables[dtype]


_NO_POINTS = np.empty(0, dtype=np.intp)
_FREE, _AMBIGUOUS = 1, 2  # bits of a lookup cell's kind


def lookup_cell_count(width: int, height: int) -> int:
    """How many lookup cells the table of a width x height maze has (its memory and build time grow so)."""
    scale = _lookup_subdivisions(width, height)
    return (width + 2 * _LOOKUP_MARGIN) * (height + 2 * _LOOKUP_MARGIN) * scale**2


def _lookup_subdivisions(width: int, height: int) -> int:
    """Lookup cells per map unit: the finest of _LOOKUP_FINEST, ..., _LOOKUP_SUBDIVISIONS whose table stays
    within _LOOKUP_FINE_CELLS, else _LOOKUP_SUBDIVISIONS halved while the table would exceed
    _LOOKUP_MAX_CELLS (which keeps flat cell indices exact in float32). A finer cell's candidates are
    some of its coarser cell's, the nearest always among them, so a point's distance is the same at
    every scale (bit for bit: the stations lie on the grid's corners, whole numbers)."""
    area = (width + 2 * _LOOKUP_MARGIN) * (height + 2 * _LOOKUP_MARGIN)
    scale = _LOOKUP_FINEST
    while scale > _LOOKUP_SUBDIVISIONS and area * scale**2 > _LOOKUP_FINE_CELLS:
        scale //= 2
    while scale > 1 and area * scale**2 > _LOOKUP_MAX_CELLS:
        scale //= 2
    return scale


def _squared_distances(sx: np.ndarray, sy: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """(sx - x)^2 + (sy - y)^2, broadcast, in as few temporary arrays as possible."""
    dx = sx - x
    dx *= dx
    dy = sy - y
    dy *= dy
    dx += dy
    return dx


def _candidate_stations(
    stations: np.ndarray, nx: int, ny: int, offset: int, scale: int, progress: Progress | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """For every lookup cell (flat index j * nx + i), the stations that can be nearest to a point of it,
    nearest to the cell's centre first: (C, K) station indices padded by repeating the first, and the
    counts (C,). Built tile by tile, each tile's cells choosing among the tile's own candidates, which
    come from halving the table box by box (each box keeps its parent's candidates that can be nearest
    in it), so a tile checks a few dozen stations, not all B. `progress(done, total)` counts tiles."""
    tiles: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []
    total = -(-nx // _LOOKUP_TILE) * -(-ny // _LOOKUP_TILE)
    boxes = [(0, 0, nx, ny, np.arange(len(stations)))]  # (i0, j0, ni, nj, candidates): a depth-first stack
    while boxes:
        i0, j0, ni, nj, near = boxes.pop()
        lo = (np.array([i0 - offset], dtype=float) / scale, np.array([j0 - offset], dtype=float) / scale)
        near = near[_possibly_nearest(stations[near], *lo, ni / scale, nj / scale)[0]]
        if ni <= _LOOKUP_TILE and nj <= _LOOKUP_TILE:  # a tile: its cells' flat indices, candidates and counts
            ii, jj = np.meshgrid(np.arange(i0, i0 + ni), np.arange(j0, j0 + nj))
            size = 1 / scale
            lo_x, lo_y = (ii.ravel() - offset) * size, (jj.ravel() - offset) * size
            order, counts = _cell_candidates(stations[near], lo_x, lo_y, size)
            tiles.append(((jj * nx + ii).ravel(), near[order], counts))
            if progress is not None:
                progress(len(tiles), total)
        elif ni >= nj:  # cut in two across the longer side, at a multiple of the tile side: the leaves are tiles
            cut = max(1, ni // _LOOKUP_TILE // 2) * _LOOKUP_TILE
            boxes += [(i0 + cut, j0, ni - cut, nj, near), (i0, j0, cut, nj, near)]  # the first half on top
        else:
            cut = max(1, nj // _LOOKUP_TILE // 2) * _LOOKUP_TILE
            boxes += [(i0, j0 + cut, ni, nj - cut, near), (i0, j0, ni, cut, near)]
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
    greatest distance to box c (otherwise that other station is nearer everywhere in the box).
    Compared as squares (no square roots; the tolerance, added to the root of the bound, still covers
    their rounding, a relative 1e-16)."""
    lo_x, lo_y = lo_x[:, None], lo_y[:, None]
    hi_x, hi_y = lo_x + np.asarray(size_x)[..., None], lo_y + np.asarray(size_y)[..., None]
    sx, sy = stations[:, 0], stations[:, 1]
    least = _squared_distances(
        np.maximum(np.maximum(lo_x - sx, sx - hi_x), 0), np.maximum(np.maximum(lo_y - sy, sy - hi_y), 0), 0.0, 0.0
    )
    greatest = _squared_distances(
        np.maximum(np.abs(sx - lo_x), np.abs(sx - hi_x)), np.maximum(np.abs(sy - lo_y), np.abs(sy - hi_y)), 0.0, 0.0
    )
    bound = np.sqrt(greatest.min(axis=1, keepdims=True)) + _LOOKUP_TOLERANCE
    return least <= bound * bound


__all__ = [
    "NearestStationLookup",
    "Progress",
    "lookup_cell_count",
]
