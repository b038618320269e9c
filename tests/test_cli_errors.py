"""Every bad input the CLI can get: one line on stderr naming the problem, exit code 2, no traceback."""

from __future__ import annotations

import json
import os

import pytest
from conftest import PAPER_MAZE

from mazelab.cli.app import main
from mazelab.maze import MAZE_FILE_LIMIT_BYTES

SCENARIO = {
    "init_robot_pos": [3.5, 1.5],
    "init_particles_pos": [[1.5, 3.5], [3.5, 3.5], [4.5, 0.5]],
    "robot_actual_angles": [1.1, 1.4, 0.35],
    "robot_compass_angles": [1.2, 1.2, 0.3],
    "maze": [list(row) for row in PAPER_MAZE],
}


def scenario_text(**changes) -> str:
    data = {**SCENARIO, **changes}
    return json.dumps({k: v for k, v in data.items() if v is not None})


FILES = {
    "ragged.txt": "0 2\n0 1 0\n",
    "letters.txt": "0 2\n0 x\n",
    "empty.txt": "# nothing\n",
    "nofree.txt": "1 2\n1 1\n",
    "nostation.txt": "0 1\n0 0\n",
    "notjson.json": "{not json",
    "truncated.json": scenario_text()[:60],
    "list.json": "[1, 2]",
    "missing_key.json": scenario_text(robot_compass_angles=None),
    "angle_lengths.json": scenario_text(robot_compass_angles=[1.0]),
    "measurements.json": scenario_text(robot_measurements=[1.0]),
    "bad_position.json": scenario_text(init_robot_pos=[1.0, "north"]),
    "triple.json": scenario_text(init_robot_pos=[1.0, 2.0, 3.0]),
    "in_wall.json": scenario_text(init_robot_pos=[0.5, 4.5]),
    "future.json": scenario_text(format_version=99),
    "bad_maze.json": scenario_text(maze=[[0, 3]]),
}

CASES = [
    # mazes
    (["run", "--maze", "{tmp}/ragged.txt"], "ragged.txt:2: 3 cells where the first row has 2: not rectangular"),
    (["run", "--maze", "{tmp}/letters.txt"], "letters.txt:2: 'x' is not a maze cell"),
    (["run", "--maze", "{tmp}/empty.txt"], "the maze is empty"),
    (["run", "--maze", "{tmp}/nofree.txt"], "no free cell"),
    (["run", "--maze", "{tmp}/nostation.txt"], "no station block"),
    (["run", "--maze", "{tmp}/none.txt"], "no such maze file"),
    (["run", "--maze", "{tmp}/binary.txt"], "not a text file"),
    (["run", "--maze", "{tmp}/huge.txt"], "too large for a maze file"),
    (["run", "--maze", "{tmp}"], "is a folder"),
    # numbers
    (["run", "--sigma", "0"], "sigma must be > 0"),
    (["run", "--sigma", "nan"], "sigma must be finite"),
    (["run", "--sigma", "inf"], "sigma must be finite"),
    (["run", "--delta", "-0.1"], "delta must be in [0, 2*pi]"),
    (["run", "--delta", "7"], "delta must be in [0, 2*pi]"),
    (["run", "--particles", "0"], "--particles"),
    (["run", "--particles", "100000000000"], "GiB of memory is available"),
    (["run", "--steps", "0"], "--steps"),
    (["run", "--sigma", "abc"], "--sigma"),
    # scenarios
    (["run", "--scenario", "{tmp}/notjson.json"], "not valid json"),
    (["run", "--scenario", "{tmp}/truncated.json"], "not valid json"),
    (["run", "--scenario", "{tmp}/list.json"], "valid dictionary"),
    (["run", "--scenario", "{tmp}/missing_key.json"], "robot_compass_angles: Field required"),
    (["run", "--scenario", "{tmp}/angle_lengths.json"], "robot_actual_angles has 3 entries but robot_compass_angles"),
    (["run", "--scenario", "{tmp}/measurements.json"], "robot_measurements has 1 entries, 3 expected"),
    (["run", "--scenario", "{tmp}/bad_position.json"], "init_robot_pos.1"),
    (["run", "--scenario", "{tmp}/triple.json"], "init_robot_pos"),
    (["run", "--scenario", "{tmp}/in_wall.json"], "is not in the free area of the maze"),
    (["run", "--scenario", "{tmp}/future.json"], "newer than this program reads"),
    (["run", "--scenario", "{tmp}/bad_maze.json"], "cells must be 0, 1 or 2"),
    (["run", "--scenario", "{tmp}/missing.json"], "no such scenario file"),
    (["run", "--scenario", "{tmp}/in_wall.json", "--maze", "maze_10x10"], "differs"),
    (["compare", "{tmp}/notjson.json"], "not valid json"),
    # names and outputs
    (["run", "--filter", "kalman"], "valid names: SIRParticleFilter"),
    (["run", "--resampling", "magic"], "unknown resampling scheme"),
    (["run", "--save-scenario", "{tmp}/no/such/folder/x.json"], "does not exist"),
    (["run", "--save-scenario", "{tmp}/exists.json"], "exists; use --force"),
    (["run", "--rrd", "{tmp}/exists.json"], "exists; use --force"),
    (["compare", "{tmp}/in_wall.json", "--filters", "sir,kalman"], "kalman"),
    (["study", "--sigma", "0.3,abc"], "--sigma"),
    (["run", "--no-viz", "--web"], "choose one of"),
    (["run", "--bogus"], "No such option"),
]


@pytest.fixture
def bad_files(tmp_path):
    for name, text in FILES.items():
        (tmp_path / name).write_text(text)
    (tmp_path / "binary.txt").write_bytes(b"\xff\xfe\x00")
    with (tmp_path / "huge.txt").open("wb") as huge:  # sparse: as large as that, at no cost
        huge.truncate(MAZE_FILE_LIMIT_BYTES + 1)
    (tmp_path / "exists.json").write_text("{}")
    return tmp_path


@pytest.mark.parametrize(("args", "message"), CASES, ids=[" ".join(a) for a, _ in CASES])
def test_each_bad_input_gets_one_line_and_exit_code_2(bad_files, capsys, args, message):
    argv = [a.replace("{tmp}", str(bad_files)) for a in args]
    assert main([*argv, "--no-viz"] if "--no-viz" not in argv and "--rrd" not in argv else argv) == 2
    err = capsys.readouterr().err
    errors = [line for line in err.splitlines() if not line.startswith("warning:")]
    assert len(errors) == 1 and errors[0].startswith("error: "), err
    assert message in errors[0] and "Traceback" not in err


@pytest.mark.skipif(os.geteuid() == 0, reason="root may write anywhere")
def test_an_unwritable_folder_is_refused(tmp_path, capsys):
    folder = tmp_path / "locked"
    folder.mkdir(mode=0o500)
    assert main(["run", "--no-viz", "--save-scenario", str(folder / "x.json")]) == 2
    assert "not writable" in capsys.readouterr().err


def test_outside_the_lab_ranges_is_a_warning_not_an_error(capsys):
    assert main(["run", "--sigma", "1.2", "--delta", "0.9", "--steps", "3", "--quiet", "--no-viz"]) == 0
    err = capsys.readouterr().err.splitlines()
    assert err == [
        "warning: sigma = 1.2 is outside the lab's range [0.2, 0.8]",
        "warning: delta = 0.9 is outside the lab's range [0.05, 0.6]",
    ]


def test_particles_outside_the_free_area_only_warn(tmp_path, capsys):
    path = tmp_path / "s.json"
    path.write_text(scenario_text(init_particles_pos=[[1.5, 3.5], [-3.0, 9.0]]))
    assert main(["run", "--scenario", str(path), "--quiet", "--no-viz"]) == 0
    assert "1 of the 2 initial particles lie outside the free area" in capsys.readouterr().err
