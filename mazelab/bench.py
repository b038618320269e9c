"""The speed benchmark (`python main.py bench`): particle-steps per second of the filters on each
backend (numpy, and compiled where numba is installed: mazelab.backend) side by side, and of a plain
numpy reference step measured in the same run, on a small and a large maze. A row is one filter's
median step on a recorded walk, its reads included (`measure`); the warm-up steps also let the
particles start to gather, as in a real run.
"""

from __future__ import annotations

import contextlib
import math
import os
import platform
import statistics
import time
import tracemalloc
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np

from mazelab.backend import BACKENDS, chosen_backend, numba_available, use_backend
from mazelab.maze import EMPTY, STATION_WALL, WALL, Maze
from mazelab.model import OUTSIDE_PENALTY, ROBOT_SPEED
from mazelab.registry import filter_entry
from mazelab.robot import Robot
from mazelab.simulation import simulate

BENCH_SIGMA, BENCH_DELTA = 0.3, 0.5
BENCH_FILTERS = ("sir", "apf", "rpf")
FULL_COUNTS = (1_000, 10_000, 100_000, 1_000_000)
QUICK_COUNTS = (1_000, 100_000, 1_000_000)
LARGE_MAZE_CELLS = {EMPTY: 0.75, WALL: 0.17, STATION_WALL: 0.08}  # about 2,700 stations at 100 x 100
REFERENCE_LIMIT = 2.5e7  # the reference step is skipped when N x B exceeds this (its matrix needs N x B x 24 bytes)


@dataclass(frozen=True)
class BenchRow:
    """One measurement: a filter (or the reference step) at N particles on one maze, on a backend."""

    maze: str
    filter_name: str
    particles: int
    seconds_per_step: float
    peak_bytes: int
    backend: str = "numpy"


def large_maze(size: int = 100, seed: int = 5) -> Maze:
    """A seeded random size x size maze: each cell free, wall or station block with LARGE_MAZE_CELLS' odds."""
    rng = np.random.default_rng(seed)
    kinds, odds = zip(*LARGE_MAZE_CELLS.items(), strict=True)
    return Maze(rng.choice(kinds, size=(size, size), p=odds), source=f"generated {size}x{size}")


def record_walk(world: Maze, steps: int, seed: int = 1) -> list[tuple[float, float]]:
    """The (compass angle, measurement) of each step of a seeded lost robot's walk."""
    rng = np.random.default_rng(seed)
    robot = Robot(BENCH_SIGMA, BENCH_DELTA, world.random_free_place(rng), rng=rng)
    return [robot.step(world) for _ in range(steps)]


def time_steps(step: Callable[[float, float], None], walk: list[tuple[float, float]], warmup: int) -> float:
    """The median time of one step (seconds) over the walk, after `warmup` untimed steps."""
    times = []
    for k, (compass_angle, z) in enumerate(walk):
        started = time.perf_counter()
        step(compass_angle, z)
        if k >= warmup:
            times.append(time.perf_counter() - started)
    return statistics.median(times)


def filter_stepper(
    name: str, world: Maze, particles: int, backend: str | None = None
) -> Callable[[float, float], None]:
    """A step of a fresh filter (on `backend`, default the chosen one; the grid filter at its default
    resolution too), followed by the reads `simulate` makes (estimate, ESS, confidence)."""
    rng = np.random.default_rng(2)
    with use_backend(backend or chosen_backend()):
        filt = filter_entry(name).filter_class(
            world, BENCH_SIGMA, BENCH_DELTA, world.random_free_places(particles, rng), rng
        )

    def step(compass_angle: float, z: float) -> None:
        filt.step(compass_angle, z)
        _ = filt.estimate, filt.ess, filt.is_confident

    return step


def reference_stepper(world: Maze, particles: int, seed: int = 2) -> Callable[[float, float], None]:
    """The textbook SIR step in plain numpy, for comparison: float64 (N, 2) particles, resampling by a
    binary search per particle, and the nearest station from the full N x B distance matrix."""
    rng = np.random.default_rng(seed)
    state = {"x": world.random_free_places(particles, rng), "w": np.full(particles, 1 / particles)}
    log_penalty = math.log(OUTSIDE_PENALTY)

    def step(compass_angle: float, z: float) -> None:
        x, w = state["x"], state["w"]
        ancestors = np.searchsorted(np.cumsum(w), (np.arange(particles) + rng.random()) / particles)
        headings = compass_angle + BENCH_DELTA * (rng.random(particles) - 0.5)
        steps = ROBOT_SPEED * np.column_stack([np.cos(headings), np.sin(headings)])
        x = x[np.minimum(ancestors, particles - 1)] + steps
        d = np.sqrt(((x[:, None, :] - world.stations[None, :, :]) ** 2).sum(axis=2)).min(axis=1)  # (N, B) matrix
        log_w = -0.5 * ((z - d) / BENCH_SIGMA) ** 2 + np.where(world.is_free(x[:, 0], x[:, 1]), 0.0, log_penalty)
        w = np.exp(log_w - log_w.max())
        w /= w.sum()
        state["x"], state["w"] = x, w
        _ = w @ x, 1 / np.sum(w**2)

    return step


def traced(make_step: Callable[[], Callable[[float, float], None]], walk: list[tuple[float, float]]) -> tuple:
    """(the stepper `make_step` makes, the peak bytes allocated (tracemalloc) while making it and running
    the walk's first two steps with it)."""
    tracemalloc.start()
    try:
        step = make_step()
        for compass_angle, z in walk[:2]:
            step(compass_angle, z)
        return step, tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()


def measure(
    maze_name: str,
    world: Maze,
    counts: tuple[int, ...],
    steps: int,
    warmup: int,
    backends: tuple[str, ...] | None = None,
) -> Iterator[BenchRow]:
    """The rows of one maze: every filter at every N on each backend (default: the chosen one), then
    the reference step where it is affordable; each timed on the walk after its two traced steps
    (`traced`: the peak memory of its creation and first two steps, left out of the time)."""
    walk = record_walk(world, 2 + warmup + steps)
    world.station_distances_and_free(np.zeros(1, np.float32), np.zeros(1, np.float32))  # build the float32 tables
    for n in counts:
        for name in BENCH_FILTERS:
            for backend in backends or (chosen_backend(),):
                step, peak = traced(lambda name=name, n=n, b=backend: filter_stepper(name, world, n, b), walk)
                seconds = time_steps(step, walk[2:], warmup)
                yield BenchRow(maze_name, filter_entry(name).name, n, seconds, peak, backend)
        if n * len(world.stations) <= REFERENCE_LIMIT:
            step, peak = traced(lambda n=n: reference_stepper(world, n), walk)
            seconds = time_steps(step, walk[2 : 2 + warmup + max(3, steps // 4)], 1)
            yield BenchRow(maze_name, "reference", n, seconds, peak)


def sir_run(world: Maze, particles: int, steps: int, seed: int, run: Callable = simulate) -> tuple[float, Any]:
    """A whole `simulate` (or `run`) run of SIR on the chosen backend: (wall-clock seconds, its result)."""
    robot = Robot(BENCH_SIGMA, BENCH_DELTA, world.random_free_place(np.random.default_rng(seed)))
    started = time.perf_counter()
    result = run(robot, world, BENCH_SIGMA, BENCH_DELTA, particles, steps, seed=seed)
    return time.perf_counter() - started, result


def run_model_line(
    world: Maze, particles: int = 1_000_000, steps: int = 12, seed: int = 4, reference: float | None = None
) -> str:
    """run_model(..., visualize=False) timed end to end against the same seeded run's filter steps
    (simulate records them: 1.00x is no overhead) and the reference step at the same N (unless given,
    seconds per step), in this process: the bench's line."""
    from mazelab.simulation import run_model  # the paper's entry point, as a notebook calls it

    sir_run(world, particles, 2, seed)  # warm the lookup tables
    total = sir_run(world, particles, steps, seed, partial(run_model, visualize=False))[0]
    own = float(sir_run(world, particles, steps, seed)[1].step_seconds.sum())
    if reference is None:
        reference = time_steps(reference_stepper(world, particles), record_walk(world, 4), 1)
    return (
        f"run_model(), SIR, N = {particles:,}, {steps} steps, visualize=False: {total:.2f} s, {total / own:.2f}x "
        f"its filter steps' own time ({own:.2f} s), {steps * reference / total:.1f}x the reference step"
    )


def cpu_model() -> str:
    """The CPU's model name from /proc/cpuinfo (Linux), else what platform knows."""
    name = ""
    with contextlib.suppress(OSError), open("/proc/cpuinfo", encoding="utf-8") as info:
        name = next((line.split(":", 1)[1].strip() for line in info if line.startswith("model name")), "")
    return name or platform.processor() or platform.machine()


def format_table(rows: list[BenchRow]) -> str:
    """The rows as a text table, each filter's speed also as a multiple of the reference step's and, on
    the compiled backend, of the same filter's on numpy (at the same N: the inverse ratio of the times)."""
    on_numpy = {(r.maze, r.filter_name, r.particles): r.seconds_per_step for r in rows if r.backend == "numpy"}
    lines = [
        "Speed in millions of particle-steps per second (N particles x steps / time); x numpy: a compiled row's",
        "speed over the same filter's on the numpy backend; x reference: the filter's speed over the plain numpy",
        "reference step's at the same N (- where the reference's N x B matrix would not fit in memory, so it",
        "was not run).",
        f"{'maze':<22} {'filter':<26} {'backend':<9} {'N':>9} {'M/s':>9} {'ms/step':>9} {'peak MB':>8} "
        f"{'x numpy':>8} {'x reference':>12}",
    ]
    for r in rows:
        speed, base = r.particles / r.seconds_per_step, on_numpy.get((r.maze, "reference", r.particles))
        ratio = "(itself)" if r.filter_name == "reference" else f"{base / r.seconds_per_step:.1f}x" if base else "-"
        on_numpy_seconds = on_numpy.get((r.maze, r.filter_name, r.particles)) if r.backend != "numpy" else None
        versus = f"{on_numpy_seconds / r.seconds_per_step:.2f}x" if on_numpy_seconds else "-"
        millions = f"{speed / 1e6:.3g}" if speed < 1e8 else f"{speed / 1e6:.0f}"  # 0.0088 (not 0.00), 25.6, 102
        lines.append(
            f"{r.maze:<22} {r.filter_name:<26} {r.backend:<9} {r.particles:>9,} {millions:>9} "
            f"{1e3 * r.seconds_per_step:9.2f} {r.peak_bytes / 2**20:8.1f} {versus:>8} {ratio:>12}"
        )
    return "\n".join(lines)


def available_backends() -> tuple[str, ...]:
    """The backends this machine has: numpy, and compiled where numba imports."""
    return BACKENDS if numba_available() else BACKENDS[:1]


def kernels_start_seconds(world: Maze) -> tuple[float, int]:
    """The compiled backend's start in this process: (seconds to import numba and the kernels and run
    two steps of each filter on `world`, how many kernels had to be compiled rather than loaded from
    the cache)."""
    started = time.perf_counter()
    from mazelab.kernels import model, weights  # imports numba

    walk = record_walk(world, 2)
    for name in BENCH_FILTERS:
        step = filter_stepper(name, world, 200, backend="compiled")
        for compass_angle, z in walk:
            step(compass_angle, z)
    kernels = (model.move, model.log_likelihood, weights.systematic, weights.normalise)
    return time.perf_counter() - started, sum(sum(k.serial.stats.cache_misses.values()) for k in kernels)


def run_benchmark(
    small: Maze, quick: bool = False, echo: Callable[[str], None] = print, backends: tuple[str, ...] | None = None
) -> list[BenchRow]:
    """Measure and print everything (with `echo`, one line a call) and return the table's rows: on the
    `small` maze and a generated large one (`large_maze`), on `backends` side by side (None: every
    backend this machine has); `quick`: fewer sizes and steps (40 s a backend on a 2-core virtual
    machine; the full run, minutes)."""
    backends = backends or available_backends()
    counts, steps, warmup = (QUICK_COUNTS, 8, 4) if quick else (FULL_COUNTS, 30, 10)
    echo(
        f"CPU: {cpu_model()}, {os.cpu_count()} cores; numpy {np.__version__}; backends {', '.join(backends)}; "
        f"median of {steps} steps after {warmup} warm-up steps; peak memory by tracemalloc (filter + 2 steps)"
    )
    if "compiled" in backends:
        seconds, compiled = kernels_start_seconds(small)
        how = f"{compiled} kernels compiled (the first use on this machine)" if compiled else "loaded from the cache"
        echo(f"compiled backend: numba imported and the kernels {how} in {seconds:.1f} s, once per process")
    rows: list[BenchRow] = []
    for label, world in (("small", small), ("large", large_maze())):
        echo(f"{label}: {Path(world.source).name}, {world.height}x{world.width}, {len(world.stations)} stations")
        rows += measure(f"{label} {world.height}x{world.width}", world, counts, steps, warmup, backends=backends)
    echo(format_table(rows))
    grid_ms = 1e3 * time_steps(filter_stepper("grid", small, 1), record_walk(small, 12 if quick else 32), 2)
    echo(f"GridBayesFilter on the small maze (resolution 0.02): {grid_ms:.1f} ms/step")
    key = ("small", "reference", 10**6)  # the reference step at N = 10^6 on the small maze, if it ran
    reference = next((r.seconds_per_step for r in rows if (r.maze[:5], r.filter_name, r.particles) == key), None)
    for backend in backends:
        with use_backend(backend):
            seconds, result = sir_run(small, 1500, 50 if quick else 200, 3)
            per_step, own = 1e3 * seconds / len(result.step_seconds), 1e3 * float(np.mean(result.step_seconds))
            echo(
                f"[{backend}] simulate(), SIR, N = 1,500 on the small maze: {per_step:.2f} ms/step, of which the "
                f"filter {own:.2f}"
            )
            echo(f"[{backend}] " + run_model_line(small, reference=reference))
            if not quick:
                seconds, result = sir_run(small, 1_000_000, 200, 4)
                echo(
                    f"[{backend}] simulate(), SIR, N = 1,000,000, 200 steps on the small maze: {seconds:.1f} s "
                    f"(last-step error {float(result.errors[-1]):.3f})"
                )
    return rows
