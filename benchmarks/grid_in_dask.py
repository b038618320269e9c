"""The grid filter's cost per step in this process and inside a Dask worker, and why they differ.

    uv run python benchmarks/grid_in_dask.py [--steps 60] [--repeats 3] [--mazes paper_5x5,maze_10x10]

Each place runs the exact grid filter on the same seeded walk, in a fresh process: this process as
started, the same with one of the environment variables a Dask nanny sets for its workers
(MALLOC_TRIM_THRESHOLD_=65536; OMP/MKL/OPENBLAS_NUM_THREADS=1), a plain thread, a worker of a real
distributed.LocalCluster (the nanny's environment), and such a worker without MALLOC_TRIM_THRESHOLD_.
Per step: the thread's CPU time and the wall time (medians over the steps) and the minor page
faults (their mean; Linux), each the median of `--repeats` processes. Then a study's own
`ms_per_step` for the grid filter, in process and on a LocalCluster. The machine's load average is
printed with the figures (the wall times depend on it; the CPU times and page faults much less).

Why: glibc's malloc serves a request above its mmap threshold with fresh pages from the kernel, and
gives them back on free. The threshold normally rises to the size of the largest block freed (so a
loop of same-sized arrays reuses its memory), but setting MALLOC_TRIM_THRESHOLD_ (any value, as the
nanny does) turns that adjustment off: the threshold stays at 128 KiB, and every array of the grid
(350 x 350 cells = 1 MB on paper_5x5) becomes 250 page faults, zeroed by the kernel, on every step.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import subprocess
import sys
import threading
import time
import warnings
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

NANNY_THREADS = {"OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1"}
TRIM = {"MALLOC_TRIM_THRESHOLD_": "65536"}


def grid_step_costs(maze: str = "paper_5x5", steps: int = 60, seed: int = 3) -> dict:
    """The grid filter on a seeded walk of `maze`, measured in the calling thread: per step its CPU
    time (ms), wall time (ms) and minor page faults, with the environment variables that matter."""
    from mazelab.grid_filter import GridBayesFilter
    from mazelab.maze import find_maze, load_maze
    from mazelab.robot import Robot
    from mazelab.seeding import start_place

    world = load_maze(find_maze(maze))
    robot = Robot(0.3, 0.5, start_place(world, seed))
    robot.rng = np.random.default_rng(seed)
    filt = GridBayesFilter(world, 0.3, 0.5)
    who = resource.RUSAGE_THREAD if hasattr(resource, "RUSAGE_THREAD") else resource.RUSAGE_SELF
    cpu, wall, faults = [], [], []
    for k in range(steps + 1):
        angle, z = robot.step(world)
        c0, w0, f0 = time.thread_time(), time.perf_counter(), resource.getrusage(who).ru_minflt
        filt.step(angle, z)
        _ = filt.estimate, filt.ess, filt.is_confident  # what a run reads every step (mazelab.simulation.record_steps)
        if k:  # the first step makes the buffers
            cpu.append(time.thread_time() - c0)
            wall.append(time.perf_counter() - w0)
            faults.append(resource.getrusage(who).ru_minflt - f0)
    names = ("MALLOC_TRIM_THRESHOLD_", *NANNY_THREADS)
    return {
        "cpu_ms": 1e3 * statistics.median(cpu),
        "wall_ms": 1e3 * statistics.median(wall),
        "faults": statistics.fmean(faults),
        "cells": f"{filt.shape[0]}x{filt.shape[1]}",
        "env": {name: os.environ.get(name) for name in names if os.environ.get(name) is not None},
    }


def in_thread(maze: str, steps: int) -> dict:
    """`grid_step_costs` in a new thread of this process."""
    out: dict = {}
    thread = threading.Thread(target=lambda: out.update(grid_step_costs(maze, steps)))
    thread.start()
    thread.join()
    return out


def in_worker(maze: str, steps: int, keep_trim: bool = True, profile: bool = True) -> dict:
    """`grid_step_costs` in the worker of a one-worker LocalCluster (its nanny's environment, less
    MALLOC_TRIM_THRESHOLD_ unless `keep_trim`; distributed's sampling profiler off unless `profile`);
    run in a fresh process, as the nanny also sets its variables in the process that starts it."""
    import dask
    from distributed import Client, LocalCluster

    environ = dict(dask.config.get("distributed.nanny.pre-spawn-environ"))
    if not keep_trim:
        environ.pop("MALLOC_TRIM_THRESHOLD_", None)
    settings = {"distributed.nanny.pre-spawn-environ": environ, "distributed.worker.profile.enabled": profile}
    with (
        dask.config.set(settings),
        LocalCluster(n_workers=1, threads_per_worker=1, host="127.0.0.1", dashboard_address=None) as cluster,
        Client(cluster) as client,
    ):
        client.run(sys.path.insert, 0, str(Path(__file__).resolve().parent))
        return client.submit(grid_step_costs, maze, steps, pure=False).result()


def study_ms_per_step(maze: str, steps: int, dask: bool) -> dict:
    """A study of the grid filter (4 runs) in this process or on a one-worker LocalCluster: the median
    `ms_per_step` of its rows (wall time) and the CPU time of the process that ran them per step."""
    import mazelab

    kwargs = {"maze": maze, "filters": ["grid"], "runs": 4, "steps": steps, "seed": 1}
    warm = {**kwargs, "runs": 1, "steps": 2}  # imports and first allocations, not measured
    if not dask:
        mazelab.study(**warm)
        started = time.process_time()
        rows = mazelab.study(**kwargs).rows
        cpu = time.process_time() - started
    else:
        from distributed import Client, LocalCluster

        with (
            LocalCluster(n_workers=1, threads_per_worker=1, host="127.0.0.1", dashboard_address=None) as cluster,
            Client(cluster) as client,
        ):
            mazelab.study(**warm, dask=client)
            (before,) = client.run(time.process_time).values()
            rows = mazelab.study(**kwargs, dask=client).rows
            (after,) = client.run(time.process_time).values()
            cpu = after - before
    return {"ms_per_step": statistics.median(r["ms_per_step"] for r in rows), "cpu_ms": 1e3 * cpu / (4 * steps)}


def fresh(place: str, maze: str, steps: int, env: dict[str, str] | None = None) -> dict:
    """One measurement in a fresh Python process (glibc reads its malloc variables at start)."""
    command = [sys.executable, __file__, "--one", place, "--mazes", maze, "--steps", str(steps)]
    done = subprocess.run(command, env={**os.environ, **(env or {})}, capture_output=True, text=True, check=True)
    return json.loads(done.stdout.strip().splitlines()[-1])


PLACES = {  # what a row measures: (the place in the fresh process, extra environment)
    "this process": ("here", None),
    "  + MALLOC_TRIM_THRESHOLD_=65536": ("here", TRIM),
    "  + OMP/MKL/OPENBLAS_NUM_THREADS=1": ("here", NANNY_THREADS),
    "a thread of this process": ("thread", None),
    "LocalCluster worker (nanny env)": ("worker", None),
    "  - MALLOC_TRIM_THRESHOLD_": ("worker-no-trim", None),
    "  - distributed's profiler": ("worker-no-profile", None),
}


def one(place: str, maze: str, steps: int) -> dict:
    warnings.simplefilter("ignore")
    if place == "here":
        return grid_step_costs(maze, steps)
    if place == "thread":
        return in_thread(maze, steps)
    if place.startswith("worker"):
        return in_worker(maze, steps, keep_trim=place != "worker-no-trim", profile=place != "worker-no-profile")
    return study_ms_per_step(maze, steps, dask=place == "study-dask")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=60)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--mazes", default="paper_5x5,maze_10x10")
    parser.add_argument("--one", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.one:
        print(json.dumps(one(args.one, args.mazes, args.steps)))
        return
    print(f"load average {os.getloadavg()[0]:.2f} on {os.cpu_count()} cores; medians of {args.repeats} fresh processes")
    for maze in args.mazes.split(","):
        print(f"\n{maze}, {args.steps} steps: the grid filter's step and reads (estimate, ESS, confidence)")
        print(f"{'where':<36} {'cells':>9} {'CPU ms/step':>11} {'wall ms/step':>12} {'page faults/step':>16}")
        for label, (place, env) in PLACES.items():
            rows = [fresh(place, maze, args.steps, env) for _ in range(args.repeats)]
            cpu, wall, faults = (statistics.median(r[key] for r in rows) for key in ("cpu_ms", "wall_ms", "faults"))
            print(f"{label:<36} {rows[0]['cells']:>9} {cpu:>11.2f} {wall:>12.2f} {faults:>16.0f}")
        for place, label in (("study-here", "in this process"), ("study-dask", "on a LocalCluster")):
            rows = [fresh(place, maze, args.steps) for _ in range(args.repeats)]
            wall, cpu = (statistics.median(r[key] for r in rows) for key in ("ms_per_step", "cpu_ms"))
            print(f"a study of the grid filter {label:<18}: ms_per_step {wall:.2f} (wall), CPU {cpu:.2f} ms/step")
    print(f"\nload average {os.getloadavg()[0]:.2f} at the end")


if __name__ == "__main__":
    main()
