"""Random mazes for studies of maze size and station count: `generate_maze(rows, columns, stations, rng)`.

The algorithm: start from an empty grid and visit the cells in a random order, turning a cell into a
wall when it keeps the free area connected, until the wanted share of walls is reached. A cell can
become a wall without disconnecting anything when its free 4-neighbours are joined to one another
through its ring of 8 neighbours (a "simple" cell in digital topology): every path through the cell
can then go round it. The test is local, so each step costs O(1), and the free area is 4-connected
by construction. (It is sufficient, not necessary: should too few walls fit for the stations, an exact
global test adds the rest.) Finally `stations` walls, those beside the free area first, become
station blocks (2).
"""

from __future__ import annotations

import re
from collections.abc import Callable

import numpy as np

from mazelab.lookup import Progress
from mazelab.maze import EMPTY, STATION_WALL, WALL, Maze, check_maze_size
from mazelab.modes import label_components

DEFAULT_WALL_SHARE = 0.3  # share of the cells that become walls (station blocks included)
CELLS_PER_STATION_BLOCK = 25  # the default station count: one block per this many cells
# The ring of 8 neighbours in cyclic order (N, NE, E, SE, S, SW, W, NW): consecutive entries are
# 4-adjacent, so a run of free ring cells is a 4-connected path round the centre.
_RING = ((-1, 0), (-1, 1), (0, 1), (1, 1), (1, 0), (1, -1), (0, -1), (-1, -1))
_EDGE_NEIGHBOURS = (0, 2, 4, 6)  # the positions of N, E, S, W in _RING


def parse_size(text: str) -> tuple[int, int]:
    """'20x20' (rows x columns) -> (20, 20); a clear ValueError otherwise."""
    match = re.fullmatch(r"\s*(\d+)\s*[xX]\s*(\d+)\s*", text)
    if match is None:
        raise ValueError(f"maze size {text!r} is not ROWSxCOLUMNS, e.g. 20x20")
    rows, columns = int(match[1]), int(match[2])
    if rows < 1 or columns < 1 or rows * columns < 2:
        raise ValueError(f"maze size {text!r} is too small: it needs room for a free cell and a station block")
    check_maze_size(rows, columns)
    return rows, columns


def default_station_count(rows: int, columns: int) -> int:
    """One station block per CELLS_PER_STATION_BLOCK cells, at least one."""
    return max(1, round(rows * columns / CELLS_PER_STATION_BLOCK))


def check_generation(rows: int, columns: int, stations: int, wall_share: float = DEFAULT_WALL_SHARE) -> None:
    """Refuse a maze that cannot be generated (one line), before any work: a size, a station count or
    a wall share out of range."""
    check_maze_size(rows, columns)
    if stations < 1:
        raise ValueError(f"a maze needs at least one station block, got --stations {stations}")
    if not 0 <= wall_share < 1:
        raise ValueError(f"the wall share must be in [0, 1), got {wall_share}")
    if stations >= rows * columns:
        raise ValueError(f"{stations} station blocks do not fit in a {rows}x{columns} maze with a free cell")


def generate_maze(
    rows: int,
    columns: int,
    stations: int,
    rng: np.random.Generator,
    wall_share: float = DEFAULT_WALL_SHARE,
    progress: Progress | None = None,
) -> Maze:
    """A random rows x columns maze with `stations` station blocks and a 4-connected free area.

    About `wall_share` of the cells become walls (fewer if no more can be added without cutting the
    free area); at least one cell stays free. The same generator state gives the same maze.
    `progress(done, total)` follows the walls added (a 1000 x 1000 maze takes some seconds).
    """
    check_generation(rows, columns, stations, wall_share)
    grid = np.full((rows, columns), EMPTY, dtype=np.int8)
    wanted = max(stations, round(wall_share * rows * columns))
    walls = _add_walls(grid, wanted, rng, _can_become_wall, progress)
    if walls < stations:  # rare: only free cycles are left, which the local test cannot open
        walls += _add_walls(grid, stations - walls, rng, free_area_is_connected)
    free = np.pad(grid == EMPTY, 1)  # `stations` walls become station blocks, those beside the free area first
    beside_free = free[:-2, 1:-1] | free[2:, 1:-1] | free[1:-1, :-2] | free[1:-1, 2:]
    preferred = np.argwhere((grid == WALL) & beside_free)
    others = np.argwhere((grid == WALL) & ~beside_free)
    chosen = preferred[rng.permutation(len(preferred))[:stations]]
    if len(chosen) < stations:
        chosen = np.concatenate([chosen, others[rng.permutation(len(others))[: stations - len(chosen)]]])
    grid[chosen[:, 0], chosen[:, 1]] = STATION_WALL
    if progress is not None:
        progress(wanted, wanted)
    return Maze(grid, source=f"generated {rows}x{columns} maze")


def _add_walls(
    grid: np.ndarray,
    wanted: int,
    rng: np.random.Generator,
    allowed: Callable[[np.ndarray, int, int], bool],
    progress: Progress | None = None,
) -> int:
    """Turn up to `wanted` free cells into walls, in random order, where `allowed`; returns how many.

    A cell refused early may be allowed once its neighbours changed, so the passes repeat until
    `wanted` is reached or a pass adds nothing. `progress(added, wanted)` is called every 2**14 walls.
    """
    added = 0
    while added < wanted:
        before = added
        for index in rng.permutation(np.flatnonzero(grid.ravel() == EMPTY)):
            r, c = divmod(int(index), grid.shape[1])
            if added < wanted and allowed(grid, r, c):
                grid[r, c] = WALL
                added += 1
                if progress is not None and added % 2**14 == 0 and added < wanted:
                    progress(added, wanted)
        if added == before:
            break
    return added


def _can_become_wall(grid: np.ndarray, r: int, c: int) -> bool:
    """Whether the free cell (r, c) can become a wall with the rest of the free area still connected.

    True when its free 4-neighbours all lie in one run of free cells of its 8-neighbour ring (cells
    beyond the border count as walls); a free cell with no free 4-neighbour is the last free cell.
    """
    rows, columns = grid.shape
    ring = [0 <= r + dr < rows and 0 <= c + dc < columns and grid[r + dr, c + dc] == EMPTY for dr, dc in _RING]
    edge_free = [i for i in _EDGE_NEIGHBOURS if ring[i]]
    if not edge_free:
        return False
    if all(ring):
        return True
    start = ring.index(False)  # walk the ring from a blocked cell, labelling its runs of free cells
    run_of, run = {}, 0
    for step in range(1, 9):
        i = (start + step) % 8
        if ring[i]:
            run_of[i] = run
        elif ring[(i - 1) % 8]:
            run += 1
    return len({run_of[i] for i in edge_free}) == 1


def free_area_is_connected(grid: np.ndarray, r: int | None = None, c: int | None = None) -> bool:
    """Whether the free cells (0) of a grid form one 4-connected region; with (r, c), whether they still
    do with that cell a wall (the exact, global and slower test of `_can_become_wall`)."""
    free = np.asarray(grid) == EMPTY
    if r is not None:
        free[r, c] = False
    return bool(label_components(free, diagonal=False).max(initial=-1) == 0)


def maze_file_text(world: Maze, command: str) -> str:
    """The maze in the mazes/ file format, headed by a comment saying how to make it again."""
    blocks = int((world.grid == STATION_WALL).sum())
    header = (
        f"# A generated {world.height}x{world.width} maze with {blocks} station blocks and a connected free area.\n"
        f"# Made by: {command}\n"
    )
    return header + world.to_text()


def maze_picture(world: Maze) -> str:
    """The maze drawn in text, two characters per cell: '##' wall, '[]' station block, '. ' free."""
    symbols = {EMPTY: ". ", WALL: "##", STATION_WALL: "[]"}
    return "".join("".join(symbols[v] for v in row).rstrip() + "\n" for row in world.grid.tolist())


def describe_maze(world: Maze) -> str:
    """Size, free cells, station blocks and stations, and whether the free area is connected."""
    blocks = int((world.grid == STATION_WALL).sum())
    connected = "connected" if free_area_is_connected(world.grid) else "NOT connected"
    return (
        f"{world.height}x{world.width}, {len(world.free_cells)} free cells ({connected}), "
        f"{blocks} station blocks, {len(world.stations)} stations"
    )
