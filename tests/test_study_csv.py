"""The study's CSV is the old file or the new whole one: runs stream into the journal NAME.runs.jsonl,
which a file size limit cuts back to whole lines and which the next study reports; two studies never
share it."""

from __future__ import annotations

import csv
import io
import json
import subprocess
import sys
from pathlib import Path

import pytest
from conftest import ROOT, finished_rows

from mazelab.cli.app import main
from mazelab.experiments import executor
from mazelab.experiments.journal import Journal

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

    def look(unit, backend, **options):
        seen.append(table.read_text())  # what a reader of the CSV sees while the study runs
        return real(unit, backend, **options)

    monkeypatch.setattr(executor, "run_unit_timed", look)
    assert main([*STUDY, "--csv", str(table), "--force"]) == 0
    assert seen and set(seen) == {"old\n"}
    assert len(rows(table)) == 12 and len(finished_rows(table.with_name("s.runs.jsonl"))) == 12
    assert f"written to {table}" in capsys.readouterr().out


@pytest.mark.skipif(resource is None or sys.platform == "win32", reason="RLIMIT_FSIZE")
def test_a_file_size_limit_leaves_the_old_csv_and_whole_lines_in_the_journal(tmp_path):
    table = tmp_path / "s.csv"
    table.write_text("old\n")
    limit = 6000  # bytes: the journal's session line (about 1400) and some runs fit, not all forty (about 30000)

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
    journal = table.with_name("s.runs.jsonl")
    assert f"cannot write {table}" in line and f"the finished rows are in {journal}" in line
    assert "Traceback" not in process.stderr
    assert table.read_text() == "old\n"
    text = journal.read_text()
    assert text.endswith("\n") and 0 < len(text) <= limit and finished_rows(journal)
    assert all(json.loads(line) for line in text.splitlines())  # whole lines only


def test_a_leftover_journal_is_reported_and_replaced_only_with_force(tmp_path, capsys):
    table = tmp_path / "s.csv"
    journal = table.with_name("s.runs.jsonl")
    journal.write_text('{"session": {"parameters": {}}}\n')
    assert main([*STUDY, "--csv", str(table)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"{journal} holds the runs of an earlier study" in err and "--force" in err
    assert journal.read_text() == '{"session": {"parameters": {}}}\n' and not table.exists()
    assert main([*STUDY, "--csv", str(table), "--force"]) == 0
    assert len(rows(table)) == 12 and len(finished_rows(journal)) == 12


def test_a_stopped_studys_journal_is_named_before_its_record(tmp_path, capsys):
    table = tmp_path / "s.csv"
    table.with_name("s.runs.jsonl").write_text('{"session": {"parameters": {}}}\n')
    table.with_name("s.record.json").write_text("{}")  # an earlier study's record too
    assert main([*STUDY, "--csv", str(table)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "s.runs.jsonl holds the runs of an earlier study" in err
    assert "add --resume to the same command" in err and "record" not in err


def test_a_second_study_with_the_same_csv_is_refused(tmp_path, capsys):
    table = tmp_path / "s.csv"
    running = Journal(table.with_name("s.runs.jsonl"))  # the first study, still running: it holds the journal
    try:
        for force in ([], ["--force"], ["--resume"]):
            assert main([*STUDY, "--csv", str(table), *force]) == 2
            err = capsys.readouterr().err
            assert err.count("\n") == 1 and f"another study is writing {table.with_name('s.runs.jsonl')}" in err
    finally:
        running.close()
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
