"""The command line: the demo, `run`, and one-line errors with exit code 2."""

from __future__ import annotations

import subprocess
import sys

import pytest
from conftest import ROOT

from mazelab.cli.app import main


def test_run_prints_a_summary(capsys):
    assert main(["run", "--steps", "30", "--particles", "300", "--seed", "1", "--quiet"]) == 0
    assert "SIRParticleFilter: last-step error" in capsys.readouterr().out


def test_run_saves_and_replays_a_scenario(tmp_path, capsys):
    path = tmp_path / "s.json"
    args = ["run", "--maze", "paper_5x5", "--steps", "25", "--particles", "200", "--seed", "2", "--quiet"]
    assert main([*args, "--save-scenario", str(path)]) == 0
    assert path.exists()
    assert main([*args, "--save-scenario", str(path)]) == 2  # exists: refused without --force
    assert "use --force" in capsys.readouterr().err
    for name in ["apf", "rpf", "grid"]:
        assert main(["run", "--scenario", str(path), "--filter", name, "--quiet"]) == 0
    assert main(["run", "--scenario", str(path), "--maze", "maze_10x10", "--quiet"]) == 2
    assert "differs" in capsys.readouterr().err


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["run", "--particles", "0"], "particle_count must be a whole number >= 1"),  # the library's check
        (["run", "--steps", "-3"], "--steps"),
        (["run", "--sigma", "abc"], "--sigma"),
        (["run", "--sigma", "-1"], "sigma must be > 0"),
        (["run", "--delta", "9"], "delta must be in [0, 2*pi]"),
        (["run", "--maze", "no_such_maze"], "no such maze file"),
        (["run", "--filter", "kalman"], "choose from"),
        (["run", "--scenario", "missing.json"], "no such scenario file"),
        (["run", "--save-scenario", "/no/such/folder/x.json"], "does not exist"),
        (["run", "--bogus"], "No such option"),
    ],
)
def test_bad_arguments_get_one_line_and_exit_code_2(capsys, args, message):
    assert main(args) == 2
    err = capsys.readouterr().err
    assert message in err and err.count("\n") == 1 and "Traceback" not in err


def test_python_main_py_runs_the_demo(tmp_path):
    env = {"PATH": "/usr/bin:/bin", "HOME": str(tmp_path)}
    done = subprocess.run(
        [sys.executable, str(ROOT / "main.py")], cwd=tmp_path, capture_output=True, text=True, timeout=300, env=env
    )
    assert done.returncode == 0, done.stderr
    assert "SIRParticleFilter: last-step error" in done.stdout
    assert "step  200/200" in done.stdout


def test_compare_on_a_saved_scenario_uses_the_options_its_run_set_and_says_so(tmp_path, capsys):
    """A run saved with a non-default option scores the same by `run --scenario` and in `compare`'s
    row of its filter; the option is named on stderr; one given on the command line wins, silently."""
    path, table = tmp_path / "s.json", tmp_path / "errors.csv"
    args = ["run", "--maze", "paper_5x5", "--steps", "30", "--particles", "300", "--seed", "4", "--quiet"]
    assert main([*args, "--filter", "rpf", "--option", "threshold=0.6", "--save-scenario", str(path)]) == 0
    capsys.readouterr()
    assert main(["run", "--scenario", str(path), "--quiet", "--no-viz"]) == 0
    replayed = capsys.readouterr().out.splitlines()[0]
    assert main(["compare", str(path), "--filters", "sir,rpf", "--csv", str(table), "--no-viz"]) == 0
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "threshold 0.6" in err
    last = table.read_text().splitlines()[-1].split(",")
    assert f"last-step error {float(last[2]):.3f}" in replayed
    assert main(["compare", str(path), "--filters", "rpf", "--option", "threshold=0.2", "--no-viz"]) == 0
    assert capsys.readouterr().err == ""
