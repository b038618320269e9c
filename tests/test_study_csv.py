"""The study's CSV is the old file or the new whole one: rows stream into NAME.csv.partial, which a
file size limit cuts back to whole rows and which the next study reports; two studies never share it."""

from __future__ import annotations

import csv
import io
import subprocess
import sys
from pathlib import Path

import pytest
from conftest import ROOT

from mazelab.cli.app import main
from mazelab.experiments import executor
from mazelab.experiments.rowlog import RowLog

try:
    import resource
except ImportError:  # not on Windows
    resource = None

STUDY = ["study", "--maze", "paper_5x5", "--runs", "12", "--steps", "5", "--particles", "30", "--filters", "sir"]
STUDY += ["--seed", "1", "--workers", "1"]


def rows(path: Path) -> list[dict[str, str]]:
    return list(csv.DictReader(io.StringIO(path.read_text())))


def test_force_keeps_the_old_csv_until_the_new_one_is_whole(tmp_path, monkeypatch, capsys):
    table = tmp_path / "s.csv"
    table.write_text("old\n")
    seen = []
    real = executor.run_unit_timed

    def look(unit):
        seen.append(table.read_text())  # what a reader of the CSV sees while the study runs
        return real(unit)

    monkeypatch.setattr(executor, "run_unit_timed", look)
    assert main([*STUDY, "--csv", str(table), "--force"]) == 0
    assert seen and set(seen) == {"old\n"}
    assert len(rows(table)) == 12 and not table.with_name("s.csv.partial").exists()
    assert f"written to {table}" in capsys.readouterr().out


@pytest.mark.skipif(resource is None or sys.platform == "win32", reason="RLIMIT_FSIZE")
def test_a_file_size_limit_leaves_the_old_csv_and_whole_rows_in_the_partial_file(tmp_path):
    table = tmp_path / "s.csv"
    table.write_text("old\n")
    limit = 6000  # bytes: the record (about 3000) and some rows fit, not all forty (about 11000 bytes)

    def limited() -> None:
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))

    process = subprocess.run(
        [sys.executable, str(ROOT / "main.py"), *STUDY, "--runs", "40", "--csv", str(table), "--force", "--no-viz"],
        capture_output=True,
        text=True,
        preexec_fn=limited,
        timeout=300,
    )
    assert process.returncode == 1, process.stderr
    (line,) = process.stderr.strip().splitlines()[-1:]
    assert f"cannot write {table}" in line and f"the finished rows are in {table}.partial" in line
    assert "Traceback" not in process.stderr
    assert table.read_text() == "old\n"
    partial = table.with_name("s.csv.partial").read_text()
    assert partial.endswith("\n") and 0 < len(partial) <= limit
    assert all(
        len(row) == len(rows(table.with_name("s.csv.partial"))[0]) for row in rows(table.with_name("s.csv.partial"))
    )


def test_a_leftover_partial_file_is_reported_and_replaced_only_with_force(tmp_path, capsys):
    table = tmp_path / "s.csv"
    partial = table.with_name("s.csv.partial")
    partial.write_text("rows of a stopped study\n")
    assert main([*STUDY, "--csv", str(table)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"{partial} holds the rows of an earlier study" in err and "--force" in err
    assert partial.read_text() == "rows of a stopped study\n" and not table.exists()
    assert main([*STUDY, "--csv", str(table), "--force"]) == 0
    assert f"discarded the rows of an earlier stopped study in {partial}" in capsys.readouterr().err
    assert len(rows(table)) == 12 and not partial.exists()


def test_a_stopped_studys_partial_file_is_named_before_its_record(tmp_path, capsys):
    table = tmp_path / "s.csv"
    table.with_name("s.csv.partial").write_text("rows of a stopped study\n")
    table.with_name("s.record.json").write_text("{}")  # a stopped study leaves its record too
    assert main([*STUDY, "--csv", str(table)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"{table}.partial holds the rows of an earlier study" in err
    assert "add --resume to the same command" in err and "record" not in err


def test_a_second_study_with_the_same_csv_is_refused(tmp_path, capsys):
    table = tmp_path / "s.csv"
    running = RowLog(table)  # the first study, still running: it holds s.csv.partial
    try:
        for force in ([], ["--force"]):
            assert main([*STUDY, "--csv", str(table), *force]) == 2
            err = capsys.readouterr().err
            assert err.count("\n") == 1 and f"another study is writing {table}.partial" in err
    finally:
        running.discard()
    assert not table.exists()


def test_the_repeat_line_pastes_back_and_gives_the_same_table(tmp_path, monkeypatch, capsys):
    """ "Repeat this study" repeats the study, not its files: pasted back beside the CSV, figure and record
    the study wrote, it is not refused ("exists; use --force") and prints the same table."""
    import shlex

    monkeypatch.chdir(tmp_path)
    words = ["study", "--maze", "paper_5x5", "--filters", "sir", "--runs", "2", "--steps", "8", "--particles", "60",
             "--workers", "1", "--no-viz", "--csv", "s.csv", "--record", "r.json"]  # fmt: skip
    assert main(words) == 0
    first = capsys.readouterr().out
    repeat = next(line for line in first.splitlines() if line.startswith("Repeat this study: "))
    pasted = shlex.split(repeat.removeprefix("Repeat this study: "))
    assert "--csv" not in pasted and "--record" not in pasted and "--seed" in pasted
    assert main(pasted[pasted.index("study") :]) == 0
    again = capsys.readouterr().out

    def table(out: str) -> list[str]:  # the table's rows, less the last column (ms/step, a timing)
        return [line.rsplit(maxsplit=1)[0] for line in out.splitlines() if line.startswith("SIR")]

    assert table(again) == table(first) and table(first)
