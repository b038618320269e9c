"""The paper's particle filters (mazelab.filters: the SIR, APF and RPF steps), each rule on its own and
against the exact grid filter:

- the RPF regularises exactly at the steps whose previous ESS fell below N_T, each of R runs by its own;
- the APF's second-stage weight is p(z | x) / p(z | mu), so without compass noise it is uniform;
- they converge in most seeded runs, restart from the prior when no particle explains z, and repeat a
  seeded run bit for bit;
- the filters' names resolve (and an unknown one lists the valid ones).
"""

from __future__ import annotations

import numpy as np
import pytest
from conftest import recorded_walk

from mazelab.filters import AuxiliaryParticleFilter, ParticleFilter, RegularizedParticleFilter
from mazelab.model import LOG_UNDERFLOW, ROBOT_SPEED, log_likelihood
from mazelab.registry import entries
from mazelab.robot import Robot
from mazelab.simulation import simulate

PARTICLE_FILTERS = [entry.name for entry in entries() if issubclass(entry.filter_class, ParticleFilter)]


# -- the RPF: regularise exactly when N_eff < N_T ------------------------------------------------------
@pytest.mark.parametrize("threshold", [0.2, 0.5])
def test_the_rpf_regularises_exactly_at_the_steps_whose_ess_fell_below_n_t(paper_world, threshold):
    """Algorithm 6: IF N_eff < N_T, resample and jitter; so step k+1 regularises iff the ESS after step
    k is below threshold * N (the first step never: the initial weights are uniform, ESS = N)."""
    count = 600
    rpf = RegularizedParticleFilter(
        paper_world, 0.3, 0.5, paper_world.random_free_places(count, np.random.default_rng(1)),
        np.random.default_rng(2), threshold=threshold,
    )  # fmt: skip
    expected, ess_before = [], rpf.ess
    for k, (compass, z) in enumerate(recorded_walk(paper_world, 7, 80)):
        if ess_before < threshold * count:
            expected.append(k)  # resampled_at holds the steps done before it
        rpf.step(compass, z)
        ess_before = rpf.ess
    assert 3 <= len(expected) < 80  # both branches taken
    assert rpf.resampled_at == expected


def test_the_rpf_regularises_each_of_r_runs_by_its_own_ess(paper_world):
    """R runs together: run r regularises at its own steps, as the single run r would."""
    seeds = (3, 4, 5)
    walks = [recorded_walk(paper_world, s, 50) for s in seeds]
    particles = np.stack([paper_world.random_free_places(300, np.random.default_rng(s)) for s in seeds])
    together = RegularizedParticleFilter(paper_world, 0.3, 0.5, particles, [np.random.default_rng(s) for s in seeds])
    alone = [
        RegularizedParticleFilter(paper_world, 0.3, 0.5, p, np.random.default_rng(s))
        for p, s in zip(particles, seeds, strict=True)
    ]
    for k in range(50):
        together.step(np.array([w[k][0] for w in walks]), np.array([w[k][1] for w in walks]))
        for r, filt in enumerate(alone):
            filt.step(*walks[r][k])
    assert together.resampled_at == [filt.resampled_at for filt in alone]
    assert len({len(steps) for steps in together.resampled_at}) > 1 or together.resampled_at[0]


def test_rpf_regularises_when_ess_falls_below_the_threshold(paper_world):
    robot = Robot(0.3, 0.5, (3.5, 1.5))
    result = simulate(robot, paper_world, 0.3, 0.5, 1000, 60, filtering_algorithm="rpf", seed=5, threshold=0.5)
    # it regularises at the start of step k when ESS after step k-1 was below 0.5 N
    low = np.flatnonzero(result.ess[:-1] < 0.5 * 1000) + 1
    assert len(low) > 0
    rpf = RegularizedParticleFilter(paper_world, 0.3, 0.5, paper_world.random_free_places(1000))
    assert rpf.bandwidth == pytest.approx(1000 ** (-1 / 6))  # A = (4/4)^(1/6) = 1 in two dimensions


# -- the APF: the second-stage weight ---------------------------------------------------------------
def test_the_apfs_second_stage_weight_is_the_likelihood_ratio(paper_world):
    """Algorithm 5 with mu_i one draw of the transition: x^j ~ p(x_k | x^{i^j}) and w^j = p(z | x^j) /
    p(z | mu^{i^j}). Computed here independently: the same draws replayed from a copy of the filter's
    Generator, in the order the step makes them (mu's headings, the resampling offset, x's headings)."""
    count, compass, z, delta = 400, 0.7, 1.3, 0.5
    start = paper_world.random_free_places(count, np.random.default_rng(5)).astype(np.float32)
    rng = np.random.default_rng(6)
    replay = np.random.default_rng(6)
    apf = AuxiliaryParticleFilter(paper_world, 0.3, delta, start, rng)
    apf.step(compass, z)

    def moved(points, uniforms):
        headings = (uniforms - np.float32(0.5)) * np.float32(delta) + np.float32(compass)
        return points + ROBOT_SPEED * np.column_stack([np.cos(headings), np.sin(headings)])

    mu = moved(start.astype(float), replay.random(count, dtype=np.float32).astype(float))
    first = log_likelihood(z, mu, paper_world, 0.3)
    w_first = np.exp(first - first.max())
    w_first /= w_first.sum()
    u = replay.random()  # systematic resampling: ancestors from one offset
    ancestors = np.searchsorted(np.cumsum(w_first), (np.arange(count) + u) / count, side="right")
    x = moved(start.astype(float)[ancestors], replay.random(count, dtype=np.float32).astype(float))
    log_w = log_likelihood(z, x, paper_world, 0.3) - first[ancestors]  # p(z | x^j) / p(z | mu^{i^j})
    expected = np.exp(log_w - log_w.max())
    expected /= expected.sum()
    np.testing.assert_allclose(apf.positions, x, atol=1e-4)
    np.testing.assert_allclose(apf.weights, expected, rtol=2e-3, atol=1e-9)


def test_without_compass_noise_the_apfs_second_stage_weights_are_equal(paper_world):
    """With Delta = 0 the move is deterministic, so x^j = mu^{i^j} and every ratio p(z|x^j) / p(z|mu^{i^j})
    is 1: the weights after the step are uniform (without the division they would be p(z | x^j))."""
    particles = paper_world.random_free_places(500, np.random.default_rng(8))
    apf = AuxiliaryParticleFilter(paper_world, 0.3, 0.0, particles, np.random.default_rng(9))
    apf.step(0.4, 1.1)
    np.testing.assert_allclose(apf.weights, 1 / 500, rtol=1e-5)


# -- convergence, degenerate runs ----------------------------------------------------------------------
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
