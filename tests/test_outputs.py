"""One file per output (mazelab.cli.options.check_outputs): two outputs of `study`, `compare` or
`accuracy` that are one file, by name, through a symlink or as a hard link, are refused in one line
(exit 2) before any run, with nothing written. Real processes for the commands, real links."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest
from conftest import ROOT

from mazelab.cli.app import main

STUDY = ["study", "--maze", "paper_5x5", "--runs", "2", "--steps", "3", "--particles", "20", "--filters", "sir"]
STUDY += ["--seed", "1", "--workers", "1", "--no-viz"]
ACCURACY = ["accuracy", "--maze", "paper_5x5", "--runs", "1", "--steps", "4", "--particles", "20", "--filters", "sir"]


def command(tmp_path: Path, *arguments: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, str(ROOT / "main.py"), *arguments], cwd=tmp_path, capture_output=True,
                          text=True, timeout=120)  # fmt: skip


@pytest.mark.parametrize(
    ("arguments", "expected"),
    [
        ([*STUDY, "--csv", "s.csv", "--traces", "s.csv"], "--csv and --traces are one file (s.csv)"),
        ([*STUDY, "--csv", "s.csv", "--record", "s.csv"], "--csv and --record are one file (s.csv)"),
        ([*STUDY, "--csv", "s.csv", "--plot", "./s.csv"], "--csv and --plot are one file (s.csv)"),
        ([*STUDY, "--csv", "s.csv", "--record", "s.runs.jsonl"], "--csv's journal and --record are one file"),
        ([*STUDY, "--csv", "s.csv", "--plot", "s.record.json"], "--plot and the record are one file (s.record.json)"),
        ([*STUDY, "--csv", "s.csv", "--traces", "s.summary.csv"], "--traces and the summary CSV are one file"),
        ([*STUDY, "--csv", "s.csv", "--summary-csv", "s.csv"], "--csv and --summary-csv are one file (s.csv)"),
        ([*STUDY, "--csv", "s.csv", "--traces", "s.runs.jsonl"], "--csv's journal and --traces are one file"),
        ([*STUDY[:-1], "--plot", "t.rrd", "--rrd", "t.rrd"], "--plot and --rrd are one file (t.rrd)"),
        ([*ACCURACY, "--csv", "a.csv", "--record", "a.csv"], "--csv and --record are one file (a.csv)"),
    ],
)
def test_two_outputs_of_one_name_are_refused_before_any_run(tmp_path, arguments, expected):
    done = command(tmp_path, *arguments)
    assert done.returncode == 2, done.stderr
    (line,) = done.stderr.splitlines()
    assert line.startswith("error: ") and expected in line and "give each output a name of its own" in line
    assert done.stdout == "" and list(tmp_path.iterdir()) == []  # no header, no run, no file


def test_a_symlink_or_a_hard_link_to_another_output_is_the_same_file(tmp_path, capsys):
    table = tmp_path / "s.csv"
    table.write_text("old\n")
    (tmp_path / "link.csv").symlink_to(table)
    os.link(table, tmp_path / "hard.csv")
    for other in ("link.csv", "hard.csv"):
        assert main([*STUDY, "--csv", str(table), "--traces", str(tmp_path / other), "--force"]) == 2
        err = capsys.readouterr().err
        assert f"--csv and --traces are one file ({table} and {tmp_path / other})" in err
    assert main([*ACCURACY, "--csv", str(table), "--record", str(tmp_path / "link.csv"), "--force"]) == 2
    assert "--csv and --record are one file" in capsys.readouterr().err
    assert table.read_text() == "old\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["hard.csv", "link.csv", "s.csv"]


def test_outputs_of_their_own_names_are_accepted(tmp_path, capsys):
    names = ["--csv", "s.csv", "--traces", "t.csv", "--record", "r.json", "--plot", "p.png"]
    assert main([*STUDY, *[str(tmp_path / n) if n[0] != "-" else n for n in names]]) == 0
    assert sorted(p.name for p in tmp_path.iterdir()) == [
        "p.png",
        "r.json",
        "s.csv",
        "s.runs.jsonl",
        "s.summary.csv",
        "t.csv",
    ]


@pytest.mark.parametrize(
    ("arguments", "expected"),
    [
        (["--csv", "c.csv", "--plot", "c.csv"], "--csv and --plot are one file (c.csv)"),
        (["--csv", "c.csv", "--traces", "c.record.json"], "--traces and the record are one file (c.record.json)"),
        (["--plot", "c.rrd", "--rrd", "c.rrd"], "--plot and --rrd are one file (c.rrd)"),
    ],
)
def test_compares_outputs_of_one_name_are_refused_before_any_run(tmp_path, arguments, expected):
    scenario = ROOT / "model_parameters" / "paper_5x5.json"
    done = command(tmp_path, "compare", str(scenario), "--filters", "sir", *arguments)
    assert done.returncode == 2, done.stderr
    (line,) = done.stderr.splitlines()
    assert expected in line and done.stdout == "" and list(tmp_path.iterdir()) == []


def test_a_runs_scenario_and_recording_of_one_name_are_refused_before_the_run(tmp_path):
    done = command(tmp_path, "run", "--steps", "5", "--save-scenario", "r.rrd", "--rrd", "r.rrd")
    assert done.returncode == 2, done.stderr
    (line,) = done.stderr.splitlines()
    assert "--save-scenario and --rrd are one file (r.rrd)" in line and done.stdout == ""
    assert list(tmp_path.iterdir()) == []
