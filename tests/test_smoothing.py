"""The exact smoother (mazelab.smoothing): the forward-backward pass on the grid equals a brute-force sum
over every path of cells of the discretised model, its backward step is the prediction's adjoint, the
smoothed density at the last step is the filtered one, checkpoints change no number, and on seeded walks
the smoothed mean is nearer the truth than the filtered mean."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
from conftest import PAPER_MAZE, recorded_walk

from mazelab import checks
from mazelab.checks import MemoryBudget, MemoryLimitError
from mazelab.constants import OUTSIDE_PENALTY
from mazelab.grid_filter import GridBayesFilter, arc_kernel
from mazelab.learning import grid_log_evidence
from mazelab.maze import Maze, load_maze
from mazelab.model import ROBOT_SPEED
from mazelab.registry import filter_entry
from mazelab.robot import Robot
from mazelab.scenario import find_scenario, load_scenario
from mazelab.smoothing import BackwardStep, Genealogy, score_smoothers, smooth

TINY = Maze([[2, 0], [0, 0]])
TINY_MODEL = {"sigma": 0.4, "delta": 0.6}
TINY_GRID = {"resolution": 0.5, "margin": 0.5, "speed": 0.5}  # 6 x 6 cells, one cell a step
TINY_WALK = ([0.3, 2.0, -1.2], [0.6, 0.9, 0.4])  # compass angles, measurements (any data has a posterior)


def enumerated_marginals(world, sigma, delta, angles, zs, resolution, margin, speed):
    """p(x_k = cell | z_1:K) for k = 1..K and log p(z_1:K), summed over every path (x_0, ..., x_K) of cells of
    the discretised model apart from the smoother: the prior uniform on the free cells, the transition
    T_k[i, j] = arc kernel of th0_k at the offset from cell i to cell j (mass leaving the grid is lost), the
    likelihood the Gaussian of the distance to the nearest station at the cell's centre, times the outside
    penalty off the free area."""
    n = round((world.width + 2 * margin) / resolution)
    centres = -margin + (np.arange(n) + 0.5) * resolution
    rows, cols = np.divmod(np.arange(n * n), n)  # cell index = row (y) * n + column (x)
    x, y = centres[cols], centres[rows]
    free = world.is_free(x, y)
    prior = free / free.sum()
    distance = world.distance_to_nearest_station(np.column_stack([x, y]))
    transitions, likelihoods = [], []
    for compass_angle, z in zip(angles, zs, strict=True):
        kernel = arc_kernel(compass_angle, delta, speed, resolution)
        r = kernel.shape[0] // 2
        T = np.zeros((n * n, n * n))
        for i, j in itertools.product(range(n * n), repeat=2):
            dy, dx = rows[j] - rows[i], cols[j] - cols[i]
            if abs(dy) <= r and abs(dx) <= r:
                T[i, j] = kernel[dy + r, dx + r]
        transitions.append(T)
        gaussian = np.exp(-0.5 * ((z - distance) / sigma) ** 2) / (sigma * math.sqrt(2 * math.pi))
        likelihoods.append(gaussian * np.where(free, 1.0, OUTSIDE_PENALTY))
    # the joint weight of every path: an array with one axis per x_0..x_K (36^4 paths for K = 3)
    joint = prior.reshape((-1,) + (1,) * len(angles))
    for k, (T, lik) in enumerate(zip(transitions, likelihoods, strict=True)):
        shape = (1,) * k + (n * n, n * n) + (1,) * (len(angles) - k - 1)
        joint = joint * (T * lik[None, :]).reshape(shape)
    total = joint.sum()
    axes = range(len(angles) + 1)
    marginals = [joint.sum(axis=tuple(a for a in axes if a != k)) / total for k in range(1, len(angles) + 1)]
    return marginals, math.log(total)


def smoothed_densities(*walk, **options):
    """smooth's answer and every step's smoothed density (step -> a copy of what it hands `visit`)."""
    densities = {}
    result = smooth(*walk, visit=lambda k, density: densities.__setitem__(k, density.copy()), **options)
    return result, densities


def test_the_smoother_and_the_grid_evidence_equal_the_enumeration_of_every_path_of_the_discretised_model():
    angles, zs = TINY_WALK
    expected, log_evidence = enumerated_marginals(TINY, *TINY_MODEL.values(), angles, zs, **TINY_GRID)
    result, densities = smoothed_densities(TINY, *TINY_MODEL.values(), angles, zs, **TINY_GRID)
    positions = GridBayesFilter(TINY, *TINY_MODEL.values(), **TINY_GRID).positions  # the cells, as a density ravels
    for k in (1, 2, 3):
        # the same sums in another order: float64 round-off, far below any mass that matters
        np.testing.assert_allclose(densities[k].ravel(), expected[k - 1], rtol=0, atol=1e-12)
        assert result.means[k - 1] == pytest.approx(expected[k - 1] @ positions, abs=1e-12)
    evidence = grid_log_evidence(TINY, angles, zs, *TINY_MODEL.values(), **TINY_GRID)  # the exact parameter posterior's
    assert evidence == pytest.approx(log_evidence, abs=1e-12)


def test_the_backward_step_is_the_adjoint_of_the_prediction(rng):
    """<P f, g> = <f, P^T g> for any f, g on the grid, with the step's own compass angle."""
    grid = GridBayesFilter(Maze(PAPER_MAZE), 0.3, 0.5, resolution=0.1)
    f, g = rng.random(grid.shape), rng.random(grid.shape)
    for compass_angle in (0.4, 2.5):
        backward = BackwardStep(grid)
        forward = grid.predict(f, compass_angle)
        assert np.vdot(forward, g) == pytest.approx(np.vdot(f, backward.adjoint(g, compass_angle)), rel=1e-12)


def test_the_smoothed_density_at_the_last_step_is_the_filtered_one(paper_world):
    rng = np.random.default_rng(4)
    robot = Robot(0.3, 0.5, paper_world.random_free_place(rng), rng=rng)
    walk = [robot.step(paper_world) for _ in range(7)]
    angles, zs = zip(*walk, strict=True)
    result, densities = smoothed_densities(paper_world, 0.3, 0.5, angles, zs, resolution=0.1)
    grid = GridBayesFilter(paper_world, 0.3, 0.5, resolution=0.1)
    for compass_angle, z in walk:
        grid.step(compass_angle, z)
    np.testing.assert_allclose(densities[7], grid.density, rtol=1e-12, atol=0)
    np.testing.assert_allclose(result.means[-1], grid.mean, rtol=1e-12)


@pytest.mark.parametrize("checkpoint_every", [1, 3, 7])
def test_checkpoints_and_recomputation_change_no_number(paper_world, checkpoint_every):
    """Every B: the refiltered densities are the forward pass's bit for bit, so the answer is the same as
    keeping every filtered density (B = K)."""
    walk = TINY_WALK[0] * 3, [1.0, 0.5, 0.8] * 3
    whole, every = smoothed_densities(paper_world, 0.3, 0.5, *walk, checkpoint_every=9, resolution=0.1)
    blocks, visited = smoothed_densities(paper_world, 0.3, 0.5, *walk, checkpoint_every=checkpoint_every,
                                         resolution=0.1)  # fmt: skip
    np.testing.assert_array_equal(blocks.means, whole.means)
    assert list(visited) == list(range(9, 0, -1))  # every step's smoothed density, from the last one back
    for k in range(1, 10):
        np.testing.assert_array_equal(visited[k], every[k])


def test_the_smoothed_mean_is_nearer_the_truth_than_the_filtered_mean_in_nine_of_ten_walks(paper_world):
    """The smoothed mean E[x_k | z_1:K] has the least expected squared error of any estimate from all the
    measurements, the filtered one only from those up to k; on the paper's maze the early steps of a
    global localisation are many-moded for the filter and not for the smoother, so the walk's mean error
    is smaller smoothed in (almost) every seeded walk: the issue asks at least 9 of 10."""
    wins = 0
    for seed in range(10):
        rng = np.random.default_rng(seed)
        robot = Robot(0.3, 0.5, paper_world.random_free_place(rng), rng=rng)
        walk = [robot.step(paper_world) + robot.position for _ in range(30)]
        angles, zs, xs, ys = (np.array(column) for column in zip(*walk, strict=True))
        result = smooth(paper_world, 0.3, 0.5, angles, zs, resolution=0.05)
        smoothed, filtered = (np.hypot(*(means - np.column_stack([xs, ys])).T) for means in
                              (result.means, result.filtered_means))  # fmt: skip
        wins += smoothed.mean() < filtered.mean()
    assert wins >= 9


def test_a_smoothing_that_does_not_fit_in_memory_is_refused_saying_how_much_it_needs(paper_world, monkeypatch):
    """The grid (70 x 70 cells, 1.2 MB for the filter) fits a 4 MB budget; 10,000 steps' checkpoints and
    one block (100 + 100 grids of 38 kB) do not."""
    monkeypatch.setattr(checks, "memory_budget", lambda: MemoryBudget(5 * 2**20, "test budget"))
    with pytest.raises(MemoryLimitError, match=r"^smoothing 10000 steps on the grid's 70x70 cells \(203 grids\) needs"):
        smooth(paper_world, 0.3, 0.5, [0.1] * 10_000, [1.0] * 10_000, resolution=0.1)


def test_bad_walks_are_refused_in_one_line(paper_world):
    with pytest.raises(ValueError, match="one measurement per compass angle"):
        smooth(paper_world, 0.3, 0.5, [0.1, 0.2], [1.0], resolution=0.1)
    with pytest.raises(ValueError, match="checkpoint_every must be a step number"):
        smooth(paper_world, 0.3, 0.5, [0.1], [1.0], checkpoint_every=0, resolution=0.1)
    with pytest.raises(ValueError, match="no cell of the grid explains z_2"):
        smooth(paper_world, 0.3, 0.05, [0.1, 0.2], [1.0, 900.0], resolution=0.1)


# -- the particle smoothers (Genealogy), against the filters' own steps and the exact smoother ------------
PARTICLE_FILTERS = ("sir", "apf", "rpf")


def recorded_run(world, walk, filter_name, lag=4, count=300, seed=5, **options):
    """One seeded filter over a walk ((compass angle, z) pairs), its Genealogy (lag, options), and its mean
    after each step: (genealogy, means (K, 2))."""
    genealogy = Genealogy(lag, **options)
    rng = np.random.default_rng(seed)
    filt = filter_entry(filter_name).filter_class(world, 0.3, 0.5, world.random_free_places(count, rng), rng)
    means = []
    for compass_angle, z in walk:
        filt.step(compass_angle, z)
        means.append(filt.mean)
        genealogy.record(filt)
    return genealogy.finish(), np.array(means)


@pytest.mark.parametrize("filter_name", ["sir", "apf"])
def test_the_path_smoother_follows_each_particles_lineage_back_through_the_engines_ancestry(paper_world, filter_name):
    """Each traced path moves exactly L (ROBOT_SPEED) a step, as the arc motion moves a particle from its
    ancestor (float32 positions: 1e-5 map units); a wrong ancestor lies anywhere else in the cloud."""
    genealogy, _ = recorded_run(paper_world, recorded_walk(paper_world, 3, 25), filter_name, clouds=True)
    traced = np.array([genealogy.clouds["path"][k][0].astype(float) for k in range(1, 26)])
    steps = np.hypot(*np.diff(traced, axis=0).transpose(2, 0, 1))  # from step k - 1 to step k
    np.testing.assert_allclose(steps, ROBOT_SPEED, atol=1e-5)


@pytest.mark.parametrize("filter_name", PARTICLE_FILTERS)
def test_the_fixed_lag_smoother_is_the_path_smoother_of_the_walk_cut_lag_steps_later(paper_world, filter_name):
    """Lag 0 is the filter's mean at every step; the path smoother at K is the filter's mean at K; the
    fixed-lag estimate of step k is the path smoother's of the same seeded run stopped at step k + L."""
    walk, lag = recorded_walk(paper_world, 4, 20), 4
    genealogy, means = recorded_run(paper_world, walk, filter_name, lag)
    filtered, fixed, path = (genealogy.means[name] for name in ("filter", "lag", "path"))
    filters_mean = np.array([filtered[k][0] for k in range(1, 21)])
    np.testing.assert_allclose(filters_mean, means, atol=1e-6)  # the kernels sum float32 positions: 1e-6 map units
    np.testing.assert_allclose(path[20][0], means[-1], atol=1e-6)
    for k in (1, 9, 16):
        cut, _ = recorded_run(paper_world, walk[: k + lag], filter_name, lag)
        assert np.array_equal(fixed[k], cut.means["path"][k])
    distinct = genealogy.distinct["path"]
    assert distinct[1][0] < distinct[19][0] <= 300  # the path degeneracy: fewer ancestors further back


def test_a_run_restarted_from_the_prior_is_traced_from_the_step_before_its_restart(paper_world):
    """At a restart no particle has an ancestor: the steps before it are the path smoother's of the walk
    stopped the step before (its own particles and weights)."""
    walk = recorded_walk(paper_world, 6, 12)
    walk[7] = (walk[7][0], 40.0)  # nothing in the maze lies 40 from a station: the filter restarts at step 8
    path, _ = recorded_run(paper_world, walk, "sir")
    before, _ = recorded_run(paper_world, walk[:7], "sir")
    for k in range(1, 8):
        assert np.array_equal(path.means["path"][k], before.means["path"][k])


@pytest.mark.parametrize("filter_name", ["sir", "apf"])
def test_the_particle_smoothers_agree_with_the_exact_smoother_within_their_monte_carlo_error(filter_name):
    """On the paper's saved walk (1500 particles): the path smoother's mean at step k lies within 4
    spread_k / sqrt(D_k) of the exact smoothed mean (the error of an average of D_k draws from the smoothed
    posterior, D_k the distinct ancestors it rests on) plus one grid cell (the exact smoother's own error);
    over the walk the path smoother is nearer the exact smoothed posterior than the filter is, in mean and
    in total variation."""
    stored = load_scenario(find_scenario("paper_5x5"))
    world = stored.world() or load_maze("paper_5x5")
    particles, grid = stored.init_particles_pos, {"resolution": 0.05}
    scores = score_smoothers(world, stored.robot(), stored.sigma, stored.delta, [filter_name], lag=10, seed=1,
                             initial_particles=particles, grid_options=grid)  # fmt: skip
    rows, spreads = scores.rows, scores.exact.spreads
    assert [row["step"] for row in rows] == list(range(1, 201))
    for row in rows:
        bound = 4 * spreads[row["step"] - 1] / math.sqrt(row["path_ancestors"]) + 0.05
        assert row["path_error"] < bound, row
    for what in ("error", "tv"):
        assert np.mean([r[f"path_{what}"] for r in rows]) < np.mean([r[f"filter_{what}"] for r in rows])


def test_a_particle_smoother_needs_particles_and_measurements(paper_world):
    robot = Robot(0.3, 0.5, (0.5, 0.5), actual_angles=[0.1], compass_angles=[0.1])
    with pytest.raises(ValueError, match=r"^a particle smoother needs a filter's genealogy: grid keeps no particles$"):
        score_smoothers(paper_world, robot, 0.3, 0.5, ["grid"])
    with pytest.raises(ValueError, match=r"^smoothing needs the walk's measurements: the scenario stores none"):
        score_smoothers(paper_world, robot, 0.3, 0.5, ["sir"])


def test_a_genealogy_that_does_not_fit_in_memory_is_refused_saying_how_much_it_needs(paper_world, monkeypatch):
    monkeypatch.setattr(checks, "memory_budget", lambda: MemoryBudget(10**9, "a test's budget"))
    robot = Robot(
        0.3, 0.5, (0.5, 0.5), actual_angles=[0.1] * 1000, compass_angles=[0.1] * 1000, measurements=[1.0] * 1000
    )
    with pytest.raises(MemoryLimitError, match=r"^the genealogy of 1000 steps of 100000 particles .* needs about 2\.2"):
        score_smoothers(paper_world, robot, 0.3, 0.5, ["sir"], particle_count=100_000)
