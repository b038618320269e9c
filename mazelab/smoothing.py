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

Memory: the forward pass keeps alpha_k at every B-th step only (checkpoints, B = ceil(sqrt(K)) unless
told), and the backward pass refilters one block of B steps at a time from its checkpoint when it
reaches it: about 2 sqrt(K) grids instead of K, for a second forward pass. On maze_10x10 at the
default resolution (600 x 600 cells, 2.75 MB a grid) a 200-step walk keeps 14 checkpoints and 15
refiltered grids rather than 200: a peak of 165 MB allocated against 640 MB when every filtered density
is kept (`uv run python benchmarks/smoothing_memory.py`).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Collection, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from mazelab.checks import angle, coordinate, step_number
from mazelab.grid_filter import BYTES_PER_GRID_CELL, GridBayesFilter, GridWorkspace, arc_kernel, arc_kernel_shape
from mazelab.limits import check_memory
from mazelab.maze import Maze
from mazelab.model import check_model_parameters

BYTES_PER_DENSITY_CELL = 8  # a float64 grid: what each checkpoint, each refiltered step and each kept density takes


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
    log_evidence : float
        log p(z_1:K) of the discretised model (the grid filter's exact value).
    positions : array (M, 2)
        The grid's cell centres, in the order of a density's `ravel()`.
    shape : (rows, columns)
        The grid's shape (rows along y).
    checkpoint_every : int
        B, the steps between two filtered densities kept by the forward pass.
    densities : dict
        Step k -> p(x_k | z_1:K) on the grid (an array of `shape`), for the steps asked to keep.
    """

    means: np.ndarray
    spreads: np.ndarray
    filtered_means: np.ndarray
    log_evidence: float
    positions: np.ndarray
    shape: tuple[int, int]
    checkpoint_every: int
    densities: dict[int, np.ndarray] = field(default_factory=dict)

    def errors(self, true_positions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The distance of the smoothed and of the filtered mean to the truth, per step.

        Parameters
        ----------
        true_positions : array (K, 2)
            The robot's position after each step's move (map units).

        Returns
        -------
        (smoothed (K,), filtered (K,)), map units
        """
        return np.hypot(*(self.means - true_positions).T), np.hypot(*(self.filtered_means - true_positions).T)


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
        self.grid = grid
        self.work = GridWorkspace(grid.shape, arc_kernel_shape(grid.speed, grid.resolution))
        self._angle: float | None = None
        self._kernel_shape = arc_kernel_shape(grid.speed, grid.resolution)
        self._spectrum: np.ndarray | None = None

    def likelihood(self, z: float) -> np.ndarray:
        """l_k = p(z_k | x) on the cells divided by its largest value (equation (3), the grid filter's
        log_likelihood: the one source of it).

        Parameters
        ----------
        z : float
            z_k, the measured distance (map units).

        Returns
        -------
        array of the grid's shape, values in [0, 1]
        """
        log_lik = self.grid.log_likelihood(z)
        return np.exp(log_lik - log_lik.max())

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
        if self._angle != compass_angle or self._spectrum is None:
            grid = self.grid
            flipped = arc_kernel(compass_angle, grid.delta, grid.speed, grid.resolution)[::-1, ::-1]
            self._spectrum = self.work.kernel_spectrum(np.ascontiguousarray(flipped))  # the workspace's own buffer
            self._angle = compass_angle
        return self.work.convolve(values, self._kernel_shape, self._spectrum)

    def __call__(self, beta: np.ndarray, compass_angle: float, z: float, k: int) -> np.ndarray:
        """beta_{k-1} from beta_k and step k's compass angle and measurement, scaled so that its largest
        value is 1 (beta matters only up to a constant: the smoothed density is normalised)."""
        previous = np.clip(self.adjoint(self.likelihood(z) * beta, compass_angle), 0.0, None)  # FFT round-off < 0
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
    keep: Collection[int] = (),
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
    keep : collection of int
        The steps whose smoothed densities the answer keeps (each one grid of memory).
    visit : callable (k, density) -> None, optional
        Called with every step's smoothed density (read-only, valid during the call only), from k = K
        down to 1: what a caller measures per step without keeping K grids.
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
    steps = len(angles)
    sigma, delta = check_model_parameters(sigma, delta, (world.width, world.height))
    grid = GridBayesFilter(world, sigma, delta, **grid_options)
    block = checkpoint_block(steps, checkpoint_every)
    outside = [k for k in keep if not (isinstance(k, (int, np.integer)) and 1 <= k <= steps)]
    if outside:
        raise ValueError(f"keep names steps 1..{steps} of the walk, got {outside[0]!r}")
    check_smoother_memory(grid.shape, steps, block, len(set(keep)))
    checkpoints, filtered_means = forward(grid, angles, zs, block)
    log_evidence = grid.log_evidence  # the refiltering below adds to it again
    means, spreads, kept = np.empty((steps, 2)), np.empty(steps), {}
    backward, beta = BackwardStep(grid), np.ones(grid.shape)
    for start in reversed(range(0, steps, block)):  # the block of steps start+1 .. end
        end = min(start + block, steps)
        filtered = refilter(grid, checkpoints.pop(start), angles[start:end], zs[start:end])
        for k in range(end, start, -1):
            smoothed = smoothed_density(filtered.pop(), beta, k)
            means[k - 1], spreads[k - 1] = moments(smoothed, grid.positions)
            if k in keep:
                kept[k] = smoothed.copy()
            if visit is not None:
                smoothed.flags.writeable = False
                visit(k, smoothed)
            if k > 1:
                beta = backward(beta, angles[k - 1], zs[k - 1], k)
    return SmoothedWalk(means, spreads, filtered_means, log_evidence, grid.positions, grid.shape, block, kept)


def forward(
    grid: GridBayesFilter, angles: np.ndarray, zs: np.ndarray, block: int
) -> tuple[dict[int, np.ndarray], np.ndarray]:
    """The grid filter over the walk: its prior and alpha_k at k = B, 2B, ... < K (the checkpoints,
    step -> density) and its mean at every step (K, 2). `grid.log_evidence` is then log p(z_1:K)."""
    checkpoints, means = {0: grid.density.copy()}, np.empty((len(angles), 2))
    for k in range(1, len(angles) + 1):
        grid.step(angles[k - 1], zs[k - 1])
        if grid.reinitialised_at:  # the filter restarted: the model gives this walk no posterior
            raise ValueError(
                f"no cell of the grid explains z_{k} = {zs[k - 1]:g} (sigma {grid.sigma:g}, delta {grid.delta:g}): "
                "the walk has no smoothed posterior under this model"
            )
        means[k - 1] = grid.mean
        if k % block == 0 and k < len(angles):
            checkpoints[k] = grid.density.copy()
    return checkpoints, means


def refilter(grid: GridBayesFilter, start: np.ndarray, angles: np.ndarray, zs: np.ndarray) -> list[np.ndarray]:
    """The filtered densities of a block of steps again, from the one before it (a checkpoint): the
    grid filter's same operations, so the same numbers bit for bit as the forward pass's."""
    grid.density = start
    densities = []
    for compass_angle, z in zip(angles, zs, strict=True):
        grid.step(compass_angle, z)
        densities.append(grid.density.copy())
    return densities


def smoothed_density(alpha: np.ndarray, beta: np.ndarray, k: int) -> np.ndarray:
    """alpha_k beta_k normalised: p(x_k | z_1:K) (into alpha's array)."""
    alpha *= beta
    total = alpha.sum()
    if not total > 0:
        raise ValueError(f"the smoothed density of step {k} underflows on the grid (no cell explains the walk)")
    alpha /= total
    return alpha


def moments(density: np.ndarray, positions: np.ndarray) -> tuple[np.ndarray, float]:
    """The mean (2,) of a density on the cells and the root of its covariance's trace (map units)."""
    weights = density.ravel()
    mean = weights @ positions
    return mean, math.sqrt(max(0.0, float(weights @ ((positions - mean) ** 2).sum(axis=1))))


def checkpoint_block(steps: int, checkpoint_every: int | None) -> int:
    """B: checkpoint_every (a whole number >= 1, else a one-line ValueError), or ceil(sqrt(steps)):
    about 2 sqrt(K) grids at once."""
    if checkpoint_every is None:
        return max(1, math.isqrt(steps - 1) + 1)
    return step_number("checkpoint_every", checkpoint_every)


def check_smoother_memory(shape: tuple[int, int], steps: int, block: int, kept: int) -> None:
    """Refuse a smoothing whose grids would not fit, in one line saying how much it needs: the
    checkpoints, one block of refiltered densities, the kept densities, beta and its product, and the
    backward pass's FFT buffers."""
    cells = shape[0] * shape[1]
    grids = math.ceil(steps / block) + min(block, steps) + kept + 3
    check_memory(
        f"smoothing {steps} steps on the grid's {shape[0]}x{shape[1]} cells ({grids} grids)",
        grids * cells * BYTES_PER_DENSITY_CELL + cells * BYTES_PER_GRID_CELL,
    )


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


__all__ = ["BackwardStep", "SmoothedWalk", "check_walk", "smooth"]
