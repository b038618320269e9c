"""mazelab.cli.hints and the command line's errors that name the fix (what students trip over):

- a decimal comma is told to be a point (run's numbers, study's lists); a list given as several
  arguments is shown as one; a missing argument gets an example;
- a maze named as a scenario, a CSV or a maze file handed to compare, a folder as an output, a
  recording that is not .rrd, a Maze asked about a 1-D array: one line saying what to type;
- every run and study prints the command that repeats it, and that command repeats it bit for bit;
- maze generate and study spell the wall share both ways, and a generated maze says how it was made.
"""

from __future__ import annotations

import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from mazelab.cli.app import main
from mazelab.invocation import command_prefix
from mazelab.maze import load_maze

ROOT = Path(__file__).resolve().parent.parent


def error_line(capsys) -> str:
    err = capsys.readouterr().err
    assert err.count("\n") == 1, err
    return err


@pytest.mark.parametrize(
    ("args", "fix"),
    [
        (["run", "--sigma", "0,3", "--no-viz"], "write 0.3 (a decimal point, not a comma)"),
        (["run", "--delta=0,5", "--no-viz"], "write 0.5"),
        (["study", "--sigma", "0,3", "--runs", "1"], "for one value write 0.3, for a list 0.3,0.4"),
        (["study", "--sigma", "0.2", "0.4", "--runs", "1"], "a list is one argument, comma-separated: --sigma 0.2,0.4"),
        (["compare"], "e.g. "),
        (["exercise", "new"], "exercise new my_exercise"),
        (["run", "--scenario", "maze_20x20", "--no-viz"], "maze_20x20 is a maze: --maze maze_20x20"),
        (["run", "--rrd", "out.png"], "a recording is an .rrd file (e.g. --rrd out.rrd)"),
    ],
)
def test_a_puzzling_input_gets_one_line_that_names_the_fix(tmp_path, monkeypatch, capsys, args, fix):
    monkeypatch.chdir(tmp_path)
    assert main(args) == 2
    assert fix in error_line(capsys)


def test_compare_says_what_a_file_is_when_it_is_no_scenario(tmp_path, capsys):
    table, maze = tmp_path / "errors.csv", tmp_path / "m.txt"
    table.write_text("step,SIRParticleFilter\n1,0.5\n")
    maze.write_text((ROOT / "mazes" / "paper_5x5.txt").read_text())
    assert main(["compare", str(table), "--no-viz"]) == 2
    assert "looks like a CSV" in error_line(capsys)
    assert main(["compare", str(maze), "--no-viz"]) == 2
    assert f"looks like a maze file: --maze {maze}" in error_line(capsys)


def test_a_folder_as_an_output_asks_for_a_file_in_it(tmp_path, capsys):
    (tmp_path / "recs").mkdir()
    assert main(["run", "--save-scenario", str(tmp_path / "recs"), "--no-viz", "--quiet", "--steps", "3"]) == 2
    line = error_line(capsys)
    assert "is a folder: name a file in it" in line and "only regular files" not in line


def test_the_maze_api_says_what_shape_it_takes(paper_world):
    with pytest.raises(ValueError, match=r"points must have shape \(N, 2\).*or give x and y apart; got shape \(3,\)"):
        paper_world.distance_to_nearest_station(np.array([1.0, 2.0, 3.0]))
    with pytest.raises(ValueError, match=r"points must have shape \(N, 2\)"):
        paper_world.nearest_station([1.0, 2.0, 3.0])
    assert paper_world.distance_to_nearest_station([[1.5, 1.5]]).shape == (1,)


def _printed_command(text: str, what: str) -> list[str]:
    command = re.search(rf"Repeat this {what}: (.+)", text).group(1)
    return shlex.split(command)


def test_a_runs_repeat_line_repeats_it_bit_for_bit_with_its_options(tmp_path):
    first = subprocess.run(
        [sys.executable, str(ROOT / "main.py"), "run", "--maze", "paper_5x5", "--steps", "20", "--no-viz", "--quiet",
         "--option", "resampling=residual", "--filter", "apf"],
        cwd=tmp_path, capture_output=True, text=True, check=True,
    )  # fmt: skip
    command = _printed_command(first.stdout, "run")
    assert "--option" in command and "resampling=residual" in command and "--seed" in command
    activated = {**os.environ, "PATH": f"{Path(sys.executable).parent}{os.pathsep}{os.environ['PATH']}"}
    again = subprocess.run(command, cwd=tmp_path, capture_output=True, text=True, check=True, env=activated)
    assert again.stdout.splitlines()[0] == first.stdout.splitlines()[0]


def test_a_runs_repeat_line_pastes_back_after_the_run_saved_its_files(tmp_path, monkeypatch, capsys):
    """The files the run wrote (--save-scenario, --rrd) are not written again by the repeat line, which
    would find them taken; and --force, which would replace them unasked, is not repeated either."""
    monkeypatch.chdir(tmp_path)
    args = ["run", "--maze", "paper_5x5", "--steps", "8", "--particles", "100", "--quiet"]
    assert main([*args, "--save-scenario", "s.json", "--rrd", "r.rrd", "--force"]) == 0
    first = capsys.readouterr().out
    command = _printed_command(first, "run")
    assert not {"--save-scenario", "s.json", "--rrd", "r.rrd", "--force"} & set(command)
    assert main([*command[len(shlex.split(command_prefix())) :], "--no-viz"]) == 0
    (summary,) = [line for line in first.splitlines() if line.startswith("SIRParticleFilter:")]
    assert capsys.readouterr().out.splitlines()[0] == summary


def test_a_studys_repeat_line_repeats_its_rows(tmp_path, capsys):
    args = ["study", "--maze", "paper_5x5", "--runs", "2", "--steps", "10", "--particles", "60", "--no-viz"]
    assert main([*args, "--workers", "1", "--csv", str(tmp_path / "a.csv")]) == 0
    command = _printed_command(capsys.readouterr().out, "study")
    at = command.index("study")
    repeat = [*command[at:], "--csv", str(tmp_path / "b.csv")]  # the line repeats the study, not its files
    assert "--csv" not in command
    assert main(repeat) == 0
    a, b = ((tmp_path / n).read_text().splitlines() for n in ("a.csv", "b.csv"))
    columns = a[0].split(",")
    timing = [columns.index("ms_per_step"), columns.index("run_seconds")]

    def untimed(line: str) -> list[str]:
        return [cell for i, cell in enumerate(line.split(",")) if i not in timing]

    assert [untimed(line) for line in a] == [untimed(line) for line in b]


def test_a_comparisons_repeat_line_pastes_back_beside_its_files(tmp_path, monkeypatch, capsys):
    """Repeat this comparison: the same table again, its files (--csv, --plot) left out, so that the
    pasted line is not refused for files the first one wrote."""
    monkeypatch.chdir(tmp_path)
    args = ["compare", "paper_5x5", "--filters", "sir,apf", "--no-viz", "--csv", "e.csv"]
    assert main(args) == 0
    first = capsys.readouterr().out
    command = _printed_command(first, "comparison")
    assert "--csv" not in command and "--seed" in command
    assert main(command[command.index("compare") :]) == 0
    again = capsys.readouterr().out

    def table(out: str) -> list[str]:  # the filters' rows less ms/step (a timing, the last column)
        return [line.rsplit(maxsplit=1)[0] for line in out.splitlines() if line.startswith(("SIR", "APF", "Aux"))]

    assert table(first) == table(again) and table(first)


def test_the_wall_share_is_spelled_as_studys_on_maze_generate_too(tmp_path, capsys):
    out = tmp_path / "m.txt"
    assert main(["maze", "generate", "--size", "6x6", "--walls", "0.2", "--seed", "1", "--out", str(out)]) == 0
    text = out.read_text()
    made = re.search(r"# Made by: (.+)", text).group(1)
    assert made.startswith(f"{command_prefix()} maze generate --size 6x6") and "--wall-share 0.2" in made
    assert load_maze(str(out)).height == 6
    args = ["study", "--maze-size", "6x6", "--wall-share", "0.2", "--runs", "1", "--steps", "3", "--particles", "20"]
    assert main([*args, "--no-viz", "--workers", "1"]) == 0
