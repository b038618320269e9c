"""The exact smoother's memory and time on a long walk: checkpoints every ceil(sqrt(K)) steps against
keeping every filtered density (one block, B = K).

    uv run python benchmarks/smoothing_memory.py                     # maze_10x10, 200 steps, resolution 0.02
    uv run python benchmarks/smoothing_memory.py --steps 50 --every 10

For each B: the peak of the memory numpy allocated during `mazelab.smoothing.smooth` (tracemalloc, which
numpy reports its arrays to) above what was allocated before it, the grids the smoother counts (the
checkpoints, one block, beta and its product), and the wall time (with the load average: the machine may
be shared). The two runs give the same smoothed means bit for bit (checked here).
"""

from __future__ import annotations

import argparse
import os
import time
import tracemalloc

import numpy as np

from mazelab.bench import BENCH_DELTA, BENCH_SIGMA, record_walk
from mazelab.grid_filter import GRID_RESOLUTION, check_grid_memory
from mazelab.maze import load_maze
from mazelab.smoothing import checkpoint_block, smooth


def measure(world, walk, resolution: float, every: int | None) -> tuple[float, float, np.ndarray]:
    """Peak MB allocated during one smoothing, its seconds and its smoothed means."""
    angles, zs = zip(*walk, strict=True)
    tracemalloc.start()
    before, _ = tracemalloc.get_traced_memory()
    started = time.perf_counter()
    result = smooth(world, BENCH_SIGMA, BENCH_DELTA, angles, zs, checkpoint_every=every, resolution=resolution)
    seconds = time.perf_counter() - started
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    return (peak - before) / 2**20, seconds, result.means


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--maze", default="maze_10x10")
    parser.add_argument("--steps", type=int, default=200)
    parser.add_argument("--resolution", type=float, default=GRID_RESOLUTION)
    parser.add_argument("--every", type=int, default=None, help="B for the first run (default ceil(sqrt(K)))")
    args = parser.parse_args()
    world = load_maze(args.maze)
    world.prepare()
    walk = record_walk(world, args.steps)
    print(f"{args.maze}, {args.steps} steps, resolution {args.resolution:g}, load average {os.getloadavg()[0]:.2f}")
    print(f"{'B':>5} {'grids':>6} {'peak MB':>9} {'seconds':>8}")
    means, shape = [], check_grid_memory(world.width, world.height, args.resolution)  # the grid's (rows, columns)
    for every in (args.every, args.steps):
        block = checkpoint_block(shape, args.steps, every)
        peak, seconds, smoothed = measure(world, walk, args.resolution, every)
        grids = -(-args.steps // block) + min(block, args.steps) + 2
        print(f"{block:>5} {grids:>6} {peak:>9.0f} {seconds:>8.1f}")
        means.append(smoothed)
    grid_mb = shape[0] * shape[1] * 8 / 2**20
    print(f"one grid of {shape[0]}x{shape[1]} cells: {grid_mb:.2f} MB; K of them: {args.steps * grid_mb:.0f} MB")
    print("the same smoothed means bit for bit:", bool(np.array_equal(*means)))


if __name__ == "__main__":
    main()
