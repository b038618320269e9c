"""How close each filter comes to the exact posterior (mazelab.experiments.accuracy, `mazelab accuracy`):
the distance is averaged over the second half of the steps; the table has every filter against the exact
grid filter (the reference at distance 0 from itself); its CSV and record, on generated mazes too."""

from __future__ import annotations

import csv
import json
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from mazelab.cli.app import main
from mazelab.experiments.accuracy import ACCURACY_FILTERS


def read_csv(path: Path) -> list[dict[str, str]]:
    with path.open(newline="") as handle:
        return list(csv.DictReader(handle))


# -- accuracy: the second half of the steps --------------------------------------------------------
def test_accuracy_averages_the_distance_over_the_second_half_of_the_steps():
    """The first localisation is not accuracy: 10 steps 3 units off, then 10 steps 0.1 off gives 0.1."""
    from mazelab.experiments.study import distance_to_exact

    exact = np.zeros((20, 2))
    estimates = np.r_[np.full((10, 2), [3.0, 0.0]), np.full((10, 2), [0.0, 0.1])]
    assert distance_to_exact(estimates, exact) == pytest.approx(0.1)
    assert distance_to_exact(estimates[:19], exact[:19]) == pytest.approx((3.0 + 9 * 0.1) / 10)  # steps 10-19


# -- the command ------------------------------------------------------------------------------------
def test_accuracy_reports_every_filter_against_the_exact_posterior(capsys):
    args = ["accuracy", "--maze", "paper_5x5", "--runs", "1", "--steps", "12", "--particles", "150", "--workers", "1"]
    assert main(args) == 0
    out = capsys.readouterr().out
    cells = [re.split(r"\s{2,}", line.strip()) for line in out.splitlines() if line.startswith("paper_5x5")]
    rows = {row[1]: row for row in cells}
    assert set(rows) == {label for label, _, _ in ACCURACY_FILTERS}
    assert rows["grid (exact)"][3:5] == ["0.000", "0.000"]  # the reference is at distance 0 from itself
    assert main([*args[:3], "--runs", "0"]) == 2


def test_accuracy_csv_filters_and_generated_mazes(tmp_path, capsys):
    table = tmp_path / "a.csv"
    args = ["accuracy", "--maze-size", "6x6", "--stations", "2", "--filters", "sir,ekf", "--runs", "2"]
    assert main([*args, "--steps", "10", "--particles", "100", "--workers", "1", "--csv", str(table)]) == 0
    rows = read_csv(table)
    assert [r["filter"] for r in rows[:3]] == ["SIRParticleFilter", "ExtendedKalmanFilter", "grid (exact)"]
    assert len(rows) == 2 * 3 and all(r["maze_seed"] for r in rows)
    assert all(float(r["distance_to_exact"]) == 0 for r in rows if r["filter"] == "grid (exact)")
    assert "95% CI" in capsys.readouterr().out
    assert json.loads((tmp_path / "a.record.json").read_text())["kind"] == "accuracy"


def children_of(pid: int) -> set[int]:
    """The processes whose parent is `pid` (from /proc)."""
    found = set()
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if int(fields[1]) == pid:
            found.add(int(stat.parent.name))
    return found


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="reads the process table from /proc")
@pytest.mark.parametrize("stop", [signal.SIGTERM, signal.SIGINT])
def test_a_stopped_accuracy_ends_its_workers_and_keeps_what_finished(tmp_path, stop):
    table = tmp_path / "a.csv"
    process = subprocess.Popen(
        [sys.executable, "-m", "mazelab", "accuracy", "--maze", "paper_5x5", "--runs", "200", "--workers", "2",
         "--steps", "60", "--csv", str(table)],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    for _ in range(600):  # until both workers run (at most a minute)
        workers = children_of(process.pid)
        if len(workers) >= 2:
            break
        time.sleep(0.1)
    process.send_signal(stop)
    _, err = process.communicate(timeout=60)
    assert process.returncode == 128 + stop, err
    assert re.search(r"interrupted after \d+ of 200 runs", err)
    assert not children_of(process.pid) and not any(Path(f"/proc/{pid}").exists() for pid in workers)
    if table.exists():  # the runs that finished before the stop, whole
        assert json.loads(table.with_suffix(".record.json").read_text())["status"] == "interrupted"


def test_the_same_command_after_an_interrupted_accuracy_resumes_it_and_another_replaces_it(tmp_path, monkeypatch,
                                                                                          capsys):  # fmt: skip
    """An interrupted accuracy leaves its CSV, record and journal: the same command goes on from the runs
    it finished (saying so) and ends with an uninterrupted run's CSV; one of other parameters replaces
    what it left (saying so), without --force."""
    from mazelab.experiments import study as study_module

    args = ["accuracy", "--maze", "paper_5x5", "--runs", "3", "--steps", "6", "--particles", "40", "--filters", "sir",
            "--workers", "1"]  # fmt: skip
    table, whole = tmp_path / "a.csv", tmp_path / "whole.csv"
    assert main([*args, "--csv", str(whole)]) == 0
    real, done = study_module.run_task, []

    def stop_at_the_third(task, visualize=False):
        if len(done) == 2:
            raise KeyboardInterrupt
        done.append(task)
        return real(task, visualize)

    monkeypatch.setattr(study_module, "run_task", stop_at_the_third)
    assert main([*args, "--csv", str(table)]) == 130
    assert json.loads(table.with_suffix(".record.json").read_text())["status"] == "interrupted"
    monkeypatch.setattr(study_module, "run_task", real)
    capsys.readouterr()
    assert main([*args, "--csv", str(table)]) == 0
    out = capsys.readouterr().out
    assert "resuming the interrupted run of" in out and "2 runs kept" in out
    assert table.read_text() == whole.read_text()
    monkeypatch.setattr(study_module, "run_task", stop_at_the_third)
    done.clear()
    assert main([*args, "--csv", str(table), "--force"]) == 130
    monkeypatch.setattr(study_module, "run_task", real)
    capsys.readouterr()
    assert main([*args[:-2], "--workers", "1", "--steps", "7", "--csv", str(table)]) == 0
    assert "replacing what an interrupted run left" in capsys.readouterr().out
