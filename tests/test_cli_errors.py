"""Every bad input the CLI can get: one line on stderr naming the problem, exit code 2, no traceback."""

from __future__ import annotations

import json
import os

import pytest
from conftest import PAPER_MAZE, needs_unwritable_folders

from mazelab.cli.app import main
from mazelab.maze import MAZE_FILE_LIMIT_BYTES
from mazelab.registry import entries

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
    # values that pass a finiteness check but make no sense in the model (and once broke the filters)
    "compass_angle.json": scenario_text(robot_compass_angles=[1.2, 1e300, 0.3]),
    "compass_angle_huge.json": scenario_text(robot_compass_angles=[1.2, 1.4e226, 0.3]),
    "actual_angle.json": scenario_text(robot_actual_angles=[1.1, -20000.0, 0.35]),
    "far_particle.json": scenario_text(init_particles_pos=[[3.5, 3.5], [1e39, 1]]),
    "particle_beyond_map.json": scenario_text(init_particles_pos=[[3.5, 3.5], [1.5, -11.0]]),
    "particle_beyond_given_map.json": scenario_text(init_particles_pos=[[16.0, 1.0]], maze=None),
    "far_robot.json": scenario_text(init_robot_pos=[1.5, 1e7]),
    "far_measurement.json": scenario_text(robot_measurements=[1.0, 1e300, 1.0]),
    "kidnap_in_wall.json": scenario_text(kidnap_at=2, kidnap_position=[0.5, 4.5]),
    "kidnap_in_wall_given_map.json": scenario_text(kidnap_at=2, kidnap_position=[0.5, 4.5], maze=None),
    "kidnap_far.json": scenario_text(kidnap_at=2, kidnap_position=[1e39, 1.0]),
    "deep.json": "[" * 100_000 + "]" * 100_000,
    "deep_object.json": '{"a":' * 20 + "1" + "}" * 20,
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
    (["run", "--maze", "/dev/zero"], "/dev/zero: not a regular file (a device, pipe or socket); a maze is a text file"),
    (["run", "--maze", "/dev/urandom"], "/dev/urandom: not a regular file"),
    (["run", "--maze", "{tmp}/fifo"], "fifo: not a regular file"),
    (["maze", "show", "/dev/zero"], "/dev/zero: not a regular file"),
    (["run", "--maze", "{tmp}/long_rows.txt"], "long_rows.txt:1: a 1x4001 maze is too large: at most 4000 rows"),
    (["maze", "generate", "--size", "100000x100000"], "a 100000x100000 maze is too large: at most 4000 rows and"),
    (["maze", "generate", "--size", "10x4001"], "a 10x4001 maze is too large"),
    (["study", "--maze-size", "20x20,100000x100000"], "a 100000x100000 maze is too large"),
    # numbers
    (["run", "--sigma", "0"], "sigma must be > 0"),
    (["run", "--sigma", "nan"], "sigma must be finite"),
    (["run", "--sigma", "inf"], "sigma must be finite"),
    (["run", "--delta", "-0.1"], "delta must be in [0, 2*pi]"),
    (["run", "--delta", "7"], "delta must be in [0, 2*pi]"),
    (["run", "--particles", "0"], "particle_count"),  # the library's one check of the count, as one line
    (["run", "--particles", "100000000000"], "GiB of memory is available"),
    (["run", "--steps", "0"], "--steps"),
    (["run", "--steps", "1000000000000"], "steps 1000000000000 needs about 931322.6 GiB, but only"),
    (["study", "--steps", "1000000000000"], "steps 1000000000000 needs about 931322.6 GiB"),
    (["study", "--particles", "10,100000000000"], "particle_count 100000000000 needs about 37252.9 GiB"),
    (["study", "--runs", "1000000000000", "--sigma", "0.3,0.4"], "a study of 2000000000000 runs needs about"),
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
    (
        ["run", "--scenario", "{tmp}/compass_angle.json"],
        "compass_angle.json: robot_compass_angles[1] must lie within [-10000, 10000] radians, got 1e+300",
    ),
    (
        ["run", "--scenario", "{tmp}/compass_angle_huge.json"],
        "robot_compass_angles[1] must lie within [-10000, 10000] radians, got 1.4e+226",
    ),
    (
        ["compare", "{tmp}/compass_angle.json"],
        "robot_compass_angles[1] must lie within [-10000, 10000] radians, got 1e+300",
    ),
    (
        ["run", "--scenario", "{tmp}/actual_angle.json"],
        "robot_actual_angles[1] must lie within [-10000, 10000] radians, got -20000",
    ),
    (
        ["run", "--scenario", "{tmp}/far_particle.json", "--filter", "rpf"],
        "init_particles_pos[1][0] must lie within [-1e+06, 1e+06] map units, got 1e+39",
    ),
    (
        ["run", "--scenario", "{tmp}/particle_beyond_map.json"],
        "particle_beyond_map.json: init_particles_pos[1] = (1.5, -11) lies more than 10 map units beyond the 5 x 5 map",
    ),
    (
        ["run", "--scenario", "{tmp}/particle_beyond_given_map.json", "--maze", "paper_5x5"],
        "init_particles_pos[0] = (16, 1) lies more than 10 map units beyond the 5 x 5 map (1 such point(s))",
    ),
    (
        ["run", "--scenario", "{tmp}/far_robot.json"],
        "init_robot_pos[1] must lie within [-1e+06, 1e+06] map units, got 1e+07",
    ),
    (
        ["run", "--scenario", "{tmp}/far_measurement.json"],
        "robot_measurements[1] must lie within [-1e+06, 1e+06] map units, got 1e+300",
    ),
    (
        ["run", "--scenario", "{tmp}/kidnap_in_wall.json"],
        "kidnap_in_wall.json: kidnap_position (0.5, 4.5) is not in the free area of the scenario's maze",
    ),
    (
        ["run", "--scenario", "{tmp}/kidnap_in_wall_given_map.json", "--maze", "paper_5x5"],
        "the kidnap position (0.5, 4.5) is not in the free area of the maze",
    ),
    (
        ["run", "--scenario", "{tmp}/kidnap_far.json"],
        "kidnap_position[0] must lie within [-1e+06, 1e+06] map units, got 1e+39",
    ),
    (["run", "--scenario", "{tmp}/deep.json"], "deep.json: json nested 100000 deep; a scenario nests at most 16 deep"),
    (["compare", "{tmp}/deep_object.json"], "deep_object.json: json nested 20 deep"),
    (["run", "--scenario", "/dev/zero"], "/dev/zero: not a regular file (a device, pipe or socket); a scenario is"),
    (["compare", "/dev/urandom"], "/dev/urandom: not a regular file"),
    (["run", "--scenario", "{tmp}"], "is a folder, not a scenario file"),
    (["run", "--scenario", "{tmp}/in_wall.json", "--maze", "maze_10x10"], "differs"),
    (["compare", "{tmp}/notjson.json"], "not valid json"),
    # names and outputs
    (
        ["run", "--filter", "kalman"],
        f"unknown filter 'kalman' (choose from {', '.join(e.short_name for e in entries())}, or FILE.py:Class)",
    ),
    (["run", "--resampling", "magic"], "unknown resampling scheme"),
    (["run", "--save-scenario", "{tmp}/no/such/folder/x.json"], "does not exist"),
    (["run", "--save-scenario", "{tmp}/exists.json"], "exists; use --force"),
    (["run", "--rrd", "{tmp}/exists.rrd"], "exists; use --force"),
    (["run", "--rrd", "{tmp}/exists.json"], "a recording is an .rrd file"),
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
    (tmp_path / "exists.rrd").write_bytes(b"")
    (tmp_path / "long_rows.txt").write_text("0" * 4000 + "2\n")
    os.mkfifo(tmp_path / "fifo")  # opening it would block: it must be refused before that
    return tmp_path


@pytest.mark.parametrize(("args", "message"), CASES, ids=[" ".join(a) for a, _ in CASES])
def test_each_bad_input_gets_one_line_and_exit_code_2(bad_files, capsys, args, message):
    argv = [a.replace("{tmp}", str(bad_files)) for a in args]
    draws = argv[0] in ("run", "compare", "study") and "--no-viz" not in argv and "--rrd" not in argv
    assert main([*argv, "--no-viz"] if draws else argv) == 2
    err = capsys.readouterr().err
    errors = [line for line in err.splitlines() if not line.startswith("warning:")]
    assert len(errors) == 1 and errors[0].startswith("error: "), err
    assert message in errors[0] and "Traceback" not in err


@needs_unwritable_folders
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
