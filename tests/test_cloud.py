"""What every particle filter of the registry shares (ParticleFilter on mazelab.smc), each rule on its own:

- its ESS is 1 / sum_i W_i^2 of the weights it holds, for one run and per run of R;
- the engine restarts a run that no particle explains from the prior, weighted by that run's own z;
- the green circle (`is_confident`) counts weight within distance 1 of the estimate, not particles;
- each particle keeps the heading of its last move (the transition).
"""

from __future__ import annotations

import numpy as np
import pytest
from conftest import recorded_walk

from mazelab.constants import CONFIDENCE_SHARE
from mazelab.filters import ParticleFilter, SIRParticleFilter
from mazelab.registry import entries
from mazelab.resampling import RESAMPLING_SCHEMES
from mazelab.weights import Weights

PARTICLE_FILTERS = [entry.filter_class for entry in entries() if issubclass(entry.filter_class, ParticleFilter)]


# -- the effective sample size: N_eff = 1 / sum_i W_i^2 (Arulampalam et al., eq. 51) -----------------------
@pytest.mark.parametrize("cls", PARTICLE_FILTERS)
def test_the_ess_is_one_over_the_sum_of_the_squared_normalised_weights(paper_world, cls):
    """Known weights (1/2, 1/4, 1/4) give 1 / (1/4 + 1/16 + 1/16) = 8/3, for one run and per run of R;
    after real steps the ESS is that of the weights the filter holds, computed here independently."""
    one = cls(paper_world, 0.3, 0.5, np.full((3, 2), 2.5), np.random.default_rng(1))
    one.log_weights = np.log([0.5, 0.25, 0.25])
    assert one.ess == pytest.approx(8 / 3, rel=1e-12) and isinstance(one.ess, float)
    two = cls(paper_world, 0.3, 0.5, np.full((2, 3, 2), 2.5), [np.random.default_rng(1), np.random.default_rng(2)])
    two.log_weights = np.log([[0.5, 0.25, 0.25], [1 / 3, 1 / 3, 1 / 3]])
    np.testing.assert_allclose(two.ess, [8 / 3, 3.0], rtol=1e-12)
    filt = cls(paper_world, 0.3, 0.5, paper_world.random_free_places(400, np.random.default_rng(3)),
               np.random.default_rng(4))  # fmt: skip
    for compass, z in recorded_walk(paper_world, 5, 12):
        filt.step(compass, z)
        weights = np.exp(np.asarray(filt.log_weights, dtype=float))
        assert weights.sum() == pytest.approx(1.0, rel=1e-5)  # normalised in float32 arithmetic
        assert filt.ess == pytest.approx(1.0 / np.sum(weights**2), rel=1e-9)


# -- a restart: from the prior, weighted by the run's own z ---------------------------------------------
@pytest.mark.parametrize("cls", PARTICLE_FILTERS)
def test_a_run_that_restarts_weights_the_prior_by_its_own_measurement(paper_world, cls):
    """No particle explains z_k (here 50, beyond any station of the 5x5 maze): that run, and only it,
    restarts from the prior with W_i proportional to p(z_k | x_i) of its own z_k (not another run's)."""
    seeds = (3, 4, 5)
    particles = np.stack([paper_world.random_free_places(200, np.random.default_rng(s)) for s in seeds])
    filt = cls(paper_world, 0.3, 0.5, particles, [np.random.default_rng(s) for s in seeds])
    filt.step(np.zeros(3), np.array([1.0, 1.0, 1.0]))
    filt.step(np.zeros(3), np.array([1.0, 50.0, 1.0]))
    assert filt.reinitialised_at == [[], [2], []]
    # run 1's fresh prior weighted by p(50 | x), which underflows everywhere: uniform (z = 1 would not be)
    np.testing.assert_allclose(filt.weights[1], 1 / 200, rtol=1e-12)
    assert not np.allclose(filt.weights[0], 1 / 200)
    filt.step(np.zeros(3), np.array([1.0, 1.0, 1.0]))
    filt.step(np.zeros(3), np.array([1.2, 1.5, 50.0]))
    assert filt.reinitialised_at == [[], [2], [4]]
    np.testing.assert_allclose(filt.weights[2], 1 / 200, rtol=1e-12)


# -- the green circle: weight, not particles --------------------------------------------------------
def cloud(world, near: int, far: int, near_weight: float) -> SIRParticleFilter:
    """`near` particles at (2, 2) sharing `near_weight`, `far` at (4.5, 4.5) sharing the rest."""
    positions = np.array([[2.0, 2.0]] * near + [[4.5, 4.5]] * far)
    filt = SIRParticleFilter(world, 0.3, 0.5, positions, np.random.default_rng(0))
    weights = np.r_[np.full(near, near_weight / near), np.full(far, (1 - near_weight) / far)]
    filt.log_weights = np.log(weights)
    return filt


def test_the_green_circle_counts_the_weight_within_one_not_the_particles(paper_world):
    """95% of the weight within distance 1 of the estimate: 90 of 100 particles holding 96% of the
    weight is confident; 97 of 100 holding 90% is not."""
    heavy = cloud(paper_world, 90, 10, 0.96)
    assert np.hypot(*(heavy.estimate - 2.0)) < 1 and heavy.is_confident
    light = cloud(paper_world, 97, 3, 0.90)
    assert np.hypot(*(light.estimate - 2.0)) < 1 and not light.is_confident
    assert CONFIDENCE_SHARE == 0.95


# -- the transition ---------------------------------------------------------------------------------
def test_particles_keep_their_last_heading(paper_world, rng):
    sir = SIRParticleFilter(paper_world, 0.3, 0.2, paper_world.random_free_places(500, rng), rng)
    sir.step(1.0, 1.0)
    assert np.all(np.abs(sir.headings - 1.0) <= 0.1)


@pytest.mark.parametrize("scheme", ["systematic", "stratified", "residual"])
def test_the_steps_resampling_hook_is_the_textbook_scheme_applied_to_each_run(paper_world, scheme):
    """SMC.step -> SMC.ancestors -> mazelab.resampling's scheme: for R runs, run r's ancestors are the
    scheme's of row r with run r's Generator (on the compiled backend systematic runs in its counting
    form, which must give the very same ancestors); a run not due keeps its own particles."""
    runs, count = 3, 64
    particles = np.stack([paper_world.random_free_places(count, np.random.default_rng(s)) for s in range(runs)])
    filt = SIRParticleFilter(paper_world, 0.3, 0.5, particles, [np.random.default_rng(10 + r) for r in range(runs)],
                             resampling=scheme)  # fmt: skip
    W = np.random.default_rng(5).dirichlet(np.full(count, 0.3), size=runs)
    textbook = RESAMPLING_SCHEMES[scheme]
    expected = [textbook(W[r], np.random.default_rng(10 + r)) for r in range(runs)]
    np.testing.assert_array_equal(filt.ancestors(Weights(np.log(W)), np.ones(runs, dtype=bool)), expected)
    due = np.array([False, True, False])  # the Generators of runs 0 and 2 untouched: 1 draws its own again
    filt.rngs[1] = np.random.default_rng(11)
    expected[0], expected[2] = np.arange(count), np.arange(count)
    np.testing.assert_array_equal(filt.ancestors(Weights(np.log(W)), due), expected)
