"""Nothing absurd accepted: model numbers beyond what float64 (and float32 particles) can carry on the
map, a replayed walk through walls, loose scenario types, oversized requests (the recording counted),
and files that only look right, are refused in one line naming the option or the file."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from mazelab import checks
from mazelab.checks import ADDRESS_SPACE_SOURCE, MemoryBudget, check_recording, sigma_range
from mazelab.cli.app import main
from mazelab.maze import Maze, load_maze
from mazelab.robot import Robot
from mazelab.simulation import convergence_step, simulate

RUN = ["run", "--maze", "paper_5x5", "--steps", "5", "--particles", "50", "--seed", "1", "--quiet", "--no-viz"]


def one_error_line(capsys) -> str:
    captured = capsys.readouterr()
    lines = [line for line in captured.err.splitlines() if not line.startswith("warning:")]
    assert len(lines) == 1 and lines[0].startswith("error: ") and "Traceback" not in captured.err, captured.err
    return lines[0]


@pytest.mark.parametrize("sigma", ["1e300", "1e160", "1e50", "1e-320"])
@pytest.mark.parametrize("name", ["sir", "apf", "rpf", "ekf"])
def test_an_absurd_sigma_is_refused_in_one_line(sigma, name, capsys):
    assert main([*RUN, "--filter", name, "--sigma", sigma]) == 2
    assert "sigma must lie within" in one_error_line(capsys)


def test_the_sigma_range_follows_the_map_and_keeps_measurements_storable():
    small, large = sigma_range(5, 5), sigma_range(4000, 4000)
    assert small[0] < 1e-9 < 10 < small[1] < large[1] and large[1] * 10 + math.hypot(4000, 4000) <= 1e6


@pytest.mark.parametrize("bandwidth", ["1e300", "1e-300"])
def test_an_absurd_bandwidth_is_refused_in_one_line(bandwidth, capsys):
    assert main([*RUN, "--filter", "rpf", "--bandwidth", bandwidth]) == 2
    assert "bandwidth must be" in one_error_line(capsys)
    assert main(["study", "--maze", "paper_5x5", "--runs", "1", "--filters", "rpf", "--bandwidth", bandwidth]) == 2
    assert "bandwidth must be" in one_error_line(capsys)


def test_accuracy_refuses_an_absurd_sigma_and_a_huge_run_count_before_any_work(capsys, monkeypatch):
    assert main(["accuracy", "--sigma", "1e300"]) == 2
    assert "sigma must lie within" in one_error_line(capsys)
    monkeypatch.setattr(checks, "memory_budget", lambda: MemoryBudget(8 * 2**30, "test budget"))
    assert main(["accuracy", "--runs", "10000000"]) == 2
    assert "a study of 80000000 runs needs" in one_error_line(capsys)  # 4 mazes x 2 RPF bandwidths
    assert capsys.readouterr().out == ""


def test_nan_errors_never_count_as_converged():
    assert convergence_step(np.array([np.nan, np.nan])) is None
    assert convergence_step(np.array([1.0, 0.1, np.nan])) is None
    assert convergence_step(np.array([1.0, 0.1, 0.2])) == 2


def _saved_scenario(tmp_path: Path) -> dict:
    path = tmp_path / "s.json"
    assert main([*RUN[:3], "--steps", "40", "--particles", "50", "--seed", "3", "--quiet", "--no-viz",
                 "--save-scenario", str(path)]) == 0  # fmt: skip
    return json.loads(path.read_text())


def _scenario_file(tmp_path: Path, data: dict, name: str = "edited.json") -> Path:
    path = tmp_path / name
    path.write_text(json.dumps(data))
    return path


def test_a_replayed_walk_through_walls_is_refused_naming_the_step(tmp_path, capsys):
    data = _saved_scenario(tmp_path)
    data["robot_actual_angles"] = [math.pi] * len(data["robot_actual_angles"])
    capsys.readouterr()
    assert main(["run", "--scenario", str(_scenario_file(tmp_path, data)), "--no-viz", "--quiet"]) == 2
    line = one_error_line(capsys)
    assert "robot_actual_angles[" in line and "of the replayed walk leaves the free area" in line


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"seed": True}, "seed: Input should be a valid integer"),
        ({"seed": -3}, "seed: Input should be greater than or equal to 0"),
        ({"sigma": "0.3"}, "sigma: Input should be a valid number"),
        ({"filtering_algorithm": 3}, "filtering_algorithm: Input should be a valid string"),
        ({"filter_options": {"resampling": 3}}, "unknown resampling scheme 3; choose one of systematic"),
        ({"filter_options": {"speed": 100}}, "speed must be in (0, 1]"),
        ({"filter_options": {"outside_penalty": 0}}, "outside_penalty must be in (0, 1]"),
        (
            {"filter_options": {"recovery": "augmented", "alpha_slow": 0.5, "alpha_fast": 0.1}},
            "alpha_slow < alpha_fast",
        ),
        ({"robot_actual_angles": [], "robot_compass_angles": [], "robot_measurements": []}, "at least 1 item"),
        ({"robot_measurements": "negative"}, "robot_measurements[3] = -100 is below"),
    ],
)
def test_scenarios_have_strict_types(tmp_path, capsys, change, message):
    data = _saved_scenario(tmp_path)
    if change.get("robot_measurements") == "negative":
        data["robot_measurements"][3] = -100.0
    elif change.get("robot_measurements") == "far":
        data["robot_measurements"][3] = 1e6
    else:
        data.update(change)
    path = _scenario_file(tmp_path, data)
    capsys.readouterr()
    assert main(["run", "--scenario", str(path), "--no-viz", "--quiet"]) == 2
    line = one_error_line(capsys)
    assert line.startswith(f"error: {path}: ") and message in line


@pytest.mark.parametrize("kind", ["utf-16", "binary", "5000-digit seed"])
def test_unreadable_scenario_files_are_named(tmp_path, capsys, kind):
    path = tmp_path / "bad.json"
    if kind == "utf-16":
        path.write_text('{"init_robot_pos": [1, 2]}', encoding="utf-16")
    elif kind == "binary":
        path.write_bytes(bytes(range(256)))
    else:
        path.write_text('{"seed": ' + "9" * 5000 + "}")
    assert main(["run", "--scenario", str(path), "--no-viz"]) == 2
    assert one_error_line(capsys).startswith(f"error: {path}: ")


def test_a_negative_seed_names_the_option(capsys):
    for command in (RUN, ["study", "--runs", "1"], ["maze", "generate"], ["accuracy"]):
        assert main([*command, "--seed", "-1"]) == 2
        assert "'--seed'" in one_error_line(capsys)


def test_study_refuses_what_run_refuses_before_any_run(capsys):
    study = ["study", "--runs", "2", "--steps", "3"]
    assert main([*study, "--maze", "paper_5x5", "--bandwidth", "multimodal", "--filters", "sir"]) == 2
    assert "does not take --bandwidth" in one_error_line(capsys)
    assert main([*study, "--maze-size", "5x5", "--stations", "0"]) == 2
    assert "--stations 0" in one_error_line(capsys)
    assert "Study:" not in capsys.readouterr().out


def test_the_recording_counts_in_the_memory_check(tmp_path, monkeypatch, capsys):
    budget = MemoryBudget(800 * 2**20, ADDRESS_SPACE_SOURCE)  # ulimit -v of about 1 GB, less Python's share
    check_recording(100, 200, 5000, budget)
    checks.check_memory("particles alone", 250_000 * checks.BYTES_PER_PARTICLE, budget)  # fits without Rerun
    with pytest.raises(checks.MemoryLimitError):
        check_recording(250_000, 20, 5000, budget)
    monkeypatch.setattr(checks, "memory_budget", lambda: budget)
    target = tmp_path / "out.rrd"
    assert main([*RUN[:3], "--particles", "1000000", "--steps", "3", "--rrd", str(target)]) == 2
    assert "with a recording of 3 steps needs" in one_error_line(capsys)
    assert not target.exists()


def test_view_refuses_a_file_that_only_starts_like_a_recording(tmp_path, capsys):
    fake = tmp_path / "fake.rrd"
    fake.write_bytes(b"RRF2" + bytes(200))
    assert main(["view", str(fake)]) == 2
    assert f"{fake}: not a Rerun recording" in one_error_line(capsys)


def test_a_maze_file_with_a_byte_order_mark_loads(tmp_path):
    shipped = load_maze("paper_5x5")
    text = Path(shipped.source).read_text(encoding="utf-8")
    path = tmp_path / "bom.txt"
    path.write_bytes(b"\xef\xbb\xbf" + text.encode("utf-8"))
    assert np.array_equal(Maze.from_file(path).grid, shipped.grid)


def test_the_python_api_checks_world_seed_count_and_resolution(paper_world):
    robot = Robot(0.3, 0.5, (1.5, 1.5))
    with pytest.raises(ValueError, match="world must be a Maze"):
        simulate(robot, None, 0.3, 0.5, 10, 3)
    with pytest.raises(ValueError, match="seed must be a whole number"):
        simulate(robot, paper_world, 0.3, 0.5, 10, 3, seed=1.5)
    with pytest.raises(ValueError, match="particle_count is 7 but 10 initial particles"):
        simulate(robot, paper_world, 0.3, 0.5, 7, 3, [(1.5, 1.5)] * 10)
    for resolution in (0, 100, float("nan")):
        with pytest.raises(ValueError, match="resolution must"):
            simulate(robot, paper_world, 0.3, 0.5, 10, 3, filtering_algorithm="grid", resolution=resolution)


@pytest.mark.parametrize("option", [["--kld-epsilon", "1e300"], ["--kld-epsilon", "1e-320"], ["--kld-z", "1e300"]])
def test_absurd_kld_numbers_are_refused(option, capsys):
    assert main([*RUN, "--kld", *option]) == 2
    assert "KLD" in one_error_line(capsys)
