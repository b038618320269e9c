"""What a student following the paper meets on the command line: repeatable runs from one seed,
replays that agree with compare, scenarios with only the paper's keys, recordings viewed without a
display, and help that fits a terminal."""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import urllib.request
from typing import Any

import numpy as np
import pytest
import typer
from conftest import ROOT

from mazelab.cli.app import app, main
from mazelab.maze import load_maze, shipped_mazes
from mazelab.registry import entries, filter_entry
from mazelab.robot import Robot
from mazelab.simulation import simulate

PAPER_KEYS = ["init_robot_pos", "init_particles_pos", "robot_actual_angles", "robot_compass_angles"]
SMALL = ["--particles", "300", "--steps", "60"]


def run_output(capsys, argv: list[str]) -> str:
    assert main(argv) == 0, capsys.readouterr().err
    return capsys.readouterr().out


def test_run_with_a_seed_repeats_exactly(capsys):
    first = run_output(capsys, ["run", "--seed", "123", "--no-viz", *SMALL])
    second = run_output(capsys, ["run", "--seed", "123", "--no-viz", *SMALL])
    assert first == second and "seed 123" in first
    other = run_output(capsys, ["run", "--seed", "124", "--no-viz", *SMALL])
    assert other != first  # the seed decides the start too, not only the filter


def test_a_run_without_a_seed_prints_the_one_that_repeats_it(capsys):
    first = run_output(capsys, ["run", "--no-viz", "--quiet", *SMALL])
    seed = re.search(r"--seed (\d+)", first.strip().splitlines()[-1]).group(1)
    assert run_output(capsys, ["run", "--seed", seed, "--no-viz", "--quiet", *SMALL]) == first


def summary_figures(text: str) -> tuple[str, str]:
    """(last-20% error, convergence step) from a run's summary line."""
    match = re.search(r"last-20% error ([\d.]+); (?:converged at step (\d+)|not converged)", text)
    return match.group(1), match.group(2) or "never"


def test_a_replay_agrees_with_compare(tmp_path, capsys):
    path = tmp_path / "s.json"
    run_output(capsys, ["run", "--maze", "paper_5x5", "--seed", "5", "--no-viz", "--quiet", *SMALL,
                        "--save-scenario", str(path)])  # fmt: skip
    table = run_output(capsys, ["compare", str(path), "--filters", "sir,rpf", "--no-viz"])
    for name in ("sir", "rpf"):  # the table's rows are the registry's labels
        replay = run_output(capsys, ["run", "--scenario", str(path), "--filter", name, "--no-viz", "--quiet"])
        (row,) = [line.split() for line in table.splitlines() if line.split()[:1] == [filter_entry(name).label]]
        last_20, converged = summary_figures(replay)
        assert row[2] == last_20 and row[3:5] == ["step", converged]
        assert "seed 5" in replay


def test_a_replay_refuses_particles_and_steps_it_would_ignore(tmp_path, capsys):
    path = tmp_path / "s.json"
    run_output(capsys, ["run", "--seed", "1", "--no-viz", "--quiet", *SMALL, "--save-scenario", str(path)])
    assert main(["run", "--scenario", str(path), "--particles", "500", "--steps", "50", "--no-viz"]) == 2
    (line,) = capsys.readouterr().err.splitlines()
    assert "--particles and --steps" in line and "300 particles and 60 steps" in line


def papers_keys_only(tmp_path, maze: str, particles: int, seed: int = 3):
    """A scenario file with only the paper's four keys, made on a shipped maze."""
    world = load_maze(maze)
    robot = Robot(0.3, 0.5, world.random_free_place(np.random.default_rng(seed)))
    result = simulate(robot, world, 0.3, 0.5, particles, 30, seed=seed)
    data = result.scenario.model_dump()
    path = tmp_path / f"{maze}.json"
    path.write_text(json.dumps({key: data[key] for key in PAPER_KEYS}))
    return path


def test_a_scenario_with_the_papers_keys_runs_on_the_one_maze_it_fits(tmp_path, capsys):
    path = papers_keys_only(tmp_path, "paper_5x5", 1500)
    assert main(["compare", str(path), "--filters", "sir", "--no-viz", "--seed", "4"]) == 0
    err = capsys.readouterr().err
    assert "using paper_5x5, the one shipped maze it fits" in err
    assert "default sigma 0.3, delta 0.5" in err
    assert "outside the free area" not in err


def test_a_scenario_that_fits_several_mazes_or_none_is_refused_with_one_line(tmp_path, capsys):
    path = tmp_path / "few.json"
    path.write_text(json.dumps({"init_robot_pos": [0.5, 0.5], "init_particles_pos": [[0.5, 0.5]],
                                "robot_actual_angles": [0.0], "robot_compass_angles": [0.0]}))  # fmt: skip
    for argv in (["compare", str(path)], ["run", "--scenario", str(path)]):
        assert main([*argv, "--no-viz"]) == 2
        (line,) = capsys.readouterr().err.splitlines()
        assert "several shipped mazes fit" in line and "pass --maze" in line
    path.write_text(json.dumps({"init_robot_pos": [0.5, 0.5], "init_particles_pos": [[99.5, 99.5]],
                                "robot_actual_angles": [0.0], "robot_compass_angles": [0.0]}))  # fmt: skip
    assert main(["compare", str(path), "--no-viz"]) == 2
    assert "no shipped maze fits" in capsys.readouterr().err
    assert main(["compare", str(path), "--no-viz", "--maze", "maze_20x20", "--filters", "sir"]) == 2
    error = capsys.readouterr().err.splitlines()[-1]  # far off any map: refused by the bounds, not guessed
    assert error.startswith("error: init_particles_pos[0]")
    path.write_text(json.dumps({"init_robot_pos": [0.5, 0.5], "init_particles_pos": [[7.5, 7.5]],
                                "robot_actual_angles": [0.0], "robot_compass_angles": [0.0]}))  # fmt: skip
    assert main(["compare", str(path), "--no-viz", "--maze", "paper_5x5", "--filters", "sir"]) == 0  # only warns


def test_a_mistyped_maze_lists_the_shipped_ones(capsys):
    assert main(["run", "--maze", "maze10x10", "--no-viz"]) == 2
    (line,) = capsys.readouterr().err.splitlines()
    assert line.startswith("error: maze10x10: no such maze file") and all(name in line for name in shipped_mazes())


def test_visualize_refuses_unknown_words_but_takes_file_names(tmp_path, paper_world):
    robot = Robot(0.3, 0.5, (3.5, 3.5))
    with pytest.raises(ValueError, match="did you mean 'viewer'"):
        simulate(robot, paper_world, 0.3, 0.5, 50, 2, seed=1, visualize="viwer")
    assert not (tmp_path / "viwer").exists() and not os.path.exists("viwer")
    path = tmp_path / "run.rrd"
    simulate(robot, paper_world, 0.3, 0.5, 50, 2, seed=1, visualize=str(path))
    assert path.stat().st_size > 0


def commands(group: Any, prefix: tuple[str, ...] = ()) -> list[tuple[tuple[str, ...], Any]]:
    """Every command of the app (click's) with its words, sub-commands included."""
    found = [(prefix, group)]
    for name, command in group.commands.items():
        if hasattr(command, "commands"):
            found += commands(command, (*prefix, name))
        else:
            found.append(((*prefix, name), command))
    return found


def test_every_help_fits_one_screen_of_80_columns(monkeypatch, capsys):
    monkeypatch.setenv("COLUMNS", "80")
    for words, command in commands(typer.main.get_command(app)):
        assert main([*words, "--help"]) == 0
        text = capsys.readouterr().out
        lines = text.splitlines()
        assert len(lines) <= 42 and max(map(len, lines)) <= 80, (words, len(lines))
        names = [name for param in command.params if not getattr(param, "hidden", False) for name in param.opts]
        for name in names:
            if name.startswith("--"):
                assert re.search(rf"(^|[\s,/]){re.escape(name)}(\s|$)", text), (words, name)  # never cut
        assert "<bool>" not in text and "--no-force" not in text
        if words in (("run",), ("study",)):
            assert "[default: maze_10x10]" in " ".join(text.split())  # rich took it for markup and hid it


def children(pid: int) -> list[int]:
    """The child processes of `pid` (Linux's /proc)."""
    return [int(child) for task in os.listdir(f"/proc/{pid}/task")
            for child in open(f"/proc/{pid}/task/{task}/children").read().split()]  # fmt: skip


@pytest.mark.parametrize("stop", [signal.SIGINT, signal.SIGTERM])
def test_mazelab_view_serves_a_recording_on_localhost(tmp_path, capsys, stop):
    path = tmp_path / "run.rrd"
    run_output(capsys, ["run", "--maze", "paper_5x5", "--steps", "3", "--particles", "50", "--seed", "1",
                        "--quiet", "--rrd", str(path)])  # fmt: skip
    process = subprocess.Popen(
        [sys.executable, str(ROOT / "main.py"), "view", str(path)], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
        text=True,
    )  # fmt: skip
    try:
        lines = [process.stdout.readline() for _ in range(3)]
        url = re.fullmatch(r"(http://127\.0\.0\.1:\d+/\S*)\n", lines[2]).group(1)  # a line of its own
        with urllib.request.urlopen(url, timeout=10) as page:
            assert page.status == 200 and b"Rerun" in page.read()
        (server,) = children(process.pid)
    finally:
        process.send_signal(stop)
        out, err = process.communicate(timeout=30)
    assert process.returncode == 0 and "Traceback" not in err
    assert "Stopped serving" in out
    assert not os.path.exists(f"/proc/{server}")  # the rerun server ended with it


def test_the_demo_prints_a_command_that_repeats_it(capsys):
    demo = run_output(capsys, ["--no-viz"])
    command = re.search(r"Repeat this run: .*mazelab (run --seed \d+)", demo).group(1).split()
    summary = [line for line in demo.splitlines() if line.startswith("SIRParticleFilter: last-step error")]
    again = run_output(capsys, [*command, "--no-viz", "--quiet"])
    assert summary == [line for line in again.splitlines() if not line.startswith("Repeat this run:")]


def test_step_10_reads_the_papers_file_and_an_old_place_is_named(tmp_path, monkeypatch, paper_world):
    from particle_filter import load_scenario, run_model

    monkeypatch.chdir(tmp_path)
    robot = Robot(0.3, 0.5, (3.5, 3.5))
    run_model(robot, paper_world, 0.3, 0.5, 100, 5, save_parameters=True, seed=1, visualize=False)
    assert sorted(path.name for path in tmp_path.iterdir()) == ["model_parameters.json"]
    with open("model_parameters.json") as file:  # the paper's step 10, word for word
        assert set(PAPER_KEYS) <= set(json.load(file))
    (tmp_path / "model_parameters").mkdir()
    (tmp_path / "model_parameters.json").rename(tmp_path / "model_parameters" / "model_parameters.json")
    with pytest.raises(ValueError, match=r"no such scenario file \(older versions saved to model_parameters/"):
        load_scenario("model_parameters.json")


def test_mazelab_view_refuses_what_is_not_a_recording(tmp_path, capsys):
    (tmp_path / "s.json").write_text("{}")
    for name in ("s.json", "missing.rrd"):
        assert main(["view", str(tmp_path / name)]) == 2
        (line,) = capsys.readouterr().err.splitlines()
        assert line.startswith(f"error: {tmp_path / name}: ")


def test_options_the_docs_and_the_programs_lines_use_are_in_the_help(capsys):
    """The study's options that docs/studies.md and its "Repeat this study" lines use are listed by
    --help; every flag `mazelab filters NAME` advertises is one that run takes (the flags are generated
    from the declarations, Option.flag)."""
    assert main(["study", "--help"]) == 0
    text = capsys.readouterr().out
    for flag in ("--backend", "--stations", "--wall-share", "--summary-csv", "--dask-timeout", "--draw-run"):
        assert re.search(rf"^\s+{flag}\b", text, re.M), flag
    for name in [e.short_name for e in entries()]:
        assert main(["filters", name]) == 0
        advertised = set(re.findall(r"\[(--[a-z-]+(?:/--[a-z-]+)?)\]", capsys.readouterr().out))
        for flags in advertised:
            for flag in flags.split("/"):
                words = [flag] if flag in ("--kld", "--recovery", "--sensor-resetting") else [flag, "x"]
                assert main(["run", *words, "--help"]) == 0, (name, flag)  # parsed, not "No such option"
                capsys.readouterr()
