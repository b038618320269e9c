"""The local pool (mazelab.experiments.executor) when a worker dies just after another run finished:
the main process is between taking that run's rows and handing out more, the pool is broken, and
`submit` says so (BrokenProcessPool). The study restarts the pool and ends with every run, as when a
run's own future reports the death. Deterministic: the worker kills itself at a known point (once the
main process holds another run's rows) and the main process goes on only once the pool is broken.
Real worker processes, a real kill -9."""

from __future__ import annotations

import os
import signal
import time
from concurrent.futures import ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from pathlib import Path

import pytest

from mazelab.experiments import executor
from mazelab.experiments.plan import plan_study, study_mazes

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

    plan = plan_study(study_mazes(["paper_5x5"]), "sir", sigma=[0.3], delta=[0.5], particles=[30],
                      runs=8, steps=4, seed=1)  # fmt: skip
    with pytest.warns(UserWarning, match="a worker process died"):
        outcome = executor.run_study(plan.tasks(), 2, on_records=on_records)
    assert (tmp_path / "killed").exists() and len(pools) == 2  # one restart
    assert outcome.lost is None and outcome.failures == [] and not outcome.interrupted
    assert sorted(taken) == list(range(1, 9)) and [r.run for r in outcome.records] == list(range(1, 9))
