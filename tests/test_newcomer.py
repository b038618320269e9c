"""What a student meets first: working in a folder of their own, commands printed so that they can be
pasted back, a scenario replayed on the wrong maze, overridden parameters, error wording, the help,
the order of a --web run's output, and the step panel of the viewer."""

from __future__ import annotations

import json
import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import typer
from conftest import ROOT
from test_visualization import _ctrl_c_once, latest, load

from mazelab import maze as maze_module
from mazelab.cli.app import main
from mazelab.cli.options import flag_spellings
from mazelab.invocation import PROJECT_DIR, command_prefix
from mazelab.maze import LAB_MAZES, Maze, MazeError, shipped_mazes
from mazelab.registry import entries
from mazelab.robot import Robot
from mazelab.simulation import check_walk, simulate
from mazelab.viz import processes

PAPER_MAZE = ((2, 0, 1, 0, 0), (0, 0, 0, 0, 1), (1, 1, 1, 0, 0), (1, 0, 0, 0, 0), (0, 0, 2, 0, 1))
# a student's shell: not inside `uv run`, no display, the project not on PYTHONPATH
STUDENT_ENV = {
    k: v
    for k, v in os.environ.items()
    if k not in ("UV", "UV_RUN_RECURSION_DEPTH", "DISPLAY", "WAYLAND_DISPLAY", "PYTHONPATH", "RERUN")
}
LAB_SCRIPT = """
import json

from draw import Maze
from particle_filter import Robot, run_model

world = Maze.from_file("paper_5x5")  # a shipped maze, by its name, from any folder
robot = Robot(0.3, 0.5, world.random_free_place())
run_model(robot, world, 0.3, 0.5, particle_count=200, steps=5, save_parameters=True, visualize=False, seed=1)
with open("model_parameters.json") as f:
    print(len(json.load(f)["robot_actual_angles"]), "steps saved here")
"""


# -- a folder of one's own -------------------------------------------------------------------------
def test_a_lab_script_in_a_folder_of_its_own_runs_with_the_projects_python(tmp_path):
    (tmp_path / "lab.py").write_text(LAB_SCRIPT)
    done = subprocess.run(
        [sys.executable, "lab.py"], cwd=tmp_path, env=STUDENT_ENV, capture_output=True, text=True, timeout=120
    )
    assert done.returncode == 0, done.stderr
    assert "5 steps saved here" in done.stdout and (tmp_path / "model_parameters.json").is_file()
    assert f"scenario saved to {(tmp_path / 'model_parameters.json').resolve()}" in done.stdout  # says where


def test_the_command_a_run_prints_can_be_pasted_in_a_folder_of_its_own(tmp_path):
    """The demo ends with `Repeat this run: ...`: that command, run as printed in the same folder,
    repeats the run (the same summary line)."""
    env = {**STUDENT_ENV, "PATH": os.defpath}  # the environment not activated: `mazelab` is not on the PATH
    demo = subprocess.run(
        [sys.executable, "-m", "mazelab", "--no-viz"], cwd=tmp_path, env=env, capture_output=True, text=True
    )
    assert demo.returncode == 0, demo.stderr
    command = re.search(r"Repeat this run: (.+)", demo.stdout).group(1)
    assert command.startswith(f"{shlex.quote(sys.executable)} -m mazelab run --seed ")
    again = subprocess.run(
        [*shlex.split(command), "--no-viz", "--quiet"], cwd=tmp_path, env=env, capture_output=True, text=True
    )
    assert again.returncode == 0, again.stderr
    summary = [line for line in demo.stdout.splitlines() if line.startswith("SIRParticleFilter:")]
    assert summary and summary[0] in again.stdout


@pytest.mark.parametrize(
    ("argv0", "environ", "inside", "expected"),
    [
        ("main.py", {}, True, "python main.py"),
        ("main.py", {"UV": "uv"}, True, "uv run main.py"),
        ("main.py", {"UV": "uv"}, False, f"uv run --project {shlex.quote(str(PROJECT_DIR))} main.py"),
        ("/x/.venv/bin/mazelab", {"UV": "uv"}, True, "uv run mazelab"),
        ("/x/.venv/bin/mazelab", {"UV": "uv"}, False, f"uv run --project {shlex.quote(str(PROJECT_DIR))} mazelab"),
        ("/x/.venv/bin/mazelab", {"PATH": ""}, True, f"{shlex.quote(sys.executable)} -m mazelab"),
    ],
)
def test_printed_commands_follow_how_the_program_was_started(tmp_path, argv0, environ, inside, expected):
    cwd = PROJECT_DIR if inside else tmp_path
    assert command_prefix(argv0, {"PATH": "", **environ}, cwd) == expected


def test_the_installed_command_on_the_path_is_printed_plainly(tmp_path):
    script = tmp_path / "bin" / "mazelab"
    script.parent.mkdir()
    script.write_text("#!/bin/sh\n")
    script.chmod(0o755)
    assert command_prefix(str(script), {"PATH": str(script.parent)}, tmp_path) == "mazelab"


def test_an_option_of_run_given_without_the_command_says_where_it_belongs(capsys):
    assert main(["--seed", "1"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--seed is an option of run" in err and err.rstrip().endswith("run --seed 1")


def test_shipped_mazes_are_found_by_name_from_any_folder(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    assert Maze.from_file("paper_5x5").width == 5
    with pytest.raises(MazeError, match=r"mazes/paper_5x5.txt: no such maze file .*name it 'paper_5x5'"):
        Maze.from_file("mazes/paper_5x5.txt")
    assert main(["run", "--maze", "mazes/paper_5x5.txt", "--no-viz"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "'paper_5x5'" in err


def test_accuracy_runs_on_the_named_shipped_mazes_not_on_whatever_is_in_mazes(tmp_path, monkeypatch):
    for name in shipped_mazes():
        (tmp_path / f"{name}.txt").write_text((maze_module.MAZES_DIR / f"{name}.txt").read_text())
    (tmp_path / "random_20x20.txt").write_text((maze_module.MAZES_DIR / "maze_20x20.txt").read_text())  # a student's
    monkeypatch.setattr(maze_module, "MAZES_DIR", tmp_path)
    from mazelab.cli import study as accuracy

    seen = []

    def planned(mazes, *args, **kwargs):  # the mazes the study would run on; no run
        seen.extend(maze.label for maze in mazes)
        raise typer.Exit(0)

    monkeypatch.setattr(accuracy, "accuracy_plan", planned)
    assert main(["accuracy", "--runs", "1"]) == 0
    assert seen == list(LAB_MAZES) and "random_20x20" not in seen


# -- a scenario from another maze, overridden parameters -------------------------------------------
def test_a_walk_into_a_wall_is_refused_and_a_walk_made_on_the_maze_is_not():
    world = Maze(PAPER_MAZE)
    down = Robot(0.3, 0.5, (0.5, 3.5), actual_angles=[-np.pi / 2] * 4, compass_angles=[-np.pi / 2] * 4)
    with pytest.raises(
        ValueError,
        match=r"robot_actual_angles\[2\]: step 3 of the replayed walk leaves the free area .* at \(0.50, 2.90\)",
    ):
        check_walk(world, down)
    wandered = simulate(Robot(0.3, 0.5, (3.5, 1.5)), world, 0.3, 0.5, 100, 300, seed=5)
    check_walk(world, wandered.scenario.robot())  # 300 steps of wandering stay in the free area
    kidnapped = Robot(0.3, 0.5, (0.5, 3.5), [0.0] * 3, [0.0] * 3, kidnap_at=2, kidnap_position=(0.5, 2.5))
    with pytest.raises(ValueError, match=r"the kidnap position \(0.5, 2.5\) is not in the free area"):  # in a wall
        check_walk(world, kidnapped)
    kidnapped = Robot(0.3, 0.5, (0.5, 3.5), [0.0] * 4, [0.0] * 4, kidnap_at=2, kidnap_position=(3.5, 3.5))
    with pytest.raises(ValueError, match="step 4"):  # put down in the free area, then walked into a wall
        check_walk(world, kidnapped)


@pytest.fixture
def four_keys(tmp_path, capsys) -> Path:
    """A scenario of the paper's four keys, made on paper_5x5."""
    made = tmp_path / "made.json"
    assert main(["run", "--maze", "paper_5x5", "--steps", "150", "--particles", "200", "--seed", "3",
                 "--no-viz", "--quiet", "--save-scenario", str(made)]) == 0  # fmt: skip
    data = json.loads(made.read_text())
    path = tmp_path / "four.json"
    keys = ("init_robot_pos", "init_particles_pos", "robot_actual_angles", "robot_compass_angles")
    path.write_text(json.dumps({key: data[key] for key in keys}))
    capsys.readouterr()
    return path


def test_a_scenario_replayed_on_another_maze_is_refused_in_one_line(four_keys, capsys):
    assert main(["run", "--scenario", str(four_keys), "--maze", "maze_20x20", "--no-viz"]) == 2
    err = capsys.readouterr().err
    errors = [line for line in err.splitlines() if line.startswith("error:")]
    assert len(errors) == 1 and "maze_20x20" in errors[0] and errors[0].endswith("(--maze)")
    assert main(["run", "--scenario", str(four_keys), "--maze", "paper_5x5", "--no-viz", "--quiet"]) == 0


def test_overriding_a_replayed_scenarios_sigma_or_delta_says_so(tmp_path, capsys):
    path = tmp_path / "s.json"
    args = ["--no-viz", "--quiet"]
    assert (
        main(["run", "--maze", "paper_5x5", "--steps", "20", "--seed", "1", "--save-scenario", str(path), *args]) == 0
    )
    capsys.readouterr()
    assert main(["run", "--scenario", str(path), "--sigma", "0.6", "--delta", "0.5", *args]) == 0
    err = capsys.readouterr().err
    assert "--sigma 0.6 overrides the scenario's sigma 0.3" in err and "measurements were made with 0.3" in err
    assert "--delta" not in err  # the stored value, given again, overrides nothing


# -- error wording and help ------------------------------------------------------------------------
@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["view", "{tmp}"], "is a folder, not a recording"),
        (["run", "--maze", "{tmp}/s.json", "--no-viz"], "looks like a saved scenario (json), not a maze"),
        (["run", "--filter", "sri", "--no-viz"], "did you mean sir?"),
        (["compare", "{tmp}/s.json", "--filters", "sir,apff"], "did you mean apf?"),
        (["study", "--filters", "rfp", "--runs", "1"], "did you mean rpf?"),
        (["run", "--filter", "--no-viz"], "--filter needs a value, got the option --no-viz"),
    ],
)
def test_puzzling_input_gets_a_line_that_says_what_to_do(tmp_path, capsys, args, message):
    (tmp_path / "s.json").write_text('{"init_robot_pos": [0.5, 0.5]}')
    assert main([arg.replace("{tmp}", str(tmp_path)) for arg in args]) == 2
    err = capsys.readouterr().err
    assert message in err and err.count("\n") == 1


@pytest.mark.parametrize("command", [["run"], ["compare"], ["study"], ["view"], ["maze", "show"], ["accuracy"]])
def test_help_shows_names_and_choices_not_braces_or_types(capsys, command):
    assert main([*command, "--help"]) == 0
    text = capsys.readouterr().out
    usage = text.splitlines()[0]
    assert usage.startswith("Usage:") and "{" not in usage
    assert "--filter <str>" not in text and "--filters <str>" not in text and "z_(1-delta)" not in text
    if command == ["run"]:  # the filters from the registry, every declared flag named (mazelab filters: their help)
        assert "--filter NAME" in text and ", ".join(e.short_name for e in entries()) in text
        assert all(
            f"--{name.replace('_', '-')}" in " ".join(text.split())
            for name in {o.name for _, o, _ in flag_spellings(False)}
        )


def test_every_commands_description_fits_on_its_line_of_the_help_in_80_columns(capsys, monkeypatch):
    monkeypatch.setenv("COLUMNS", "80")
    assert main(["--help"]) == 0
    text = capsys.readouterr().out
    commands = text[text.index("Commands:") :].splitlines()[1:]
    assert commands and all(line.startswith("  ") and len(line) <= 80 for line in commands)
    assert all(len(line.split()) > 1 and not line.rstrip().endswith("...") for line in commands), commands


# -- the web viewer and the step panel -------------------------------------------------------------
def test_a_web_run_prints_its_results_before_serving_and_its_address_once(monkeypatch, capsys):
    servers = []
    start = processes.WebServer.start

    def start_and_interrupt_the_wait(cls):
        server = start()
        server.process.wait = _ctrl_c_once(server.process.wait)
        servers.append(server)
        return server

    monkeypatch.setattr(processes.WebServer, "start", classmethod(start_and_interrupt_the_wait))
    assert main(["run", "--maze", "paper_5x5", "--steps", "5", "--particles", "100", "--quiet", "--web"]) == 0
    (server,) = servers
    out = capsys.readouterr().out
    assert out.count(server.url) == 1
    assert out.index("SIRParticleFilter: last-step error") < out.index("press Ctrl-C to stop serving")
    assert server.process.poll() is not None


@pytest.mark.parametrize("command", [["run", "--maze", "paper_5x5"], ["compare", "{scenario}"]])
def test_the_step_panel_has_room_for_its_line(tmp_path, capsys, command):
    """The step panel (the paper's window title) gets at least 0.17 of its column: in the web viewer at
    1400 x 900 (headless Chromium) 0.18 showed "Step 200" whole, where 0.1 cut it in half."""
    scenario = ROOT / "model_parameters" / "paper_5x5.json"
    path = tmp_path / "run.rrd"
    args = [arg.replace("{scenario}", str(scenario)) for arg in command]
    assert main([*args, "--rrd", str(path)] + (["--steps", "2", "--particles", "50"] if args[0] == "run" else [])) == 0
    blueprint = load(path, "blueprint")
    step_view = next(
        entity.removeprefix("/")
        for entity, rows in blueprint.items()
        if entity.startswith("/view/")
        and "ViewBlueprint:space_origin" in latest(rows)
        and latest(rows)["ViewBlueprint:space_origin"] == ["/title"]
    )
    (column,) = [
        latest(rows)
        for entity, rows in blueprint.items()
        if entity.startswith("/container/") and step_view in latest(rows)["ContainerBlueprint:contents"]
    ]
    shares = column["ContainerBlueprint:row_shares"]
    assert shares[column["ContainerBlueprint:contents"].index(step_view)] / sum(shares) >= 0.17
