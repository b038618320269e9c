"""A study stopped any way keeps its finished rows and leaves no worker behind: real signals to a real
`main.py study` subprocess with two pool workers."""

from __future__ import annotations

import os
import signal
import subprocess
import time
from pathlib import Path

import pytest
from conftest import finished_rows, start_study_process, wait_for_rows

pytestmark = pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="reads the process table in /proc")


def session_processes(session: int) -> list[int]:
    """Live (not zombie) processes of the session `session` (the study and its workers)."""
    found = []
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                stat = (entry / "stat").read_text()
            except OSError:
                continue
            fields = stat[stat.rindex(")") + 2 :].split()  # state, ppid, pgrp, session, ...
            if int(fields[3]) == session and fields[0] != "Z":
                found.append(int(entry.name))
    return found


OLD_CSV = "an older study's rows\n"


def start_study(tmp_path: Path) -> tuple[subprocess.Popen, Path]:
    """A long study on two workers in its own session, once its journal (s.runs.jsonl) holds a finished
    run; returns the journal."""
    long_study = ["--maze", "paper_5x5", "--runs", "3000", "--steps", "20", "--particles", "100"]
    (tmp_path / "s.csv").write_text(OLD_CSV)  # an older study's CSV, replaced (--force) only by a whole one
    long_study += ["--filters", "sir,apf", "--workers", "2", "--seed", "1", "--force"]
    process = start_study_process([*long_study, "--csv", str(tmp_path / "s.csv")])
    table = tmp_path / "s.runs.jsonl"
    wait_for_rows(table, 4, process)
    assert len(finished_rows(table)) >= 4, "the study wrote no rows"
    assert len(session_processes(process.pid)) >= 3, "the study should run on two workers"
    return process, table


def assert_no_process_left(session: int) -> None:
    deadline = time.monotonic() + 10
    while session_processes(session) and time.monotonic() < deadline:
        time.sleep(0.1)
    assert session_processes(session) == []


def assert_whole_runs(rows: list[dict[str, str]]) -> None:
    runs = {r["run"] for r in rows}
    assert rows and len(rows) == 2 * len(runs) < 2 * 3000


@pytest.mark.parametrize(
    ("signals", "code"),
    [
        ((signal.SIGINT,), 130),  # Ctrl-C: the running runs finish, the rest are cancelled
        ((signal.SIGINT, signal.SIGINT, signal.SIGINT), 130),  # impatient: the second ends the workers
        ((signal.SIGTERM,), 143),
        ((signal.SIGHUP,), 129),
    ],
    ids=["ctrl-c", "ctrl-c-thrice", "sigterm", "sighup"],
)
def test_a_stopped_study_keeps_its_rows_and_ends_its_workers(tmp_path, signals, code):
    process, table = start_study(tmp_path)
    for sig in signals:  # to the whole group, as a terminal sends Ctrl-C; SIGTERM/SIGHUP to the group too
        os.killpg(process.pid, sig)
        time.sleep(0.2)
    _, err = process.communicate(timeout=30)
    assert process.returncode == code, err
    assert "interrupted after" in err and "Traceback" not in err
    assert f"the finished rows are in {table}" in err
    assert_whole_runs(finished_rows(table))
    assert (tmp_path / "s.csv").read_text() == OLD_CSV  # the CSV is the old one or a whole new one
    assert_no_process_left(process.pid)


def test_kill_9_on_the_study_ends_its_workers_and_keeps_the_rows(tmp_path):
    process, table = start_study(tmp_path)
    before = len(finished_rows(table))
    process.kill()  # SIGKILL to the study alone: its workers learn it from the parent-death check
    process.communicate(timeout=30)
    assert_no_process_left(process.pid)
    assert len(finished_rows(table)) >= before
    assert (tmp_path / "s.csv").read_text() == OLD_CSV
