"""A study on Dask whose scheduler dies says so in one line: none of distributed's own log lines
(its client logs the lost connection at ERROR with a traceback; `distributed.client` has a level and
a handler of its own) and no run reported failed for a result the dead cluster could not send. Real
processes: a LocalCluster on 127.0.0.1 in a process of its own, killed with kill -9 mid-study."""

from __future__ import annotations

import logging
import signal
import subprocess
import sys
import time

import pytest
from conftest import ROOT, finished_rows

from mazelab.experiments.executor import QUIET_LOGGERS, quiet_distributed

distributed = pytest.importorskip("distributed")

CLUSTER = """
import time
from distributed import LocalCluster
cluster = LocalCluster(n_workers=1, threads_per_worker=1, processes=False, protocol="tcp", host="127.0.0.1",
                       dashboard_address=None)
print(cluster.scheduler_address, flush=True)
time.sleep(600)
"""
STUDY = ["study", "--maze", "paper_5x5", "--runs", "3000", "--steps", "20", "--particles", "100", "--filters", "sir"]


def test_every_logger_of_distributed_is_quiet_after_connecting():
    quiet_distributed()
    configured = [n for n in logging.Logger.manager.loggerDict if n.split(".")[0] in QUIET_LOGGERS]
    assert "distributed.client" in configured  # distributed's configuration gives it a level of its own
    for name in [*configured, "distributed.comm.tcp", "tornado.general"]:
        assert not logging.getLogger(name).isEnabledFor(logging.CRITICAL), name


def test_a_killed_scheduler_is_one_line_without_distributeds_logs(tmp_path):
    cluster = subprocess.Popen([sys.executable, "-c", CLUSTER], stdout=subprocess.PIPE, stderr=subprocess.DEVNULL,
                               text=True)  # fmt: skip
    try:
        address = cluster.stdout.readline().strip()
        assert address.startswith("tcp://127.0.0.1:"), address
        table = tmp_path / "s.csv"
        study = subprocess.Popen(
            [sys.executable, str(ROOT / "main.py"), *STUDY, "--seed", "1", "--dask", address, "--csv", str(table)],
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        )  # fmt: skip
        deadline = time.monotonic() + 120
        while not finished_rows(table.with_name("s.runs.jsonl")) and study.poll() is None:
            assert time.monotonic() < deadline, "the study wrote no rows"
            time.sleep(0.05)
        cluster.send_signal(signal.SIGKILL)  # the scheduler and its worker die at once
        _, err = study.communicate(timeout=120)
    finally:
        cluster.kill()
        cluster.wait()
    lines = [line for line in err.splitlines() if not line.startswith("runs ")]  # the progress bar aside
    assert study.returncode == 1, err
    (line,) = lines
    assert (
        line.startswith("error: lost the ")
        and "Dask" in line
        and f"rows are in {table.with_name('s.runs.jsonl')}" in line
    ), err
    assert "Traceback" not in err and "distributed" not in err and "ERROR" not in err
