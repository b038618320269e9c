"""The particle filters against the exact answer, with bounds from the mathematics of each check:

- on one walk, the mean of R seeded runs of each filter agrees with the exact grid filter's posterior
  mean within that walk's own Monte Carlo error and the grid's discretisation error;
- the RPF's regularisation moves each resampled particle by h D eps, eps ~ N(0, I_2), D D^T = S the
  weighted covariance of the cloud it resampled (Algorithm 6), no more and no less;
- the APF's first stage draws its ancestors in proportion to W_{k-1} p(z_k | mu_k) (Algorithm 5): the
  previous weights count.

Each uses the filters' public API only (the constructors, step, positions, weights, simulate).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from conftest import PAPER_MAZE

from mazelab.filters import AuxiliaryParticleFilter, RegularizedParticleFilter
from mazelab.grid_filter import GRID_RESOLUTION, GridBayesFilter
from mazelab.maze import Maze
from mazelab.model import ROBOT_SPEED, log_likelihood
from mazelab.robot import Robot
from mazelab.simulation import simulate

PARTICLE_FILTERS = ["sir", "apf", "rpf"]

# -- against the exact grid filter ---------------------------------------------------------------------
# The walk: the lab's sharpest measurement and widest compass error (sigma 0.2, Delta 0.6), where the
# weights matter most; R seeded runs of N particles each, compared from step SETTLED on.
SIGMA, DELTA, STEPS, SETTLED = 0.2, 0.6, 150, 50
RUNS, COUNT = 40, 4000
# A 2-D Gaussian's length |xi| has mean at most s = sqrt(E|xi|^2) (Jensen) and standard deviation at most
# sqrt(1 - 2/pi) s (its mean is concave in the two axes' variances, so smallest, sqrt(2/pi) s, when it lies
# along one axis). A mean of such lengths over steps, however correlated the steps are, has at most the
# mean of their standard deviations: it stays below (1 + 3 sqrt(1 - 2/pi)) s, three standard deviations
# above its mean.
LENGTH_BOUND = 1 + 3 * math.sqrt(1 - 2 / math.pi)


@pytest.fixture(scope="module")
def exact_walk():
    """One seeded walk on the paper's maze and the exact grid filter on it: its posterior means at the
    lab's resolution h and at h / 2 (steps, 2) each; the finer grid's spread and how far its update
    moved the mean, |E[x_k | z_1:k] - E[x_k | z_1:k-1]| (steps,) each."""
    world = Maze(PAPER_MAZE)
    robot = Robot(SIGMA, DELTA, world.random_free_place(np.random.default_rng(7)), rng=np.random.default_rng(70))
    coarse = GridBayesFilter(world, SIGMA, DELTA, resolution=GRID_RESOLUTION)
    fine = GridBayesFilter(world, SIGMA, DELTA, resolution=GRID_RESOLUTION / 2)
    coarse_means, fine_means, spreads, moves = [], [], [], []
    for _ in range(STEPS):
        compass, z = robot.step(world)
        predicted = fine.predict(fine.density, compass).ravel()
        predicted_mean = predicted @ fine.positions / predicted.sum()
        coarse.step(compass, z)
        fine.step(compass, z)
        coarse_means.append(coarse.estimate)
        fine_means.append(fine.estimate)
        spreads.append(math.sqrt(fine.weights @ ((fine.positions - fine.estimate) ** 2).sum(axis=1)))  # sqrt tr S
        moves.append(math.dist(fine.estimate, predicted_mean))
    return world, robot, np.array(coarse_means), np.array(fine_means), np.array(spreads), np.array(moves)


def agreement(estimates: np.ndarray, fine: np.ndarray, coarse: np.ndarray, own_bias: np.ndarray) -> tuple[float, float]:
    """The distance of R runs' mean estimate to the exact posterior mean, and the bound a correct filter
    stays below, both averaged over the steps given.

    Parameters
    ----------
    estimates : array (R, steps, 2)
        Each run's posterior means (map units).
    fine, coarse : arrays (steps, 2)
        The grid filter's posterior means at resolutions h / 2 and h.
    own_bias : array (steps,)
        The filter's own bias allowed at each step (map units; 0 for a consistent filter).

    Returns
    -------
    (distance, bound), map units

    Notes
    -----
    The R runs are independent, so their mean estimate is the filter's expectation plus xi_k, a 2-D
    Gaussian (central limit theorem) with E|xi_k|^2 = s_k^2 = tr C_k / R, C_k the runs' sample
    covariance at step k: this walk's own Monte Carlo error. The grid's scheme is second order in its
    cell size (the arc is spread bilinearly, which keeps its mean exactly, and the likelihood is taken at
    the cell centres, the midpoint rule), so the finer grid's error is a third of its distance to the
    coarser grid's answer (Richardson). So the mean distance stays below that third plus
    LENGTH_BOUND s_k plus the filter's own bias, averaged over the steps.
    """
    runs = len(estimates)
    distance = np.hypot(*(estimates.mean(axis=0) - fine).T)
    monte_carlo = np.sqrt(estimates.var(axis=0, ddof=1).sum(axis=1) / runs)
    discretisation = np.hypot(*(coarse - fine).T) / 3
    return float(distance.mean()), float(discretisation.mean() + LENGTH_BOUND * monte_carlo.mean() + own_bias.mean())


@pytest.mark.slow
@pytest.mark.parametrize("name", PARTICLE_FILTERS)
def test_particle_filters_agree_with_the_exact_grid_filter(exact_walk, name):
    """R = 40 seeded runs of N = 4000 particles on one walk: their mean estimate lies within this walk's
    Monte Carlo error and the grid's discretisation error of the exact posterior mean (`agreement`).
    The SIR's and the APF's own bias is O(1 / N), nothing here. The RPF's is not: its kernel widens the
    cloud's covariance by h^2 S at each regularisation (h = h_opt of N, Algorithm 6), which changes the
    update's gain by a factor of up to 1 + h^2, so it moves the mean by up to h^2 times the update's own
    move of it (taken from the exact filter); that much is allowed it.

    Guards the weights, the proposal, the resampling and the estimate. Measured on the numpy backend
    (distance against bound): the shipped filters 0.0013 / 0.0031 (SIR), 0.0018 / 0.0030 (APF), 0.0025 /
    0.0050 (RPF); each of these mistakes misses the bound by 2 to 9 times: the unweighted mean of the
    particles as the estimate (SIR 0.0280 / 0.0032, RPF 0.0545 / 0.0219), h D doubled in the RPF's kernel
    (0.0164 / 0.0057), the APF's first stage without W_{k-1} (0.0066 / 0.0032)."""
    world, robot, coarse, fine, spreads, moves = exact_walk
    assert spreads[SETTLED:].max() < 0.5, "the grid filter itself should have converged on this walk"
    estimates = np.array(
        [
            simulate(robot, world, SIGMA, DELTA, COUNT, STEPS, filtering_algorithm=name, seed=seed).estimates
            for seed in range(RUNS)
        ]
    )
    own_bias = np.zeros(STEPS)
    if name == "rpf":
        start = world.random_free_places(COUNT, np.random.default_rng(0))
        h = RegularizedParticleFilter(world, SIGMA, DELTA, start).bandwidth
        own_bias = h**2 * moves
    distance, bound = agreement(estimates[:, SETTLED:], fine[SETTLED:], coarse[SETTLED:], own_bias[SETTLED:])
    assert distance < bound, f"{name}: the mean estimate lies {distance:.4f} from the exact mean, bound {bound:.4f}"


# -- the RPF's jitter as applied -----------------------------------------------------------------------
def test_the_rpfs_jitter_is_h_d_eps_around_each_resampled_particle(paper_world):
    """Algorithm 6 moves each resampled particle x^{i*} by h D eps, eps ~ N(0, I_2), D D^T = S the
    weighted covariance of the cloud it resampled. Made visible here: the particles start on the maze's
    free cell centres (1 apart, many copies each) and the compass error is 0, so each move is one known
    shift; a bandwidth h = 0.02 keeps every jitter far below half the spacing, so each particle's ancestor
    is the cloud point nearest to it less the shift. Then e = (h D)^-1 (x - x^{i*}) are N = 4000 draws of
    N(0, I_2): their mean has standard error 1 / sqrt(N) per axis, their covariance's diagonal sqrt(2 / N)
    and its off-diagonal entry 1 / sqrt(N); each must lie within 4 standard errors. Measured: the
    diagonal (1.003, 1.024) against a tolerance of 0.089; with h D doubled where the kernel is built it
    is (4.01, 4.10)."""
    count, h = 4000, 0.02
    centres = np.array([(x + 0.5, y + 0.5) for x in range(paper_world.width) for y in range(paper_world.height)])
    centres = centres[paper_world.is_free(centres[:, 0], centres[:, 1])]
    start = np.repeat(centres, -(-count // len(centres)), axis=0)[:count]
    rpf = RegularizedParticleFilter(
        paper_world, 0.3, 0.0, start, np.random.default_rng(11), threshold=0.9, bandwidth=h
    )  # fmt: skip
    rpf.step(0.3, 1.2)  # every particle moves by the same shift, then is weighted: the cloud to resample
    cloud, weights = np.asarray(rpf.positions, float), np.asarray(rpf.weights, float)
    assert rpf.ess < 0.9 * count, "the weights should have degenerated enough to regularise next step"
    rpf.step(1.1, 1.0)  # regularise (resample, jitter), then move by the shift of compass angle 1.1
    assert rpf.resampled_at == [1] and rpf.reinitialised_at == []
    shift = ROBOT_SPEED * np.array([math.cos(1.1), math.sin(1.1)])
    landed = np.asarray(rpf.positions, float) - shift
    points = np.unique(cloud, axis=0)
    ancestors = points[np.argmin(((landed[:, None, :] - points[None]) ** 2).sum(axis=2), axis=1)]
    jitter = landed - ancestors
    assert np.abs(jitter).max() < 0.25, "a jitter this large would make the ancestors ambiguous"
    mean = weights @ cloud
    covariance = (weights[:, None] * (cloud - mean)).T @ (cloud - mean)  # S, the weighted covariance
    e = np.linalg.solve(h * np.linalg.cholesky(covariance), jitter.T).T  # should be N(0, I_2) draws
    se = 1 / math.sqrt(count)
    assert np.abs(e.mean(axis=0)).max() < 4 * se, f"the jitter is off centre: mean {e.mean(axis=0)}"
    sample = np.cov(e.T)
    np.testing.assert_allclose(np.diag(sample), 1.0, atol=4 * math.sqrt(2) * se, err_msg="jitter's variance")
    assert abs(sample[0, 1]) < 4 * se, f"the jitter's axes are correlated: {sample[0, 1]:.3f}"


# -- the APF's first stage -----------------------------------------------------------------------------
def first_stage_share(
    cloud: np.ndarray, weights: np.ndarray, in_a: np.ndarray, world: Maze, sigma: float, delta: float, step: tuple
) -> tuple[float, float]:
    """The share of the first stage's ancestors that cluster A gets, expected, and its standard error.

    Parameters
    ----------
    cloud, weights : arrays (N, 2), (N,)
        The particles and their normalised weights W_{k-1} before the step.
    in_a : bool array (N,)
        The particles of cluster A.
    world, sigma, delta
        The model the filter runs.
    step : (compass angle, z)

    Returns
    -------
    (share, standard error)

    Notes
    -----
    mu_i ~ p(x_k | x_{k-1}^i) is the arc of radius L around x_{k-1}^i spanning Delta around the compass
    angle, so p_i = p(z_k | mu_i) has its mean and variance over the arc, taken here at 256 headings. The
    share sum_A W_i p_i / sum W_i p_i is a ratio of sums of independent terms: its variance is about
    sum_i W_i^2 var(p_i) (1_A(i) - share)^2 / (sum_i W_i E p_i)^2 (the delta method). Resampling the
    ancestors adds at most share (1 - share) / N (multinomial; systematic resampling adds less).
    """
    compass, z = step
    headings = compass + delta * ((np.arange(256) + 0.5) / 256 - 0.5)
    arcs = cloud[:, None, :] + ROBOT_SPEED * np.stack([np.cos(headings), np.sin(headings)], axis=1)
    p = np.exp(log_likelihood(z, arcs.reshape(-1, 2), world, sigma)).reshape(len(cloud), -1)
    total = weights @ p.mean(axis=1)
    share = weights[in_a] @ p.mean(axis=1)[in_a] / total
    variance = (weights**2 * p.var(axis=1) * (in_a - share) ** 2).sum() / total**2
    return float(share), math.sqrt(variance + share * (1 - share) / len(cloud))


def test_the_apfs_first_stage_draws_ancestors_by_their_previous_weights(paper_world):
    """Algorithm 5's first stage draws ancestor i with probability W_{k-1}^i p(z_k | mu_i) (normalised).
    A hand-made case where W_{k-1} decides it: half the particles start at B = (1, 4), a station, so
    every move of step 1 (downwards) ends at distance L from it and their weights after step 1 are all
    equal; the other half start at A = (3.2, 1.2), where the same arc crosses z_1 = L only near its
    middle, so with sigma = 0.03 A's particles after step 1 weigh from under 1e-5 to 84 times a B particle,
    most of them under a tenth. Step 2's z_2 is explained mostly (94% of A's p(z_2 | mu)) by A's light
    particles, which only the previous weights hold back. From the cloud after step 1 (positions, weights) the share
    of step 2's particles descended from A is predicted with W_{k-1} and without it
    (`first_stage_share`); the filter's share must lie within 4 standard errors of the first, and the
    case is made so that the two predictions lie far more apart than that (about 0.035 against 0.175,
    standard error 0.005)."""
    a, b, sigma, delta, count = np.array([3.2, 1.2]), np.array([1.0, 4.0]), 0.03, math.pi / 2, 2000
    start = np.repeat([a, b], count // 2, axis=0)
    apf = AuxiliaryParticleFilter(paper_world, sigma, delta, start, np.random.default_rng(3))
    apf.step(-math.pi / 2, ROBOT_SPEED)
    cloud, weights = np.asarray(apf.positions, float), np.asarray(apf.weights, float)

    def nearer_a(points: np.ndarray) -> np.ndarray:
        return np.hypot(*(points - a).T) < np.hypot(*(points - b).T)

    step = (0.0, 0.3)
    share, se = first_stage_share(cloud, weights, nearer_a(cloud), paper_world, sigma, delta, step)
    unweighted, se_unweighted = first_stage_share(
        cloud, np.full(count, 1 / count), nearer_a(cloud), paper_world, sigma, delta, step
    )
    assert abs(unweighted - share) > 8 * max(se, se_unweighted), "W_{k-1} should decide this case"
    apf.step(*step)
    assert apf.reinitialised_at == []
    drawn = nearer_a(np.asarray(apf.positions, float)).mean()
    assert abs(drawn - share) < 4 * se, (
        f"{drawn:.4f} of the ancestors came from A; W_(k-1) p(z | mu) gives {share:.4f} +- {se:.4f}, "
        f"p(z | mu) alone {unweighted:.4f}"
    )
