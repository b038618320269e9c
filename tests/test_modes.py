"""Modes of a weighted cloud (mazelab.modes), the mode estimate, the RPF's bandwidths
(mazelab.regularisation) and the modes drawn in Rerun."""

from __future__ import annotations

import csv
import math

import numpy as np
import pytest
from conftest import PAPER_MAZE, ROOT
from test_visualization import load

from mazelab.cli.app import main
from mazelab.filters import RegularizedParticleFilter, SIRParticleFilter
from mazelab.grid_filter import GridBayesFilter
from mazelab.maze import Maze
from mazelab.modes import cluster_labels, find_modes, label_components
from mazelab.regularisation import (
    MIN_CLUSTER_VARIANCE,
    MIXTURE_SHRINK,
    check_bandwidth,
    mixture_kernel,
    optimal_bandwidth,
)
from mazelab.robot import Robot
from mazelab.simulation import simulate
from mazelab.viz.style import MODE_DRAWN_SHARE, MODE_MIN_RADIUS, entity_name


# -- clusters ---------------------------------------------------------------------------------------
def test_connected_bins_are_one_component_and_diagonal_neighbours_touch():
    occupied = np.array(
        [
            [1, 1, 0, 0, 1],
            [0, 1, 0, 0, 1],
            [0, 0, 1, 0, 0],  # touches the first component diagonally
            [1, 0, 0, 0, 1],
        ],
        dtype=bool,
    )
    expected = [[0, 0, -1, -1, 1], [-1, 0, -1, -1, 1], [-1, -1, 0, -1, -1], [2, -1, -1, -1, 3]]
    np.testing.assert_array_equal(label_components(occupied), expected)


def test_a_long_winding_corridor_is_one_component():
    snake = np.zeros((41, 41), dtype=bool)
    snake[::4, :] = True
    for row in range(0, 40, 4):  # join row r to row r + 4 at alternate ends
        snake[row : row + 4, 40 if (row // 4) % 2 == 0 else 0] = True
    labels = label_components(snake)
    assert labels.max() == 0 and (labels[snake] == 0).all() and (labels[~snake] == -1).all()


def test_find_modes_is_exact_on_a_constructed_cloud():
    """Three groups of points, each inside one bin, two groups in touching bins: two modes whose
    weights, means and spreads follow by hand."""
    a = np.array([[1.1, 1.1], [1.3, 1.1], [1.1, 1.3], [1.3, 1.3]])  # bin (2, 2), mean (1.2, 1.2)
    b = np.array([[1.6, 1.2], [1.8, 1.2]])  # bin (3, 2): touches a's bin
    c = np.array([[5.2, 5.2], [5.4, 5.4]])  # far away
    points = np.vstack([a, b, c])
    weights = np.array([0.1, 0.1, 0.1, 0.1, 0.15, 0.15, 0.2, 0.1])
    modes = find_modes(points, weights)
    assert len(modes) == 2
    first, second = modes
    assert first.weight == pytest.approx(0.7, abs=1e-12) and second.weight == pytest.approx(0.3, abs=1e-12)
    mean_ab = (weights[:6] @ points[:6]) / 0.7
    np.testing.assert_allclose(first.mean, mean_ab, atol=1e-12)
    variance = weights[:6] @ ((points[:6] - mean_ab) ** 2).sum(axis=1) / 0.7
    assert first.spread == pytest.approx(math.sqrt(variance), abs=1e-9)
    np.testing.assert_allclose(second.mean, (0.2 * c[0] + 0.1 * c[1]) / 0.3, atol=1e-12)
    labels, count = cluster_labels(points)  # unweighted: the bins that hold a point
    assert count == 2 and labels.tolist() == [0, 0, 0, 0, 0, 0, 1, 1]


def test_light_bins_belong_to_no_mode():
    points = np.array([[0.2, 0.2], [3.2, 0.2], [1.7, 0.2]])  # the middle point would not join them anyway
    weights = np.array([0.5, 0.5 - 1e-6, 1e-6])
    modes = find_modes(points, weights, min_mass=1e-4)
    assert len(modes) == 2 and sum(m.weight for m in modes) == pytest.approx(1 - 1e-6, abs=1e-12)


def test_the_grid_filters_binned_modes_equal_the_generic_ones():
    world = Maze(PAPER_MAZE)
    grid = GridBayesFilter(world, 0.3, 0.5)
    for angle, z in [(0.0, 1.2), (0.0, 1.0), (1.5, 1.4)]:
        grid.step(angle, z)
    fast, generic = grid.modes, find_modes(grid.positions, grid.weights)
    assert len(fast) == len(generic) >= 1
    for f, g in zip(fast, generic, strict=True):
        assert f.weight == pytest.approx(g.weight, abs=1e-9) and f.spread == pytest.approx(g.spread, abs=1e-6)
        np.testing.assert_allclose(f.mean, g.mean, atol=1e-9)


# -- the mode estimate -------------------------------------------------------------------------------
@pytest.fixture
def twin_rooms() -> Maze:
    return Maze.from_file(ROOT / "mazes" / "twin_rooms_6x12.txt")


def test_the_mode_estimate_of_a_two_room_cloud_is_in_the_heavier_room(twin_rooms, rng):
    """60% of the weight around (3.5, 3.5) in the left room, 40% around its twin (9.5, 3.5): the mean
    lies between the rooms (x = 0.6 * 3.5 + 0.4 * 9.5 = 5.9), the mode in the left room."""
    left = rng.normal((3.5, 3.5), 0.15, (600, 2))
    right = rng.normal((9.5, 3.5), 0.15, (400, 2))
    filters = {
        rule: SIRParticleFilter(twin_rooms, 0.3, 0.5, np.vstack([left, right]), estimate=rule)
        for rule in ("mean", "mode")
    }
    mean, mode = filters["mean"].estimate, filters["mode"].estimate
    assert mean[0] == pytest.approx(0.6 * left[:, 0].mean() + 0.4 * right[:, 0].mean(), abs=1e-5)
    np.testing.assert_allclose(mode, left.mean(axis=0), atol=1e-5)
    modes = filters["mode"].modes
    assert [round(m.weight, 12) for m in modes] == [0.6, 0.4]
    assert not filters["mode"].is_confident  # only 60% of the weight lies within 1 of the mode


def test_estimate_is_checked(twin_rooms):
    with pytest.raises(ValueError, match="estimate must be one of mean, mode"):
        simulate(Robot(0.3, 0.5, (0.5, 0.5)), twin_rooms, 0.3, 0.5, 10, 2, estimate="median", seed=1)


# -- the bandwidth -----------------------------------------------------------------------------------
def test_optimal_is_the_default_and_h_opt_as_a_number_repeats_it_bit_for_bit(paper_world):
    def run(**options):
        robot = Robot(0.3, 0.5, (3.5, 1.5))
        return simulate(robot, paper_world, 0.3, 0.5, 400, 40, filtering_algorithm="rpf", seed=3, **options).estimates

    default = run()
    np.testing.assert_array_equal(run(bandwidth="optimal"), default)
    np.testing.assert_array_equal(run(bandwidth=float(optimal_bandwidth(400))), default)
    assert not np.array_equal(run(bandwidth="multimodal"), default)


@pytest.mark.parametrize("bad", ["wide", "0", "-1", "nan", "inf", True])
def test_a_bad_bandwidth_is_one_clear_error(bad):
    with pytest.raises(ValueError, match="bandwidth must be optimal, multimodal or a positive number"):
        check_bandwidth(bad)


def test_the_mixture_kernel_jitters_each_mode_by_its_own_covariance(rng):
    """Cluster c of n_c points gets h_c D_c eps, h_c = MIXTURE_SHRINK h_opt(n_c): the jitter's sample
    variances in c are h_c^2 diag(S_c), within 5 standard errors (a variance estimate from n points has relative
    standard error sqrt(2 / n))."""
    a = rng.normal((2.0, 2.0), (0.2, 0.1), (8000, 2))
    b = rng.normal((9.0, 2.0), (0.05, 0.3), (2000, 2))
    points = np.vstack([a, b])
    eps = rng.standard_normal(points.shape)
    jitter = mixture_kernel(points, eps)
    for cluster in (slice(0, 8000), slice(8000, None)):
        p, j = points[cluster], jitter[cluster]
        n = len(p)
        expected = (MIXTURE_SHRINK * optimal_bandwidth(n)) ** 2 * np.maximum(np.var(p, axis=0), MIN_CLUSTER_VARIANCE)
        np.testing.assert_allclose(np.var(j, axis=0), expected, rtol=5 * math.sqrt(2 / n))


def test_the_multimodal_rpf_follows_the_exact_posterior_mean(paper_world):
    """Once localised, a particle filter's mean is a Monte Carlo estimate of the exact one: its error
    is of order the posterior's spread over sqrt(N_eff). We allow 5 such standard errors per step (the
    resampling of earlier steps inflates the variance beyond 1 / N_eff by a small factor)."""
    robot = Robot(0.3, 0.5, (3.5, 1.5))
    seen: dict[int, tuple] = {}

    def keep(k, robot, filt):
        seen[k] = (filt.ess, math.sqrt(np.trace(np.cov(filt.positions.T, aweights=filt.weights))))

    rpf = simulate(robot, paper_world, 0.3, 0.5, 2000, 80, filtering_algorithm="rpf", seed=2,
                   bandwidth="multimodal", on_step=keep)  # fmt: skip
    particles = rpf.scenario.init_particles_pos
    grid = simulate(robot, paper_world, 0.3, 0.5, None, 80, particles, "grid", seed=2)
    assert grid.converged_at is not None and grid.converged_at < 40
    for k in range(41, 81):
        ess, spread = seen[k]
        distance = float(np.hypot(*(rpf.estimates[k - 1] - grid.estimates[k - 1])))
        assert distance < 5 * spread / math.sqrt(ess) + 0.02, k  # + the grid's own error, ~ its cell size


def test_rpf_bandwidth_option_reaches_the_filter(paper_world):
    rpf = RegularizedParticleFilter(paper_world, 0.3, 0.5, paper_world.random_free_places(100), bandwidth=0.1)
    assert rpf.bandwidth == 0.1 and rpf.settings["bandwidth"] == 0.1


# -- the command line and the study ------------------------------------------------------------------
def test_study_varies_the_bandwidth_and_writes_its_column(tmp_path):
    table = tmp_path / "study.csv"
    args = ["study", "--maze", "paper_5x5", "--filters", "sir,rpf", "--bandwidth", "optimal,multimodal"]
    args += ["--runs", "1", "--steps", "15", "--particles", "200", "--seed", "4", "--workers", "1"]
    assert main([*args, "--estimate", "mode", "--csv", str(table)]) == 0
    rows = list(csv.DictReader(table.open()))
    assert [(r["bandwidth"], r["filter"], r["estimate"]) for r in rows] == [
        ("", "SIRParticleFilter", "mode"),  # SIR declares no bandwidth: an empty cell
        ("optimal", "RegularizedParticleFilter", "mode"),
        ("multimodal", "RegularizedParticleFilter", "mode"),  # SIR takes no bandwidth: it ran once
    ]
    assert rows[1]["mean_error"] != rows[2]["mean_error"]
    assert main([*args, "--bandwidth", "narrow"]) == 2
    assert main([*args, "--estimate", "median"]) == 2
    assert main(["run", "--filter", "sir", "--bandwidth", "multimodal", "--no-viz", "--quiet"]) == 2


# -- drawing -----------------------------------------------------------------------------------------
@pytest.mark.parametrize("name", ["rpf", "grid"])
def test_each_heavy_mode_is_drawn_as_a_circle_with_its_weight(tmp_path, twin_rooms, name):
    path = tmp_path / "modes.rrd"
    drawn: dict[int, list] = {}

    def keep(k, robot, filt):
        drawn[k] = [m for m in filt.modes if m.weight > MODE_DRAWN_SHARE]

    robot = Robot(0.3, 0.5, (3.5, 3.5))
    options = {"resolution": 0.05} if name == "grid" else {"bandwidth": "multimodal"}
    simulate(robot, twin_rooms, 0.3, 0.5, 1000, 25, filtering_algorithm=name, seed=0, visualize=path,
             on_step=keep, **options)  # fmt: skip
    filter_class = GridBayesFilter if name == "grid" else RegularizedParticleFilter
    entity = load(path)[f"/map/{entity_name(filter_class.name)}/modes"]
    assert any(len(modes) >= 2 for modes in drawn.values())  # the twin rooms keep two hypotheses
    for k, modes in drawn.items():
        circles = entity[k]
        np.testing.assert_allclose(circles.get("Ellipses2D:centers", []), [m.mean for m in modes] or [], atol=1e-5)
        radii = [[max(m.spread, MODE_MIN_RADIUS)] * 2 for m in modes]
        np.testing.assert_allclose(circles.get("Ellipses2D:half_sizes", []), radii or [], atol=1e-5)
        assert circles.get("Ellipses2D:labels", []) == [f"{m.weight:.0%}" for m in modes]
