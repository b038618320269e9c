"""Peak resident memory of one filter at N particles over its process's own baseline, the package's
compiled (or numpy) backend against the fused kernel (benchmarks/fused_kernel.py), each in a fresh
process:

    uv run python benchmarks/peak_memory.py                      # SIR, APF, RPF at N = 1,000,000
    uv run python benchmarks/peak_memory.py --particles 100000 --backend numpy

The baseline is the resident memory after a small run of the same filter (numpy, numba and the
kernels loaded, the walk recorded); the figure is the process's peak (getrusage's ru_maxrss) after a
fresh filter of N particles ran 12 steps of the walk, minus that baseline.
"""

from __future__ import annotations

import argparse
import os
import resource
import subprocess
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent


def resident_mb() -> float:
    """This process's resident memory now (MB, /proc/self/status)."""
    with open("/proc/self/status") as status:
        return int(status.read().split("VmRSS:")[1].split()[0]) / 1024


def measure(kind: str, name: str, particles: int) -> float:
    """Peak RSS over the baseline (MB) of filter `name` stepped by `kind` (fused, numpy, compiled)."""
    sys.path.insert(0, str(HERE))
    import fused_kernel

    from mazelab.backend import use_backend
    from mazelab.bench import filter_stepper, record_walk
    from mazelab.maze import Maze

    world = Maze.from_file("maze_10x10")
    world.prepare()
    walk = record_walk(world, 12)

    def make(count: int):
        if kind == "fused":
            return fused_kernel.Fused(name, world, count).step
        with use_backend(kind):
            return filter_stepper(name, world, count)

    small = make(1000)
    for compass_angle, z in walk:
        small(compass_angle, z)
    baseline = max(resident_mb(), resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024)
    step = make(particles)
    for compass_angle, z in walk:
        step(compass_angle, z)
    return max(0.0, resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024 - baseline)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--particles", type=int, default=1_000_000)
    parser.add_argument("--filters", default="sir,apf,rpf")
    parser.add_argument("--backend", default="compiled", help="the package's backend (numpy or compiled)")
    parser.add_argument("--one", nargs=2, metavar=("KIND", "FILTER"), help=argparse.SUPPRESS)  # a child's task
    args = parser.parse_args()
    if args.one:
        print(measure(args.one[0], args.one[1], args.particles))
        return
    print(f"load average {os.getloadavg()}; peak RSS over the baseline at N = {args.particles:,}, MB")
    print(f"{'filter':<6} {'fused':>8} {args.backend:>9} {'ratio':>6}")
    for name in args.filters.split(","):
        figures = []
        for kind in ("fused", args.backend):
            command = [sys.executable, __file__, "--particles", str(args.particles), "--one", kind, name]
            figures.append(float(subprocess.run(command, capture_output=True, text=True, check=True).stdout))
        print(f"{name:<6} {figures[0]:8.1f} {figures[1]:9.1f} {figures[1] / figures[0]:5.2f}x", flush=True)


if __name__ == "__main__":
    main()
