"""The study's journal (mazelab.experiments.journal): NAME.runs.jsonl is a regular file the study creates
itself, never followed through a link (a symlink, dangling or not, or a hard link at its name is refused
in one line, --force or not); and the record beside the CSV always describes that CSV: a study killed
with kill -9 or stopped with Ctrl-C under --force keeps the old CSV *and* the old record, its own
parameters and runs wait in its journal for --resume. Real processes, real signals, real links."""

from __future__ import annotations

import csv
import importlib.util
import io
import json
import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest
from conftest import ROOT, finished_rows

from mazelab.cli.app import main
from mazelab.experiments import journal as journals
from mazelab.experiments.journal import Journal, JournalError

STUDY = ["study", "--maze", "paper_5x5", "--runs", "6", "--steps", "5", "--particles", "30", "--filters", "sir,apf"]
STUDY += ["--workers", "1", "--no-viz"]
USERS_FILE = "a user's own notes, not a study's rows\n"
OLD_CSV, OLD_RECORD = "an older study's rows\n", '{"an older study": "its record"}\n'


def rows(path: Path) -> list[dict[str, str]]:
    return list(csv.DictReader(io.StringIO(path.read_text())))


def untimed(row: dict[str, str]) -> dict[str, str]:
    return {k: v for k, v in row.items() if k not in ("ms_per_step", "run_seconds")}


def one_error(capsys) -> str:
    err = capsys.readouterr().err
    (line,) = err.splitlines()
    assert line.startswith("error: ") and "Traceback" not in err
    return line


def lines(path: Path) -> list[dict]:
    return [json.loads(line) for line in path.read_text().splitlines()]


# -- the journal is the study's own file -----------------------------------------------------------------
@pytest.mark.parametrize("flags", [[], ["--force"], ["--resume"]])
def test_a_journal_that_links_to_a_users_file_is_refused_and_the_file_kept(tmp_path, capsys, flags):
    table, users = tmp_path / "s.csv", tmp_path / "notes.txt"
    if "--resume" in flags:
        assert main([*STUDY, "--seed", "1", "--csv", str(table)]) == 0
        capsys.readouterr()
        (tmp_path / "s.runs.jsonl").unlink()
    users.write_text(USERS_FILE)
    (tmp_path / "s.runs.jsonl").symlink_to(users)
    assert main([*STUDY, "--seed", "1", "--csv", str(table), *flags]) == 2
    line = one_error(capsys)
    assert f"{tmp_path / 's.runs.jsonl'} is a symlink; a journal is a regular file the program creates" in line
    assert users.read_text() == USERS_FILE and (tmp_path / "s.runs.jsonl").is_symlink()


def test_a_dangling_link_and_a_hard_link_at_the_journals_name_are_refused(tmp_path, capsys):
    table, users = tmp_path / "s.csv", tmp_path / "notes.txt"
    (tmp_path / "s.runs.jsonl").symlink_to(tmp_path / "nowhere")
    assert main([*STUDY, "--seed", "1", "--csv", str(table), "--force"]) == 2
    assert "s.runs.jsonl is a symlink" in one_error(capsys) and not (tmp_path / "nowhere").exists()
    (tmp_path / "s.runs.jsonl").unlink()
    users.write_text(USERS_FILE)
    os.link(users, tmp_path / "s.runs.jsonl")
    assert main([*STUDY, "--seed", "1", "--csv", str(table), "--force"]) == 2
    assert "s.runs.jsonl is a second name of another file (a hard link)" in one_error(capsys)
    assert users.read_text() == USERS_FILE and not table.exists()


def test_a_link_put_at_the_journals_name_after_the_checks_is_not_followed(tmp_path, monkeypatch):
    """A symlink that appears at the journal's name right after its name was checked: the journal is
    opened without following it (O_NOFOLLOW), and the user's file stays as it was."""
    users = tmp_path / "notes.txt"
    users.write_text(USERS_FILE)
    real_check = journals.check_own_file

    def check_then_link(path, status=None):
        real_check(path, status)
        if status is None and Path(path).name == "s.runs.jsonl" and not Path(path).is_symlink():
            Path(path).unlink(missing_ok=True)
            Path(path).symlink_to(users)

    monkeypatch.setattr(journals, "check_own_file", check_then_link)
    for replace, adopt in ((True, False), (False, True), (False, False)):
        with pytest.raises((JournalError, OSError)):
            Journal(tmp_path / "s.runs.jsonl", replace=replace, adopt=adopt)
        (tmp_path / "s.runs.jsonl").unlink()
    assert users.read_text() == USERS_FILE


def test_a_line_cut_short_by_a_kill_is_dropped_and_its_run_runs_again(tmp_path, capsys):
    table = tmp_path / "s.csv"
    assert main([*STUDY, "--seed", "1", "--csv", str(table)]) == 0
    whole = table.read_text()
    journal = tmp_path / "s.runs.jsonl"
    text = journal.read_text()
    journal.write_text(text[: text.rindex('{"run"') + 40])  # run 6's line cut in the middle, no end of line
    table.unlink()
    assert main([*STUDY, "--csv", str(table), "--resume"]) == 0
    assert "resuming: 10 rows kept from" in capsys.readouterr().out
    assert [untimed(r) for r in rows(table)] == [untimed(r) for r in csv.DictReader(io.StringIO(whole))]
    assert all(line.keys() & {"session", "run", "closed"} for line in lines(journal))  # the cut line is gone


# -- item 9: the record describes the CSV beside it ----------------------------------------------------------
BLOCKED_STUDY = """
import sys, time
from mazelab.experiments import executor
done, run_unit_timed = 0, executor.run_unit_timed
def run_two_then_wait(unit, backend, **options):  # runs 1 and 2 finish (their rows appended), run 3 waits to be killed
    global done
    if done == 2:
        print("blocked", flush=True)
        time.sleep(600)
    done += 1
    return run_unit_timed(unit, backend, **options)
executor.run_unit_timed = run_two_then_wait
executor.study_units = lambda tasks, workers: [(task,) for task in tasks]
from mazelab.cli.app import main
sys.exit(main(sys.argv[1:]))
"""


def blocked_study(tmp_path: Path, *flags: str) -> subprocess.Popen:
    """`study --csv s.csv --force` in a process of its own, stopped for good in its third run (two
    runs' rows are in s.runs.jsonl then): a known point to kill it at, no timing."""
    process = subprocess.Popen(
        [sys.executable, "-c", BLOCKED_STUDY, *STUDY, "--seed", "2", "--csv", str(tmp_path / "s.csv"), *flags],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env={**os.environ, "PYTHONPATH": str(ROOT)},
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )  # fmt: skip
    for line in process.stdout:
        if line == "blocked\n":
            return process
    process.wait()
    pytest.fail(f"the study did not reach its third run: {process.stderr.read()}")


def old_study(tmp_path: Path) -> None:
    (tmp_path / "s.csv").write_text(OLD_CSV)
    (tmp_path / "s.record.json").write_text(OLD_RECORD)


def test_a_killed_study_keeps_the_old_csv_and_its_record_and_resumes_from_its_own(tmp_path):
    old_study(tmp_path)
    process = blocked_study(tmp_path, "--force")
    process.kill()
    process.wait()
    assert (tmp_path / "s.csv").read_text() == OLD_CSV
    assert (tmp_path / "s.record.json").read_text() == OLD_RECORD  # it describes the old CSV beside it
    (running,) = [line["session"] for line in lines(tmp_path / "s.runs.jsonl") if "session" in line]
    assert running["parameters"]["root_seed"] == 2
    assert {r["run"] for r in finished_rows(tmp_path / "s.runs.jsonl")} == {"1", "2"}
    done = subprocess.run([sys.executable, str(ROOT / "main.py"), *STUDY, "--csv", str(tmp_path / "s.csv"),
                           "--resume"], capture_output=True, text=True, timeout=120)  # fmt: skip
    assert done.returncode == 0, done.stderr
    assert "resuming: 4 rows kept from" in done.stdout
    table = rows(tmp_path / "s.csv")
    record = json.loads((tmp_path / "s.record.json").read_text())
    (tmp_path / "whole").mkdir()
    assert main([*STUDY, "--seed", "2", "--csv", str(tmp_path / "whole" / "s.csv")]) == 0
    assert [untimed(r) for r in table] == [untimed(r) for r in rows(tmp_path / "whole" / "s.csv")]
    assert record["parameters"]["root_seed"] == 2 and record["status"] == "finished"
    assert (
        record["runs_finished"] == 6 and len(record["sessions"]) == 1 and record["sessions"][0]["status"] == "running"
    )
    assert sorted(p.name for p in tmp_path.iterdir()) == [
        "s.csv",
        "s.record.json",
        "s.runs.jsonl",
        "s.summary.csv",
        "whole",
    ]


def test_a_stopped_study_keeps_the_old_record_beside_the_old_csv(tmp_path):
    old_study(tmp_path)
    process = blocked_study(tmp_path, "--force")
    process.send_signal(signal.SIGINT)
    _, err = process.communicate(timeout=60)
    assert process.returncode == 130, err
    assert f"the finished rows are in {tmp_path / 's.runs.jsonl'}" in err
    assert (tmp_path / "s.csv").read_text() == OLD_CSV and (tmp_path / "s.record.json").read_text() == OLD_RECORD
    (stopped,) = [line["closed"] for line in lines(tmp_path / "s.runs.jsonl") if "closed" in line]
    assert stopped["status"] == "interrupted" and stopped["runs_finished"] == 2


def test_a_finished_study_replaces_the_record_with_its_csv_and_keeps_its_journal(tmp_path, capsys):
    old_study(tmp_path)
    assert main([*STUDY, "--seed", "3", "--csv", str(tmp_path / "s.csv"), "--force"]) == 0
    record = json.loads((tmp_path / "s.record.json").read_text())
    assert record["parameters"]["root_seed"] == 3 and record["runs_finished"] == 6
    assert len(rows(tmp_path / "s.csv")) == 12 and len(finished_rows(tmp_path / "s.runs.jsonl")) == 12
    assert sorted(p.name for p in tmp_path.iterdir()) == ["s.csv", "s.record.json", "s.runs.jsonl", "s.summary.csv"]


def traces_without_timing(path: Path) -> list[dict[str, str]]:
    return [{k: v for k, v in row.items() if k != "step_ms"} for row in rows(path)]


def resume(tmp_path: Path, *flags: str) -> subprocess.CompletedProcess:
    command = [sys.executable, str(ROOT / "main.py"), *STUDY, "--csv", str(tmp_path / "s.csv"), *flags, "--resume"]
    return subprocess.run(command, capture_output=True, text=True, timeout=120)


@pytest.mark.parametrize("stop", ["kill -9", "Ctrl-C"])
def test_the_old_traces_stay_beside_the_old_csv_and_a_resume_gives_whole_traces(tmp_path, stop):
    """--traces under --force: each finished run's traces are in its journal line with its rows, so a
    study stopped any way, kill -9 included, keeps them; the old t.csv stays. The resume keeps the
    finished runs with their traces and ends with the traces of an uninterrupted study."""
    old_study(tmp_path)
    (tmp_path / "t.csv").write_text("old traces\n")
    process = blocked_study(tmp_path, "--force", "--traces", str(tmp_path / "t.csv"))
    if stop == "kill -9":
        process.kill()
        process.wait()
    else:
        process.send_signal(signal.SIGINT)
        process.communicate(timeout=60)
    traced = [row for line in lines(tmp_path / "s.runs.jsonl") if "run" in line for row in line["records"]]
    assert {r["run"] for r in traced if r["trace"]["estimate"]} == {1, 2}
    assert (tmp_path / "t.csv").read_text() == "old traces\n"
    done = resume(tmp_path, "--traces", str(tmp_path / "t.csv"))
    assert done.returncode == 0, done.stderr
    assert "4 rows kept" in done.stdout
    (tmp_path / "whole").mkdir()
    whole = tmp_path / "whole" / "s.csv"
    assert main([*STUDY, "--seed", "2", "--csv", str(whole), "--traces", str(tmp_path / "whole" / "t.csv")]) == 0
    assert traces_without_timing(tmp_path / "t.csv") == traces_without_timing(tmp_path / "whole" / "t.csv")
    assert [untimed(r) for r in rows(tmp_path / "s.csv")] == [untimed(r) for r in rows(whole)]
    assert sorted(p.name for p in tmp_path.iterdir()) == [
        "s.csv",
        "s.record.json",
        "s.runs.jsonl",
        "s.summary.csv",
        "t.csv",
        "whole",
    ]


@pytest.mark.skipif(importlib.util.find_spec("distributed") is None, reason="needs dask.distributed")
def test_a_resume_that_cannot_start_keeps_the_stopped_studys_rows(tmp_path):
    """--resume from a stopped study's journal with a --dask address that does not answer: refused
    (exit 2) after the journal was opened, and its rows are all still there."""
    process = blocked_study(tmp_path)
    process.send_signal(signal.SIGINT)
    process.communicate(timeout=60)
    before = finished_rows(tmp_path / "s.runs.jsonl")
    assert {r["run"] for r in before} == {"1", "2"}
    done = resume(tmp_path, "--dask", "tcp://127.0.0.1:1")
    assert done.returncode == 2 and "cannot reach the Dask scheduler" in done.stderr
    assert finished_rows(tmp_path / "s.runs.jsonl") == before
    assert resume(tmp_path).returncode == 0 and len(rows(tmp_path / "s.csv")) == 12


@pytest.mark.parametrize("flag", ["--summary-csv", "--record", "--plot", "--traces"])
def test_a_second_study_with_an_output_the_first_is_writing_is_refused_before_its_runs(tmp_path, capsys, flag):
    """Each output is claimed before the runs: a study given an output that a running study will write
    (another --csv, the same --summary-csv, --record, --plot or --traces) is refused at once, in one line."""
    shared = tmp_path / ("shared.png" if flag == "--plot" else "shared.json" if flag == "--record" else "shared.csv")
    process = blocked_study(tmp_path, flag, str(shared))
    try:
        assert main([*STUDY, "--seed", "2", "--csv", str(tmp_path / "other.csv"), flag, str(shared)]) == 2
        assert f"another study is writing {shared} now ({flag})" in one_error(capsys)
        assert not (tmp_path / "other.runs.jsonl").exists()
    finally:
        process.kill()
        process.wait()
