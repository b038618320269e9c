"""The maze generator: valid, connected, seeded mazes; and the `maze generate` / `maze show` commands."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mazelab.cli.app import main
from mazelab.maze import EMPTY, STATION_WALL, Maze
from mazelab.maze_generator import free_area_is_connected, generate_maze, maze_picture, parse_size


def flood_fill_size(grid: np.ndarray) -> int:
    """How many free cells a 4-neighbour flood fill from the first free cell reaches (independent check)."""
    free = {(int(r), int(c)) for r, c in np.argwhere(grid == EMPTY)}
    stack, seen = [min(free)], {min(free)}
    while stack:
        r, c = stack.pop()
        for cell in ((r + 1, c), (r - 1, c), (r, c + 1), (r, c - 1)):
            if cell in free and cell not in seen:
                seen.add(cell)
                stack.append(cell)
    return len(seen)


@st.composite
def maze_requests(draw):
    rows, columns = draw(st.integers(1, 14)), draw(st.integers(1, 14))
    if rows * columns < 2:
        columns = 2
    stations = draw(st.integers(1, rows * columns - 1))
    return rows, columns, stations, draw(st.floats(0.0, 0.9)), draw(st.integers(0, 2**32))


@settings(max_examples=150, deadline=None)
@given(maze_requests())
def test_generated_mazes_are_valid_and_connected(request):
    rows, columns, stations, wall_share, seed = request
    world = generate_maze(rows, columns, stations, np.random.default_rng(seed), wall_share)
    grid = world.grid
    assert grid.shape == (rows, columns)
    assert set(np.unique(grid)) <= {0, 1, 2}
    assert (grid == STATION_WALL).sum() == stations
    free = int((grid == EMPTY).sum())
    assert free >= 1
    assert flood_fill_size(grid) == free  # the free area is one 4-connected region
    assert free_area_is_connected(grid)
    Maze(world.as_lists())  # and the lab's own validation accepts it


def test_the_wall_share_is_reached_when_it_fits():
    """A 20x20 maze at the default share has round(0.3 * 400) = 120 walls (stations included)."""
    world = generate_maze(20, 20, 12, np.random.default_rng(3))
    assert (world.grid != EMPTY).sum() == 120


def test_the_same_seed_gives_the_same_maze():
    first = generate_maze(12, 9, 5, np.random.default_rng(7))
    assert np.array_equal(first.grid, generate_maze(12, 9, 5, np.random.default_rng(7)).grid)
    assert not np.array_equal(first.grid, generate_maze(12, 9, 5, np.random.default_rng(8)).grid)


def test_connectivity_check_sees_a_diagonal_as_a_cut():
    assert free_area_is_connected(np.array([[0, 0], [1, 0]]))
    assert not free_area_is_connected(np.array([[0, 1], [1, 0]]))  # diagonal neighbours are not 4-connected
    assert not free_area_is_connected(np.array([[1, 2]]))


@pytest.mark.parametrize("text", ["20", "20x", "0x5", "axb", "1x1"])
def test_bad_sizes_are_refused(text):
    with pytest.raises(ValueError, match="maze size"):
        parse_size(text)


def test_impossible_station_counts_are_refused():
    with pytest.raises(ValueError, match="do not fit"):
        generate_maze(2, 2, 4, np.random.default_rng(0))
    with pytest.raises(ValueError, match="at least one station"):
        generate_maze(5, 5, 0, np.random.default_rng(0))


def test_maze_generate_writes_a_file_that_maze_show_prints(tmp_path, capsys):
    path = tmp_path / "x.txt"
    args = ["maze", "generate", "--size", "8x6", "--stations", "3", "--seed", "3"]
    assert main([*args, "--out", str(path)]) == 0
    world = Maze.from_file(path)
    assert world.grid.shape == (8, 6) and (world.grid == STATION_WALL).sum() == 3
    assert "--seed 3" in path.read_text()  # the file says how to make it again
    assert main([*args, "--out", str(path)]) == 2  # exists: refused without --force
    capsys.readouterr()
    assert main([*args]) == 0  # without --out: printed, the same maze
    assert capsys.readouterr().out == path.read_text()
    assert main(["maze", "show", str(path)]) == 0
    out = capsys.readouterr().out
    assert maze_picture(world) in out and "(connected)" in out and "3 station blocks" in out


def test_maze_commands_report_bad_input_in_one_line(capsys):
    assert main(["maze", "generate", "--size", "20"]) == 2
    assert "ROWSxCOLUMNS" in capsys.readouterr().err
    assert main(["maze", "show", "no_such_maze"]) == 2
    assert "no such maze file" in capsys.readouterr().err
