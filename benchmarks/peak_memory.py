"""Peak resident memory of one filter at N particles over its process's own baseline, the package's
compiled (or numpy) backend against the fused kernel (benchmarks/fused_kernel.py), each in a fresh
process:

    uv run python benchmarks/peak_memory.py                      # SIR, APF, RPF at N = 1,000,000
    uv run python benchmarks/peak_memory.py --particles 100000 --backend numpy

The baseline is the resident memory after a small run of the same filter (numpy, numba and the
kernels loaded, the walk recorded); the figure is the process's peak (getrusage's ru_maxrss) after a
fresh filter of N particles ran 12 steps of the walk, minus that baseline. On the compiled backend the
table is followed by what the filter's buffers hold after those steps (mazelab.kernels.compiled's
BufferPool: arrays by name, the count kept and their size).
"""

from __future__ import annotations

import argparse
import inspect
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
    peak = max(0.0, resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024 - baseline)
    return peak, buffers(step)


def buffers(step) -> str:
    """What the compiled filter behind `step` keeps in its buffer pool: "name count x MB, ..." ("" for
    the fused kernel and the numpy backend, which keep none)."""
    filt = inspect.getclosurevars(step).nonlocals.get("filt")  # mazelab.bench.filter_stepper's filter
    pool = getattr(getattr(filt, "ops", None), "pool", None)
    if pool is None:
        return ""
    held = ((name, slot[-1]) for name, slot in pool._slots.items())
    return ", ".join(f"{name} {len(arrays)} x {arrays[0].nbytes / 1e6:.1f}" for name, arrays in held if arrays)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--particles", type=int, default=1_000_000)
    parser.add_argument("--filters", default="sir,apf,rpf")
    parser.add_argument("--backend", default="compiled", help="the package's backend (numpy or compiled)")
    parser.add_argument("--one", nargs=2, metavar=("KIND", "FILTER"), help=argparse.SUPPRESS)  # a child's task
    args = parser.parse_args()
    if args.one:
        peak, held = measure(args.one[0], args.one[1], args.particles)
        print(peak)
        print(held)
        return
    print(f"load average {os.getloadavg()}; peak RSS over the baseline at N = {args.particles:,}, MB")
    print(f"{'filter':<6} {'fused':>8} {args.backend:>9} {'ratio':>6}")
    held = {}
    for name in args.filters.split(","):
        figures = []
        for kind in ("fused", args.backend):
            command = [sys.executable, __file__, "--particles", str(args.particles), "--one", kind, name]
            peak, held[name] = subprocess.run(command, capture_output=True, text=True, check=True).stdout.split("\n")[
                :2
            ]
            figures.append(float(peak))
        print(f"{name:<6} {figures[0]:8.1f} {figures[1]:9.1f} {figures[1] / figures[0]:5.2f}x", flush=True)
    if any(held.values()):
        print(f"\nwhat the {args.backend} filters' buffers hold after the steps (name, arrays kept x MB each):")
        for name, line in held.items():
            print(f"{name:<6} {line}")


if __name__ == "__main__":
    main()
