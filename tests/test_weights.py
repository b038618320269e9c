"""Weighted particles (mazelab.weights): each function for one run (N,) and for R runs (R, N) alike.

- log_sum_exp is log(sum(exp(log w))) without overflow or underflow, -inf where every entry is -inf;
- Weights.from_log normalises each run by its own total; add, a masked reset and lost; read-only arrays;
- the effective sample size is N_eff = 1 / sum_i W_i^2 (Arulampalam et al., eq. 51): N for equal
  weights, 1 for one particle holding all;
- weighted_mean and weighted_covariance are sum_i W_i x_i and sum_i W_i (x_i - mean)(x_i - mean)^T;
- mass_within is the weight of the points at most `radius` from the centre (the boundary counts).
"""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest

from mazelab.weights import (
    Weights,
    effective_sample_size,
    log_sum_exp,
    mass_within,
    weighted_covariance,
    weighted_mean,
)


def test_log_sum_exp_neither_overflows_nor_underflows():
    """exp(1000) overflows and exp(-1000) underflows in float64; log(e^a + e^a) = a + log 2 whatever a."""
    for top in (1000.0, -1000.0, 0.0):
        assert log_sum_exp(np.array([top, top])) == pytest.approx(top + math.log(2), rel=1e-15, abs=1e-15)
    assert log_sum_exp(np.array([-1000.0, -np.inf])) == -1000.0
    assert log_sum_exp(np.array([math.log(0.25), math.log(0.75)])) == pytest.approx(0.0, abs=1e-15)
    assert log_sum_exp(np.full(3, -np.inf)) == -np.inf and isinstance(log_sum_exp(np.zeros(3)), float)


def test_log_sum_exp_sums_each_run_and_a_run_without_weight_is_minus_infinity():
    log_w = np.array([[0.0, 0.0, 0.0], [-np.inf, -np.inf, -np.inf], [800.0, 800.0, -np.inf]])
    totals = log_sum_exp(log_w)
    assert totals.shape == (3,)
    np.testing.assert_allclose(totals[[0, 2]], [math.log(3), 800 + math.log(2)], rtol=1e-15)
    assert totals[1] == -np.inf


def test_weights_from_log_normalise_each_run_by_its_own_total_and_a_run_nothing_explains_is_lost():
    log_w = np.log([[1.0, 3.0], [2.0, 2.0]]) + np.array([[-600.0], [700.0]])  # beyond exp's range, not lost
    weights = Weights.from_log(log_w)
    np.testing.assert_allclose(weights.W, [[0.25, 0.75], [0.5, 0.5]], rtol=1e-12)
    np.testing.assert_allclose(weights.log_total, [math.log(4) - 600, math.log(4) + 700], rtol=1e-15)
    assert weights.lost.tolist() == [False, False]
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a lost run is an outcome the engine handles, not a RuntimeWarning
        lost = Weights.from_log(np.array([[-np.inf, -np.inf], [0.0, 0.0], [-800.0, -800.0]]))
    assert lost.lost.tolist() == [True, False, True]  # -inf, and a total below the smallest float64


def test_effective_sample_size_limits():
    assert effective_sample_size(np.full(10, 0.1)) == pytest.approx(10)
    assert effective_sample_size(np.eye(5)[2]) == 1


def test_the_effective_sample_size_of_known_weights_per_run():
    """(1/2, 1/4, 1/4): 1 / (1/4 + 1/16 + 1/16) = 8/3; per run of R, each run's own."""
    assert effective_sample_size(np.array([0.5, 0.25, 0.25])) == pytest.approx(8 / 3, rel=1e-15)
    runs = effective_sample_size(np.array([[0.5, 0.25, 0.25], [1 / 3, 1 / 3, 1 / 3], [0.0, 1.0, 0.0]]))
    np.testing.assert_allclose(runs, [8 / 3, 3.0, 1.0], rtol=1e-15)


def test_weighted_mean_and_covariance_are_the_weighted_sums(rng):
    """Against numpy's weighted average and covariance (np.cov with aweights and bias=True is
    sum_i W_i (x_i - m)(x_i - m)^T for weights summing to 1), float32 points as the filters hold them."""
    points = rng.normal((3.0, 1.0), (0.5, 2.0), (500, 2)).astype(np.float32)
    weights = rng.random(500) ** 2
    weights /= weights.sum()
    exact = points.astype(float)
    np.testing.assert_allclose(weighted_mean(weights, points), np.average(exact, axis=0, weights=weights), rtol=1e-6)
    covariance = weighted_covariance(weights, points)
    assert covariance.shape == (2, 2) and covariance.dtype == np.float64
    np.testing.assert_allclose(covariance, np.cov(exact.T, aweights=weights, bias=True), rtol=1e-5, atol=1e-9)


def test_weighted_summaries_of_r_runs_are_each_runs_own(rng):
    """R runs in R blocks of N rows: run r's mean and covariance are those of its block and its weights."""
    runs, n = 3, 200
    points = rng.normal(size=(runs * n, 2)) * np.repeat([1.0, 0.2, 3.0], n)[:, None] + np.repeat([0, 5, -2], n)[:, None]
    weights = rng.random((runs, n))
    weights /= weights.sum(axis=1, keepdims=True)
    means, covariances = weighted_mean(weights, points), weighted_covariance(weights, points)
    assert means.shape == (runs, 2) and covariances.shape == (runs, 2, 2)
    for r in range(runs):
        block = points[r * n : (r + 1) * n]
        np.testing.assert_allclose(means[r], weighted_mean(weights[r], block), rtol=1e-12)
        np.testing.assert_allclose(means[r], weights[r] @ block, rtol=1e-10)
        np.testing.assert_allclose(covariances[r], np.cov(block.T, aweights=weights[r], bias=True), rtol=1e-10)


def test_mass_within_is_the_weight_at_most_the_radius_away():
    """Points at distance 0.5, exactly 1, 1.5 and 3 from (2, 2), weights 0.1, 0.2, 0.3, 0.4: within 1 lie
    the first two (the boundary counts), 0.3; per run, each run's weights about its own centre."""
    points = np.array([[2.5, 2.0], [2.0, 3.0], [0.5, 2.0], [2.0, -1.0]])
    weights = np.array([0.1, 0.2, 0.3, 0.4])
    assert mass_within(weights, points, np.array([2.0, 2.0]), 1.0) == pytest.approx(0.3, abs=1e-15)
    assert mass_within(weights, points, np.array([2.0, 2.0]), 0.4) == 0.0
    assert mass_within(weights, points, np.array([2.0, 2.0]), 3.0) == pytest.approx(1.0, abs=1e-15)
    runs = np.vstack([weights, weights[::-1]])  # run 2: weights 0.4, 0.3, 0.2, 0.1, centre (0.5, 2)
    both = mass_within(runs, np.vstack([points, points]), np.array([[2.0, 2.0], [0.5, 2.0]]), 1.0)
    np.testing.assert_allclose(both, [0.3, 0.2], atol=1e-15)  # about (0.5, 2): only the third point


def test_weights_are_a_value_whose_arrays_are_read_only_and_whose_w_and_ess_are_derived():
    lw = np.log(np.array([[0.5, 0.25, 0.25], [1 / 3, 1 / 3, 1 / 3]]))
    weights = Weights(lw)
    np.testing.assert_allclose(weights.W, np.exp(lw))
    np.testing.assert_allclose(weights.ess, [1 / (0.25 + 1 / 16 + 1 / 16), 3.0])
    for array in (weights.W, weights.lw, weights.ess, weights.log_total, Weights.uniform(2, 3).lw):
        with pytest.raises(ValueError, match="read-only"):
            array[0] = 1.0


def test_add_is_the_reweighting_whose_log_total_is_the_previous_weights_mean_of_the_increments():
    """W.add(log G): W_i G_i normalised per run, and its log total log sum_i W_{k-1}^i G_k^i, the estimate
    of log p(z_k | z_1:k-1). Worked by hand."""
    previous, increments = np.array([[0.5, 0.25, 0.25], [0.2, 0.2, 0.6]]), np.array([[0.2, 0.4, 0.8], [1.0, 1.0, 0.5]])
    new = Weights(np.log(previous)).add(np.log(increments))
    carried = (previous * increments).sum(axis=1)  # 0.4 and 0.7
    np.testing.assert_allclose(new.log_total, np.log(carried), rtol=1e-14)
    np.testing.assert_allclose(new.W, previous * increments / carried[:, None], rtol=1e-14)
    uniform = Weights.uniform(2, 3).add(np.log(increments))
    np.testing.assert_allclose(uniform.log_total, np.log(increments.mean(axis=1)), rtol=1e-14)


def test_a_masked_reset_replaces_those_runs_and_keeps_the_others_to_the_bit():
    rng = np.random.default_rng(3)
    weights, other = Weights.from_log(rng.normal(size=(3, 4))), Weights.from_log(rng.normal(size=(1, 4)))
    reset = weights.reset(np.array([False, True, False]), other)
    np.testing.assert_array_equal(reset.lw[[0, 2]], weights.lw[[0, 2]])
    np.testing.assert_array_equal(reset.lw[1], other.lw[0])
    np.testing.assert_array_equal(reset.log_total, [weights.log_total[0], other.log_total[0], weights.log_total[2]])
    assert weights.reset(np.zeros(3, dtype=bool), other) is weights
