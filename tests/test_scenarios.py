"""The paper's lab procedure (steps 2-12) and the saved-scenario file format."""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import pytest

from mazelab.atomic import write_atomically
from mazelab.cli.app import main
from mazelab.scenario import Scenario, ScenarioError, load_scenario, save_scenario
from mazelab.simulation import simulate

PAPER_KEYS = ["init_robot_pos", "init_particles_pos", "robot_actual_angles", "robot_compass_angles"]


def test_the_papers_lab_steps_2_to_12(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    # 2. imports, word for word
    from draw import Maze
    from particle_filter import Robot, run_model

    # 3.-8.
    maze_map = ((2, 0, 1, 0, 0), (0, 0, 0, 0, 1), (1, 1, 1, 0, 0), (1, 0, 0, 0, 0), (0, 0, 2, 0, 1))
    world = Maze(maze_map)
    sigma = 0.3
    delta = 0.5
    robot_position = world.random_free_place()
    robot = Robot(sigma, delta, robot_position)
    particle_count = 1500
    steps = 100
    # 9. the trial run saves model_parameters.json
    trial = run_model(robot, world, sigma, delta, particle_count=particle_count, steps=steps, save_parameters=True)
    assert len(trial) == steps
    # 10. read it back with json.load
    with open("model_parameters.json") as f:  # the paper's step 10, word for word
        params = json.load(f)
    init_robot_pos = params["init_robot_pos"]
    init_particles_pos = params["init_particles_pos"]
    robot_actual_angles = params["robot_actual_angles"]
    robot_compass_angles = params["robot_compass_angles"]
    assert len(init_particles_pos) == particle_count and len(robot_actual_angles) == steps
    # 11.
    robot = Robot(sigma, delta, init_robot_pos, actual_angles=robot_actual_angles, compass_angles=robot_compass_angles)
    # 12. the three filters; counts follow from the given particles and angles
    truths = []
    for name in ["SIRParticleFilter", "AuxiliaryParticleFilter", "RegularizedParticleFilter"]:
        result = run_model(robot, world, sigma, delta, init_particles_pos=init_particles_pos, filtering_algorithm=name)
        assert len(result) == steps
        (x, y), (ex, ey) = result[0]
        assert all(isinstance(v, float) for v in (x, y, ex, ey))
        truths.append(np.array([t for t, _ in result]))
    trial_truth = np.array([t for t, _ in trial])
    for truth in truths:
        np.testing.assert_allclose(truth, trial_truth, rtol=0, atol=1e-12)


def test_saved_scenario_has_the_papers_keys_and_metadata(tmp_path, paper_world):
    from particle_filter import Robot

    robot = Robot(0.3, 0.5, (3.5, 1.5))
    result = simulate(robot, paper_world, 0.3, 0.5, 50, 20, seed=3)
    path = save_scenario(result.scenario, tmp_path / "s.json")
    data = json.loads(path.read_text())
    assert list(data)[:5] == ["format_version", *PAPER_KEYS]
    assert data["format_version"] == 3 and data["filter_options"]["resampling"] == "systematic"  # the options: v3
    without = {k: v for k, v in data.items() if k not in ("format_version", "filter_options")}
    assert Scenario.model_validate(without).format_version == 1  # no options, no kidnapping: version-1 readers
    assert len(data["robot_measurements"]) == 20 and data["steps"] == 20
    assert data["maze"] == paper_world.as_lists() and data["seed"] == 3
    assert data["sigma"] == 0.3 and data["delta"] == 0.5
    assert load_scenario(path) == result.scenario


def test_replaying_a_scenario_gives_every_filter_identical_data(tmp_path, paper_world):
    from particle_filter import Robot

    first = simulate(Robot(0.3, 0.5, (3.5, 1.5)), paper_world, 0.3, 0.5, 300, 60, seed=8)
    scenario = load_scenario(save_scenario(first.scenario, tmp_path / "s.json"))
    for name in ["sir", "apf", "rpf", "grid"]:
        robot = scenario.robot()
        replay = simulate(
            robot,
            scenario.world(),
            0.3,
            0.5,
            init_particles_pos=scenario.init_particles_pos,
            filtering_algorithm=name,
            seed=1,
        )
        np.testing.assert_array_equal(replay.true_positions, first.true_positions)
        assert replay.scenario.robot_measurements == first.scenario.robot_measurements
        assert replay.scenario.init_particles_pos == first.scenario.init_particles_pos


def test_a_file_with_only_the_papers_four_keys_loads_and_runs(tmp_path, paper_world):
    from particle_filter import Robot

    path = tmp_path / "paper.json"
    path.write_text(
        json.dumps(
            {
                "init_robot_pos": [3.5, 1.5],
                "init_particles_pos": [[1.5, 3.5], [3.5, 3.5], [4.5, 0.5]],
                "robot_actual_angles": [1.1, 1.4, 0.35],
                "robot_compass_angles": [1.2, 1.2, 0.3],
            }
        )
    )
    scenario = load_scenario(path)
    robot = Robot(
        0.3,
        0.5,
        scenario.init_robot_pos,
        actual_angles=scenario.robot_actual_angles,
        compass_angles=scenario.robot_compass_angles,
    )
    with pytest.warns(UserWarning, match="1 of the 3 initial particles lie outside the free area"):
        result = simulate(robot, paper_world, 0.3, 0.5, init_particles_pos=scenario.init_particles_pos, seed=0)
    assert len(result.errors) == 3 and result.scenario.robot_measurements is not None


@pytest.mark.parametrize(
    ("content", "message"),
    [
        ("{not json", "not valid json"),
        ('{"init_robot_pos": [1, 2]', "not valid json"),
        ("[]", "Input should be a valid dictionary"),
        ('{"init_robot_pos": [1, 2]}', "init_particles_pos: Field required"),
        (
            '{"init_robot_pos": [1, "a"], "init_particles_pos": [[1, 2]], "robot_actual_angles": [], '
            '"robot_compass_angles": []}',
            "init_robot_pos.1",
        ),
        (
            '{"init_robot_pos": [1, 2], "init_particles_pos": [[1, 2]], "robot_actual_angles": [1, 2], '
            '"robot_compass_angles": [1]}',
            "robot_actual_angles has 2 entries but robot_compass_angles has 1",
        ),
        (
            '{"init_robot_pos": [1, 2], "init_particles_pos": [[1, 2]], "robot_actual_angles": [1], '
            '"robot_compass_angles": [1], "robot_measurements": [1, 2]}',
            "robot_measurements has 2 entries",
        ),
        (
            '{"init_robot_pos": [1, 2], "init_particles_pos": [[1, 2]], "robot_actual_angles": [1], '
            '"robot_compass_angles": [1], "format_version": 99}',
            "newer than this program reads",
        ),
        (
            '{"init_robot_pos": [1, 2], "init_particles_pos": [], "robot_actual_angles": [], '
            '"robot_compass_angles": []}',
            "init_particles_pos",
        ),
        (
            '{"init_robot_pos": [1, NaN], "init_particles_pos": [[1, 2]], "robot_actual_angles": [], '
            '"robot_compass_angles": []}',
            "finite",
        ),
    ],
)
def test_bad_scenario_files_get_one_line_errors(tmp_path, content, message):
    path = tmp_path / "bad.json"
    path.write_text(content)
    with pytest.raises(ScenarioError) as error:
        load_scenario(path)
    text = str(error.value)
    assert text.startswith(str(path)) and message in text and "\n" not in text


def test_missing_scenario_file(tmp_path):
    with pytest.raises(ScenarioError, match="no such scenario file"):
        load_scenario(tmp_path / "nope.json")


def test_an_interrupted_save_leaves_the_old_file_intact(tmp_path, monkeypatch):
    path = tmp_path / "model_parameters.json"
    path.write_text("old and whole")

    def crash(*_args, **_kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(os, "replace", crash)
    with pytest.raises(KeyboardInterrupt):
        write_atomically(path, "new")
    assert path.read_text() == "old and whole"
    assert [p.name for p in tmp_path.iterdir()] == ["model_parameters.json"]  # no temporary left behind


def test_scenario_round_trips_every_float_exactly(tmp_path):
    rng = np.random.default_rng(1)
    angles = rng.uniform(0, 6.3, 50).tolist()
    scenario = Scenario(
        init_robot_pos=(0.1 + 0.2, 1 / 3),
        init_particles_pos=rng.random((10, 2)).tolist(),
        robot_actual_angles=angles,
        robot_compass_angles=angles,
        robot_measurements=rng.random(50).tolist(),
    )
    assert load_scenario(save_scenario(scenario, tmp_path / "x.json")) == scenario


PLUGIN_FILTER = "from mazelab.filters import SIRParticleFilter\n\n\nclass Mine(SIRParticleFilter):\n    pass\n"


def _plugin_scenario(tmp_path, capsys) -> tuple[Path, dict]:
    """A scenario saved by a run of the plug-in mine.py:Mine, and its json."""
    (tmp_path / "mine.py").write_text(PLUGIN_FILTER)
    saved = tmp_path / "s.json"
    args = ["run", "--filter", f"{tmp_path}/mine.py:Mine", "--maze", "paper_5x5", "--steps", "4", "--particles", "50"]
    assert main([*args, "--seed", "1", "--no-viz", "--quiet", "--save-scenario", str(saved)]) == 0
    capsys.readouterr()
    return saved, json.loads(saved.read_text())


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        ({"spec": "mine.py:Mine\nRepeat this run: rm -rf ~"}, "filter_plugin: spec must be one printable line"),
        ({"class": "Mine\nforged"}, "filter_plugin: class must be a Python class name"),
        ({"spec": "mine.py:Other"}, "filter_plugin: spec must name a .py file and the class Mine"),
        ({"spec": "mine.txt:Mine"}, "filter_plugin: spec must name a .py file"),
    ],
)
def test_a_plugin_reference_is_one_printable_line_naming_its_class(tmp_path, capsys, edit, message):
    saved, data = _plugin_scenario(tmp_path, capsys)
    data["filter_plugin"] |= edit
    saved.write_text(json.dumps(data))
    with pytest.raises(ScenarioError) as error:
        load_scenario(saved)
    assert message in str(error.value) and "\n" not in str(error.value)
    assert main(["run", "--scenario", str(saved), "--no-viz", "--quiet"]) == 2
    assert capsys.readouterr().err.count("\n") == 1


def test_a_plugin_scenario_whose_filtering_algorithm_is_not_its_plugins_name_is_refused(tmp_path, capsys):
    saved, data = _plugin_scenario(tmp_path, capsys)
    replay = ["run", "--scenario", str(saved), "--filter", f"{tmp_path}/mine.py:Mine", "--no-viz", "--quiet"]
    assert main(replay) == 0
    saved.write_text(json.dumps({**data, "filtering_algorithm": "SIRParticleFilter"}))
    assert main(replay) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "filtering_algorithm 'SIRParticleFilter' is not the name of the plug-in" in err
