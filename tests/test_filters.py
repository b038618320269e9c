"""The filters: the exact grid filter's pieces, agreement with it, convergence, and degenerate runs."""

from __future__ import annotations

import math

import numpy as np
import pytest

from mazelab.filters import AuxiliaryParticleFilter, RegularizedParticleFilter, SIRParticleFilter
from mazelab.grid_filter import GRID_RESOLUTION, GridBayesFilter, arc_kernel, fft_convolve_same
from mazelab.lab import simulate
from mazelab.model import LOG_UNDERFLOW, ROBOT_SPEED
from mazelab.registry import resolve_filter
from mazelab.robot import Robot

PARTICLE_FILTERS = ["sir", "apf", "rpf"]


@pytest.mark.parametrize(("theta", "delta"), [(0.3, 0.5), (2.0, 0.05), (-1.0, 2 * math.pi), (4.0, 0.0)])
def test_arc_kernel_is_a_density_with_the_arcs_exact_mean(theta, delta):
    kernel = arc_kernel(theta, delta, ROBOT_SPEED, GRID_RESOLUTION)
    radius = kernel.shape[0] // 2
    assert kernel.sum() == pytest.approx(1.0)
    offsets = (np.arange(kernel.shape[0]) - radius) * GRID_RESOLUTION
    mean_x, mean_y = kernel.sum(axis=0) @ offsets, kernel.sum(axis=1) @ offsets
    # E[L (cos th, sin th)] for th ~ U(theta - delta/2, theta + delta/2) is L sinc(delta/2) (cos, sin)(theta);
    # the kernel's arc is a midpoint rule of that integral, exact to O((delta/samples)^2).
    shrink = 1.0 if delta == 0 else math.sin(delta / 2) / (delta / 2)
    assert mean_x == pytest.approx(ROBOT_SPEED * shrink * math.cos(theta), abs=1e-3 * ROBOT_SPEED)
    assert mean_y == pytest.approx(ROBOT_SPEED * shrink * math.sin(theta), abs=1e-3 * ROBOT_SPEED)


def test_fft_convolution_equals_direct_convolution(rng):
    image, kernel = rng.random((17, 23)), rng.random((5, 7))
    direct = np.zeros_like(image)
    for dy in range(5):
        for dx in range(7):
            shifted = np.zeros_like(image)
            sy, sx = dy - 2, dx - 3  # kernel cell (dy, dx) moves mass by (sy, sx)
            shifted[max(sy, 0) : 17 + min(sy, 0), max(sx, 0) : 23 + min(sx, 0)] = image[
                max(-sy, 0) : 17 - max(sy, 0), max(-sx, 0) : 23 - max(sx, 0)
            ]
            direct += kernel[dy, dx] * shifted
    np.testing.assert_allclose(fft_convolve_same(image, kernel), direct, atol=1e-12)


def test_grid_prediction_moves_the_belief_along_the_compass(paper_world):
    grid = GridBayesFilter(paper_world, 0.3, 0.5)
    before = grid.estimate.copy()
    grid.density = grid.predict(grid.density, compass_angle=0.0)
    # mass only leaves through the grid's outer edge, which the prior does not reach in one step
    assert grid.density.sum() == pytest.approx(1.0)
    shift = grid.estimate - before
    assert shift[0] == pytest.approx(ROBOT_SPEED * math.sin(0.25) / 0.25, rel=1e-3)
    assert shift[1] == pytest.approx(0.0, abs=1e-9)


@pytest.mark.parametrize(
    ("name", "cls"),
    [
        ("SIRParticleFilter", SIRParticleFilter),
        ("sir", SIRParticleFilter),
        ("SIR Particle Filter", SIRParticleFilter),
        ("Auxiliary Particle Filter", AuxiliaryParticleFilter),
        ("APF", AuxiliaryParticleFilter),
        ("regularizedparticlefilter", RegularizedParticleFilter),
        ("grid", GridBayesFilter),
    ],
)
def test_filter_names(name, cls):
    assert resolve_filter(name) is cls


def test_unknown_filter_name_lists_the_valid_ones():
    with pytest.raises(ValueError, match="unknown filter 'kalman'; choose from sir, apf, rpf, grid, ekf"):
        resolve_filter("kalman")


@pytest.fixture(scope="module")
def agreement_run():
    """One seeded walk of 150 steps on the paper's maze, and the grid filter's answer to it."""
    from conftest import PAPER_MAZE

    from draw import Maze

    world = Maze(PAPER_MAZE)
    robot = Robot(0.3, 0.5, world.random_free_place(np.random.default_rng(7)), rng=np.random.default_rng(70))
    grid = GridBayesFilter(world, 0.3, 0.5)
    estimates, spreads = [], []
    for _ in range(150):
        compass, z = robot.step(world)
        grid.step(compass, z)
        estimates.append(grid.estimate)
        spreads.append(grid.posterior_std())
    return world, robot, np.array(estimates), np.array(spreads)


@pytest.mark.parametrize("name", PARTICLE_FILTERS)
def test_particle_filters_agree_with_the_exact_grid_filter(agreement_run, name):
    """With N particles the posterior mean carries a Monte Carlo error of about s sqrt(tau / N), s the
    posterior's spread (root of the covariance trace) and tau <= 10 the inefficiency of a resampled
    filter; its expected length is below that. The grid adds a discretisation bias of at most one cell.
    So the mean distance, after the grid filter has converged (step 50 on), must stay below
    3 s sqrt(10 / N) + h; a wrong weight, proposal or resampling misses it by an order of magnitude."""
    world, robot, grid_estimates, spreads = agreement_run
    n = 4000
    result = simulate(robot, world, 0.3, 0.5, n, 150, filtering_algorithm=name, seed=2024)
    np.testing.assert_array_equal(result.estimates.shape, grid_estimates.shape)
    distance = np.hypot(*(result.estimates - grid_estimates).T)[50:]
    tolerance = 3 * spreads[50:].mean() * math.sqrt(10 / n) + GRID_RESOLUTION
    assert spreads[50:].max() < 0.5, "the grid filter itself should have converged on this walk"
    assert distance.mean() < tolerance, f"{name}: mean distance {distance.mean():.4f} >= {tolerance:.4f}"


@pytest.mark.parametrize("name", PARTICLE_FILTERS)
def test_filters_converge_on_the_paper_maze_in_most_seeded_runs(paper_world, name):
    """12 seeded lost robots on the paper's maze (sigma 0.3, delta 0.5, N 1500, 200 steps).
    The exact filter converges in all of them (checked below on the same walks), so a correct
    particle filter with 1500 particles should too, bar the occasional lost mode: at least 10 of 12."""
    converged = 0
    for seed in range(12):
        start = paper_world.random_free_place(np.random.default_rng(1000 + seed))
        robot = Robot(0.3, 0.5, start)
        result = simulate(robot, paper_world, 0.3, 0.5, 1500, 200, filtering_algorithm=name, seed=seed)
        converged += result.converged_at is not None
    assert converged >= 10, f"{name} converged in only {converged} of 12 runs"


def test_grid_filter_converges_on_the_same_walks(paper_world):
    """The exact filter on the walks above, at resolution 0.05 (a cell of 0.05 is a tenth of the
    convergence radius: the same 12 of 12 converge as at 0.02, six times faster)."""
    for seed in range(12):
        start = paper_world.random_free_place(np.random.default_rng(1000 + seed))
        robot = Robot(0.3, 0.5, start)
        result = simulate(robot, paper_world, 0.3, 0.5, 10, 200, filtering_algorithm="grid", seed=seed, resolution=0.05)
        assert result.converged_at is not None


@pytest.mark.parametrize("name", [*PARTICLE_FILTERS, "grid"])
def test_a_measurement_no_particle_explains_restarts_from_the_prior(paper_world, name):
    robot = Robot(
        0.3, 0.5, (3.5, 1.5), actual_angles=[0.0] * 4, compass_angles=[0.0] * 4, measurements=[1.0, 1.0, 500.0, 1.0]
    )
    result = simulate(robot, paper_world, 0.3, 0.5, 800, filtering_algorithm=name, seed=4)
    assert result.reinitialised_at == [3]
    assert np.isfinite(result.estimates).all()
    assert LOG_UNDERFLOW < -700


@pytest.mark.parametrize("name", [*PARTICLE_FILTERS, "grid"])
def test_the_same_seed_gives_the_same_run_bit_for_bit(paper_world, name):
    def once():
        robot = Robot(0.3, 0.5, (3.5, 1.5))
        return simulate(robot, paper_world, 0.3, 0.5, 300, 40, filtering_algorithm=name, seed=99)

    first, second = once(), once()
    np.testing.assert_array_equal(first.estimates, second.estimates)
    np.testing.assert_array_equal(first.true_positions, second.true_positions)
    assert first.scenario == second.scenario


def test_rpf_regularises_when_ess_falls_below_the_threshold(paper_world):
    robot = Robot(0.3, 0.5, (3.5, 1.5))
    result = simulate(robot, paper_world, 0.3, 0.5, 1000, 60, filtering_algorithm="rpf", seed=5, threshold=0.5)
    # it regularises at the start of step k when ESS after step k-1 was below 0.5 N
    low = np.flatnonzero(result.ess[:-1] < 0.5 * 1000) + 1
    assert len(low) > 0
    rpf = RegularizedParticleFilter(paper_world, 0.3, 0.5, paper_world.random_free_places(1000))
    assert rpf.bandwidth == pytest.approx(1000 ** (-1 / 6))  # A = (4/4)^(1/6) = 1 in two dimensions


def test_particles_keep_their_last_heading(paper_world, rng):
    sir = SIRParticleFilter(paper_world, 0.3, 0.2, paper_world.random_free_places(500, rng), rng)
    sir.step(1.0, 1.0)
    assert np.all(np.abs(sir.headings - 1.0) <= 0.1)
