"""The fused limit: each filter's whole step and its reads as single-thread numba functions, written
apart from the package (it shares nothing with mazelab.kernels but the maze's lookup tables), to time
the package's compiled backend against on the same walks.

    uv run python benchmarks/fused_kernel.py                    # SIR, APF, RPF on maze_10x10 and a 50x50 maze
    uv run python benchmarks/fused_kernel.py --counts 1000,10000 --rounds 5
    uv run python benchmarks/fused_kernel.py --counts 1000000 --threads 2 --clock wall   # the package on 2 threads
    uv run python benchmarks/fused_kernel.py --counts 1500 --runs 30    # 30 runs together against one fused 45,000
    uv run python benchmarks/fused_kernel.py --counts 1000 --filters sir --kernels   # and the bare kernels' SIR step

Each fused step does what the package's step and reads do: systematic resampling (by counting), the
move (uniform heading on the arc, cos/sin, the step), the nearest station and the free flag from the
project's lookup tables, the likelihood with the outside penalty, log-domain normalisation, and the
reads (posterior mean, ESS, the share of the weight within the green circle). The random numbers come
from the same numpy Generator calls (uniforms and normals into reused buffers), so both sides pay the
same for them.

What makes it a limit rather than a straw man:
- float32 particles, log weights and weights; float64 only where a sum runs over N terms;
- cos, sin and exp as float32 polynomials (Cody-Waite range reduction, the Cephes coefficients, the
  power of two built from its bits), branch-free, so the compiler vectorises the passes that call them
  (AVX-512 where the CPU has it) instead of calling the C library once per particle;
- the nearest-station lookup with one load per cell (a code: its candidates' row and the free flag),
  the cell clamped into the table instead of a branch (the rare point beyond it is found by its flag
  and done again in a pass of its own), the candidate count selected without a branch (0 for a cell
  with one candidate) and the minimum by selects; the fully branch-free form (every cell reading a row
  of K candidates, far points for the unambiguous cells) measured 20-25% slower on the machine of
  docs/speed.md, whose branch predictor learns the count once the cloud gathers;
- sums in reassociable float64 (numba's fastmath "reassoc"), which the compiler splits into lanes;
- the weights kept unnormalised between steps (their top and total are known), the ancestors in a
  reused int32 buffer, the APF's first stage and the RPF's covariance from the passes that read the
  particles anyway.

The timing alternates the fused step and the package's (filter_stepper) round by round, the median
of each round's median step, CPU time (time.process_time: the machine is shared) or, with --clock
wall, wall-clock time (for --threads: the fused kernel runs on one); the load is printed.
"""

from __future__ import annotations

import argparse
import math
import os
import statistics
import time

import numpy as np
from llvmlite import ir
from numba import njit, types
from numba.extending import intrinsic

from mazelab.backend import use_backend
from mazelab.bench import BENCH_DELTA, BENCH_SIGMA, filter_stepper, record_walk
from mazelab.maze import Maze
from mazelab.maze_generator import default_station_count, generate_maze
from mazelab.model import OUTSIDE_PENALTY, ROBOT_SPEED, RPF_THRESHOLD
from mazelab.registry import filter_entry

F32 = np.float32
FAST = {"reassoc", "contract", "nsz", "arcp", "afn"}  # numba's fastmath flags short of "no NaN, no inf"
FAR = 1e15  # a padding candidate's coordinate: never the nearest (its squared distance stays finite)


def lookup_arrays(world: Maze) -> tuple:
    """The maze's nearest-station lookup tables (mazelab.lookup) in the fused kernel's layout.

    Returns (scale, offset, nx, ny as float32, nx, code (C,), first (C, 2), rows, width, border (b, 2)):
    `rows` holds a row of far points, then the ambiguous cells' rows of K candidates' (x, y), flat,
    `width` = 2 K values each; a cell's code is its row's offset in `rows` (0 for a cell with one
    candidate) times 2, plus 1 if the cell is free: one load per point, as the package's kind byte.
    """
    lookup = world._lookup
    first, _, border = lookup._station_tables(np.dtype(F32))  # (C, 2), the others, (b, 2)
    ambiguous, count = lookup._all.shape
    rows = np.full((ambiguous + 1, count, 2), FAR, dtype=F32)
    rows[1:] = lookup.stations.astype(F32)[lookup._all]  # each ambiguous cell's K candidates' (x, y)
    offsets = np.where(lookup.kind & 2, (lookup.row + 1) * (2 * count), 0)
    return (
        F32(lookup.scale),
        F32(lookup.offset),
        F32(lookup.nx),
        F32(lookup.ny),
        np.uint32(lookup.nx),
        (offsets * 2 + (lookup.kind & 1)).astype(np.uint32),
        np.ascontiguousarray(first),
        rows.reshape(-1),
        np.uint32(2 * count),
        np.ascontiguousarray(border),
    )


@intrinsic
def _float_from_bits(typingctx, bits):
    """The float32 whose IEEE bits are the int32 `bits` (a bitcast: no instruction)."""
    signature = types.float32(types.int32)

    def codegen(context, builder, sig, args):
        return builder.bitcast(args[0], ir.FloatType())

    return signature, codegen


@njit(cache=True, inline="always", fastmath=FAST)
def _exp(x):
    """exp(x) for float32 x <= 0 (Cephes expf: x = n ln 2 + r, |r| <= ln2/2, degree-6 polynomial),
    branch-free; 0 below -87 (where float32 would go subnormal)."""
    clamped = max(x, F32(-87.0))
    n = np.floor(clamped * F32(1.44269504088896341) + F32(0.5))
    r = clamped - n * F32(0.693359375) + n * F32(2.12194440e-4)
    p = F32(1.9875691500e-4) * r + F32(1.3981999507e-3)
    p = p * r + F32(8.3334519073e-3)
    p = p * r + F32(4.1665795894e-2)
    p = p * r + F32(1.6666665459e-1)
    p = p * r + F32(5.0000001201e-1)
    p = p * r * r + r + F32(1.0)
    value = p * _float_from_bits((np.int32(n) + np.int32(127)) << np.int32(23))
    return value if x >= F32(-87.0) else F32(0.0)


@njit(cache=True, inline="always", fastmath=FAST)
def _cos_sin(x):
    """(cos x, sin x) for float32 x of moderate size (Cephes: x = j pi/2 + r in three parts, |r| <=
    pi/4, the quadrant chosen by selects), branch-free."""
    j = np.floor(x * F32(0.636619772367581343) + F32(0.5))
    r = ((x - j * F32(1.5703125)) - j * F32(4.837512969970703125e-4)) - j * F32(7.54978995489188216e-8)
    r2 = r * r
    s = ((F32(-1.9515295891e-4) * r2 + F32(8.3321608736e-3)) * r2 + F32(-1.6666654611e-1)) * r2 * r + r
    c = (F32(2.443315711809948e-5) * r2 + F32(-1.388731625493765e-3)) * r2 + F32(4.166664568298827e-2)
    c = c * r2 * r2 - F32(0.5) * r2 + F32(1.0)
    quadrant = np.int32(j) & np.int32(3)
    swap = (quadrant & np.int32(1)) != 0
    cos_r, sin_r = (s if swap else c), (c if swap else s)
    cos_x = -cos_r if (quadrant == 1 or quadrant == 2) else cos_r
    sin_x = -sin_r if quadrant >= 2 else sin_r
    return cos_x, sin_x


@njit(cache=True)
def _beyond(px, py, border):
    """Squared distance to the nearest border station, for a point beyond the table."""
    best = F32(np.inf)
    for b in range(border.shape[0]):
        dx = border[b, 0] - px
        dy = border[b, 1] - py
        best = min(best, dx * dx + dy * dy)
    return best


@njit(cache=True, inline="always", fastmath=FAST)
def _log_lik(px, py, z, inv_sigma, free_term, outside_term, scale, offset, nxf, nyf, nx, code, first, rows, width):
    """(log p(z | x), whether x is inside the table) for one float32 point: the cell (clamped into the
    table), its code, its first candidate and, for an ambiguous cell, its row of K in the flat `rows`
    (the count selected, the minimum by selects), the Gaussian, the penalty."""
    fx = np.floor(px * scale) + offset
    fy = np.floor(py * scale) + offset
    inside = (fx >= F32(0.0)) & (fy >= F32(0.0)) & (fx < nxf) & (fy < nyf)
    cx = min(max(fx, F32(0.0)), nxf - F32(1.0))
    cy = min(max(fy, F32(0.0)), nyf - F32(1.0))
    cell = np.uint32(cy) * nx + np.uint32(cx)
    dx = first[cell, 0] - px
    dy = first[cell, 1] - py
    best = dx * dx + dy * dy
    cell_code = code[cell]
    base = cell_code >> np.uint32(1)
    for c in range(np.uint32(0), width if base != np.uint32(0) else np.uint32(0), np.uint32(2)):
        dx = rows[base + c] - px
        dy = rows[base + c + np.uint32(1)] - py
        d2 = dx * dx + dy * dy
        best = d2 if d2 < best else best
    res = (math.sqrt(best) - z) * inv_sigma
    return F32(-0.5) * res * res + (free_term if cell_code & np.uint32(1) else outside_term), inside


@njit(cache=True)
def _beyond_fix(x, y, lw, z, inv_sigma, free_term, outside_term, scale, offset, nxf, nyf, nx, code, first, rows,
                width, border):  # fmt: skip
    """Redo the likelihood of the points beyond the table (outside the free area: the penalty) in
    lw; returns the largest value rewritten (-inf if none)."""
    top = F32(-np.inf)
    for i in range(len(x)):
        wrong, inside = _log_lik(x[i], y[i], z, inv_sigma, free_term, outside_term, scale, offset, nxf, nyf, nx,
                                 code, first, rows, width)  # fmt: skip
        if not inside:
            res = (math.sqrt(_beyond(x[i], y[i], border)) - z) * inv_sigma
            lw[i] += F32(-0.5) * res * res + outside_term - wrong
            top = max(top, lw[i])
    return top


@njit(cache=True, fastmath=FAST)
def _resample(w, total, u0, ancestors):
    """Systematic resampling by counting: the points (j + u0) / n below the cumulative weight c_i
    number ceil(n c_i - u0); count where each particle's points end, then a running sum turns the
    counts into the ancestors (no search, no branch on the weights)."""
    n = len(ancestors)
    ancestors[:] = 0
    cumulative = 0.0
    inverse = 1.0 / total
    for i in range(len(w) - 1):
        cumulative += w[i] * inverse
        end = math.ceil(cumulative * n - u0)
        if end < n:
            ancestors[end] += 1
    running = 0
    for j in range(n):
        running += ancestors[j]
        ancestors[j] = running


@njit(cache=True, fastmath=FAST)
def _move(x, y, ancestors, gather, u, th0, delta, speed, out_x, out_y):
    """Equation (1), vectorised: out = x[a] + L (cos th, sin th), th = th0 + delta (u - 1/2), a the
    ancestor if `gather`, else the particle itself."""
    for j in range(len(out_x)):
        a = ancestors[j] if gather else j
        cos_h, sin_h = _cos_sin((u[j] - F32(0.5)) * delta + th0)
        out_x[j] = x[a] + cos_h * speed
        out_y[j] = y[a] + sin_h * speed


@njit(cache=True, fastmath=FAST)
def _weigh(x, y, ancestors, z, inv_sigma, free_term, outside_term, scale, offset, nxf, nyf, nx, code, first, rows,
           width, border, prior, mode, shift, lw):  # fmt: skip
    """lw = log p(z | x) plus, by `mode`, nothing (0), -prior[a] (1: the APF's second stage) or
    prior[j] - shift (2: the RPF's carried log weights; prior may be lw); returns the top of lw."""
    top = F32(-np.inf)
    outside = 0
    for j in range(len(x)):
        value, inside = _log_lik(x[j], y[j], z, inv_sigma, free_term, outside_term, scale, offset, nxf, nyf, nx, code,
                                 first, rows, width)  # fmt: skip
        if mode == 1:
            value -= prior[ancestors[j]]
        elif mode == 2:
            value += prior[j] - shift
        lw[j] = value
        top = value if value > top else top
        outside += not inside
    if outside:
        top = max(top, _beyond_fix(x, y, lw, z, inv_sigma, free_term, outside_term, scale, offset, nxf, nyf, nx, code,
                                   first, rows, width, border))  # fmt: skip
    return top


@njit(cache=True, fastmath=FAST)
def _reads(x, y, lw, top, w, radius):
    """w = exp(lw - top) (float32); returns (total, mean x, mean y, ESS, share within `radius`)."""
    s = s2 = sx = sy = 0.0
    for i in range(len(x)):
        wi = _exp(lw[i] - top)
        w[i] = wi
        s += wi
        s2 += wi * wi
        sx += wi * x[i]
        sy += wi * y[i]
    mx, my = F32(sx / s), F32(sy / s)
    r2 = F32(radius * radius)
    inside = 0.0
    for i in range(len(x)):
        dx = x[i] - mx
        dy = y[i] - my
        inside += w[i] if dx * dx + dy * dy <= r2 else F32(0.0)
    return s, sx / s, sy / s, s * s / s2, inside / s


@njit(cache=True, fastmath=FAST)
def _first_stage(lw, top, lmu, top_mu, fw):
    """The APF's first-stage weights W_{k-1} p(z | mu) unnormalised, float32, into fw; returns their
    total."""
    shift = top + top_mu
    s = 0.0
    for i in range(len(lw)):
        value = _exp(lw[i] + lmu[i] - shift)
        fw[i] = value
        s += value
    return s


@njit(cache=True, fastmath=FAST)
def _covariance_factor(x, y, w, total, h):
    """(a, c, d): h times the Cholesky factor [[a, 0], [c, d]] of the weighted covariance."""
    sx = sy = 0.0
    for i in range(len(x)):
        sx += w[i] * x[i]
        sy += w[i] * y[i]
    mx, my = sx / total, sy / total
    cxx = cxy = cyy = 0.0
    for i in range(len(x)):
        dx = x[i] - mx
        dy = y[i] - my
        cxx += w[i] * dx * dx
        cxy += w[i] * dx * dy
        cyy += w[i] * dy * dy
    cxx, cxy, cyy = cxx / total + 1e-12, cxy / total, cyy / total + 1e-12
    a = math.sqrt(cxx)
    c = cxy / a
    return F32(h * a), F32(h * c), F32(h * math.sqrt(max(cyy - c * c, 0.0)))


@njit(cache=True, fastmath=FAST)
def _jitter(x, y, ancestors, eps, a, c, d, out_x, out_y):
    """The RPF's resampled particles moved by h D eps."""
    for j in range(len(out_x)):
        i = ancestors[j]
        e0 = eps[j, 0]
        out_x[j] = x[i] + a * e0
        out_y[j] = y[i] + (c * e0 + d * eps[j, 1])


class Fused:
    """One filter's state and buffers: x, y float32, log weights lw (float32, unnormalised: their top
    `top`), the weights w = exp(lw - top) of the last reads and their total."""

    def __init__(self, name: str, world: Maze, particles: int, seed: int = 2):
        self.name, self.rng = name, np.random.default_rng(seed)
        points = world.random_free_places(particles, self.rng)
        self.x, self.y = points[:, 0].astype(F32), points[:, 1].astype(F32)
        self.nx, self.ny = np.empty_like(self.x), np.empty_like(self.y)
        self.lw, self.w = np.zeros(particles, F32), np.ones(particles, F32)
        self.top, self.total = F32(0.0), float(particles)
        self.u1, self.ancestors = np.empty(particles, F32), np.empty(particles, np.int32)
        if name == "apf":
            self.u2, self.lmu, self.fw = np.empty(particles, F32), np.empty(particles, F32), np.empty(particles, F32)
        if name == "rpf":
            self.eps = np.empty((particles, 2), F32)
        self.tables = lookup_arrays(world)
        norm = math.log(BENCH_SIGMA * math.sqrt(2 * math.pi))
        self.model = (F32(BENCH_DELTA), F32(ROBOT_SPEED))
        self.likelihood = (F32(1 / BENCH_SIGMA), F32(-norm), F32(math.log(OUTSIDE_PENALTY) - norm))
        self.h = (4 / 4) ** (1 / 6) * particles ** (-1 / 6)
        self.ess = float(particles)
        self.reads = None

    def step(self, compass_angle: float, z: float) -> None:
        """One step of the filter and its reads (estimate, ESS, confidence)."""
        n = len(self.x)
        th0, z32 = F32(compass_angle), F32(z)
        weigh = (z32, *self.likelihood, *self.tables)
        if self.name == "rpf":
            if self.ess < RPF_THRESHOLD * n:
                u0 = self.rng.random()
                self.rng.standard_normal(dtype=F32, out=self.eps)
                a, c, d = _covariance_factor(self.x, self.y, self.w, self.total, self.h)
                _resample(self.w, self.total, u0, self.ancestors)
                _jitter(self.x, self.y, self.ancestors, self.eps, a, c, d, self.nx, self.ny)
                self.x, self.nx, self.y, self.ny = self.nx, self.x, self.ny, self.y
                self.lw[:], self.top = 0.0, F32(0.0)
            self.rng.random(dtype=F32, out=self.u1)
            _move(self.x, self.y, self.ancestors, False, self.u1, th0, *self.model, self.nx, self.ny)
            top = _weigh(self.nx, self.ny, self.ancestors, *weigh, self.lw, 2, self.top, self.lw)
        elif self.name == "apf":
            self.rng.random(dtype=F32, out=self.u1)
            u0 = self.rng.random()
            self.rng.random(dtype=F32, out=self.u2)
            _move(self.x, self.y, self.ancestors, False, self.u1, th0, *self.model, self.nx, self.ny)
            top_mu = _weigh(self.nx, self.ny, self.ancestors, *weigh, self.lw, 0, F32(0.0), self.lmu)
            total = _first_stage(self.lw, self.top, self.lmu, top_mu, self.fw)
            _resample(self.fw, total, u0, self.ancestors)
            _move(self.x, self.y, self.ancestors, True, self.u2, th0, *self.model, self.nx, self.ny)
            top = _weigh(self.nx, self.ny, self.ancestors, *weigh, self.lmu, 1, F32(0.0), self.lw)
        else:
            u0 = self.rng.random()
            self.rng.random(dtype=F32, out=self.u1)
            _resample(self.w, self.total, u0, self.ancestors)
            _move(self.x, self.y, self.ancestors, True, self.u1, th0, *self.model, self.nx, self.ny)
            top = _weigh(self.nx, self.ny, self.ancestors, *weigh, self.lw, 0, F32(0.0), self.lw)
        self.x, self.nx, self.y, self.ny = self.nx, self.x, self.ny, self.y
        self.top = F32(top)
        self.total, mx, my, self.ess, share = _reads(self.x, self.y, self.lw, self.top, self.w, 1.0)
        self.reads = (np.array([mx, my]), self.ess, share >= 0.95)


def median_cpu_step(step, walk: list[tuple[float, float]], warmup: int, clock=time.process_time) -> float:
    """The median time of one step (seconds; CPU time unless `clock` says otherwise) over the walk,
    after `warmup` untimed steps."""
    times = []
    for k, (compass_angle, z) in enumerate(walk):
        started = clock()
        step(compass_angle, z)
        if k >= warmup:
            times.append(clock() - started)
    return statistics.median(times)


def kernels_stepper(world: Maze, particles: int, seed: int = 2):
    """The package's compiled operations of a SIR step called back to back from a plain loop: the same
    resampling, move (with its draws), likelihood and normalisation (with its reads) as the package's
    step, without the step, the model's calls and the hooks' checks (what they cost is the package's
    time less this)."""
    from mazelab.backend import shared_threads
    from mazelab.kernels.compiled import CompiledKernels
    from mazelab.smc import particles_array

    rng = np.random.default_rng(seed)
    kernels = CompiledKernels(world, threads=shared_threads())
    state = {"x": particles_array(world.random_free_places(particles, rng)[None], F32)}
    state["W"] = kernels.Weights.uniform(1, particles)

    def step(compass_angle: float, z: float) -> None:
        A = kernels.systematic(state["W"].W[0], rng)[None]
        x, _ = kernels.move(state["x"], A, [rng], np.array([compass_angle], F32), BENCH_DELTA, ROBOT_SPEED)
        log_g = kernels.log_likelihood(np.array([z]), x, world, BENCH_SIGMA, OUTSIDE_PENALTY)
        state["x"], state["W"] = x, kernels.Weights.from_log(log_g, x)

    return step


def fifty_by_fifty(seed: int = 50) -> Maze:
    """A generated 50x50 maze (mazelab maze generate --size 50x50 --seed 50)."""
    return generate_maze(50, 50, default_station_count(50, 50), np.random.default_rng(seed))


def compare(
    world: Maze,
    label: str,
    counts: list[int],
    rounds: int,
    filters: list[str],
    backend: str,
    clock=time.process_time,
    kernels: bool = False,
) -> None:
    """Alternate the fused step and the package's, round by round, and print the medians and the ratio
    (with `kernels`, the SIR's bare kernels too, `kernels_stepper`, after the ratio)."""
    for n in counts:
        steps = max(12, min(60, 4_000_000 // n))
        walk = record_walk(world, steps + 5)
        for name in filters:
            fused, package, bare = [], [], []
            for _ in range(rounds):
                state = Fused(name, world, n)
                fused.append(median_cpu_step(state.step, walk, 5, clock))
                with use_backend(backend):
                    stepper = filter_stepper(name, world, n)
                package.append(median_cpu_step(stepper, walk, 5, clock))
                if kernels and name == "sir":
                    bare.append(median_cpu_step(kernels_stepper(world, n), walk, 5, clock))
            f, p = statistics.median(fused), statistics.median(package)
            shown = f"   kernels alone {1e3 * statistics.median(bare):.3f}" if bare else ""
            print(f"{label:<12} {name:<4} {n:>9,} {1e3 * f:10.3f} {1e3 * p:10.3f} {f / p:8.2f}x{shown}", flush=True)


def batched_stepper(name: str, world: Maze, particles: int, runs: int, backend: str, seed: int = 2):
    """The package's filter advancing `runs` runs of `particles` together (as a study's unit), each from
    its own Generator, on the walk's inputs repeated for every run; its step and reads."""
    rngs = [np.random.default_rng(seed + r) for r in range(runs)]
    start = np.stack([world.random_free_places(particles, rng) for rng in rngs])  # (R, N, 2)
    with use_backend(backend):
        filt = filter_entry(name).filter_class(world, BENCH_SIGMA, BENCH_DELTA, start, rngs)

    def step(compass_angle: float, z: float) -> None:
        filt.step(np.full(runs, compass_angle), np.full(runs, z))
        _ = filt.estimate, filt.ess, filt.is_confident

    return step


def compare_batched(
    world: Maze, label: str, counts: list[int], runs: int, rounds: int, filters: list[str], backend: str, clock
) -> None:
    """Alternate one fused step over all R x N particles (the batched bound) and the package's step of R
    runs of N particles together, round by round."""
    for n in counts:
        steps = max(12, min(60, 4_000_000 // (n * runs)))
        walk = record_walk(world, steps + 5)
        for name in filters:
            fused, package = [], []
            for _ in range(rounds):
                fused.append(median_cpu_step(Fused(name, world, n * runs).step, walk, 5, clock))
                package.append(median_cpu_step(batched_stepper(name, world, n, runs, backend), walk, 5, clock))
            f, p = statistics.median(fused), statistics.median(package)
            shown = f"{runs} x {n:,}"
            print(f"{label:<12} {name:<4} {shown:>12} {1e3 * f:10.3f} {1e3 * p:10.3f} {f / p:8.2f}x", flush=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--counts", default="1000,10000,100000,1000000")
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--filters", default="sir,apf,rpf")
    parser.add_argument("--mazes", default="maze_10x10,50x50")
    parser.add_argument("--backend", default="compiled", help="the package's backend to time (numpy or compiled)")
    parser.add_argument("--threads", type=int, default=1, help="the package's threads (MAZELAB_THREADS)")
    parser.add_argument("--clock", choices=("cpu", "wall"), default="cpu", help="CPU time, or wall-clock time")
    parser.add_argument("--runs", type=int, default=1, help="R > 1: R runs of N together against one fused N x R")
    parser.add_argument("--kernels", action="store_true", help="also the SIR's compiled kernels called back to back")
    args = parser.parse_args()
    os.environ["MAZELAB_THREADS"] = str(args.threads)
    clock = time.process_time if args.clock == "cpu" else time.perf_counter
    counts = [int(c) for c in args.counts.split(",")]
    filters = args.filters.split(",")
    print(f"load average {os.getloadavg()}; {args.clock} ms per step (median of {args.rounds} alternating rounds)")
    print(f"{'maze':<12} {'':<4} {'N':>9} {'fused':>10} {args.backend:>10} {'package/fused speed':>8}")
    for name in args.mazes.split(","):
        world = fifty_by_fifty() if name == "50x50" else Maze.from_file(name)
        world.prepare()
        if args.runs > 1:
            compare_batched(world, name, counts, args.runs, args.rounds, filters, args.backend, clock)
        else:
            compare(world, name, counts, args.rounds, filters, args.backend, clock, args.kernels)


if __name__ == "__main__":
    main()
