"""The kidnapped robot (Robot.kidnap, simulate's kidnap_at, the scenario's kidnapping) and its measure
(mazelab.experiments.kidnapping), each rule on its own:

- at step K the robot is put down at its new place and then takes step K's move; the place is seeded;
- every filter replaying a saved kidnapping sees the same walk; a walk recorded without it cannot be
  kidnapped; scenarios without one stay version 1, and bad kidnappings in a file are refused;
- "re-localised" looks at the mean error of the last DEFAULT_WINDOW steps; recovery_steps counts from the
  kidnapping;
- the command line kidnaps, recovers and adapts, and the recovery table runs as docs/kidnapped.md says.
"""

from __future__ import annotations

import json
import math
from types import SimpleNamespace

import numpy as np
import pytest

from mazelab.cli.app import main
from mazelab.experiments.runs import DEFAULT_WINDOW, recovery_steps, relocalised
from mazelab.model import CONVERGENCE_RADIUS, ROBOT_SPEED
from mazelab.robot import Robot
from mazelab.scenario import Scenario, ScenarioError, load_scenario, save_scenario
from mazelab.simulation import simulate

PARTICLE_FILTERS = ["sir", "apf", "rpf"]


# -- kidnapping ----------------------------------------------------------------------------------
def kidnapped_run(world, name="sir", seed=5, **options):
    robot = Robot(0.3, 0.5, (3.5, 1.5))
    return simulate(robot, world, 0.3, 0.5, 200, 30, filtering_algorithm=name, seed=seed, kidnap_at=12, **options)


def test_the_kidnapped_robot_moves_from_its_new_place(paper_world):
    """Step K: the robot is put down at kidnap_position, then takes step K's move (equation (1))."""
    result = kidnapped_run(paper_world)
    scenario = result.scenario
    assert scenario.kidnap_at == 12 and paper_world.is_free(*scenario.kidnap_position)
    x, y = scenario.kidnap_position
    angle = scenario.robot_actual_angles[11]
    expected = (x + ROBOT_SPEED * math.cos(angle), y + ROBOT_SPEED * math.sin(angle))
    assert tuple(result.true_positions[11]) == expected
    steps = np.hypot(*np.diff(result.true_positions, axis=0).T)
    np.testing.assert_allclose(np.delete(steps, 10), ROBOT_SPEED, rtol=1e-12)  # every step but the jump
    assert scenario.format_version == 3  # it stores the filter's options too
    assert kidnapped_run(paper_world).scenario.kidnap_position == scenario.kidnap_position  # seeded
    assert kidnapped_run(paper_world, seed=6).scenario.kidnap_position != scenario.kidnap_position


def test_every_filter_replaying_a_saved_kidnapping_sees_the_same_walk(tmp_path, paper_world):
    first = kidnapped_run(paper_world)
    path = save_scenario(first.scenario, tmp_path / "k.json")
    data = json.loads(path.read_text())
    assert data["format_version"] == 3 and data["kidnap_at"] == 12
    scenario = load_scenario(path)
    assert scenario == first.scenario
    for name in PARTICLE_FILTERS:
        robot = scenario.robot()
        replay = simulate(robot, paper_world, 0.3, 0.5, init_particles_pos=scenario.init_particles_pos, seed=9,
                          filtering_algorithm=name)  # fmt: skip
        np.testing.assert_array_equal(replay.true_positions, first.true_positions)
        assert replay.scenario.robot_measurements == first.scenario.robot_measurements
        assert replay.scenario.kidnap_position == first.scenario.kidnap_position
        # asking for the same kidnapping again replays it; another one is refused
        again = simulate(robot, paper_world, 0.3, 0.5, 50, seed=9, kidnap_at=12, filtering_algorithm=name)
        np.testing.assert_array_equal(again.true_positions, first.true_positions)
        with pytest.raises(ValueError, match="replays a kidnapping at step 12"):
            simulate(robot, paper_world, 0.3, 0.5, 50, seed=9, kidnap_at=13, filtering_algorithm=name)


def test_a_walk_recorded_without_kidnapping_cannot_be_kidnapped(paper_world):
    robot = Robot(0.3, 0.5, (3.5, 1.5))
    simulate(robot, paper_world, 0.3, 0.5, 50, 20, seed=1)
    with pytest.raises(ValueError, match="recorded without this kidnapping"):
        simulate(robot, paper_world, 0.3, 0.5, 50, 20, seed=1, kidnap_at=10)
    with pytest.raises(ValueError, match="after the last step"):
        simulate(Robot(0.3, 0.5, (3.5, 1.5)), paper_world, 0.3, 0.5, 50, 20, seed=1, kidnap_at=21)
    with pytest.raises(ValueError, match="step number >= 1"):
        simulate(Robot(0.3, 0.5, (3.5, 1.5)), paper_world, 0.3, 0.5, 50, 20, seed=1, kidnap_at=0)


def test_scenarios_without_a_kidnapping_stay_version_1(tmp_path, paper_world):
    result = simulate(Robot(0.3, 0.5, (3.5, 1.5)), paper_world, 0.3, 0.5, 50, 10, seed=2)
    data = json.loads(save_scenario(result.scenario, tmp_path / "s.json").read_text())
    assert data["format_version"] == 3 and "kidnap_at" not in data  # version 3: it stores the options
    del data["format_version"], data["filter_options"]
    assert Scenario.model_validate(data).format_version == 1


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        ({"kidnap_at": 2}, "give both or neither"),
        ({"kidnap_at": 2, "kidnap_position": [1.5, 1.5], "format_version": 1}, "needs format_version 2"),
        ({"kidnap_at": 4, "kidnap_position": [1.5, 1.5]}, "after the last step"),
        ({"kidnap_at": 0, "kidnap_position": [1.5, 1.5]}, "kidnap_at"),
    ],
)
def test_bad_kidnappings_in_a_scenario_file_are_refused(tmp_path, extra, message):
    data = {"init_robot_pos": [1.5, 1.5], "init_particles_pos": [[1, 1]], "robot_actual_angles": [0, 0, 0],
            "robot_compass_angles": [0, 0, 0], **extra}  # fmt: skip
    path = tmp_path / "bad.json"
    path.write_text(json.dumps(data))
    with pytest.raises(ScenarioError, match=message):
        load_scenario(path)
    valid = {key: value for key, value in data.items() if key != "format_version"}
    assert Scenario.model_validate({**valid, "kidnap_at": 2, "kidnap_position": [1.5, 1.5]}).format_version == 2


# -- the kidnap study's windows ---------------------------------------------------------------------
def kidnapped(errors, kidnap_at=5):
    return SimpleNamespace(errors=np.asarray(errors, dtype=float), inputs=SimpleNamespace(kidnap_at=kidnap_at))


def test_relocalised_means_the_mean_error_of_the_last_window_steps_is_small():
    """The last DEFAULT_WINDOW (30) steps: 10 good final steps after 20 bad ones is not re-localised."""
    assert DEFAULT_WINDOW == 30
    bad, good = 3 * CONVERGENCE_RADIUS, 0.1 * CONVERGENCE_RADIUS
    assert relocalised(kidnapped([bad] * 40 + [good] * 30))
    assert not relocalised(kidnapped([bad] * 40 + [bad] * 20 + [good] * 10))
    assert relocalised(kidnapped([bad] * 60 + [good] * 30))  # what came before the window does not count
    # the window is 30 steps exactly: a perfect step 30 steps from the end pulls 29 just too large ones
    # below the radius (mean 0.986), a window of 29 misses it, one of 31 takes in the bad step before
    edge = [100 * CONVERGENCE_RADIUS] * 10 + [0.0] + [1.02 * CONVERGENCE_RADIUS] * 29
    assert relocalised(kidnapped(edge)) and not relocalised(kidnapped([*edge[1:], 1.02 * CONVERGENCE_RADIUS]))


def test_recovery_steps_count_from_the_kidnapping_step():
    """R - K: the error stays below the radius from step R on, K the kidnap step (1-based)."""
    errors = [0.1] * 4 + [2.0] * 6 + [0.1] * 10  # kidnapped at step 5; good again from step 11
    assert recovery_steps(kidnapped(errors, kidnap_at=5)) == 6
    assert recovery_steps(kidnapped([0.1] * 20, kidnap_at=5)) == 0
    assert recovery_steps(kidnapped([0.1] * 10 + [2.0] * 10, kidnap_at=5)) is None


def test_a_seeded_sensor_resetting_run_recovers_and_recovery_steps_say_when(paper_world):
    """Seed 9 (sigma 0.3, 200 particles, kidnapped at step 12 of 30): localised before, lost after,
    found again; recovery_steps marks the first step of the final good stretch."""
    robot = Robot(0.3, 0.5, (3.5, 1.5))
    result = simulate(robot, paper_world, 0.3, 0.5, 200, 30, filtering_algorithm="sir", seed=9, kidnap_at=12,
                      recovery="sensor")  # fmt: skip
    errors, steps = result.errors, recovery_steps(result)
    assert errors[10] < CONVERGENCE_RADIUS and errors[11] >= CONVERGENCE_RADIUS  # found, then carried off
    assert steps is not None and steps > 0
    assert (errors[11 + steps :] < CONVERGENCE_RADIUS).all() and errors[11 + steps - 1] >= CONVERGENCE_RADIUS


# -- the command line ------------------------------------------------------------------------------
def test_run_kidnaps_recovers_and_adapts_from_the_command_line(capsys, tmp_path):
    path = tmp_path / "k.json"
    args = ["run", "--maze", "paper_5x5", "--steps", "60", "--particles", "500", "--seed", "2", "--quiet"]
    assert main([*args, "--kidnap-at", "30", "--sensor-resetting", "--save-scenario", str(path)]) == 0
    assert "kidnapped at step 30" in capsys.readouterr().out
    assert (
        main(["run", "--scenario", str(path), "--filter", "apf", "--kld", "--resampling", "residual", "--quiet"]) == 0
    )
    out = capsys.readouterr().out
    assert "kidnapped at step 30" in out and "particle count: mean" in out
    assert main(["run", "--scenario", str(path), "--kidnap-at", "20", "--quiet"]) == 2
    assert main(["run", "--filter", "grid", "--recovery", "--quiet"]) == 2
    assert main(["run", "--recovery", "--alpha-slow", "0.5", "--quiet"]) == 2
    assert "alpha_slow" in capsys.readouterr().err


def test_the_recovery_table_runs_as_the_readme_says_from_any_folder(tmp_path):
    """`python -m mazelab.experiments.kidnapping RUNS` finds the shipped maze wherever it is started."""
    import subprocess
    import sys

    done = subprocess.run(
        [sys.executable, "-m", "mazelab.experiments.kidnapping", "1"], cwd=tmp_path, capture_output=True, text=True
    )
    assert done.returncode == 0, done.stderr
    lines = done.stdout.strip().splitlines()
    assert lines[0].startswith("filter") and len(lines) == 2 + 3 * 3  # header, rule, three filters x three variants
    assert [line.split()[0] for line in lines[2::3]] == ["SIR", "APF", "RPF"]  # the registry's labels
