"""Weighted particles (mazelab.weights): each function for one run (N,) and for R runs (R, N) alike.

- log_sum_exp is log(sum(exp(log w))) without overflow or underflow, -inf where every entry is -inf;
- weights_from_logs normalises each run by its own total (NaN for a run whose total is -inf);
- the effective sample size is N_eff = 1 / sum_i W_i^2 (Arulampalam et al., eq. 51): N for equal
  weights, 1 for one particle holding all;
- weighted_mean and weighted_covariance are sum_i W_i x_i and sum_i W_i (x_i - mean)(x_i - mean)^T;
- mass_within is the weight of the points at most `radius` from the centre (the boundary counts).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from mazelab.weights import (
    Weights,
    effective_sample_size,
    log_sum_exp,
    mass_within,
    weighted_covariance,
    weighted_mean,
    weights_from_logs,
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


def test_weights_from_logs_normalise_each_run_by_its_own_total():
    log_w = np.log([[1.0, 3.0], [2.0, 2.0]]) + np.array([[-900.0], [700.0]])  # far beyond exp's range
    weights = weights_from_logs(log_w, log_sum_exp(log_w))
    np.testing.assert_allclose(weights, [[0.25, 0.75], [0.5, 0.5]], rtol=1e-12)
    lost = weights_from_logs(np.array([[-np.inf, -np.inf], [0.0, 0.0]]), np.array([-np.inf, math.log(2)]))
    assert np.isnan(lost[0]).all() and lost[1].tolist() == [0.5, 0.5]


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


def test_weights_are_a_value_whose_w_and_ess_are_derived():
    lw = np.log(np.array([[0.5, 0.25, 0.25], [1 / 3, 1 / 3, 1 / 3]]))
    weights = Weights(lw)
    np.testing.assert_allclose(weights.W, np.exp(lw))
    np.testing.assert_allclose(weights.ess, [1 / (0.25 + 1 / 16 + 1 / 16), 3.0])
    with pytest.raises(AttributeError, match="value"):
        weights.lw = lw[::-1]


def test_the_log_mean_increment_is_the_previous_weights_mean_of_the_increments():
    """log sum_i W_{k-1}^i G_k^i, the estimate of log p(z_k | z_1:k-1): from the total of w = W_{k-1} G
    where the weights carry W_{k-1}; from the mean of G (W_{k-1} = 1/N after resampling) times the
    factor fresh weights lack (the APF's first-stage total) where they are fresh. Worked by hand."""
    previous, increments = np.array([0.5, 0.25, 0.25]), np.array([0.2, 0.4, 0.8])
    log_w = np.stack([np.log(previous * increments), np.log(increments)])  # run 0 carries W_{k-1}; run 1 fresh
    totals = log_sum_exp(log_w)
    factor = math.log(0.6)
    weights = Weights(None, unnormalised=(log_w, totals), increment=(totals, np.array([False, True]), factor, 3))
    carried = 0.5 * 0.2 + 0.25 * 0.4 + 0.25 * 0.8  # 0.4
    fresh = 0.6 * (0.2 + 0.4 + 0.8) / 3  # 0.28
    np.testing.assert_allclose(weights.log_mean_increment, np.log([carried, fresh]), rtol=1e-14)
    np.testing.assert_allclose(weights.W, [previous * increments / carried, increments / 1.4], rtol=1e-14)


@pytest.mark.parametrize("runs", [1, 3])
@pytest.mark.parametrize("factor", [0.0, "per run"])
def test_every_run_or_none_fresh_gives_the_masks_increments_to_the_bit(runs, factor):
    """fresh = True (every run resampled) or False (none): the same float64 values, bit for bit, as the
    mask of all or no runs (one run's are worked on Python floats, the same double arithmetic in the
    same order); 32 draws, as a sum in another order differs in the last bit for about a third."""
    rng = np.random.default_rng(5)
    for _ in range(32):
        totals = rng.normal(-3.0, 2.0, runs)
        log_factor = rng.normal(-1.0, 0.5, runs) if factor == "per run" else factor
        for fresh, mask in ((True, np.ones(runs, dtype=bool)), (False, np.zeros(runs, dtype=bool))):
            fast = Weights(None, increment=(totals, fresh, log_factor, 1000)).log_mean_increment
            masked = Weights(None, increment=(totals, mask, log_factor, 1000)).log_mean_increment
            assert fast.dtype == masked.dtype == np.float64
            np.testing.assert_array_equal(fast.view(np.int64), masked.view(np.int64))


def test_the_log_parts_give_log_w_without_making_it():
    log_w, totals = np.array([[-1.0, -2.5, -np.inf]], dtype=np.float32), np.array([0.75])
    derived = Weights(None, unnormalised=(log_w, totals))
    log_a, shifts = derived.log_parts
    assert log_a is log_w and shifts is totals and "lw" not in vars(derived)  # nothing made
    np.testing.assert_array_equal(np.subtract(log_a, shifts[:, None], dtype=float), derived.lw)  # the same bits
    assert derived.log_parts[0] is derived.lw and derived.log_parts[1] is None  # once made, itself
    held = Weights(np.array([[-0.1, -2.3]]))
    assert held.log_parts[0] is held.lw and held.log_parts[1] is None
