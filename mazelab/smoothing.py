"""The exact smoother of the lab's model on the grid: p(x_k | z_1:K) for every step k of a walk, from
the forward-backward pass over the grid filter (mazelab.grid_filter). It is the reference a particle
smoother is measured against, as the grid filter is the particle filters' reference.

Forward, the grid filter gives alpha_k = p(x_k | z_1:k). Backward, beta_k(x) ∝ p(z_k+1:K | x_k = x):

    beta_K = 1,    beta_{k-1} = P_k^T (l_k beta_k),    p(x_k | z_1:K) ∝ alpha_k beta_k,

with l_k = p(z_k | x) on the cells (equation (3), the outside penalty) and P_k the prediction of step k:
the linear convolution with the arc kernel of its own compass angle th0_k, cropped to the grid. Its
adjoint P_k^T is the linear convolution with the same kernel flipped (a correlation), cropped the same
way, so that the mass the prediction drops beyond the grid's margin is dropped here too. Both passes
are the discretised model's exact answer: a brute-force sum over every path of cells gives the same
(tests/test_smoothing.py).

Memory: alpha_k is kept at every B-th step only (checkpoints, B = ceil(sqrt(K)) unless told), each block
refiltered from its checkpoint on the way back: about 2 sqrt(K) grids instead of K (docs/smoothing.md).

The particle smoothers, the path and the fixed-lag one (`Genealogy`, scored against the exact one by
`score_smoothers`), follow the engine's `SMC.ancestry` back. Forward filtering backward sampling is not built:
the model's arc motion has no transition density, and its backward kernel is the genealogy (docs/smoothing.md).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from mazelab.checks import angle, check_memory, coordinate, step_number
from mazelab.grid_filter import BYTES_PER_GRID_CELL, GridBayesFilter, GridWorkspace, arc_kernel, arc_kernel_shape
from mazelab.maze import Maze
from mazelab.model import DEFAULT_PARTICLE_COUNT, check_model_parameters
from mazelab.registry import FilterEntry, filter_entry
from mazelab.robot import Robot

BYTES_PER_DENSITY_CELL = 8  # a float64 grid: what each checkpoint and each refiltered step takes
BYTES_PER_RECORDED_PARTICLE = 24  # Genealogy: a particle's float32 position, float64 weight and int64 ancestor


@dataclass(frozen=True)
class SmoothedWalk:
    """The exact smoother's answer for a walk of K steps: row k - 1 of each array is step k.

    Attributes
    ----------
    means : array (K, 2)
        E[x_k | z_1:K], the smoothed posterior means (map units).
    spreads : array (K,)
        The root of the trace of Cov[x_k | z_1:K] (map units): how spread the smoothed belief is.
    filtered_means : array (K, 2)
        E[x_k | z_1:k], the grid filter's means on the same grid (what the smoother improves on).
    """

    means: np.ndarray
    spreads: np.ndarray
    filtered_means: np.ndarray


class BackwardStep:
    """The backward pass's step on a grid filter's cells: beta_{k-1} = P_k^T (l_k beta_k), scaled.

    It has its own FFT buffers (mazelab.grid_filter.GridWorkspace) and its own kernel spectrum, so that
    the grid filter's cached spectrum of the same angle is never overwritten.

    Parameters
    ----------
    grid : GridBayesFilter
        The filter whose grid, model (sigma, delta, speed, outside penalty) and prediction this reverses.
    """

    def __init__(self, grid: GridBayesFilter):
        self.grid, self._kernel_shape = grid, arc_kernel_shape(grid.speed, grid.resolution)
        self.work = GridWorkspace(grid.shape, self._kernel_shape)
        self._spectrum: tuple[float, np.ndarray] | None = None  # (th0, its flipped kernel's spectrum)

    def adjoint(self, values: np.ndarray, compass_angle: float) -> np.ndarray:
        """P^T values: the linear convolution with the flipped arc kernel of `compass_angle`, cropped to
        the grid (the adjoint of GridBayesFilter.predict before its clip: <P f, g> = <f, P^T g>).

        Parameters
        ----------
        values : array of the grid's shape
        compass_angle : float
            th0_k of the prediction this reverses (radians).

        Returns
        -------
        array of the grid's shape: a view of the workspace, valid until the next call
        """
        if self._spectrum is None or self._spectrum[0] != compass_angle:
            grid = self.grid
            flipped = arc_kernel(compass_angle, grid.delta, grid.speed, grid.resolution)[::-1, ::-1]
            self._spectrum = (compass_angle, self.work.kernel_spectrum(np.ascontiguousarray(flipped)))  # its own buffer
        return self.work.convolve(values, self._kernel_shape, self._spectrum[1])

    def __call__(self, beta: np.ndarray, compass_angle: float, z: float, k: int) -> np.ndarray:
        """beta_{k-1} from beta_k and step k's compass angle and measurement, scaled so that its largest
        value is 1 (beta matters only up to a constant: the smoothed density is normalised)."""
        log_lik = self.grid.log_likelihood(z)  # equation (3), the grid filter's: the one source of it
        previous = np.clip(self.adjoint(np.exp(log_lik - log_lik.max()) * beta, compass_angle), 0.0, None)  # FFT: < 0
        top = previous.max()
        if not top > 0:
            raise ValueError(f"the measurements after step {k - 1} are impossible from every cell of the grid")
        previous /= top
        return previous


def smooth(
    world: Maze,
    sigma: float,
    delta: float,
    compass_angles: Sequence[float],
    measurements: Sequence[float],
    *,
    visit: Callable[[int, np.ndarray], Any] | None = None,
    checkpoint_every: int | None = None,
    **grid_options: Any,
) -> SmoothedWalk:
    """p(x_k | z_1:K) for k = 1..K on the grid filter's grid, by forward-backward with checkpoints.

    Parameters
    ----------
    world : Maze
    sigma, delta : float
        The model's measurement noise (map units) and compass error's full width (radians).
    compass_angles, measurements : sequences of K floats
        th0_k and z_k of each step (a scenario's robot_compass_angles and robot_measurements).
    visit : callable (k, density) -> None, optional
        Called with every step's smoothed density p(x_k | z_1:K) (an array of the grid's shape, read-only,
        valid during the call only: a copy keeps it), from k = K down to 1: what a caller measures per step
        without keeping K grids.
    checkpoint_every : int, optional
        B, the steps between two kept filtered densities: ceil(sqrt(K)) by default; K keeps every
        filtered density of the walk (one block, no second pass).
    **grid_options
        GridBayesFilter's options (resolution, margin, outside_penalty, speed).

    Returns
    -------
    SmoothedWalk
    """
    angles, zs = check_walk(compass_angles, measurements)
    sigma, delta = check_model_parameters(sigma, delta, (world.width, world.height))
    grid = GridBayesFilter(world, sigma, delta, **grid_options)
    block = checkpoint_block(grid.shape, len(angles), checkpoint_every)
    prior = grid.density.copy()
    checkpoints, filtered_means = forward(grid, angles, zs, lambda k: k % block == 0 and k < len(angles))
    means, spreads = backward(grid, {0: prior, **checkpoints}, angles, zs, block, visit)
    return SmoothedWalk(means, spreads, filtered_means)


def backward(
    grid: GridBayesFilter,
    checkpoints: dict[int, np.ndarray],
    angles: np.ndarray,
    zs: np.ndarray,
    block: int,
    visit: Callable[[int, np.ndarray], Any] | None,
) -> tuple[np.ndarray, np.ndarray]:
    """The backward pass from k = K down to 1, each block of B steps refiltered from its checkpoint (taken
    from `checkpoints`): the smoothed means (K, 2) and spreads (K,), each step's density handed to `visit`."""
    steps = len(angles)
    means, spreads = np.empty((steps, 2)), np.empty(steps)
    step_back, beta = BackwardStep(grid), np.ones(grid.shape)
    for start in reversed(range(0, steps, block)):  # the block of steps start+1 .. end
        end = min(start + block, steps)
        grid.density = checkpoints.pop(start)
        filtered, _ = forward(grid, angles[start:end], zs[start:end], lambda k: True)  # the same numbers, bit for bit
        for k in range(end, start, -1):
            smoothed = filtered[k - start]  # alpha_k beta_k normalised: p(x_k | z_1:K)
            smoothed *= beta
            total = smoothed.sum()
            if not total > 0:
                raise ValueError(f"the smoothed density of step {k} underflows on the grid (no cell explains the walk)")
            smoothed /= total
            means[k - 1] = smoothed.ravel() @ grid.positions  # the mean, and the root of the covariance's trace
            spreads[k - 1] = math.sqrt(
                max(0.0, float(smoothed.ravel() @ ((grid.positions - means[k - 1]) ** 2).sum(axis=1)))
            )
            if visit is not None:
                smoothed.flags.writeable = False
                visit(k, smoothed)
            if k > 1:
                beta = step_back(beta, angles[k - 1], zs[k - 1], k)
    return means, spreads


def forward(
    grid: GridBayesFilter, angles: np.ndarray, zs: np.ndarray, keep: Callable[[int], bool]
) -> tuple[dict[int, np.ndarray], np.ndarray]:
    """The grid filter over steps 1..n (th0 `angles`, z `zs`) from its density: alpha_k of each step k that
    `keep` asks for (step -> density; the forward pass's checkpoints, every B-th step, or a block's every
    step from its checkpoint when the backward pass refilters it) and the mean at every step (n, 2);
    `grid.log_evidence` then adds log p(z_1:n)."""
    kept, means = {}, np.empty((len(angles), 2))
    for k in range(1, len(angles) + 1):
        grid.step(angles[k - 1], zs[k - 1])
        if grid.reinitialised_at:  # the filter restarted: the model gives this walk no posterior
            raise ValueError(
                f"no cell of the grid explains z_{k} = {zs[k - 1]:g} (sigma {grid.sigma:g}, delta {grid.delta:g}): "
                "the walk has no smoothed posterior under this model"
            )
        means[k - 1] = grid.mean
        if keep(k):
            kept[k] = grid.density.copy()
    return kept, means


def checkpoint_block(shape: tuple[int, int], steps: int, checkpoint_every: int | None) -> int:
    """B: checkpoint_every (a whole number >= 1, else a one-line ValueError), or ceil(sqrt(steps)): about
    2 sqrt(K) grids at once. A smoothing whose grids would not fit is refused in one line saying how much
    it needs: the checkpoints, one block of refiltered densities, beta and its product, and the backward
    pass's FFT buffers."""
    every = checkpoint_every
    block = max(1, math.isqrt(steps - 1) + 1) if every is None else step_number("checkpoint_every", every)
    cells = shape[0] * shape[1]
    grids = math.ceil(steps / block) + min(block, steps) + 3
    check_memory(
        f"smoothing {steps} steps on the grid's {shape[0]}x{shape[1]} cells ({grids} grids)",
        grids * cells * BYTES_PER_DENSITY_CELL + cells * BYTES_PER_GRID_CELL,
    )
    return block


def check_walk(compass_angles: Sequence[float], measurements: Sequence[float]) -> tuple[np.ndarray, np.ndarray]:
    """The walk's compass angles and measurements as float arrays of the same length K >= 1, each
    value checked (mazelab.checks), or a one-line ValueError.

    Parameters
    ----------
    compass_angles : sequence of K floats
        th0_k (radians).
    measurements : sequence of K floats
        z_k (map units).

    Returns
    -------
    (angles (K,), measurements (K,)), float64
    """
    angles = np.array([angle("compass angle", a) for a in compass_angles], dtype=float)
    zs = np.array([coordinate("measurement", z) for z in measurements], dtype=float)
    if len(angles) != len(zs) or len(angles) == 0:
        raise ValueError(
            f"a walk needs one measurement per compass angle, at least one step: got {len(angles)} angles "
            f"and {len(zs)} measurements"
        )
    return angles, zs


# -- particle smoothers: the genealogy of a particle filter, scored against the exact smoother -----------
SMOOTHERS = ("filter", "lag", "path")  # lag 0, the fixed lag L, the whole walk (Genealogy's estimates)


class Genealogy:
    """A particle filter's R runs recorded step by step (its particles, weights and `ancestry`), and
    SMOOTHERS' estimates traced back through them.

    The estimate of step k from step j >= k: the particles of step j with their weights W_j, each put
    where its ancestor stood at step k (the ancestors followed back through the recorded A's). j = K, the
    walk's end, is the genealogy (path) smoother; j = k + L the fixed-lag smoother (step k's estimate
    made once step k + L is filtered, the last L steps' at the end); j = k the filter (lag 0). A run
    restarted from the prior at step j has no ancestors there: the steps before it take the particles of
    step j - 1 and their own weights; recovery's injected particles have none either and leave the
    weight of the trace (the others' renormalised).

    Memory: BYTES_PER_RECORDED_PARTICLE of each particle of every step (R N K), which the path smoother
    needs (the fixed-lag one alone would need the last L + 1 steps only).

    Parameters
    ----------
    lag : int
        L >= 1, the fixed-lag smoother's.
    bins : (callable, int), optional
        `binned_smoother`'s bins: points (R, M, 2) -> flat bin indices (R, M), and the bins' count. Each estimate's
        weighted mass per bin is kept too (the total variation to the exact smoother's, `score_rows`).
    clouds : bool
        Keep each estimate's traced particles and weights of run 0 too (`clouds`, smoother -> step ->
        (points (M, 2), weights (M,))): what a viewer draws.
    """

    def __init__(
        self,
        lag: int,
        bins: tuple[Callable[[np.ndarray], np.ndarray], int] | None = None,
        clouds: bool = False,
    ):
        self.lag = lag
        self.bins, self.bin_count = bins if bins is not None else (None, 0)
        self.kept: list[tuple[int, np.ndarray, np.ndarray, np.ndarray, np.ndarray]] = []
        self.means: dict[str, dict[int, np.ndarray]] = {name: {} for name in SMOOTHERS}  # step -> (R, 2)
        self.masses: dict[str, dict[int, np.ndarray]] = {name: {} for name in SMOOTHERS}  # step -> (R, bin_count)
        self.distinct: dict[str, dict[int, np.ndarray]] = {name: {} for name in SMOOTHERS}  # step -> (R,)
        self.clouds: dict[str, dict[int, tuple[np.ndarray, np.ndarray]]] | None = (
            {name: {} for name in SMOOTHERS} if clouds else None
        )

    def record(self, filt: Any) -> None:
        """Keep the filter's step just made (after its `step`): the filter's estimate of it, and the
        fixed-lag smoother's of the step `lag` back.

        Parameters
        ----------
        filt : SMC
            A particle filter after step k: its `ancestry`, particles `x` (R, M, 2), weights `W`,
            `reinitialised_at` and (recovery's) `injected` are read.
        """
        A, _ = filt.ancestry
        k, runs = filt.steps_done, A.shape[0]
        restarts = filt.reinitialised_at if runs > 1 else [filt.reinitialised_at]
        cut = np.zeros(A.shape, dtype=bool)  # the particles without an ancestor at step k - 1
        cut[[k in r for r in restarts]] = True
        injected = getattr(filt, "injected", None)
        if injected is not None:
            cut[0] |= injected
        self.kept.append((k, filt.x.astype(np.float32), filt.W.W.copy(), A.astype(np.int64), cut))
        newest = len(self.kept) - 1
        for position, traced in self._traced(newest - self.lag if newest >= self.lag else newest):
            if position == newest:
                self._estimate("filter", *traced)
            if position == newest - self.lag:
                self._estimate("lag", *traced)

    def finish(self) -> Genealogy:
        """Estimate from the last step the path smoother's every step and the steps the fixed-lag
        smoother has not reached.

        Returns
        -------
        Genealogy
            Itself, its `means`, `masses` and `distinct` now holding every step.
        """
        for position, traced in self._traced(0):
            self._estimate("path", *traced)
            if position >= len(self.kept) - self.lag:
                self._estimate("lag", *traced)
        return self

    def _traced(self, oldest: int) -> Iterator[tuple[int, tuple[int, np.ndarray, np.ndarray, np.ndarray]]]:
        """The newest kept step's weighted particles traced back to the kept step `oldest`, newest first:
        (position, (k, the step's particles x (R, M, 2), the weights w (R, M), the index in x (R, M) of
        each traced particle's ancestor))."""
        _, _, W, _, _ = self.kept[-1]
        rows = np.arange(len(W))[:, None]
        index, w = np.broadcast_to(np.arange(W.shape[1]), W.shape), W
        for position in range(len(self.kept) - 1, oldest - 1, -1):
            k, x, _, A, cut = self.kept[position]
            yield position, (k, x, w, index)
            if position == oldest:
                break
            w = np.where(cut[rows, index], 0.0, w)
            total = w.sum(axis=1, keepdims=True)
            restart = (total[:, 0] <= 0) | cut.all(axis=1)  # a restarted run: the previous step's own particles
            w = w / np.where(total > 0, total, 1.0)
            index = A[rows, index]
            if restart.any():  # R > 1 runs keep N particles (KLD-sampling's varying count runs one run)
                previous = self.kept[position - 1][2]
                every = np.broadcast_to(np.arange(previous.shape[1]), previous.shape)
                index = every if restart.all() else np.where(restart[:, None], every, index)
                w = previous if restart.all() else np.where(restart[:, None], previous, w)

    def _estimate(self, name: str, k: int, x: np.ndarray, w: np.ndarray, index: np.ndarray) -> None:
        """The smoother `name`'s estimate of step k: the weighted mean (R, 2) of the traced particles
        x[index], their mass per bin and the distinct ancestors among `index`."""
        points = x[np.arange(len(w))[:, None], index]
        self.means[name][k] = np.einsum("rn,rnd->rd", w, points)
        self.distinct[name][k] = (np.diff(np.sort(index, axis=1), axis=1) != 0).sum(axis=1) + 1
        if self.clouds is not None:
            self.clouds[name][k] = (points[0].copy(), w[0].copy())
        if self.bins is not None:
            flat = self.bins(points) + np.arange(len(w))[:, None] * self.bin_count
            self.masses[name][k] = np.bincount(flat.ravel(), w.ravel(), len(w) * self.bin_count).reshape(len(w), -1)


@dataclass(frozen=True)
class SmootherScores:
    """The particle smoothers of each filter scored against the exact smoother over one walk.

    Attributes
    ----------
    exact : SmoothedWalk
        The exact smoother's answer (its means, the grid filter's means beside them).
    rows : list of dict
        One per filter and step, its SCORE_COLUMNS (docs/smoothing.md says what each measures): for the
        filter (lag 0), the fixed-lag and the path smoother, the distance of its mean to the exact smoothed
        mean (`*_error`), the total variation to it (`*_tv`) and the distinct ancestors it rests on.
    recorded : dict
        Each filter's label -> its Genealogy (SMOOTHERS' means, distinct ancestors and, when asked, clouds).
    """

    exact: SmoothedWalk
    rows: list[dict[str, Any]]
    recorded: dict[str, Genealogy] = field(default_factory=dict)


SCORE_COLUMNS = (
    "filter",
    "step",
    "exact_filtered_to_truth",
    "exact_smoothed_to_truth",
    "filter_error_to_filtered",
    *(f"{name}_{what}" for name in SMOOTHERS for what in ("error", "tv", "ancestors")),
)


def score_smoothers(
    world: Maze,
    robot: Robot,
    sigma: float,
    delta: float,
    filters: Sequence[str] | Mapping[str, Mapping[str, Any]],
    *,
    lag: int = 10,
    particle_count: int | None = None,
    initial_particles: Any = None,
    seed: int = 0,
    grid_options: dict[str, Any] | None = None,
    clouds: bool = False,
) -> SmootherScores:
    """Each particle filter's own estimate, fixed-lag and path smoothers of a walk beside the exact smoother's.

    Parameters
    ----------
    world : Maze
    robot : Robot
        One that replays a walk with its measurements (Scenario.robot of a scenario that stores them).
    sigma, delta : float
    filters : sequence of str, or mapping
        Registry names of filters that keep particles (sir, apf, rpf, a plug-in's), or each one's name -> its
        own options (e.g. {"sir": {}, "rpf": {"bandwidth": 0.05}}).
    lag : int
        L of the fixed-lag smoother (>= 1).
    particle_count, initial_particles, seed
        As mazelab.simulation.simulate takes them (each filter starts from the same particles and seed).
    grid_options : dict, optional
        GridBayesFilter's options for the exact smoother.
    clouds : bool
        Keep the traced particles of every step (Genealogy's `clouds`) for a viewer.

    Returns
    -------
    SmootherScores
    """
    from mazelab.simulation import simulate  # the layer above the model's: imported by the caller that runs

    lag, entries = check_smoothers(robot, filters, lag, particle_count, initial_particles)
    exact, exact_masses, bins = binned_smoother(world, sigma, delta, robot, dict(grid_options or {}))
    walk = (robot, world, sigma, delta, particle_count, len(exact.means), initial_particles)  # every filter's run
    rows, recorded = [], {}
    for entry, options in entries:
        g = recorded[entry.label] = Genealogy(lag, bins, clouds)
        run = simulate(*walk, entry.filter_class, seed=seed, on_step=lambda k, r, filt, g=g: g.record(filt), **options)
        rows += score_rows(entry.label, exact, exact_masses, run.true_positions, g.finish())
    return SmootherScores(exact, rows, recorded)


def binned_smoother(
    world: Maze, sigma: float, delta: float, robot: Robot, grid_options: dict[str, Any]
) -> tuple[SmoothedWalk, dict[int, np.ndarray], tuple[Callable[[np.ndarray], np.ndarray], int]]:
    """The exact smoother of the robot's walk (`smooth`), its mass in each bin at every step (step ->
    (count,)): what a particle smoother's binned mass is compared with; and the bins, the maze's unit
    cells and a ring of them over the grid's margin (a point beyond it falls in the nearest outer bin):
    points (..., 2) -> flat bin indices (...), and the bins' count."""
    ring = math.ceil(GridBayesFilter.options.resolve(grid_options, "GridBayesFilter")["margin"])
    columns, rows = world.width + 2 * ring, world.height + 2 * ring

    def bins(points: np.ndarray) -> np.ndarray:
        i = np.clip(np.floor(points[..., 0]).astype(np.int64) + ring, 0, columns - 1)
        j = np.clip(np.floor(points[..., 1]).astype(np.int64) + ring, 0, rows - 1)
        return j * columns + i

    cells, masses = bins(GridBayesFilter(world, sigma, delta, **grid_options).positions), {}  # each cell's bin

    def binned(k: int, density: np.ndarray) -> None:
        masses[k] = np.bincount(cells, density.ravel(), rows * columns)

    exact = smooth(world, sigma, delta, robot.compass_angles, robot.measurements, visit=binned, **grid_options)
    return exact, masses, (bins, rows * columns)


def check_smoothers(
    robot: Robot,
    filters: Sequence[str] | Mapping[str, Any],
    lag: int,
    particle_count: int | None,
    initial_particles: Any,
) -> tuple[int, list[tuple[FilterEntry, Mapping[str, Any]]]]:
    """The lag and each filter's entry with its options, once `score_smoothers`' inputs are checked: a
    one-line ValueError for a filter that keeps no particles, a walk without measurements, a genealogy that
    does not fit in memory."""
    lag = step_number("lag", lag)
    chosen = filters if isinstance(filters, Mapping) else {name: {} for name in filters}
    entries = [(filter_entry(name), options) for name, options in chosen.items()]
    for entry, _ in entries:
        if not entry.takes_particles:
            raise ValueError(f"a particle smoother needs a filter's genealogy: {entry.label} keeps no particles")
    if not robot.measurements:
        raise ValueError("smoothing needs the walk's measurements: the scenario stores none (robot_measurements)")
    particles = len(initial_particles) if initial_particles is not None else particle_count or DEFAULT_PARTICLE_COUNT
    check_memory(
        f"the genealogy of {len(robot.measurements)} steps of {particles} particles (the path smoother's)",
        (len(robot.measurements) + 1) * particles * BYTES_PER_RECORDED_PARTICLE,
    )
    return lag, entries


def score_rows(
    label: str, exact: SmoothedWalk, masses: dict[int, np.ndarray], truth: np.ndarray, g: Genealogy
) -> list[dict[str, Any]]:
    """One filter's rows of SCORE_COLUMNS, step by step (one run: row 0 of each estimate of its genealogy g)."""
    rows = []
    for k in range(1, len(truth) + 1):
        row = {
            "filter": label,
            "step": k,
            "exact_filtered_to_truth": float(np.hypot(*(exact.filtered_means[k - 1] - truth[k - 1]))),
            "exact_smoothed_to_truth": float(np.hypot(*(exact.means[k - 1] - truth[k - 1]))),
            "filter_error_to_filtered": float(np.hypot(*(g.means["filter"][k][0] - exact.filtered_means[k - 1]))),
        }
        for name in SMOOTHERS:
            row[f"{name}_error"] = float(np.hypot(*(g.means[name][k][0] - exact.means[k - 1])))
            row[f"{name}_tv"] = 0.5 * float(np.abs(g.masses[name][k][0] - masses[k]).sum())  # the total variation
            row[f"{name}_ancestors"] = int(g.distinct[name][k][0])
        rows.append(row)
    return rows


__all__ = [
    "SCORE_COLUMNS",
    "SMOOTHERS",
    "BackwardStep",
    "Genealogy",
    "SmoothedWalk",
    "SmootherScores",
    "check_walk",
    "score_smoothers",
    "smooth",
]
