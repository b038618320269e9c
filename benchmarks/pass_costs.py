"""The compiled SIR step's cost per pass, in ns per particle-step, one thread, N = 1,000,000, beside each
pass's floor: the time this machine takes to stream the bytes the pass must read and write (a plain
vectorised loop over arrays of N, measured here), so that "how far from the floor" is a ratio measured
on one machine, not a guess. With another checkout, the same figures for its code too, in alternating
rounds (each in its own environment):

    uv run python benchmarks/pass_costs.py
    uv run python benchmarks/pass_costs.py --other /tmp/old --rounds 5     # against another checkout

A pass is timed (CPU time) by wrapping what the step calls for it: the resampling scheme (the
ancestors), the model's transition (the move with its random draws), the model's log-likelihood, and
the normalisation with the step's reads (the weights value's `from_log`); the filter is the package's
SIRParticleFilter on the walk of mazelab.bench, on the 10 x 10 maze, MAZELAB_THREADS=1.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

# each pass's necessary traffic, bytes a particle: (read, written)
PASSES = {
    "resampling": (4, 8),  # W (float32) read, the ancestors (int64) written
    "move + draws": (16, 12),  # the ancestors and the particles gathered, the moved particles and headings
    "likelihood": (8, 4),  # the particles, log G (float32)
    "normalisation + reads": (12, 4),  # log w and the particles, W (one pass: the limit)
}


def floor_ns(read: int, written: int, count: int) -> float:
    """ns a particle to stream `read` bytes in and `written` bytes out of arrays of `count` (float32 words)."""
    import numba

    @numba.njit(nogil=True)
    def stream(sources, targets):  # pragma: no cover - compiled
        for i in range(sources.shape[1]):
            total = np.float32(0.0)
            for k in range(sources.shape[0]):
                total += sources[k, i]
            for k in range(targets.shape[0]):
                targets[k, i] = total

    sources = np.ones((read // 4, count), np.float32)
    targets = np.empty((written // 4, count), np.float32)
    stream(sources, targets)
    times = []
    for _ in range(9):
        started = time.process_time()
        stream(sources, targets)
        times.append(time.process_time() - started)
    return 1e9 * min(times) / count


def measure(count: int, steps: int) -> dict[str, float]:
    """Median CPU ns a particle of each pass over the walk's steps (after two), this checkout's code."""
    os.environ.update(MAZELAB_BACKEND="compiled", MAZELAB_THREADS="1")
    from mazelab.bench import BENCH_DELTA, BENCH_SIGMA, record_walk
    from mazelab.filters import SIRParticleFilter
    from mazelab.maze import Maze

    world = Maze.from_file("maze_10x10")
    world.prepare()
    walk = record_walk(world, steps + 2)
    rng = np.random.default_rng(2)
    filt = SIRParticleFilter(world, BENCH_SIGMA, BENCH_DELTA, world.random_free_places(count, rng), rng)
    times: dict[str, list[float]] = {name: [] for name in PASSES}

    def timed(name, function):
        def call(*args, **kwargs):
            started = time.process_time()
            result = function(*args, **kwargs)
            times[name].append(time.process_time() - started)
            return result

        return call

    filt.resample = timed("resampling", filt.resample)
    filt.model.M = timed("move + draws", filt.model.M)
    filt.model.logG = timed("likelihood", filt.model.logG)
    weights = filt.weights_class
    weights.from_log = classmethod(timed("normalisation + reads", weights.from_log.__func__))
    for k, (compass_angle, z) in enumerate(walk):
        if k == 2:
            times = {name: [] for name in PASSES}
        filt.step(compass_angle, z)
        _ = filt.estimate, filt.ess, filt.is_confident
    return {name: 1e9 * statistics.median(values) / count for name, values in times.items()}


def in_checkout(checkout: Path, count: int, steps: int) -> dict[str, float]:
    """`measure` in another checkout's environment (a fresh process)."""
    command = ["uv", "run", "--no-sync", "python", __file__, "--one", "--particles", str(count), "--steps", str(steps)]
    done = subprocess.run(command, cwd=checkout, capture_output=True, text=True, check=True)
    return json.loads(done.stdout.splitlines()[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--particles", type=int, default=1_000_000)
    parser.add_argument("--steps", type=int, default=12)
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--other", type=Path, help="another checkout (its own uv environment)")
    parser.add_argument("--one", action="store_true", help=argparse.SUPPRESS)  # a child's task
    args = parser.parse_args()
    if args.one:
        print(json.dumps(measure(args.particles, args.steps)))
        return
    here = Path(__file__).resolve().parents[1]
    subjects = [("this", here)] + ([("other", args.other)] if args.other else [])
    figures: dict[str, list[dict[str, float]]] = {label: [] for label, _ in subjects}
    print(f"load average before: {os.getloadavg()}")
    for r in range(args.rounds):
        for label, checkout in subjects if r % 2 == 0 else subjects[::-1]:
            figures[label].append(in_checkout(checkout, args.particles, args.steps))
        print(f"round {r + 1} done, load {os.getloadavg()[0]:.1f}", flush=True)
    floors = {name: floor_ns(read, written, args.particles) for name, (read, written) in PASSES.items()}
    labels = [label for label, _ in subjects]
    print(f"ns per particle-step, one thread, N = {args.particles:,} (median of {args.rounds} rounds), and the floor")
    print(f"{'pass':<24}" + "".join(f"{label:>9}" for label in labels) + f"{'floor':>9}{'x floor':>9}")
    for name in PASSES:
        medians = [statistics.median(f[name] for f in figures[label]) for label in labels]
        row = "".join(f"{m:9.2f}" for m in medians)
        print(f"{name:<24}{row}{floors[name]:9.2f}{medians[0] / floors[name]:8.1f}x")
    totals = [sum(statistics.median(f[n] for f in figures[label]) for n in PASSES) for label in labels]
    print(f"{'the four':<24}" + "".join(f"{t:9.2f}" for t in totals) + f"{sum(floors.values()):9.2f}")


if __name__ == "__main__":
    sys.exit(main())
