"""The resampling schemes and KLD-sampling (mazelab.resampling).

- every scheme is unbiased, E[N_i] = N W_i, and gives no offspring to a particle without weight;
  systematic and residual keep at least floor(N W_i) copies, systematic at most ceil(N W_i);
- systematic resampling's O(N) count (the compiled backend's) is the textbook inverse CDF's ancestors;
- an unknown scheme's name lists the valid ones, and every scheme runs in every particle filter;
- KLD-sampling (Fox 2003): the bound of eq. 13, its options checked, the sample stops at Fox's first
  sufficient count, and the particle count shrinks as the robot is found.
"""

from __future__ import annotations

import numpy as np
import pytest

from mazelab.resampling import (
    KLD_QUANTILE,
    RESAMPLING_SCHEMES,
    KLDSampling,
    check_scheme,
    kld_resample,
    kld_sample_size,
    systematic_resample,
)
from mazelab.robot import Robot
from mazelab.simulation import run_model, simulate

PARTICLE_FILTERS = ["sir", "apf", "rpf"]


# -- the schemes -------------------------------------------------------------------------------------
@pytest.mark.parametrize("scheme", sorted(RESAMPLING_SCHEMES))
def test_resampling_gives_the_expected_offspring_counts(scheme):
    weights = np.array([0.05, 0.4, 0.25, 0.1, 0.2, 0.0, 0.0, 0.0])
    resample, rng, draws = RESAMPLING_SCHEMES[scheme], np.random.default_rng(11), 4000
    n = len(weights)
    counts = np.zeros((draws, n))
    for r in range(draws):
        ancestors = resample(weights, rng)
        assert len(ancestors) == n
        counts[r] = np.bincount(ancestors, minlength=n)
    # Unbiasedness: E[count_i] = N W_i. Multinomial has the largest variance, N W_i (1 - W_i), of the
    # four schemes, so 5 of its standard errors over `draws` repetitions bound every scheme's mean.
    bound = 5 * np.sqrt(n * weights * (1 - weights) / draws) + 1e-12
    assert np.all(np.abs(counts.mean(axis=0) - n * weights) <= bound)
    assert counts[:, weights == 0].sum() == 0
    if scheme in ("systematic", "residual"):
        assert np.all(counts >= np.floor(n * weights))  # at least floor(N W_i) copies
    if scheme == "systematic":
        assert np.all(counts <= np.ceil(n * weights))


@pytest.mark.parametrize("scheme", sorted(RESAMPLING_SCHEMES))
def test_every_scheme_draws_several_runs_in_one_call_as_each_alone(scheme):
    """Row r of a call on R runs' weights with R Generators is the scheme's answer for run r alone, to the
    bit (the engine draws every due run in one call): a row drawn from another run's Generator fails."""
    rng = np.random.default_rng(12)
    weights = rng.random((5, 300)) ** 6
    weights[2, ::2] = 0.0
    weights /= weights.sum(axis=1, keepdims=True)
    resample = RESAMPLING_SCHEMES[scheme]
    together = resample(weights, [np.random.default_rng(seed) for seed in range(5)])
    alone = np.array([resample(w, np.random.default_rng(seed)) for seed, w in enumerate(weights)])
    np.testing.assert_array_equal(together, alone)
    swapped = resample(weights, [np.random.default_rng(seed) for seed in (1, 0, 2, 3, 4)])
    assert not np.array_equal(swapped[:2], alone[:2])


def test_unknown_resampling_scheme_lists_the_valid_ones():
    with pytest.raises(ValueError, match="systematic"):
        check_scheme("magic")
    assert check_scheme("Stratified") == "stratified"


def test_the_textbook_systematic_and_the_compiled_counting_form_give_the_same_ancestors(paper_world):
    """`systematic_resample` is the textbook (u ~ U[0, 1), u_m = (u + m) / M, the inverse CDF by a
    binary search), the numpy backend's; the compiled backend runs its O(N) counting form. For the same
    u they must pick the same ancestors, M = N and M below and above N, with particles of no weight
    among them."""
    pytest.importorskip("numba")
    from mazelab.kernels.compiled import CompiledKernels

    counting = CompiledKernels(paper_world).systematic
    rng = np.random.default_rng(21)
    for trial in range(200):
        n = int(rng.integers(1, 400))
        weights = rng.random(n) ** 4
        weights[rng.random(n) < 0.3] = 0.0  # particles with no weight get no offspring
        weights = weights / weights.sum() if weights.sum() > 0 else np.full(n, 1 / n)
        for count in (n, max(1, n // 3), 2 * n + 1):
            textbook = systematic_resample(weights, np.random.default_rng(trial), count)
            np.testing.assert_array_equal(counting(weights, np.random.default_rng(trial), count), textbook)


@pytest.mark.parametrize("name", PARTICLE_FILTERS)
@pytest.mark.parametrize("scheme", sorted(RESAMPLING_SCHEMES))
def test_run_model_takes_every_resampling_scheme(paper_world, name, scheme):
    robot = Robot(0.3, 0.5, (3.5, 1.5))
    pairs = run_model(
        robot, paper_world, 0.3, 0.5, 100, 8, filtering_algorithm=name, seed=1, visualize=False, resampling=scheme
    )
    assert len(pairs) == 8 and all(np.isfinite(pairs[-1][1]))


# -- KLD-sampling ----------------------------------------------------------------------------------
def test_kld_bound_matches_a_hand_computation():
    """Fox (2003) eq. 13 for k = 10 bins, epsilon = 0.05, z = z_0.99 = 2.3263479:
    2/(9(k-1)) = 2/81 = 0.0246914, sqrt = 0.1571348; 1 - 0.0246914 + 0.1571348 * 2.3263479 = 1.3408589;
    cubed 2.4107339; times (k-1)/(2 eps) = 90: n = 216.966. With z = 2.33 (rounded): 217.245."""
    assert abs(KLD_QUANTILE - 2.3263479) < 1e-7
    assert kld_sample_size(10, 0.05, KLD_QUANTILE) == pytest.approx(216.966, abs=1e-3)
    assert kld_sample_size(10, 0.05, 2.33) == pytest.approx(217.245, abs=1e-3)
    assert kld_sample_size(1, 0.05, 2.33) == 0
    assert KLDSampling().required_count(10) == 217
    assert KLDSampling().required_count(2) == 100  # 65.9 is below the least count


def test_kld_z_is_a_quantile_not_a_probability():
    with pytest.warns(UserWarning, match="looks like a probability"):
        KLDSampling(z=0.99)
    with pytest.raises(ValueError, match=r"KLD epsilon must lie in \[1e-09, 1\], got 0"):
        KLDSampling(epsilon=0)
    with pytest.raises(ValueError, match="KLD bin_size must be > 0"):
        KLDSampling(bin_size=0)
    with pytest.raises(ValueError, match="below min_count"):
        KLDSampling(min_count=100, max_count=50)


@pytest.mark.parametrize("spread", [0.3, 3.0])
def test_kld_resampling_stops_at_foxs_first_sufficient_count(spread, rng):
    """The sample is a prefix of Fox's sequential draw: its count n is the first at which
    n >= required_count(k_n), k_n the bins occupied by samples 1..n."""
    positions = rng.normal(5.0, spread, (3000, 2))
    weights = np.full(3000, 1 / 3000)
    options = KLDSampling()

    def move(ancestors):
        return positions[ancestors], np.zeros(len(ancestors))

    ancestors, drawn, _ = kld_resample(weights, move, options, systematic_resample, rng, 50_000)
    np.testing.assert_array_equal(drawn, positions[ancestors])
    cells = np.floor(drawn / options.bin_size).astype(np.int64)
    _, first = np.unique(cells, axis=0, return_index=True)
    new = np.zeros(len(drawn), dtype=bool)
    new[first] = True
    enough = np.arange(1, len(drawn) + 1) >= options.required_count(np.cumsum(new))
    assert enough[-1] and not enough[:-1].any()


@pytest.mark.parametrize("name", ["sir", "apf"])
def test_kld_particle_count_shrinks_as_the_robot_is_found(paper_world, name):
    robot = Robot(0.3, 0.5, (3.5, 1.5))
    result = simulate(robot, paper_world, 0.3, 0.5, 2000, 120, filtering_algorithm=name, seed=4, kld=True)
    counts = result.extras["particle_count"]
    assert counts.shape == (120,) and counts.min() >= 100 and counts.max() <= 2000
    assert counts[0] > 3 * counts[-20:].mean()  # the prior covers the maze; the posterior a few bins
    assert result.converged_at is not None


def test_the_inverse_cdf_of_several_runs_is_each_runs_search_on_ties_and_empty_bins():
    """R runs' rows are searched on their float64 bits (mazelab.resampling._inverse_cdf): points exactly on
    a cumulative weight, before the first and at 1, and particles of no weight give each row's float search."""
    from mazelab.resampling import _inverse_cdf

    weights = np.array([[0.0, 0.25, 0.0, 0.5, 0.25, 0.0], [0.5, 0.0, 0.0, 0.0, 0.0, 0.5]])
    points = np.array([[0.0, 0.25, 0.5, 0.75, 0.999, 1.0], [0.0, 0.1, 0.5, 0.5, 0.75, 1.0]])
    together = _inverse_cdf(points, weights)
    np.testing.assert_array_equal(together, [[1, 3, 3, 4, 4, 6], [0, 0, 5, 5, 5, 6]])  # u = 1: N, as a search
    np.testing.assert_array_equal(together, [_inverse_cdf(p, w) for p, w in zip(points, weights, strict=True)])
