"""One run on 1 thread and on more, side by side: the compiled step's wall and CPU time per step at
each N, in alternating rounds (1 thread, then 2, then 1 ...), and whether the same seed gave the same
run on each count (the estimates of every step compared bit for bit); then what one call over a
single chunk costs on 1 thread and on more, with TBB's threads and with numba's workqueue.

    uv run python benchmarks/threads.py                                   # SIR, APF, RPF at N = 1e4, 1e5, 1e6
    uv run python benchmarks/threads.py --counts 1000000 --filters sir --rounds 7

A round times `steps` steps of a fresh filter (mazelab.bench.filter_stepper: the step and the reads
`simulate` makes) on the bench's walk on the 10 x 10 maze, after warm-up steps; a figure is the median
over the rounds of each round's median step (CPU: of each round's mean step, the process's CPU, every
thread's; spinning threads count). The speed-up is 1 thread's time over the others'. The machine's load
average is printed before and after: on a machine shared with other work, a thread speed-up reads low
(the second core is not free).
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from mazelab.backend import use_backend, use_threads
from mazelab.bench import BENCH_DELTA, BENCH_SIGMA, filter_stepper, record_walk
from mazelab.maze import Maze
from mazelab.registry import filter_entry


def timed_round(name: str, world: Maze, particles: int, threads: int, walk: list, warmup: int) -> tuple:
    """(median wall s, mean CPU s) of one fresh filter's steps on `threads` threads: the CPU over all
    the timed steps (the system counts a running thread's CPU at its clock ticks, so one step's would
    leave out the other threads')."""
    with use_threads(threads):
        step = filter_stepper(name, world, particles, backend="compiled")
    walls = []
    for k, (compass_angle, z) in enumerate(walk):
        if k == warmup:
            cpu = time.process_time()
        wall = time.perf_counter()
        step(compass_angle, z)
        if k >= warmup:
            walls.append(time.perf_counter() - wall)
    return statistics.median(walls), (time.process_time() - cpu) / len(walls)


def estimates(name: str, world: Maze, particles: int, threads: int, walk: list) -> np.ndarray:
    """The estimate after every step of a seeded run on `threads` threads."""
    rng = np.random.default_rng(2)
    with use_backend("compiled"), use_threads(threads):
        filt = filter_entry(name).filter_class(
            world, BENCH_SIGMA, BENCH_DELTA, world.random_free_places(particles, rng), rng
        )
    out = []
    for compass_angle, z in walk:
        filt.step(compass_angle, z)
        out.append(np.asarray(filt.estimate, dtype=float).copy())
    return np.array(out)


def call_overhead(threads: int, calls: int = 400) -> float:
    """Median wall seconds of one kernel call over one chunk (4,096 values, a microsecond's work) on
    `threads` threads, each call 0.2 ms after the last, as the passes of a step at N = 10^5 follow each
    other: what a call pays to start the threads and wait for them."""
    from mazelab.kernels import CHUNK, THREADED_FROM
    from mazelab.kernels.weights import systematic

    weights, offsets, out = np.full((1, CHUNK), 1 / CHUNK), np.full(1, 0.5), np.empty((1, CHUNK), np.int64)
    times = []
    for _ in range(calls):
        started = time.perf_counter()
        systematic(threads, THREADED_FROM, weights, offsets, out)  # as large: on the threads
        times.append(time.perf_counter() - started)
        while time.perf_counter() < started + 2e-4:
            pass
    return statistics.median(times[10:])


def print_call_overheads(threads: int) -> None:
    """One line per threading layer (each in a fresh process: numba takes one a process) of call_overhead."""
    for layer in ("tbb", "workqueue"):
        code = f"import threads; print(*(threads.call_overhead(t) for t in (1, {threads})))"
        env = {**os.environ, "NUMBA_THREADING_LAYER": layer}
        done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env,
                              cwd=Path(__file__).parent, check=False)  # fmt: skip
        if done.returncode:
            print(f"{layer}: does not load here ({done.stderr.strip().splitlines()[-1]})")
            continue
        one, more = (1e6 * float(value) for value in done.stdout.split())
        print(f"a call over one chunk, {layer}: {one:.1f} us on 1 thread, {more:.1f} us on {threads}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--counts", default="10000,100000,1000000")
    parser.add_argument("--filters", default="sir,apf,rpf")
    parser.add_argument("--threads", type=int, default=2, help="the count set against 1")
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--maze", default="maze_10x10")
    args = parser.parse_args()
    world = Maze.from_file(args.maze)
    world.prepare()
    print(f"load average before {os.getloadavg()}; median of {args.rounds} alternating rounds, ms per step")
    print(f"{'filter':<6} {'N':>9} {'1: wall':>9} {'cpu':>8} {f'{args.threads}: wall':>9} {'cpu':>8} "
          f"{'speed-up wall':>13} {'same run':>9}")  # fmt: skip
    for n in (int(c) for c in args.counts.split(",")):
        steps = max(12, min(40, 4_000_000 // n))
        walk = record_walk(world, steps + 3)
        for name in args.filters.split(","):
            figures: dict[int, list] = {1: [], args.threads: []}
            for _ in range(args.rounds):
                for threads in (1, args.threads):
                    figures[threads].append(timed_round(name, world, n, threads, walk, 3))
            (w1, c1), (w2, c2) = ([statistics.median(f[i] for f in figures[t]) for i in (0, 1)] for t in figures)
            same = np.array_equal(
                estimates(name, world, n, 1, walk[:8]), estimates(name, world, n, args.threads, walk[:8])
            )
            print(f"{name:<6} {n:>9,} {1e3 * w1:9.2f} {1e3 * c1:8.2f} {1e3 * w2:9.2f} {1e3 * c2:8.2f} "
                  f"{w1 / w2:12.2f}x {'yes' if same else 'NO':>9}", flush=True)  # fmt: skip
    print_call_overheads(args.threads)
    print(f"load average after {os.getloadavg()}")


if __name__ == "__main__":
    main()
