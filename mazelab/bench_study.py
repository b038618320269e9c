"""The study benchmark (part of `python main.py bench`): the fixed cost of a run, a study's runs per
second on one worker, on all cores and on a local Dask cluster, and how the cost of a run grows
with the runs advanced together (R), the particle count (N) and the station count."""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass

from mazelab.experiments.batch_runs import run_batch
from mazelab.experiments.executor import default_workers, run_study
from mazelab.experiments.study import MazeChoice, RunTask, run_task, study_settings, study_tasks
from mazelab.maze import Maze

STUDY_FILTERS = ("SIRParticleFilter", "AuxiliaryParticleFilter", "RegularizedParticleFilter")
STUDY_SIGMA, STUDY_DELTA, STUDY_SEED = 0.4, 0.5, 2024


def study_of(world: Maze, runs: int, steps: int, particles: int, settings: int = 1) -> list[RunTask]:
    """The paper's study on `world`: `settings` sigmas x `runs` runs of the three filters."""
    sigmas = [STUDY_SIGMA + 0.1 * i for i in range(settings)]
    chosen = study_settings([MazeChoice.from_maze(str(world.source), world)], sigmas, [STUDY_DELTA], [particles])
    return study_tasks(chosen, STUDY_FILTERS, runs, steps, STUDY_SEED)


def runs_per_second(tasks: list[RunTask], workers: int = 1, dask: object = None) -> float:
    """A study's runs per second of wall time (every filter of a run counts as one run)."""
    started = time.perf_counter()
    outcome = run_study(tasks, workers, dask=dask)
    return len({(r.setting, r.run) for r in outcome.records}) / (time.perf_counter() - started)


@dataclass(frozen=True)
class RunCost:
    """The cost of one run's filter step when R runs advance together: microseconds per run and step."""

    label: str
    runs: int
    particles: int
    stations: int
    microseconds: float


def run_cost(world: Maze, runs: int, particles: int, steps: int, label: str = "") -> RunCost:
    """Microseconds per filter step of one run (the three filters' mean), R = `runs` advancing together;
    R = 1 is the one-by-one path (run_task), with its robot walk and bookkeeping included alike."""
    tasks = study_of(world, runs, steps, particles)
    started = time.perf_counter()
    if runs == 1:
        run_task(tasks[0])
    else:
        run_batch(tasks)
    seconds = time.perf_counter() - started
    return RunCost(label, runs, particles, len(world.stations), 1e6 * seconds / (runs * steps * len(STUDY_FILTERS)))


def local_dask_runs_per_second(tasks: list[RunTask], workers: int) -> float | None:
    """runs_per_second on a LocalCluster of `workers` processes on 127.0.0.1; None without dask."""
    try:
        from distributed import Client, LocalCluster
    except ImportError:
        return None
    with (
        LocalCluster(n_workers=workers, threads_per_worker=1, host="127.0.0.1", dashboard_address=":0") as cluster,
        Client(cluster) as client,
    ):
        return runs_per_second(tasks, dask=client)


def run_study_benchmark(small: Maze, large: Maze, quick: bool, echo: Callable[[str], None] = print) -> None:
    """Print the study figures: per-run overhead, runs per second, and the cost's growth with R, N, B."""
    steps, runs, settings = (40, 12, 2) if quick else (200, 30, 4)
    cores = default_workers()
    for world in (small, large):  # warm up: each maze's lookup tables are built on first use
        run_cost(world, 2, 100, 2)
    one = run_cost(small, 1, 1500, steps)
    batched = run_cost(small, runs, 1500, steps)
    gain = one.microseconds / batched.microseconds
    echo(
        f"Study runs (3 filters, N = 1,500, {steps} steps): {one.microseconds:.0f} us per filter step run by run, "
        f"{batched.microseconds:.0f} us with {runs} runs advanced together ({gain:.1f}x)"
    )
    tasks = study_of(small, runs, steps, 1500, settings)
    figures = [("1 worker", runs_per_second(tasks, 1)), (f"{cores} workers", runs_per_second(tasks, cores))]
    dask = local_dask_runs_per_second(tasks, cores)
    figures.append((f"local Dask cluster, {cores} workers", dask))
    echo(
        f"Study of {settings} settings x {runs} runs: "
        + ", ".join(f"{label} {rate:.2f} runs/s" if rate else f"{label}: dask not installed" for label, rate in figures)
    )
    echo("Cost of one run's filter step, us (the three filters' mean) as R, N and the station count grow:")
    grid = [run_cost(small, r, 1500, steps // 2, "R") for r in (1, 4, 16, 32)]
    grid += [run_cost(small, runs, n, steps // 2, "N") for n in (500, 1500, 5000)]
    grid += [run_cost(world, runs, 1500, steps // 2, "stations") for world in (small, large)]
    echo(f"  {'varied':<9} {'R':>4} {'N':>6} {'stations':>9} {'us/step':>9} {'ns/particle':>12}")
    for cost in grid:
        echo(
            f"  {cost.label:<9} {cost.runs:>4} {cost.particles:>6,} {cost.stations:>9,} {cost.microseconds:>9.0f} "
            f"{1e3 * cost.microseconds / cost.particles:>12.1f}"
        )


__all__ = [
    "STUDY_FILTERS",
    "RunCost",
    "local_dask_runs_per_second",
    "run_cost",
    "run_study_benchmark",
    "runs_per_second",
    "study_of",
]
