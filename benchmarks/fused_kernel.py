"""The fused limit: each filter's whole step and its reads as one single-thread numba function, written
apart from the package (it shares nothing with mazelab.kernels but the maze's lookup tables), to time
the package's compiled backend against on the same walks.

    uv run python benchmarks/fused_kernel.py                    # SIR, APF, RPF on maze_10x10 and a 50x50 maze
    uv run python benchmarks/fused_kernel.py --counts 1000,10000 --rounds 5

Each fused step does what the package's step and reads do: systematic resampling (by counting, fused
with the gather), the move (uniform heading on the arc, cos/sin, the step), the nearest station and
the free flag from the project's lookup tables, the likelihood with the outside penalty, log-domain
normalisation, and the reads (posterior mean, ESS, the share of the weight within the green circle).
The random numbers come from the same numpy Generator calls (uniforms and normals into reused
buffers), so both sides pay the same for them. Everything else is fused: the ancestors are never
stored, the weights are kept unnormalised between steps (their total is known), the APF's first stage
and the RPF's covariance come out of the passes that already read the particles.

The timing alternates the fused step and the package's (filter_stepper) round by round, the median
of each round's median step, CPU time (time.process_time: the machine is shared); the load is printed.
"""

from __future__ import annotations

import argparse
import math
import os
import statistics
import time

import numpy as np
from numba import njit

from mazelab.backend import use_backend
from mazelab.bench import BENCH_DELTA, BENCH_SIGMA, filter_stepper, record_walk
from mazelab.maze import Maze
from mazelab.maze_generator import default_station_count, generate_maze
from mazelab.model import OUTSIDE_PENALTY, ROBOT_SPEED, RPF_THRESHOLD

F32 = np.float32


def lookup_arrays(world: Maze) -> tuple:
    """The maze's nearest-station lookup tables (mazelab.lookup) as plain arrays and numbers."""
    lookup = world._lookup
    tables = lookup._station_tables(np.dtype(F32))
    return (
        F32(lookup.scale),
        lookup.offset,
        lookup.nx,
        lookup.ny,
        lookup.kind,
        lookup.row,
        np.ascontiguousarray(tables.first),
        np.ascontiguousarray(tables.all_x),
        np.ascontiguousarray(tables.all_y),
        np.ascontiguousarray(tables.border),
    )


@njit(cache=True)
def _beyond(px, py, border):
    """Squared distance to the nearest border station, for a point beyond the table (a call of its
    own: written into the inlined _log_lik, the loop slows every point several times)."""
    best = F32(np.inf)
    for b in range(border.shape[0]):
        dx = border[b, 0] - px
        dy = border[b, 1] - py
        d2 = dx * dx + dy * dy
        if d2 < best:
            best = d2
    return best


@njit(cache=True, inline="always")
def _log_lik(px, py, z, inv_sigma, free_term, outside_term, scale, offset, nx, ny, kind, row, first, all_x, all_y,
             border):  # fmt: skip
    """log p(z | x) for one float32 point: the lookup cell, its candidates, the Gaussian, the penalty."""
    ix = math.floor(px * scale) + offset
    iy = math.floor(py * scale) + offset
    best = F32(-1.0)
    free = False
    if ix >= 0 and iy >= 0 and ix < nx and iy < ny:
        cell = iy * nx + ix
        k = kind[cell]
        if k & 2:
            r = row[cell]
            best = F32(np.inf)
            for c in range(all_x.shape[0]):
                dx = all_x[c, r] - px
                dy = all_y[c, r] - py
                d2 = dx * dx + dy * dy
                if d2 < best:
                    best = d2
        else:
            dx = first[cell, 0] - px
            dy = first[cell, 1] - py
            best = dx * dx + dy * dy
        free = (k & 1) != 0
    if best < 0:
        best = _beyond(px, py, border)
    res = (math.sqrt(best) - z) * inv_sigma
    return -0.5 * res * res + (free_term if free else outside_term)


@njit(cache=True)
def _reads(x, y, lw, w, top):
    """Unnormalised weights w = exp(lw - top) into `w`; returns (total, mean x, mean y, ESS), one pass."""
    s = s2 = sx = sy = 0.0
    for i in range(len(x)):
        wi = math.exp(lw[i] - top)
        w[i] = wi
        s += wi
        s2 += wi * wi
        sx += wi * x[i]
        sy += wi * y[i]
    return s, sx / s, sy / s, s * s / s2


@njit(cache=True)
def _share(x, y, w, total, mx, my, radius):
    """The share of the weight within `radius` of (mx, my)."""
    inside = 0.0
    r2 = radius * radius
    for i in range(len(x)):
        dx = x[i] - mx
        dy = y[i] - my
        if dx * dx + dy * dy <= r2:
            inside += w[i]
    return inside / total


@njit(cache=True)
def sir_step(x, y, w, total, nx_, ny_, lw, u, offset_u, th0, delta, speed, z, inv_sigma, free_term, outside_term,
             scale, offset, nx, ny, kind, row, first, all_x, all_y, border, radius):  # fmt: skip
    """Algorithm 4 fused: resample (counting) + move + likelihood in one pass, then the reads."""
    n = len(x)
    cumulative = 0.0
    j = 0
    top = -np.inf
    inv_total = 1.0 / total
    for i in range(n):
        cumulative += w[i] * inv_total
        end = min(n, math.ceil(cumulative * n - offset_u)) if i < n - 1 else n
        while j < end:
            heading = (u[j] - F32(0.5)) * delta + th0
            px = x[i] + math.cos(heading) * speed
            py = y[i] + math.sin(heading) * speed
            nx_[j] = px
            ny_[j] = py
            lj = _log_lik(px, py, z, inv_sigma, free_term, outside_term, scale, offset, nx, ny, kind, row, first,
                          all_x, all_y, border)  # fmt: skip
            lw[j] = lj
            if lj > top:
                top = lj
            j += 1
    new_total, mx, my, ess = _reads(nx_, ny_, lw, w, top)
    return new_total, mx, my, ess, _share(nx_, ny_, w, new_total, mx, my, radius)


@njit(cache=True)
def apf_step(x, y, w, total, nx_, ny_, lw, lmu, u1, u2, offset_u, th0, delta, speed, z, inv_sigma, free_term,
             outside_term, scale, offset, nx, ny, kind, row, first, all_x, all_y, border, radius):  # fmt: skip
    """Algorithm 5 fused: the auxiliary points and first stage in one pass, its exponentials in a second,
    resample + move + likelihood + second stage in a third, then the reads."""
    n = len(x)
    top = -np.inf
    for i in range(n):
        heading = (u1[i] - F32(0.5)) * delta + th0
        px = x[i] + math.cos(heading) * speed
        py = y[i] + math.sin(heading) * speed
        li = _log_lik(px, py, z, inv_sigma, free_term, outside_term, scale, offset, nx, ny, kind, row, first,
                      all_x, all_y, border)  # fmt: skip
        lmu[i] = li
        first_stage = math.log(w[i]) + li  # w holds W * total: the common log total cancels
        lw[i] = first_stage
        if first_stage > top:
            top = first_stage
    s = 0.0
    for i in range(n):
        e = math.exp(lw[i] - top)
        lw[i] = e
        s += e
    cumulative = 0.0
    j = 0
    top2 = -np.inf
    for i in range(n):
        cumulative += lw[i] / s
        end = min(n, math.ceil(cumulative * n - offset_u)) if i < n - 1 else n
        while j < end:
            heading = (u2[j] - F32(0.5)) * delta + th0
            px = x[i] + math.cos(heading) * speed
            py = y[i] + math.sin(heading) * speed
            nx_[j] = px
            ny_[j] = py
            second = _log_lik(px, py, z, inv_sigma, free_term, outside_term, scale, offset, nx, ny, kind, row, first,
                              all_x, all_y, border) - lmu[i]  # fmt: skip
            u1[j] = second  # u1 is spent: it holds the second stage
            if second > top2:
                top2 = second
            j += 1
    new_total, mx, my, ess = _reads(nx_, ny_, u1, w, top2)
    return new_total, mx, my, ess, _share(nx_, ny_, w, new_total, mx, my, radius)


@njit(cache=True)
def rpf_step(x, y, w, total, nx_, ny_, lw, u, eps, offset_u, regularise, h, th0, delta, speed, z, inv_sigma,
             free_term, outside_term, scale, offset, nx, ny, kind, row, first, all_x, all_y, border,
             radius):  # fmt: skip
    """Algorithm 6 fused: if the ESS fell below N_T, resample + jitter (h D eps, D D^T the weighted
    covariance, its moments from one pass) into the other buffer; then move + likelihood + weight in
    one pass, then the reads."""
    n = len(x)
    if regularise:
        sx = sy = 0.0
        for i in range(n):
            sx += w[i] * x[i]
            sy += w[i] * y[i]
        mx0, my0 = sx / total, sy / total
        cxx = cxy = cyy = 0.0
        for i in range(n):
            dx = x[i] - mx0
            dy = y[i] - my0
            cxx += w[i] * dx * dx
            cxy += w[i] * dx * dy
            cyy += w[i] * dy * dy
        cxx, cxy, cyy = cxx / total + 1e-12, cxy / total, cyy / total + 1e-12
        a = math.sqrt(cxx)
        c = cxy / a
        d = math.sqrt(max(cyy - c * c, 0.0))
        a32, c32, d32 = F32(h * a), F32(h * c), F32(h * d)
        cumulative = 0.0
        j = 0
        for i in range(n):
            cumulative += w[i] / total
            end = min(n, math.ceil(cumulative * n - offset_u)) if i < n - 1 else n
            while j < end:
                e0 = eps[j, 0]
                nx_[j] = x[i] + a32 * e0
                ny_[j] = y[i] + c32 * e0 + d32 * eps[j, 1]
                j += 1
        for i in range(n):
            x[i] = nx_[i]
            y[i] = ny_[i]
            w[i] = 1.0
        total = float(n)
    top = -np.inf
    log_total = math.log(total)
    for i in range(n):
        heading = (u[i] - F32(0.5)) * delta + th0
        px = x[i] + math.cos(heading) * speed
        py = y[i] + math.sin(heading) * speed
        nx_[i] = px
        ny_[i] = py
        li = math.log(w[i]) - log_total + _log_lik(px, py, z, inv_sigma, free_term, outside_term, scale, offset,
                                                    nx, ny, kind, row, first, all_x, all_y, border)  # fmt: skip
        lw[i] = li
        if li > top:
            top = li
    new_total, mx, my, ess = _reads(nx_, ny_, lw, w, top)
    return new_total, mx, my, ess, _share(nx_, ny_, w, new_total, mx, my, radius)


class Fused:
    """One filter's state and buffers, stepped by the fused kernel: x, y float32, unnormalised weights."""

    def __init__(self, name: str, world: Maze, particles: int, seed: int = 2):
        self.name, self.rng = name, np.random.default_rng(seed)
        points = world.random_free_places(particles, self.rng)
        self.x, self.y = points[:, 0].astype(F32), points[:, 1].astype(F32)
        self.nx, self.ny = np.empty_like(self.x), np.empty_like(self.y)
        self.w, self.total = np.ones(particles), float(particles)
        self.lw, self.lmu = np.empty(particles), np.empty(particles)
        self.u1, self.u2 = np.empty(particles, F32), np.empty(particles, F32)
        self.eps = np.empty((particles, 2), F32)
        self.tables = lookup_arrays(world)
        norm = math.log(BENCH_SIGMA * math.sqrt(2 * math.pi))
        self.model = (F32(BENCH_DELTA), F32(ROBOT_SPEED))
        self.likelihood = (1 / BENCH_SIGMA, -norm, math.log(OUTSIDE_PENALTY) - norm)
        self.h = (4 / 4) ** (1 / 6) * particles ** (-1 / 6)
        self.ess = float(particles)
        self.reads = None

    def step(self, compass_angle: float, z: float) -> None:
        n = len(self.x)
        th0 = F32(compass_angle)
        if self.name == "rpf":
            regularise = self.ess < RPF_THRESHOLD * n
            offset_u = self.rng.random() if regularise else 0.0
            if regularise:
                self.rng.standard_normal(dtype=F32, out=self.eps)
            self.rng.random(dtype=F32, out=self.u1)
            out = rpf_step(self.x, self.y, self.w, self.total, self.nx, self.ny, self.lw, self.u1, self.eps,
                           offset_u, regularise, self.h, th0, *self.model, z, *self.likelihood, *self.tables,
                           1.0)  # fmt: skip
        elif self.name == "apf":
            self.rng.random(dtype=F32, out=self.u1)
            offset_u = self.rng.random()
            self.rng.random(dtype=F32, out=self.u2)
            out = apf_step(self.x, self.y, self.w, self.total, self.nx, self.ny, self.lw, self.lmu, self.u1, self.u2,
                           offset_u, th0, *self.model, z, *self.likelihood, *self.tables, 1.0)  # fmt: skip
        else:
            offset_u = self.rng.random()
            self.rng.random(dtype=F32, out=self.u1)
            out = sir_step(self.x, self.y, self.w, self.total, self.nx, self.ny, self.lw, self.u1, offset_u, th0,
                           *self.model, z, *self.likelihood, *self.tables, 1.0)  # fmt: skip
        self.total, mx, my, self.ess, share = out
        self.x, self.nx, self.y, self.ny = self.nx, self.x, self.ny, self.y
        self.reads = (np.array([mx, my]), self.ess, share >= 0.95)


def median_cpu_step(step, walk: list[tuple[float, float]], warmup: int) -> float:
    """The median CPU time of one step (seconds) over the walk, after `warmup` untimed steps."""
    times = []
    for k, (compass_angle, z) in enumerate(walk):
        started = time.process_time()
        step(compass_angle, z)
        if k >= warmup:
            times.append(time.process_time() - started)
    return statistics.median(times)


def fifty_by_fifty(seed: int = 50) -> Maze:
    """A generated 50x50 maze (mazelab maze generate --size 50x50 --seed 50)."""
    return generate_maze(50, 50, default_station_count(50, 50), np.random.default_rng(seed))


def compare(world: Maze, label: str, counts: list[int], rounds: int, filters: list[str], backend: str) -> None:
    """Alternate the fused step and the package's, round by round, and print the medians and the ratio."""
    for n in counts:
        steps = max(12, min(60, 4_000_000 // n))
        walk = record_walk(world, steps + 5)
        for name in filters:
            fused, package = [], []
            for _ in range(rounds):
                state = Fused(name, world, n)
                fused.append(median_cpu_step(state.step, walk, 5))
                with use_backend(backend):
                    stepper = filter_stepper(name, world, n)
                package.append(median_cpu_step(stepper, walk, 5))
            f, p = statistics.median(fused), statistics.median(package)
            print(f"{label:<12} {name:<4} {n:>9,} {1e3 * f:10.3f} {1e3 * p:10.3f} {f / p:8.2f}x", flush=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--counts", default="1000,10000,100000,1000000")
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--filters", default="sir,apf,rpf")
    parser.add_argument("--mazes", default="maze_10x10,50x50")
    parser.add_argument("--backend", default="compiled", help="the package's backend to time (numpy or compiled)")
    args = parser.parse_args()
    counts = [int(c) for c in args.counts.split(",")]
    filters = args.filters.split(",")
    print(f"load average {os.getloadavg()}; CPU ms per step (median of {args.rounds} alternating rounds)")
    print(f"{'maze':<12} {'':<4} {'N':>9} {'fused':>10} {args.backend:>10} {'package/fused speed':>8}")
    for name in args.mazes.split(","):
        world = fifty_by_fifty() if name == "50x50" else Maze.from_file(name)
        world.prepare()
        compare(world, name, counts, args.rounds, filters, args.backend)


if __name__ == "__main__":
    main()
