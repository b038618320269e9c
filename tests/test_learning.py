"""Parameter learning (mazelab.learning): the exact posterior p(sigma, delta | z_1:K) on a grid of values
from the grid filter's evidence, the chain diagnostics (effective sample size, quantiles' Monte Carlo
error) against their values for known processes, and a PMMH chain whose posterior mean and 90% interval
agree with the exact posterior within the chain's Monte Carlo error plus the grid's own error."""

from __future__ import annotations

import math
import re
from concurrent.futures import ProcessPoolExecutor
from statistics import NormalDist

import numpy as np
import pytest

from mazelab.grid_filter import GridBayesFilter
from mazelab.learning import (
    ParameterGrid,
    ParameterPosterior,
    chain_ess,
    exact_parameter_posterior,
    grid_log_evidence,
    pmmh,
    quantile_error,
)
from mazelab.registry import filter_entry
from mazelab.robot import Robot

STANDARD_ERRORS = 3  # per comparison: P(|N(0, 1)| > 3) = 0.27%, so six comparisons at once false-alarm < 2%


def seeded_walk(world, sigma, delta, steps, seed=7):
    """The compass angles and measurements of a seeded robot walking with the model (sigma, delta)."""
    rng = np.random.default_rng(seed)
    robot = Robot(sigma, delta, world.random_free_place(rng), rng=rng)
    return tuple(zip(*[robot.step(world) for _ in range(steps)], strict=True))


def test_each_cell_is_the_grid_filters_evidence_and_an_executor_map_gives_the_same(paper_world):
    angles, zs = seeded_walk(paper_world, 0.4, 0.3, 6)
    grid = ParameterGrid(cells=(2, 3))
    serial = exact_parameter_posterior(paper_world, angles, zs, grid, resolution=0.1)
    sigma, delta = grid.centres[0][1], grid.centres[1][2]
    filt = GridBayesFilter(paper_world, sigma, delta, resolution=0.1)
    for compass_angle, z in zip(angles, zs, strict=True):
        filt.step(compass_angle, z)
    assert serial.log_evidence[1, 2] == filt.log_evidence
    with ProcessPoolExecutor(max_workers=2) as pool:  # the cells pickle: what a study's executor needs
        spread = exact_parameter_posterior(paper_world, angles, zs, grid, mapper=pool.map, resolution=0.1)
    np.testing.assert_array_equal(spread.log_evidence, serial.log_evidence)
    assert serial.mass.sum() == pytest.approx(1.0)


def test_the_posteriors_mean_and_interval_are_those_of_its_density_constant_on_each_cell():
    grid = ParameterGrid((0.2, 0.8), (0.1, 0.5), cells=(6, 4))
    flat = ParameterPosterior(grid, np.zeros(grid.cells))  # the evidence says nothing: the uniform prior
    np.testing.assert_allclose(flat.mean, [0.5, 0.3])
    np.testing.assert_allclose(flat.interval(0.9), [[0.23, 0.77], [0.12, 0.48]])
    one_cell = np.full(grid.cells, -np.inf)
    one_cell[2, 1] = -3.0  # all the mass in sigma's cell [0.4, 0.5), delta's [0.2, 0.3)
    peaked = ParameterPosterior(grid, one_cell)
    np.testing.assert_allclose(peaked.mean, [0.45, 0.25])
    np.testing.assert_allclose(peaked.interval(0.9), [[0.405, 0.495], [0.205, 0.295]])


@pytest.mark.parametrize("phi", [0.0, 0.6])
def test_the_effective_sample_size_of_an_ar1_chain_is_n_times_1_minus_phi_over_1_plus_phi(phi):
    """tau = (1 + phi) / (1 - phi) for x_t = phi x_t-1 + e_t. Geyer's estimate sums the autocorrelations up
    to a lag M (well below 10 tau here); its relative standard deviation is about sqrt(2 (2M + 1) / n)
    (Sokal 1997), so sqrt(2 (20 tau + 1) / n) bounds it and 4 of those bound the check."""
    n, rng = 200_000, np.random.default_rng(3)
    noise = rng.standard_normal(n)
    x = np.empty(n)
    x[0] = noise[0] / math.sqrt(1 - phi**2)
    for t in range(1, n):  # a plain loop: 0.1 s
        x[t] = phi * x[t - 1] + noise[t]
    tau = (1 + phi) / (1 - phi)
    tolerance = 4 * math.sqrt(2 * (20 * tau + 1) / n)
    assert chain_ess(x) == pytest.approx(n / tau, rel=tolerance)


def test_the_quantiles_monte_carlo_error_is_that_of_independent_draws():
    """For n independent N(0, 1) draws the p-quantile's standard error is sqrt(p (1 - p) / n) / phi(z_p).
    The estimate is half the distance between two sample quantiles about 2 n s apart in rank (s that
    standard error in p), so its relative error is about 1 / sqrt(2 n s); 4 of those bound the check."""
    n, p = 100_000, 0.05
    x = np.random.default_rng(4).standard_normal(n)
    spread = math.sqrt(p * (1 - p) / n)
    expected = spread / NormalDist().pdf(NormalDist().inv_cdf(p))
    assert quantile_error(x, p) == pytest.approx(expected, rel=4 / math.sqrt(2 * n * spread))


def test_pmmh_refuses_a_filter_whose_evidence_does_not_estimate_p_z_and_bad_settings(paper_world):
    """The refusals read the registry's declaration: the RPF's caveat is the one every table prints."""
    needs = r"^PMMH needs a filter whose evidence estimates p\(z_1:K\): "
    with pytest.raises(ValueError, match=needs + re.escape(f"RPF's is {filter_entry('rpf').evidence}") + "$"):
        pmmh(paper_world, [0.1], [1.0], 10, filter_name="rpf")
    with pytest.raises(ValueError, match=needs + "with recovery it does not"):
        pmmh(paper_world, [0.1], [1.0], 10, filter_name="sir", recovery="augmented")
    with pytest.raises(ValueError, match=r"^threshold must be in \(0, 1\] \(a share of N\), got 5$"):
        pmmh(paper_world, [0.1], [1.0], 10, filter_name="sir", threshold=5)  # the filter's own check, one line
    with pytest.raises(ValueError, match=needs + "EKF keeps none$"):
        pmmh(paper_world, [0.1], [1.0], 10, filter_name="ekf")
    with pytest.raises(ValueError, match="outside the prior's box"):
        pmmh(paper_world, [0.1], [1.0], 10, start=(0.1, 0.3))
    with pytest.raises(ValueError, match="particle_count must be a whole number >= 1, got 0"):
        pmmh(paper_world, [0.1], [1.0], 10, particle_count=0)
    with pytest.raises(ValueError, match=r"the sigma range must be \(low, high\) with low < high"):
        ParameterGrid(sigma_range=(0.5, 0.3))


def test_a_seeded_chain_repeats_itself(paper_world):
    angles, zs = seeded_walk(paper_world, 0.4, 0.3, 5)
    first, second = (pmmh(paper_world, angles, zs, 20, particle_count=50, seed=9) for _ in range(2))
    np.testing.assert_array_equal(first.samples, second.samples)
    assert 0 < first.accepted <= 20 and first.log_evidence.shape == (20,)


def test_pmmh_with_the_grid_filter_is_metropolis_hastings_on_its_exact_evidence(paper_world):
    angles, zs = seeded_walk(paper_world, 0.4, 0.3, 4)
    chain = pmmh(paper_world, angles, zs, 8, filter_name="grid", seed=2, resolution=0.1)
    assert chain.accepted > 0
    for (sigma, delta), log_z in zip(chain.samples, chain.log_evidence, strict=True):
        assert log_z == grid_log_evidence(paper_world, angles, zs, sigma, delta, resolution=0.1)


@pytest.mark.slow
def test_the_pmmh_chain_agrees_with_the_exact_posterior(paper_world):
    """A seeded PMMH chain (SIR, 200 particles: Var(log Z_hat) about 0.6 on this walk, where the chain
    mixes well) against the exact posterior on 8 x 8 cells of the lab's box at a grid resolution of 0.1.
    The exact answer's own error is measured by halving the grid's resolution (0.05) and, apart, its
    cells' width (16 x 16): for an error of order p >= 1 in the cell size, the coarse grid's error is
    difference / (1 - 2^-p) <= 2 differences. Each of the posterior mean and the 90% interval's ends, of
    sigma and of delta, must lie within STANDARD_ERRORS of the chain's Monte Carlo errors plus that."""
    angles, zs = seeded_walk(paper_world, 0.4, 0.3, 20)
    cells = ParameterGrid(cells=(8, 8))
    exact = exact_parameter_posterior(paper_world, angles, zs, cells, resolution=0.1)
    finer = exact_parameter_posterior(paper_world, angles, zs, cells, resolution=0.05)
    narrower = exact_parameter_posterior(paper_world, angles, zs, ParameterGrid(cells=(16, 16)), resolution=0.1)

    def summary(posterior):
        return np.column_stack([posterior.mean, posterior.interval()])  # rows sigma, delta: mean, low, high

    grid_error = 2 * (abs(summary(finer) - summary(exact)) + abs(summary(narrower) - summary(exact)))
    chain = pmmh(paper_world, angles, zs, 3000, particle_count=200, burn_in=300, seed=1, proposal_scale=(0.08, 0.3))
    monte_carlo = np.column_stack([chain.mean_error, chain.interval_error()])
    chained = np.column_stack([chain.mean, chain.interval()])
    assert (chain.ess > 100).all()  # a Monte Carlo error from fewer effective draws is itself unreliable
    assert (abs(chained - summary(exact)) <= STANDARD_ERRORS * monte_carlo + grid_error).all(), (
        chained,
        summary(exact),
        monte_carlo,
        grid_error,
    )
