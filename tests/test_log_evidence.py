"""The log evidence log p(z_1:k): exact for the grid filter (checked against a case worked by hand),
estimated by every particle filter (particles' logLt; the APF's from its first stage, as Pitt and
Shephard), within its Monte Carlo error of the grid filter's, and reported per step and by compare."""

from __future__ import annotations

import math

import numpy as np
import pytest
from conftest import recorded_walk

from mazelab.grid_filter import GridBayesFilter
from mazelab.maze import Maze
from mazelab.registry import filter_entry


def gaussian(z: float, d: float, sigma: float) -> float:
    return math.exp(-0.5 * ((z - d) / sigma) ** 2) / (sigma * math.sqrt(2 * math.pi))


def test_the_grid_filters_log_evidence_is_the_sum_worked_by_hand():
    """A 1 x 2 maze: a station wall (stations at its four corners) beside one free cell; cells of 0.5
    give four free cells, prior 1/4 each. Steps of exactly one cell (L = 0.5, Delta = 0): west, then east.

    Step 1 moves the mass of the cells at x = 1.25 into the wall (x = 0.75, penalty 1/2) and of x = 1.75
    to x = 1.25; every one of these cell centres is sqrt(1/8) from a station, so
        p(z_1) = 1/4 (1/2 + 1/2 + 1 + 1) N(z_1; sqrt(1/8)),
    and the posterior is 1/6 on each wall cell, 1/3 on each free cell. Step 2 moves it back east:
    1/6 at x = 1.25 (distance sqrt(1/8)) and 1/3 at x = 1.75 (distance sqrt(0.75^2 + 0.25^2)), so
        p(z_2 | z_1) = 2/6 N(z_2; sqrt(1/8)) + 2/3 N(z_2; sqrt(0.625))."""
    sigma, near, far = 0.3, math.sqrt(1 / 8), math.sqrt(0.625)
    grid = GridBayesFilter(Maze([[2, 0]]), sigma, 0.0, resolution=0.5, margin=0.0, speed=0.5)
    grid.step(math.pi, 0.4)
    first = math.log(0.25 * 3 * gaussian(0.4, near, sigma))
    assert grid.log_evidence == pytest.approx(first, abs=1e-12)
    grid.step(0.0, 0.7)
    second = math.log(2 / 6 * gaussian(0.7, near, sigma) + 2 / 3 * gaussian(0.7, far, sigma))
    assert grid.log_evidence == pytest.approx(first + second, abs=1e-12)


@pytest.mark.parametrize(
    ("name", "options"),
    [("sir", {}), ("sir", {"threshold": 0.5}), ("apf", {}), ("rpf", {"bandwidth": 0.01})],
)
def test_each_particle_filter_estimates_the_exact_log_evidence_within_its_monte_carlo_error(paper_world, name, options):
    """Z_hat = prod_k p_hat(z_k | z_1:k-1) is unbiased for p(z_1:k) (Del Moral), so by the delta method
    E[log Z_hat] = log Z - Var(log Z_hat) / 2 to second order; the mean of M seeded runs lies within 4
    standard errors sd / sqrt(M) of that. The RPF's kernel changes the posterior it carries (a kernel
    as wide as h_opt biases its estimate), so it is held to this with a narrow kernel, h = 0.01."""
    steps, count, seeds = 20, 1000, 30
    walk = recorded_walk(paper_world, 3, steps)
    grid = GridBayesFilter(paper_world, 0.3, 0.5)
    for compass_angle, z in walk:
        grid.step(compass_angle, z)
    estimates = []
    for seed in range(seeds):
        particles = paper_world.random_free_places(count, np.random.default_rng(seed))
        filt = filter_entry(name).filter_class(
            paper_world, 0.3, 0.5, particles, np.random.default_rng(seed + 100), **options
        )
        for compass_angle, z in walk:
            filt.step(compass_angle, z)
        estimates.append(filt.log_evidence)
    estimates = np.array(estimates)
    variance = estimates.var(ddof=1)
    assert abs(estimates.mean() - (grid.log_evidence - variance / 2)) < 4 * math.sqrt(variance / seeds)


def test_a_run_reports_the_log_evidence_of_every_step_and_compare_shows_it(paper_world):
    from mazelab.experiments.runs import comparison_table
    from mazelab.robot import Robot
    from mazelab.simulation import simulate

    rng = np.random.default_rng(5)
    robot = Robot(0.3, 0.5, paper_world.random_free_place(rng), rng=rng)
    result = simulate(robot, paper_world, 0.3, 0.5, 300, 15, filtering_algorithm="sir", seed=5)
    assert result.log_evidence.shape == (15,) and np.isfinite(result.log_evidence).all()
    increments = np.diff(result.log_evidence)
    assert (increments != 0).all()  # each step adds its own log p(z_k | z_1:k-1)
    table = comparison_table({"SIRParticleFilter": result})
    assert "log p(z_1:K)" in table.splitlines()[0]
    assert f"{result.log_evidence[-1]:.1f}" in table.splitlines()[2]
