"""Geometry of the maze and its file format: exact checks."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import MAZES, PAPER_MAZE, ROOT
from hypothesis import given, settings
from hypothesis import strategies as st

from mazelab.maze import MAZE_FILE_LIMIT_BYTES, Maze, MazeError, parse_maze_text


def brute_force_distance(world: Maze, points: np.ndarray) -> np.ndarray:
    return np.sqrt(((points[:, None, :] - world.stations[None]) ** 2).sum(-1)).min(axis=1)


def test_paper_maze_stations_are_the_corners_of_its_two_station_blocks(paper_world):
    # cell (row 0, col 0) covers [0,1) x [4,5); cell (row 4, col 2) covers [2,3) x [0,1)
    expected = {(0, 4), (1, 4), (0, 5), (1, 5), (2, 0), (3, 0), (2, 1), (3, 1)}
    assert {tuple(p) for p in paper_world.stations.tolist()} == expected
    assert (paper_world.width, paper_world.height) == (5, 5)


def test_shared_corners_of_neighbouring_station_blocks_count_once():
    world = Maze([[2, 2], [0, 0]])
    assert len(world.stations) == 6


@pytest.mark.parametrize("form", [tuple, list, np.array])
def test_maze_accepts_tuples_lists_and_arrays(form):
    grid = form([form(row) for row in PAPER_MAZE]) if form is not np.array else np.array(PAPER_MAZE)
    assert np.array_equal(Maze(grid).grid, np.array(PAPER_MAZE))


def test_is_free_follows_the_map_frame(paper_world):
    # row 0 is the top: (0.5, 4.5) is the station block, (1.5, 4.5) is free, (2.5, 4.5) a wall
    assert not paper_world.is_free(0.5, 4.5)
    assert paper_world.is_free(1.5, 4.5)
    assert not paper_world.is_free(2.5, 4.5)
    assert paper_world.is_free(0.0, 0.0)  # bottom-left cell (row 4, col 0) is free, its corner included
    assert not paper_world.is_free(5.0, 3.5)  # x = W is outside [0, W)
    assert not paper_world.is_free(-0.01, 3.5)
    assert not paper_world.is_free(1.5, 5.0)
    xs = np.array([[1.5, 2.5], [0.5, 3.5]])
    ys = np.array([[4.5, 4.5], [0.5, 0.5]])
    assert paper_world.is_free(xs, ys).tolist() == [[True, False], [True, True]]


@pytest.mark.parametrize("path", MAZES, ids=lambda p: p.stem)
def test_nearest_station_lookup_equals_brute_force(path, rng):
    world = Maze.from_file(path)
    inside = rng.uniform(0, 1, (5000, 2)) * [world.width, world.height]
    around = rng.uniform(-4, 4, (5000, 2)) + rng.uniform(0, 1, (5000, 2)) * [world.width, world.height]
    far = rng.normal(0, 50, (200, 2))
    corners = world.stations + rng.uniform(-1e-9, 1e-9, world.stations.shape)
    points = np.concatenate([inside, around, far, corners])
    np.testing.assert_allclose(world.distance_to_nearest_station(points), brute_force_distance(world, points))
    # the nearest station's coordinates (the EKF's data association) are at exactly that distance
    nearest = world.nearest_station(points)
    assert nearest.shape == points.shape and (nearest[:, None] == world.stations).all(axis=2).any(axis=1).all()
    assert np.array_equal(np.sqrt(((nearest - points) ** 2).sum(axis=1)), world.distance_to_nearest_station(points))
    assert np.array_equal(world.nearest_station(points[0]), nearest[0])


@pytest.mark.parametrize("path", MAZES, ids=lambda p: p.stem)
def test_one_point_paths_give_the_array_paths_values_bit_for_bit(path, rng):
    # the robot's measurement and wall checks and the EKF's association, each a point at a time, and
    # again from the lookup cells' kept candidates
    world = Maze.from_file(path)
    around = rng.uniform(-3, 3, (2000, 2)) + rng.uniform(0, 1, (2000, 2)) * [world.width, world.height]
    points = np.concatenate([around, world.stations, rng.normal(0, 50, (50, 2))])
    distances = world.distance_to_nearest_station(points)
    free = world.is_free(points[:, 0], points[:, 1])
    nearest = world.nearest_station(points)
    for _ in range(2):
        for k, (x, y) in enumerate(points.tolist()):
            assert world.distance_at(x, y) == distances[k] == world.distance_to_nearest_station(x, y)
            assert world.free_at(x, y) == free[k] == world.is_free(x, y)
            assert np.array_equal(world.nearest_station(np.array([x, y])), nearest[k])


def test_distance_takes_scalars_pairs_and_arrays(paper_world):
    assert paper_world.distance_to_nearest_station(1.0, 4.0) == 0.0
    assert paper_world.distance_to_nearest_station(4.0, 3.0) == pytest.approx(np.hypot(1, 2))
    assert paper_world.distance_to_nearest_station(np.array([[4.0, 3.0]])).shape == (1,)
    assert paper_world.distance_to_nearest_station(np.zeros(3), np.zeros(3)).shape == (3,)


def test_random_free_places_are_free_and_uniform_over_free_cells(paper_world, rng):
    points = paper_world.random_free_places(40_000, rng)
    assert paper_world.is_free(points[:, 0], points[:, 1]).all()
    cells = np.floor(points).astype(int)  # (column, y row) of each point's cell
    counts = np.unique(cells[:, 1] * 5 + cells[:, 0], return_counts=True)[1]
    expected = len(points) / len(paper_world.free_cells)
    # each count is Binomial(n, 1/F): its standard deviation is below sqrt(expected)
    assert len(counts) == len(paper_world.free_cells)
    assert np.abs(counts - expected).max() < 5 * np.sqrt(expected)
    x, y = paper_world.random_free_place(rng)
    assert isinstance(x, float) and paper_world.is_free(x, y)


def test_shipped_mazes_load_and_round_trip_through_text():
    assert len(MAZES) >= 4
    for path in MAZES:
        world = Maze.from_file(path)
        assert np.array_equal(Maze(parse_maze_text(world.to_text())).grid, world.grid)


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("0 2\n0 1 0\n", "maze.txt:2: 3 cells where the first row has 2: not rectangular"),
        ("0 2\n0 x\n", "maze.txt:2: 'x' is not a maze cell"),
        ("# only a comment\n\n", "maze.txt: the maze is empty"),
        ("1 2\n1 1\n", "maze.txt: the maze has no free cell"),
        ("0 1\n0 0\n", "maze.txt: the maze has no station block"),
    ],
)
def test_bad_maze_files_are_refused_naming_file_and_line(tmp_path, text, message):
    path = tmp_path / "maze.txt"
    path.write_text(text)
    with pytest.raises(MazeError) as error:
        Maze.from_file(path)
    assert message in str(error.value)
    assert "\n" not in str(error.value)


def test_missing_binary_and_enormous_maze_files_are_refused(tmp_path):
    with pytest.raises(MazeError, match="no such maze file"):
        Maze.from_file(tmp_path / "missing.txt")
    (tmp_path / "binary.txt").write_bytes(b"\xff\xfe\x00\x01")
    with pytest.raises(MazeError, match="not a text file"):
        Maze.from_file(tmp_path / "binary.txt")
    with (tmp_path / "huge.txt").open("wb") as huge:  # sparse: as large as that, at no cost
        huge.truncate(MAZE_FILE_LIMIT_BYTES + 1)
    with pytest.raises(MazeError, match="too large"):
        Maze.from_file(tmp_path / "huge.txt")


def test_maze_file_format_allows_commas_compact_rows_and_comments():
    assert parse_maze_text("# top\n2,0,1  # a comment\n010\n") == [[2, 0, 1], [0, 1, 0]]


@pytest.mark.parametrize("bad", [[], [[]], [[0, 2], [0]], [[0, 3]], [[0, 2.0]], [[True, 2]], 5])
def test_bad_maze_maps_raise_value_errors(bad):
    with pytest.raises(ValueError):
        Maze(bad)


@settings(max_examples=60, deadline=None)
@given(st.lists(st.lists(st.integers(0, 2), min_size=1, max_size=7), min_size=1, max_size=7))
def test_any_grid_gives_a_maze_or_a_clear_error(rows):
    try:
        world = Maze(rows)
    except MazeError as error:
        assert "\n" not in str(error)
        return
    points = np.random.default_rng(0).uniform(-2, 9, (300, 2))
    np.testing.assert_allclose(world.distance_to_nearest_station(points), brute_force_distance(world, points))


def test_mazes_folder_is_where_the_tests_expect():
    assert (ROOT / "mazes" / "paper_5x5.txt").exists()


@pytest.mark.parametrize("path", MAZES, ids=lambda p: p.stem)
def test_float32_lookup_gives_the_free_flag_and_the_distance(path, rng):
    """The particles' float32 lookup: its free flag is is_free's for the very same float32 points, and
    its distance matches brute force up to float32 rounding (relative 6e-8 of coordinates below 30,
    a few ulps through the subtraction, squares and root: 1e-5 map units is ample)."""
    world = Maze.from_file(path)
    points = (rng.uniform(-5, 5, (20_000, 2)) + rng.uniform(0, 1, (20_000, 2)) * [world.width, world.height]).astype(
        np.float32
    )
    distance, free = world.station_distances_and_free(points[:, 0], points[:, 1])
    assert distance.dtype == np.float32
    np.testing.assert_array_equal(free, world.is_free(points[:, 0].astype(float), points[:, 1].astype(float)))
    np.testing.assert_allclose(distance, brute_force_distance(world, points.astype(float)), rtol=0, atol=1e-5)
