"""Studies at scale: a run keeps its arrays and builds its Scenario only when asked."""

from __future__ import annotations

import re

import numpy as np
from conftest import PAPER_MAZE

from mazelab import bench as benchmark
from mazelab.maze import Maze
from mazelab.robot import Robot
from mazelab.scenario import load_scenario, save_scenario
from mazelab.simulation import simulate


def test_a_run_builds_its_scenario_only_when_asked_and_it_round_trips(tmp_path, paper_world):
    robot = Robot(0.3, 0.5, paper_world.random_free_place(np.random.default_rng(1)))
    result = simulate(robot, paper_world, 0.3, 0.5, 200, 15, seed=7, kidnap_at=9)
    assert "scenario" not in result.__dict__  # nothing turned into lists or validated yet
    inputs = result.inputs
    assert (inputs.seed, inputs.kidnap_at) == (7, 9) and inputs.init_particles_pos.shape == (200, 2)
    scenario = result.scenario
    assert result.scenario is scenario  # built once
    assert scenario.init_particles_pos == [tuple(p) for p in inputs.init_particles_pos.tolist()]
    assert (scenario.seed, scenario.kidnap_at, scenario.kidnap_position) == (7, 9, inputs.kidnap_position)
    assert load_scenario(save_scenario(scenario, tmp_path / "s.json")) == scenario


def test_run_model_figures_on_a_tiny_run():
    line = benchmark.run_model_line(Maze(PAPER_MAZE), particles=300, steps=3)
    figures = re.fullmatch(
        r"run_model\(\), SIR, N = 300, 3 steps, visualize=False: (\S+) s, (\S+)x its filter steps' own time "
        r"\((\S+) s\), (\S+)x the reference step",
        line,
    )
    assert figures is not None, line
    total, overhead, own, times_reference = (float(value) for value in figures.groups())
    assert overhead > 0 and min(total, own, times_reference) >= 0, line  # the times themselves round to 0.00
