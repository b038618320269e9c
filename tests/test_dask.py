"""study --dask: a study's runs on a real Dask cluster (a LocalCluster on 127.0.0.1) give every run's
figures bit for bit as the local study does."""

from __future__ import annotations

import csv
import io
import os
import signal
import time

import pytest
from conftest import finished_rows, start_study_process, wait_for_rows

import mazelab
from mazelab.cli.app import main
from mazelab.experiments import executor
from mazelab.experiments.executor import run_study
from mazelab.experiments.study import MazeChoice, study_settings, study_tasks
from mazelab.maze import load_maze

distributed = pytest.importorskip("distributed")

TIMING = ("ms_per_step", "run_seconds")  # the only columns that may differ: they are measured


@pytest.fixture(scope="module")
def cluster():
    with distributed.LocalCluster(
        n_workers=2, threads_per_worker=1, processes=False, protocol="tcp", host="127.0.0.1", dashboard_address=None
    ) as local:
        yield local


def rows_without_timing(text: str) -> list[dict[str, str]]:
    return [{k: v for k, v in row.items() if k not in TIMING} for row in csv.DictReader(io.StringIO(text))]


def test_a_study_on_dask_gives_the_local_studys_runs(cluster, tmp_path, capsys):
    args = ["study", "--maze", "paper_5x5", "--sigma", "0.3,0.6", "--runs", "3", "--steps", "30"]
    args += ["--particles", "200", "--seed", "11", "--no-viz"]
    assert main([*args, "--workers", "1", "--csv", str(tmp_path / "local.csv")]) == 0
    assert main([*args, "--dask", cluster.scheduler_address, "--csv", str(tmp_path / "dask.csv")]) == 0
    out = capsys.readouterr().out
    assert f"on the Dask cluster at {cluster.scheduler_address}" in out
    local, remote = (rows_without_timing((tmp_path / f"{n}.csv").read_text()) for n in ("local", "dask"))
    assert len(local) == 2 * 3 * 3 and remote == local  # every run's final error, convergence, ESS ... alike


def test_the_workers_are_asked_once(cluster, monkeypatch, capsys):
    """study --dask and mazelab.study(dask=...) ask the cluster's workers whether they can run the study
    once, before any run (executor.open_cluster)."""
    asked = []
    check = executor.check_workers
    monkeypatch.setattr(
        executor, "check_workers", lambda client, backend: asked.append(backend) or check(client, backend)
    )
    args = ["study", "--maze", "paper_5x5", "--runs", "2", "--steps", "10", "--particles", "50", "--seed", "3"]
    assert main([*args, "--filters", "sir", "--no-viz", "--dask", cluster.scheduler_address]) == 0
    mazelab.study("paper_5x5", filters="sir", runs=2, steps=10, particles=50, seed=3, dask=cluster.scheduler_address)
    assert len(asked) == 2  # one per study


def test_run_study_takes_a_client(cluster):
    world = load_maze("paper_5x5")
    settings = study_settings([MazeChoice.from_maze("paper_5x5", world)], [0.4], [0.5], [100])
    tasks = study_tasks(settings, ["SIRParticleFilter"], 4, 10, 5)
    with distributed.Client(cluster.scheduler_address) as client:
        remote = run_study(tasks, dask=client)
    local = run_study(tasks, 1)
    assert [r.final_error for r in remote.records] == [r.final_error for r in local.records]
    assert not remote.interrupted and not remote.failures


@pytest.mark.parametrize("address", ["tcp://127.0.0.1:1", "no-port-here"])
def test_an_unreachable_or_wrong_address_is_one_line_and_exit_2(address, capsys):
    started = time.monotonic()
    assert main(["study", "--maze", "paper_5x5", "--runs", "2", "--steps", "5", "--dask", address]) == 2
    assert time.monotonic() - started < 10
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("error: ") and address in err


def test_ctrl_c_on_a_dask_study_cancels_the_rest_and_keeps_the_finished_rows(cluster, tmp_path):
    table = tmp_path / "s.csv"
    long_study = ["--maze", "paper_5x5", "--runs", "2000", "--steps", "20", "--particles", "100", "--filters", "sir"]
    process = start_study_process(
        [*long_study, "--seed", "1", "--csv", str(table), "--dask", cluster.scheduler_address]
    )
    wait_for_rows(table.with_name("s.runs.jsonl"), 2, process)
    deadline = time.monotonic() + 60
    os.killpg(process.pid, signal.SIGINT)
    _, err = process.communicate(timeout=60)
    assert process.returncode == 130 and "interrupted after" in err and "Traceback" not in err, err
    rows = finished_rows(table.with_name("s.runs.jsonl"))
    assert 2 <= len(rows) < 2000 and not table.exists()
    while cluster.scheduler.tasks and time.monotonic() < deadline:  # the client is gone: nothing left to run
        time.sleep(0.1)
    assert not cluster.scheduler.tasks
