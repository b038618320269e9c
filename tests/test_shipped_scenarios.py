"""The scenarios shipped in model_parameters/: each loads, fits the shipped maze it stores, and replays;
they are found by name from any folder, as the shipped mazes are."""

from pathlib import Path

import numpy as np
import pytest

from mazelab.cli.app import main
from mazelab.maze import load_maze
from mazelab.model import CONVERGENCE_RADIUS
from mazelab.scenario import ScenarioError, load_scenario
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


def test_a_shipped_scenario_is_found_by_its_name_from_any_folder(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    assert load_scenario("paper_5x5").seed == load_scenario(SHIPPED[0].parent / "paper_5x5.json").seed
    assert main(["compare", "twin_rooms_6x12", "--filters", "ekf", "--no-viz"]) == 0
    assert capsys.readouterr().out.startswith("twin_rooms_6x12.json: 1500 particles")
    with pytest.raises(ScenarioError, match=r"model_parameters/paper_5x5.json: no such .*name it 'paper_5x5'"):
        load_scenario("model_parameters/paper_5x5.json")
    (tmp_path / "paper_5x5.json").write_text((SHIPPED[0].parent / "maze_10x10.json").read_text())
    assert load_scenario("paper_5x5.json").maze == load_scenario("maze_10x10").maze  # one's own file comes first
