"""The scenarios shipped in model_parameters/: each loads, fits the shipped maze it stores, and replays."""

from pathlib import Path

import numpy as np
import pytest

from mazelab.mazes import load_maze
from mazelab.model import CONVERGENCE_RADIUS
from mazelab.scenario import load_scenario
from mazelab.simulation import simulate

SHIPPED = sorted((Path(__file__).parent.parent / "model_parameters").glob("*.json"))


def test_scenarios_are_shipped():
    assert {path.stem for path in SHIPPED} >= {"paper_5x5", "maze_10x10", "twin_rooms_6x12"}


@pytest.mark.parametrize("path", SHIPPED, ids=lambda path: path.stem)
def test_a_shipped_scenario_is_its_mazes_and_replays_to_the_same_walk(path):
    scenario = load_scenario(path)
    world = scenario.world()
    assert world is not None and np.array_equal(world.grid, load_maze(path.stem).grid)  # named after its maze
    assert world.is_free(*np.asarray(scenario.init_particles_pos).T).all()
    runs = [
        simulate(
            scenario.robot(), world, scenario.sigma, scenario.delta, init_particles_pos=scenario.init_particles_pos,
            filtering_algorithm=name, seed=scenario.seed,
        )
        for name in (scenario.filtering_algorithm, "AuxiliaryParticleFilter")
    ]  # fmt: skip
    assert len(runs[0].errors) == scenario.steps
    np.testing.assert_array_equal(runs[0].true_positions, runs[1].true_positions)  # one walk for every filter
    assert runs[0].errors[-1] < CONVERGENCE_RADIUS  # the filter it was saved with found the robot
