"""What a study's runs cost on each backend: a filter step run by run against R runs advanced together,
a study's runs per second on 1 worker, on every core's worker and on a local Dask cluster, and the cost
of one run's filter step as R, N and the station count grow (the 10 x 10 maze and mazelab.bench's
seeded 100 x 100 one).

    uv run python benchmarks/study_costs.py            # the full sizes: 30 runs, 200 steps, 4 settings
    uv run python benchmarks/study_costs.py --quick    # 12 runs, 40 steps, 2 settings
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable
from typing import Any

from mazelab.backend import cores, use_backend
from mazelab.bench import available_backends, large_maze
from mazelab.maze import Maze

STUDY_FILTERS = ("SIRParticleFilter", "AuxiliaryParticleFilter", "RegularizedParticleFilter")
STUDY_SIGMA, STUDY_DELTA, STUDY_SEED = 0.4, 0.5, 2024


def study_of(world: Maze, runs: int, steps: int, particles: int, settings: int = 1) -> list[Any]:
    """The paper's study on `world`: `settings` sigmas x `runs` runs of the three filters (RunTask)."""
    from mazelab.experiments.study import MazeChoice, study_settings, study_tasks  # studies: the experiments

    sigmas = [STUDY_SIGMA + 0.1 * i for i in range(settings)]
    chosen = study_settings([MazeChoice.from_maze(str(world.source), world)], sigmas, [STUDY_DELTA], [particles])
    return study_tasks(chosen, STUDY_FILTERS, runs, steps, STUDY_SEED)


def runs_per_second(tasks: list[Any], workers: int = 1, dask: Any = False) -> float:
    """A study's runs per second of wall time (every filter of a run counts as one run), on `workers`
    processes, or with `dask` on a LocalCluster of `workers` processes on 127.0.0.1 (or the Client given)."""
    from distributed import Client, LocalCluster

    from mazelab.experiments.executor import run_study

    if dask:
        with (
            LocalCluster(n_workers=workers, threads_per_worker=1, host="127.0.0.1", dashboard_address=":0") as cluster,
            Client(cluster) as client,
        ):
            return runs_per_second(tasks, workers, client)
    started = time.perf_counter()
    outcome = run_study(tasks, workers, dask=dask or None)
    return len({(r.setting, r.run) for r in outcome.records}) / (time.perf_counter() - started)


def run_cost(world: Maze, runs: int, particles: int, steps: int, label: str = "") -> tuple:
    """(label, R, N, stations, microseconds per filter step of one run: the three filters' mean) with R =
    `runs` advancing together; R = 1 is the one-by-one path (run_task), its robot walk and bookkeeping
    included alike."""
    from mazelab.experiments.study import run_batch, run_task

    tasks = study_of(world, runs, steps, particles)
    started = time.perf_counter()
    if runs == 1:
        run_task(tasks[0])
    else:
        run_batch(tasks)
    seconds = time.perf_counter() - started
    return label, runs, particles, len(world.stations), 1e6 * seconds / (runs * steps * len(STUDY_FILTERS))


def run_study_benchmark(small: Maze, large: Maze, quick: bool, echo: Callable[[str], None] = print) -> None:
    """Print the study figures: per-run overhead, runs per second, and the cost's growth with R, N, B."""
    steps, runs, settings = (40, 12, 2) if quick else (200, 30, 4)
    workers = cores()
    for world in (small, large):  # warm up: each maze's lookup tables are built on first use
        run_cost(world, 2, 100, 2)
    one = run_cost(small, 1, 1500, steps)
    batched = run_cost(small, runs, 1500, steps)
    gain = one[-1] / batched[-1]
    echo(
        f"Study runs (3 filters, N = 1,500, {steps} steps): {one[-1]:.0f} us per filter step run by run, "
        f"{batched[-1]:.0f} us with {runs} runs advanced together ({gain:.1f}x)"
    )
    tasks = study_of(small, runs, steps, 1500, settings)
    figures = [("1 worker", runs_per_second(tasks, 1)), (f"{workers} workers", runs_per_second(tasks, workers))]
    figures.append((f"local Dask cluster, {workers} workers", runs_per_second(tasks, workers, dask=True)))
    echo(
        f"Study of {settings} settings x {runs} runs: "
        + ", ".join(f"{label} {rate:.2f} runs/s" for label, rate in figures)
    )
    echo("Cost of one run's filter step, us (the three filters' mean) as R, N and the station count grow:")
    grid = [run_cost(small, r, 1500, steps // 2, "R") for r in (1, 4, 16, 32)]
    grid += [run_cost(small, runs, n, steps // 2, "N") for n in (500, 1500, 5000)]
    grid += [run_cost(world, runs, 1500, steps // 2, "stations") for world in (small, large)]
    echo(f"  {'varied':<9} {'R':>4} {'N':>6} {'stations':>9} {'us/step':>9} {'ns/particle':>12}")
    for label, r, n, stations, microseconds in grid:
        echo(f"  {label:<9} {r:>4} {n:>6,} {stations:>9,} {microseconds:>9.0f} {1e3 * microseconds / n:>12.1f}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="fewer runs, steps and settings")
    parser.add_argument("--maze", default="maze_10x10")
    args = parser.parse_args()
    small, large = Maze.from_file(args.maze), large_maze()
    for backend in available_backends():
        with use_backend(backend):
            print(f"[{backend}] studies:")
            run_study_benchmark(small, large, args.quick)


if __name__ == "__main__":
    main()
