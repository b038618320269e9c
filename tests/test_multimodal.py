"""The twin-rooms maze keeps a bimodal posterior: the exact filter splits its belief between the rooms."""

from __future__ import annotations

import numpy as np
from conftest import ROOT

from mazelab.grid_filter import GridBayesFilter
from mazelab.maze import Maze
from mazelab.robot import Robot


def test_twin_rooms_posterior_stays_split_between_the_rooms():
    """Seed 0 wanders the left room for 100 steps. The right room is the left one shifted by 6 cells,
    stations included, and the transition model commutes with shifts, so until the robot reaches the
    door the exact posterior gives the twin place the same mass as the true one: half each."""
    world = Maze.from_file(ROOT / "mazes" / "twin_rooms_6x12.txt")
    rng = np.random.default_rng(0)
    robot = Robot(0.3, 0.5, world.random_free_place(rng), rng=rng)
    grid = GridBayesFilter(world, 0.3, 0.5)
    for _ in range(100):
        grid.step(*robot.step(world))
    truth = np.array(robot.position)
    twin = truth + np.array([6.0 if truth[0] < 6 else -6.0, 0.0])
    near = [grid.weights[np.hypot(*(grid.positions - p).T) < 1].sum() for p in (truth, twin)]
    assert near[0] > 0.45 and near[1] > 0.45
    assert not grid.is_confident  # the mean lies between the modes: the circle must not turn green
