"""The lost robot (mazelab.robot): it wanders free of the walls by the paper's rules (a compass error
within Delta/2, at most MAX_STRAIGHT_STEPS straight steps, or the number it is given), replays recorded
angles and its own walk exactly, measures with the model's sigma, and refuses inconsistent inputs."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
from conftest import MAZES

from mazelab.maze import Maze
from mazelab.model import MAX_STRAIGHT_STEPS
from mazelab.robot import Robot


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
    for wrong in (0, 2.5, True):
        with pytest.raises(ValueError, match=f"^max_straight_steps must be a whole number >= 1, got {wrong}$"):
            Robot(0.3, 0.1, (3.5, 1.5), max_straight_steps=wrong)


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
