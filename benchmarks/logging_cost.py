"""The cost of drawing a run in Rerun, per step, against the filter's own cost.

    python benchmarks/logging_cost.py [--steps 50]

For 1e3, 1e4 and 1e5 SIR particles on maze_10x10, drawing every particle and drawing at most
DEFAULT_MAX_DRAWN of them, into an .rrd file in a temporary folder: the time spent in log_step
(logging is asynchronous, so this is what the run waits for), the time to flush and close the
file at the end, the sum of both per step, the filter's own time per step and the file's size.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from draw import DEFAULT_MAX_DRAWN, Maze, Visualization, open_view
from particle_filter import Robot, simulate

MAZE = Path(__file__).resolve().parent.parent / "mazes" / "maze_10x10.txt"


class TimedView:
    """A view that times the view it wraps: seconds per log_step, and for close."""

    def __init__(self, view):
        self.view, self.step_seconds, self.close_seconds = view, [], 0.0

    def log_step(self, *args):
        started = time.perf_counter()
        self.view.log_step(*args)
        self.step_seconds.append(time.perf_counter() - started)

    def close(self):
        started = time.perf_counter()
        self.view.close()
        self.close_seconds = time.perf_counter() - started


def measure(world: Maze, particles: int, max_drawn: int, steps: int, folder: Path) -> dict:
    path = folder / f"run-{particles}-{max_drawn}.rrd"
    view = TimedView(open_view(Visualization(path, max_drawn=max_drawn), world, "SIRParticleFilter"))
    robot = Robot(0.3, 0.5, world.random_free_place(np.random.default_rng(1)))
    result = simulate(robot, world, 0.3, 0.5, particles, steps, seed=2, visualize=view)
    log_ms = 1e3 * np.median(view.step_seconds)
    total_ms = 1e3 * (sum(view.step_seconds) + view.close_seconds) / steps
    return {
        "log_ms": log_ms,
        "close_s": view.close_seconds,
        "total_ms": total_ms,
        "filter_ms": 1e3 * np.median(result.step_seconds),
        "mb": path.stat().st_size / 1e6,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=50)
    steps = parser.parse_args().steps
    world = Maze.from_file(MAZE)
    print(f"{steps} steps, SIR on {MAZE.name}, recording to an .rrd file")
    print(f"{'particles':>9} {'drawn':>7} {'log_step ms':>11} {'close s':>8} {'logging ms/step':>15} "
          f"{'filter ms/step':>14} {'file MB':>8}")  # fmt: skip
    with tempfile.TemporaryDirectory() as folder:
        measure(world, 1000, 1000, 5, Path(folder))  # warm-up: imports, the batcher's threads
        for particles in (1_000, 10_000, 100_000):
            for max_drawn in sorted({particles, min(particles, DEFAULT_MAX_DRAWN)}, reverse=True):
                m = measure(world, particles, max_drawn, steps, Path(folder))
                print(f"{particles:>9} {min(particles, max_drawn):>7} {m['log_ms']:>11.2f} {m['close_s']:>8.2f} "
                      f"{m['total_ms']:>15.2f} {m['filter_ms']:>14.2f} {m['mb']:>8.1f}")  # fmt: skip


if __name__ == "__main__":
    main()
