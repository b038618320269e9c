"""The state-space model, the robot and the resampling schemes."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
from conftest import MAZES

from mazelab.maze import Maze
from mazelab.model import MAX_STRAIGHT_STEPS, OUTSIDE_PENALTY, ROBOT_SPEED, log_likelihood, move, sample_headings
from mazelab.resampling import RESAMPLING_SCHEMES, resampling_scheme
from mazelab.robot import Robot
from mazelab.weights import effective_sample_size


def test_move_is_equation_one():
    start = np.array([[1.0, 2.0], [0.0, 0.0]])
    moved = move(start, np.array([0.0, math.pi / 2]))
    np.testing.assert_allclose(moved, [[1.0 + ROBOT_SPEED, 2.0], [0.0, ROBOT_SPEED]], atol=1e-15)


def test_headings_are_uniform_on_the_compass_interval(rng):
    headings = sample_headings(1.0, 0.5, 100_000, rng)
    assert headings.min() >= 0.75 and headings.max() <= 1.25
    # U(a, b) has mean (a+b)/2 and std (b-a)/sqrt(12); the sample mean's std is that over sqrt(n)
    assert abs(headings.mean() - 1.0) < 5 * 0.5 / math.sqrt(12) / math.sqrt(len(headings))
    assert headings.std() == pytest.approx(0.5 / math.sqrt(12), rel=0.01)


def test_log_likelihood_is_equation_three_with_the_outside_penalty(paper_world):
    sigma, z = 0.3, 1.2
    inside, outside = np.array([[1.5, 3.5]]), np.array([[-0.5, 3.5]])
    d = paper_world.distance_to_nearest_station(inside)[0]
    gauss = math.exp(-0.5 * ((z - d) / sigma) ** 2) / (sigma * math.sqrt(2 * math.pi))
    assert math.exp(log_likelihood(z, inside, paper_world, sigma)[0]) == pytest.approx(gauss, rel=1e-12)
    d_out = paper_world.distance_to_nearest_station(outside)[0]
    gauss_out = math.exp(-0.5 * ((z - d_out) / sigma) ** 2) / (sigma * math.sqrt(2 * math.pi))
    assert math.exp(log_likelihood(z, outside, paper_world, sigma)[0]) == pytest.approx(
        OUTSIDE_PENALTY * gauss_out, rel=1e-12
    )


@pytest.mark.parametrize("path", MAZES, ids=lambda p: p.stem)
def test_wandering_robot_stays_free_and_follows_the_paper_rules(path):
    world = Maze.from_file(path)
    rng = np.random.default_rng(3)
    robot = Robot(0.3, 0.5, world.random_free_place(rng), rng=rng)
    run_length = 0
    for _ in range(600):
        robot.step(world)
        assert world.is_free(*robot.position)
    actual, compass = np.array(robot.actual_angles), np.array(robot.compass_angles)
    assert np.all(np.abs(actual - compass) <= 0.25)
    for previous, current in itertools.pairwise(compass):
        run_length = run_length + 1 if current == previous else 1
        assert run_length <= MAX_STRAIGHT_STEPS
    assert len(set(compass.tolist())) > 600 / MAX_STRAIGHT_STEPS  # it turns


def test_max_straight_steps_is_an_argument(paper_world):
    robot = Robot(0.3, 0.1, (3.5, 1.5), rng=np.random.default_rng(1), max_straight_steps=3)
    for _ in range(60):
        robot.step(paper_world)
    compass = robot.compass_angles
    runs = [len(list(g)) for _, g in itertools.groupby(compass)]
    assert max(runs) <= 3


def test_replaying_the_angles_retraces_the_path_exactly(paper_world):
    first = Robot(0.3, 0.5, (3.5, 1.5), rng=np.random.default_rng(5))
    path = []
    for _ in range(200):
        first.step(paper_world)
        path.append(first.position)
    replay = Robot(
        0.3,
        0.5,
        (3.5, 1.5),
        actual_angles=first.actual_angles,
        compass_angles=first.compass_angles,
        measurements=first.measurements,
    )
    observed = [(replay.step(paper_world), replay.position) for _ in range(200)]
    assert [position for _, position in observed] == path  # bit for bit, not only to 1e-12
    assert [z for (_, z), _ in observed] == first.measurements
    assert [c for (c, _), _ in observed] == first.compass_angles


def test_reset_replays_the_recorded_walk(paper_world):
    robot = Robot(0.3, 0.5, (3.5, 1.5), rng=np.random.default_rng(8))
    walk = [robot.step(paper_world) for _ in range(50)]
    robot.reset()
    assert [robot.step(paper_world) for _ in range(50)] == walk


def test_measurement_noise_has_the_models_sigma(paper_world):
    robot = Robot(0.4, 0.5, (3.5, 1.5), rng=np.random.default_rng(2))
    truth = paper_world.distance_to_nearest_station(3.5, 1.5)
    noise = np.array([robot.measure(paper_world) for _ in range(20_000)]) - truth
    assert abs(noise.mean()) < 5 * 0.4 / math.sqrt(len(noise))
    assert noise.std() == pytest.approx(0.4, rel=0.03)  # the sample std's relative error is ~1/sqrt(2n)


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"actual_angles": [0.1]}, "give both"),
        ({"actual_angles": [0.1, 0.2], "compass_angles": [0.1]}, "actual_angles has 2 entries"),
        ({"actual_angles": [0.1], "compass_angles": [0.1], "measurements": [1.0, 2.0]}, "measurements has 2"),
        ({"actual_angles": [float("nan")], "compass_angles": [0.1]}, "finite"),
    ],
)
def test_inconsistent_robot_inputs_are_refused(kwargs, message):
    with pytest.raises(ValueError, match=message):
        Robot(0.3, 0.5, (1.5, 1.5), **kwargs)


@pytest.mark.parametrize(("sigma", "delta"), [(0, 0.5), (-1, 0.5), (float("inf"), 0.5), (0.3, -0.1), (0.3, 7.0)])
def test_impossible_sigma_or_delta_is_refused(sigma, delta):
    with pytest.raises(ValueError):
        Robot(sigma, delta, (1.5, 1.5))


def test_sigma_outside_the_lab_range_warns():
    with pytest.warns(UserWarning, match="outside the lab's range"):
        Robot(1.5, 0.5, (1.5, 1.5))


@pytest.mark.parametrize("scheme", sorted(RESAMPLING_SCHEMES))
def test_resampling_gives_the_expected_offspring_counts(scheme):
    weights = np.array([0.05, 0.4, 0.25, 0.1, 0.2, 0.0, 0.0, 0.0])
    resample, rng, draws = resampling_scheme(scheme), np.random.default_rng(11), 4000
    n = len(weights)
    counts = np.zeros((draws, n))
    for r in range(draws):
        ancestors = resample(weights, rng)
        assert len(ancestors) == n
        counts[r] = np.bincount(ancestors, minlength=n)
    # Unbiasedness: E[count_i] = N W_i. Multinomial has the largest variance, N W_i (1 - W_i), of the
    # four schemes, so 5 of its standard errors over `draws` repetitions bound every scheme's mean.
    bound = 5 * np.sqrt(n * weights * (1 - weights) / draws) + 1e-12
    assert np.all(np.abs(counts.mean(axis=0) - n * weights) <= bound)
    assert counts[:, weights == 0].sum() == 0
    if scheme in ("systematic", "residual"):
        assert np.all(counts >= np.floor(n * weights))  # at least floor(N W_i) copies
    if scheme == "systematic":
        assert np.all(counts <= np.ceil(n * weights))


def test_effective_sample_size_limits():
    assert effective_sample_size(np.full(10, 0.1)) == pytest.approx(10)
    assert effective_sample_size(np.eye(5)[2]) == 1


def test_unknown_resampling_scheme_lists_the_valid_ones():
    with pytest.raises(ValueError, match="systematic"):
        resampling_scheme("magic")


def test_systematic_resampling_counts_equal_the_inverse_cdf_definition():
    """The O(N) count of systematic resampling must pick, for every point u_m = (m + U) / N, the index i
    with cumsum(W)[i-1] <= u_m < cumsum(W)[i]: the binary search of the definition, for the same U."""
    rng = np.random.default_rng(21)
    for n in (1, 7, 1000):
        weights = rng.random(n) ** 4
        weights[rng.random(n) < 0.3] = 0.0  # particles with no weight get no offspring
        weights = weights / weights.sum() if weights.sum() > 0 else np.full(n, 1 / n)
        offset = np.random.default_rng(n).random()
        expected = np.searchsorted(np.cumsum(weights), (np.arange(n) + offset) / n, side="right")
        fast = resampling_scheme("systematic")(weights, np.random.default_rng(n))
        np.testing.assert_array_equal(fast, expected)
