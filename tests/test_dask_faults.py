"""A study whose cluster or pool fails keeps its finished rows and ends with one line: a Dask scheduler
that dies, a cluster without workers (--dask-timeout), a local worker killed with kill -9, and
--dask addresses of another scheme. Real clusters: distributed.LocalCluster on 127.0.0.1."""

from __future__ import annotations

import csv
import io
import os
import signal
import threading
from pathlib import Path

import pytest
from conftest import finished_rows
from test_executor import kill_run_2_after_another_run, wait_until_broken

from mazelab.cli.app import main
from mazelab.experiments import executor
from mazelab.experiments.journal import Journal

distributed = pytest.importorskip("distributed")

STUDY = ["study", "--maze", "paper_5x5", "--steps", "5", "--particles", "30", "--filters", "sir", "--seed", "2"]


def local_cluster(workers: int):
    return distributed.LocalCluster(
        n_workers=workers, threads_per_worker=1, processes=False, protocol="tcp", host="127.0.0.1",
        dashboard_address=None,
    )  # fmt: skip


REAL_RUN_UNIT = executor.run_unit_timed


SCHEDULER_KILLED = threading.Event()


def hold_until_killed(unit, backend, **options):
    """Run 1 as it is; a later run waits until the test has killed the scheduler (bounded: closing
    the cluster may wait for this thread). The worker runs in the test's process (processes=False)."""
    if unit[0].run > 1:
        SCHEDULER_KILLED.wait(5)
    return REAL_RUN_UNIT(unit, backend, **options)


def rows(path: Path) -> list[dict[str, str]]:
    return list(csv.DictReader(io.StringIO(path.read_text())))


@pytest.mark.parametrize("address", ["tls://127.0.0.1:8786", "http://127.0.0.1:8786", "inproc://x", "ucx://h:1"])
def test_another_scheme_than_tcp_is_one_line_and_exit_2(address, capsys):
    assert main([*STUDY, "--runs", "2", "--dask", address]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "only tcp:// is supported" in err and "Traceback" not in err


def test_a_dead_scheduler_is_one_line_keeps_the_rows_and_the_old_csv(tmp_path, monkeypatch, capsys):
    """The scheduler dies at a known point: just after the study appended run 1's rows, while the
    cluster's one worker holds the next run until it is gone; no timing decides how many runs finish."""
    table = tmp_path / "s.csv"
    table.write_text("old\n")
    cluster, killed = local_cluster(1), SCHEDULER_KILLED
    killed.clear()
    real_write = Journal.write

    def write_then_kill_the_scheduler(journal, line):
        real_write(journal, line)
        if "run" in line and not killed.is_set():
            killed.set()
            cluster.close()  # the scheduler (and its worker) go away mid-study

    monkeypatch.setattr(executor, "run_unit_timed", hold_until_killed)
    monkeypatch.setattr(executor, "study_units", lambda tasks, workers: [(task,) for task in tasks])
    monkeypatch.setattr(Journal, "write", write_then_kill_the_scheduler)
    try:
        code = main([*STUDY, "--runs", "60", "--dask", cluster.scheduler_address, "--csv", str(table), "--force"])
    finally:
        cluster.close()
    err = capsys.readouterr().err
    assert code == 1, err
    lines = [line for line in err.splitlines() if line.startswith("error")]
    journal = table.with_name("s.runs.jsonl")
    assert len(lines) == 1 and "Dask scheduler" in lines[0] and f"rows are in {journal}" in lines[0], err
    assert "Traceback" not in err and "FutureCancelledError" not in err
    assert table.read_text() == "old\n"
    assert 1 <= len(finished_rows(journal)) < 60


def test_a_cluster_without_workers_ends_after_the_dask_timeout(tmp_path, capsys):
    table = tmp_path / "s.csv"
    with local_cluster(0) as cluster:
        code = main([*STUDY, "--runs", "3", "--dask", cluster.scheduler_address, "--dask-timeout", "0.5",
                     "--csv", str(table)])  # fmt: skip
    err = capsys.readouterr().err
    assert code == 1
    (line,) = [line for line in err.splitlines() if line.startswith("error")]
    assert "no run finished on the Dask cluster within 0.5 s (--dask-timeout): no worker is left" in line
    assert "0 of 3 runs finished" in line and not table.exists()


def kill_the_worker_always(unit, backend, **options):
    if any(task.run == 2 for task in unit):
        os.kill(os.getpid(), signal.SIGKILL)
    return REAL_RUN_UNIT(unit, backend, **options)


def test_a_killed_local_worker_restarts_the_pool_and_the_study_goes_on(tmp_path, monkeypatch, capsys):
    """Run 2's worker dies (kill -9) at a known point: just after the study appended another run's
    rows, before it hands out more (the pool is broken then); no timing decides the path."""
    pools = kill_run_2_after_another_run(tmp_path, monkeypatch)
    real_write = Journal.write

    def write_then_kill_run_2(journal, line):
        real_write(journal, line)
        if "run" in line and not (tmp_path / "go").exists():
            (tmp_path / "go").touch()
            wait_until_broken(pools[-1])

    monkeypatch.setattr(Journal, "write", write_then_kill_run_2)
    table = tmp_path / "s.csv"
    assert main([*STUDY, "--runs", "8", "--workers", "2", "--csv", str(table)]) == 0
    assert (tmp_path / "killed").exists()
    assert sorted(int(r["run"]) for r in rows(table)) == list(range(1, 9))
    assert "a worker process died" in capsys.readouterr().err


def test_workers_that_keep_dying_stop_the_study_with_the_rows_kept(tmp_path, monkeypatch, capsys):
    monkeypatch.setattr(executor, "run_unit_timed", kill_the_worker_always)
    monkeypatch.setattr(executor, "study_units", lambda tasks, workers: [(task,) for task in tasks])
    table = tmp_path / "s.csv"
    assert main([*STUDY, "--runs", "6", "--workers", "2", "--csv", str(table)]) == 1
    err = capsys.readouterr().err
    (line,) = [line for line in err.splitlines() if line.startswith("error")]
    journal = table.with_name("s.runs.jsonl")
    assert "worker processes died" in line and f"rows are in {journal}" in line
    assert "2" not in {r["run"] for r in finished_rows(journal)} and not table.exists()
