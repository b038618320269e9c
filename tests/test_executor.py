"""The local pool (mazelab.experiments.executor) when a worker dies just after another run finished:
the main process is between taking that run's rows and handing out more, the pool is broken, and
`submit` says so (BrokenProcessPool). The study restarts the pool and ends with every run, as when a
run's own future reports the death. Deterministic: the worker kills itself at a known point (once the
main process holds another run's rows) and the main process goes on only once the pool is broken.
Real worker processes, a real kill -9."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from pathlib import Path

import pytest

from mazelab.experiments import executor
from mazelab.experiments.api import plan_study, study_mazes

WAIT_SECONDS = 60  # for a condition that comes within milliseconds: a bound, not a timing


REAL_RUN_UNIT = executor.run_unit_timed


def die_once_another_run_has_finished(unit, backend, **options):
    """run_unit_timed, but run 2's first attempt waits until the main process has taken another run's
    rows (the file `go`), then dies as with kill -9 (the file `killed` says it did)."""
    folder = Path(os.environ["MAZELAB_TEST_DIR"])
    if any(task.run == 2 for task in unit) and not (folder / "killed").exists():
        deadline = time.monotonic() + WAIT_SECONDS
        while not (folder / "go").exists() and time.monotonic() < deadline:
            time.sleep(0.01)  # waits for a condition; the outcome does not depend on how long
        (folder / "killed").touch()
        os.kill(os.getpid(), signal.SIGKILL)
    return REAL_RUN_UNIT(unit, backend, **options)


def wait_until_broken(pool: ProcessPoolExecutor) -> None:
    """Return once `submit` refuses: the pool has seen its worker die."""
    deadline = time.monotonic() + WAIT_SECONDS
    while time.monotonic() < deadline:
        try:
            probe = pool.submit(os.getpid)
        except BrokenProcessPool:
            return
        probe.exception()  # ran on the other worker, or failed with the pool: either way, ask again
    pytest.fail("the pool never saw its worker die")


def known_pools(monkeypatch) -> list[ProcessPoolExecutor]:
    """The executor's pools (real ones), in the order it makes them, where a test can see them."""
    pools: list[ProcessPoolExecutor] = []

    class KnownPool(ProcessPoolExecutor):
        def __init__(self, *args, **kwargs):
            super().__init__(*args, **kwargs)
            pools.append(self)

    monkeypatch.setattr(executor, "ProcessPoolExecutor", KnownPool)
    return pools


def kill_run_2_after_another_run(tmp_path: Path, monkeypatch) -> list[ProcessPoolExecutor]:
    """Units of one run each; run 2's worker dies once `go` exists (see die_once_another_run_has_finished)."""
    monkeypatch.setenv("MAZELAB_TEST_DIR", str(tmp_path))
    monkeypatch.setattr(executor, "run_unit_timed", die_once_another_run_has_finished)
    monkeypatch.setattr(executor, "study_units", lambda tasks, workers: [(task,) for task in tasks])
    return known_pools(monkeypatch)


def test_a_worker_dying_just_after_another_run_finished_restarts_the_pool(tmp_path, monkeypatch):
    pools = kill_run_2_after_another_run(tmp_path, monkeypatch)
    taken = []

    def on_records(records) -> None:
        taken.append(records[0].run)
        if len(taken) == 1:  # the first finished run's rows: now run 2's worker dies
            (tmp_path / "go").touch()
            wait_until_broken(pools[-1])

    plan = plan_study(study_mazes(["paper_5x5"]), "sir", {"sigma": [0.3], "delta": [0.5], "particles": [30]},
                      runs=8, steps=4, seed=1)  # fmt: skip
    with pytest.warns(UserWarning, match="a worker process died"):
        outcome = executor.run_study(plan.tasks, 2, on_records=on_records)
    assert (tmp_path / "killed").exists() and len(pools) == 2  # one restart
    assert outcome.lost is None and outcome.failures == [] and not outcome.interrupted
    assert sorted(taken) == list(range(1, 9)) and [r.run for r in outcome.records] == list(range(1, 9))


CUT_SHORT = """
import os, signal, struct, threading
from concurrent.futures import ProcessPoolExecutor
from mazelab.experiments.executor import end_workers

def write_half_and_die(_):
    # what a worker killed while it wrote a unit's rows leaves: a message cut short in the result pipe
    RESULTS._writer._send(struct.pack("!i", 1_000_000) + b"rows")
    os.kill(os.getpid(), signal.SIGKILL)

pool = ProcessPoolExecutor(1)
RESULTS = pool._result_queue  # the forked worker's own handle on it
future = pool.submit(write_half_and_die, 0)
for process in list(pool._processes.values()):
    process.join(60)
ending = threading.Thread(target=end_workers, args=(pool,), daemon=True)
ending.start()
ending.join(60)
print("ended" if not ending.is_alive() else "hung", flush=True)
os._exit(0 if not ending.is_alive() else 1)
"""


def test_ending_the_workers_returns_when_one_was_killed_while_it_wrote_its_rows():
    """SIGTERM to a study's process group can kill a worker in the middle of writing a unit's rows (a
    large result is written in several pieces): the pool's thread then waits for the rest of the message
    for ever, and the study, ending its workers, with it. Deterministic: the worker writes the start of a
    message and kills itself; ending the workers must return (in a process of its own: a hung pool
    thread would keep the test process from exiting)."""
    if os.name != "posix":
        pytest.skip("the forked worker shares the pool's result queue (POSIX)")
    done = subprocess.run([sys.executable, "-c", CUT_SHORT], capture_output=True, text=True, timeout=120)
    assert done.stdout.strip() == "ended", done.stderr


CUT_SHORT_IN_A_STUDY = """
import gc, os, signal, struct, sys
from multiprocessing.queues import SimpleQueue
from pathlib import Path
from mazelab.experiments import executor
from mazelab.experiments.api import plan_study, study_mazes

real = executor.run_unit_timed

def cut_short_once(unit, backend, **options):
    flag = Path(sys.argv[1])
    if any(task.run == 2 for task in unit) and not flag.exists():
        flag.touch()
        results = next(o for o in gc.get_objects() if isinstance(o, SimpleQueue))  # the pool's result queue
        results._writer._send(struct.pack("!i", 1_000_000) + b"rows")  # the start of a unit's rows
        os.kill(os.getpid(), signal.SIGKILL)
    return real(unit, backend, **options)

executor.run_unit_timed = cut_short_once
plan = plan_study(study_mazes(["paper_5x5"]), ["sir"], {"sigma": [0.3], "delta": [0.5], "particles": [50]}, runs=4,
                  steps=5, seed=1)
outcome = executor.run_study(plan.tasks, 2)
print(sorted({record.run for record in outcome.records}), len(outcome.failures), flush=True)
"""


def test_a_worker_killed_while_it_wrote_its_rows_restarts_the_pool(tmp_path):
    """A worker killed in the middle of writing a unit's rows (kill -9, out of memory) leaves the pool's
    thread waiting for the rest of the message, and no future says the pool is broken: the study sees
    the dead worker itself, restarts the pool and ends with every run. Deterministic: the worker of run 2
    writes the start of a message and kills itself, once (in a process of its own: a hang would keep the
    test process from exiting)."""
    if os.name != "posix":
        pytest.skip("the forked worker shares the pool's result queue (POSIX)")
    flag = tmp_path / "killed"
    done = subprocess.run([sys.executable, "-c", CUT_SHORT_IN_A_STUDY, str(flag)], capture_output=True, text=True,
                          timeout=300)  # fmt: skip
    assert flag.exists() and done.stdout.strip() == "[1, 2, 3, 4] 0", done.stderr


def raise_in_the_worker(unit):
    """A unit whose work raises where it runs (picklable: the pool's workers import it)."""
    raise ValueError(f"unit {unit[0]} cannot run")


def test_a_unit_that_raises_in_a_local_worker_is_a_failure_that_says_where():
    """On the local pool a unit that raises is a RunFailure of each of its tasks, said to have failed in
    a worker process (not on a Dask cluster, which this run never had)."""
    collected: list = []
    executor.Units([(1,), (2,)], raise_in_the_worker, workers=2).run(collected.extend, lambda count: None)
    assert sorted(failure.message for failure in collected) == [
        "in a worker process: ValueError: unit 1 cannot run",
        "in a worker process: ValueError: unit 2 cannot run",
    ]
