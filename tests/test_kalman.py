"""The extended Kalman filter: its exact motion moments, the textbook update, the free area's prior,
tracking from the known start, and its place in the CLI, the experiments and the viewer."""

from __future__ import annotations

import math

import numpy as np
import pytest
from test_visualization import load

from mazelab.cli.app import main
from mazelab.declaration import options_of
from mazelab.kalman import (
    START_STD,
    ExtendedKalmanFilter,
    arc_moments,
    covariance_ellipse,
    free_area_moments,
    gaussian_mass_within,
    kalman_update,
)
from mazelab.maze import Maze, load_maze
from mazelab.model import (
    CONFIDENCE_RADIUS,
    LAB_DELTA_RANGE,
    LAB_SIGMA_RANGE,
    ROBOT_SPEED,
    Sensor,
    headings_from_uniforms,
    move,
)
from mazelab.registry import filter_entry
from mazelab.robot import Robot
from mazelab.simulation import simulate
from mazelab.viz.style import COVARIANCE_SIGMAS, entity_name

SAMPLES = 400_000


# -- the motion moments ----------------------------------------------------------------------------
@pytest.mark.parametrize(("theta", "delta"), [(0.3, 0.5), (2.0, 0.05), (-1.0, 0.6), (4.0, 2 * math.pi)])
def test_q_is_the_covariance_of_the_sampled_arc(theta, delta):
    """The model's own sampler (headings_from_uniforms, move) against arc_moments."""
    headings = headings_from_uniforms(np.random.default_rng(1).random(SAMPLES), theta, delta)
    steps = move(np.zeros((SAMPLES, 2)), headings)
    assert_sample_moments(steps, *arc_moments(theta, delta, ROBOT_SPEED))


def assert_sample_moments(sample: np.ndarray, mean: np.ndarray, covariance: np.ndarray) -> None:
    """Each entry of the sample's mean and covariance lies within 5 of its standard errors (the
    standard deviation of x_i, or of (x_i - m_i)(x_j - m_j), over the sample, / sqrt(n)) of the truth."""
    n = len(sample)
    np.testing.assert_array_less(np.abs(sample.mean(axis=0) - mean), 5 * sample.std(axis=0) / math.sqrt(n) + 1e-15)
    centred = sample - sample.mean(axis=0)
    for i in range(2):
        for j in range(2):
            products = centred[:, i] * centred[:, j]
            assert abs(products.mean() - covariance[i, j]) <= 5 * products.std() / math.sqrt(n) + 1e-15, (i, j)


@pytest.mark.parametrize("delta", [0.0, 1e-4, 0.05, 0.6, math.pi, 2 * math.pi])
def test_q_is_exact_where_it_is_known(delta):
    """Every step has length L, so trace Q = L^2 - |mean|^2; along th0 Q's variance is the tiny
    Delta^4 / 720 L^2 to leading order, across it Delta^2 / 12 L^2; a full circle is isotropic."""
    theta = 0.7
    mean, q = arc_moments(theta, delta, ROBOT_SPEED)
    assert np.trace(q) == pytest.approx(ROBOT_SPEED**2 - mean @ mean, abs=1e-15)
    assert np.allclose(q, q.T) and np.all(np.linalg.eigvalsh(q) >= 0)
    along = np.array([math.cos(theta), math.sin(theta)])
    across = np.array([-math.sin(theta), math.cos(theta)])
    assert along @ q @ across == pytest.approx(0.0, abs=1e-15)
    if delta <= 0.05:
        assert along @ q @ along == pytest.approx(ROBOT_SPEED**2 * delta**4 / 720, rel=1e-3, abs=1e-16)
        assert across @ q @ across == pytest.approx(ROBOT_SPEED**2 * delta**2 / 12, rel=1e-3, abs=1e-16)
    if delta == 2 * math.pi:
        np.testing.assert_allclose(mean, 0.0, atol=1e-15)
        np.testing.assert_allclose(q, ROBOT_SPEED**2 / 2 * np.eye(2), atol=1e-15)


# -- the update ------------------------------------------------------------------------------------
def test_the_update_is_the_textbook_ekf_on_a_hand_computed_case():
    """m = (3, 4), station (0, 0): h = 5, H = (0.6, 0.8); P = diag(1, 2), r = 0.36: S = 0.36 + 1.28 + 0.36
    = 2, K = P H^T / S = (0.3, 0.8); z = 6: innovation 1, m = (3.3, 4.8); P - K H P = [[0.82, -0.48],
    [-0.48, 0.72]] (Joseph's form gives the same for this optimal gain)."""
    world = Maze([[2, 0, 0, 0, 0]] + [[0] * 5] * 4)  # one station block: its nearest corner to (4, 0) is (1, 4)
    expected, h = Sensor(0.6).linearised(world, np.array([4.0, 0.0]))
    assert expected == 5.0 and np.array_equal(h, [0.6, -0.8])
    mean, covariance = kalman_update(np.array([3.0, 4.0]), np.diag([1.0, 2.0]), np.array([0.6, 0.8]), 1.0, 0.36)
    np.testing.assert_allclose(mean, [3.3, 4.8], atol=1e-14)
    np.testing.assert_allclose(covariance, [[0.82, -0.48], [-0.48, 0.72]], atol=1e-14)


def test_the_filter_predicts_and_updates_with_the_station_nearest_its_mean(paper_world):
    ekf = ExtendedKalmanFilter(paper_world, 0.3, 0.5, init="start", start=(3.5, 1.5))
    assert np.allclose(ekf.covariance, START_STD**2 * np.eye(2))
    step, q = arc_moments(1.0, 0.5, ROBOT_SPEED)
    predicted_mean, predicted_covariance = ekf.mean + step, ekf.covariance + q
    ekf.step(1.0, 1.2)
    offset = predicted_mean - paper_world.nearest_station(predicted_mean)
    h = np.hypot(*offset)
    expected = kalman_update(predicted_mean, predicted_covariance, offset / h, 1.2 - h, 0.3**2)
    np.testing.assert_allclose(ekf.estimate, expected[0])
    np.testing.assert_allclose(ekf.covariance, expected[1])
    assert ekf.innovation == pytest.approx(1.2 - h)
    assert math.isnan(ekf.ess) and ekf.count == 1 and ekf.reinitialised_at == []


def test_at_the_station_itself_there_is_no_update(paper_world):
    station = paper_world.stations[0].astype(float)
    assert Sensor(0.3).linearised(paper_world, station) == (0.0, None)
    ekf = ExtendedKalmanFilter(paper_world, 0.3, 0.5)
    ekf.mean, covariance = station.copy(), ekf.covariance.copy()
    ekf.update(0.5)
    assert np.array_equal(ekf.mean, station) and np.array_equal(ekf.covariance, covariance)
    assert math.isnan(ekf.innovation)


# -- the prior and the confidence ------------------------------------------------------------------
def test_the_prior_is_the_free_areas_exact_mean_and_covariance():
    """The free row of this maze is the rectangle [0, 3] x [1, 2]: mean (1.5, 1.5), variances 9/12, 1/12."""
    world = Maze([[0, 0, 0], [2, 1, 2]])
    mean, covariance = free_area_moments(world)
    np.testing.assert_allclose(mean, [1.5, 1.5])
    np.testing.assert_allclose(covariance, np.diag([9 / 12, 1 / 12]), atol=1e-15)
    ekf = ExtendedKalmanFilter(world, 0.3, 0.5)
    assert ekf.settings["init"] == "prior" and np.array_equal(ekf.mean, mean)


def test_the_prior_matches_a_uniform_sample_of_a_shipped_maze():
    world = load_maze("maze_10x10")
    sample = world.random_free_places(SAMPLES, np.random.default_rng(3))
    assert_sample_moments(sample, *free_area_moments(world))


@pytest.mark.parametrize("covariance", [np.diag([0.1, 0.1]), np.diag([0.02, 0.6]), [[0.3, 0.2], [0.2, 0.25]]])
def test_the_gaussian_mass_within_the_radius(covariance):
    covariance = np.asarray(covariance, dtype=float)
    sample = np.random.default_rng(5).multivariate_normal([0, 0], covariance, SAMPLES)
    share = float((np.hypot(*sample.T) <= CONFIDENCE_RADIUS).mean())
    mass = gaussian_mass_within(covariance, CONFIDENCE_RADIUS)
    assert mass == pytest.approx(share, abs=5 * math.sqrt(share * (1 - share) / SAMPLES))
    if covariance[0, 0] == covariance[1, 1] and covariance[0, 1] == 0:  # isotropic: 1 - exp(-r^2 / 2 s^2)
        assert mass == pytest.approx(-math.expm1(-(CONFIDENCE_RADIUS**2) / (2 * covariance[0, 0])), rel=1e-12)
    assert gaussian_mass_within(np.zeros((2, 2)), CONFIDENCE_RADIUS) == 1.0


def test_options_are_checked(paper_world):
    with pytest.raises(ValueError, match="init must be one of prior, start"):
        ExtendedKalmanFilter(paper_world, 0.3, 0.5, init="somewhere")
    with pytest.raises(ValueError, match="needs the robot's start"):
        ExtendedKalmanFilter(paper_world, 0.3, 0.5, init="start")


# -- tracking and global localisation --------------------------------------------------------------
TRACKING_SEEDS = 10


@pytest.mark.parametrize("maze", ["maze_10x10", "twin_rooms_6x12"])
@pytest.mark.parametrize("sigma", LAB_SIGMA_RANGE)
@pytest.mark.parametrize("delta", LAB_DELTA_RANGE)
def test_from_the_known_start_it_tracks_the_robot(maze, sigma, delta):
    """At the corners of the lab's ranges, in at least 9 of 10 seeded runs the mean error over steps
    101-200 stays below 0.5 (measured: 1438 of 1440 runs over the shipped mazes and ranges; a miss is a
    walk along the map's edge, where the range says little across the path and the Gaussian knows no wall)."""
    world = load_maze(maze)
    kept = 0
    for seed in range(TRACKING_SEEDS):
        robot = Robot(sigma, delta, world.random_free_place(np.random.default_rng(seed)))
        result = simulate(robot, world, sigma, delta, 1, 200, filtering_algorithm="ekf", seed=seed, init="start")
        kept += result.errors[100:200].mean() < 0.5
    assert kept >= TRACKING_SEEDS - 1


def test_from_the_prior_it_starts_lost_and_simulate_hands_it_the_start(paper_world):
    robot = Robot(0.3, 0.5, (3.5, 1.5))
    tracking = simulate(robot, paper_world, 0.3, 0.5, 1, 1, filtering_algorithm="ekf", seed=1, init="start")
    lost = simulate(robot, paper_world, 0.3, 0.5, 1, 1, filtering_algorithm="ekf", seed=1)
    assert tracking.errors[0] < 0.3 < lost.errors[0]
    assert not lost.confident[0]


# -- its place among the filters -------------------------------------------------------------------
def test_it_is_registered_and_gets_no_particle_filter_options():
    for name in ["ekf", "EKF", "ExtendedKalmanFilter", "Extended Kalman Filter"]:
        assert filter_entry(name).filter_class is ExtendedKalmanFilter
    assert not any(option in options_of(ExtendedKalmanFilter) for option in ("threshold", "recovery", "kld"))


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--kld"], "ExtendedKalmanFilter does not take --kld"),
        (["--recovery"], "ExtendedKalmanFilter does not take --recovery"),
        (["--resampling", "residual"], "ExtendedKalmanFilter does not take --resampling"),
        (["--init", "somewhere"], "init must be one of prior, start, got 'somewhere'"),
    ],
)
def test_the_cli_refuses_particle_filter_options_for_the_ekf(capsys, args, message):
    assert main(["run", "--filter", "ekf", "--steps", "5", "--quiet", "--no-viz", *args]) == 2
    err = capsys.readouterr().err
    assert message in err and err.count("\n") == 1


def test_the_cli_runs_it_from_the_start_and_refuses_init_for_the_others(capsys):
    assert main(["run", "--filter", "ekf", "--init", "start", "--steps", "20", "--seed", "2", "--quiet"]) == 0
    assert "ExtendedKalmanFilter: last-step error" in capsys.readouterr().out
    assert main(["run", "--filter", "sir", "--init", "start", "--steps", "5", "--quiet"]) == 2
    assert "SIRParticleFilter does not take --init" in capsys.readouterr().err


def test_compare_has_an_ekf_row(tmp_path, capsys):
    path = tmp_path / "s.json"
    args = ["run", "--maze", "paper_5x5", "--steps", "30", "--particles", "300", "--seed", "4", "--quiet"]
    assert main([*args, "--save-scenario", str(path)]) == 0
    assert main(["compare", str(path), "--filters", "sir,ekf", "--no-viz"]) == 0
    rows = {line.split()[0]: line.split() for line in capsys.readouterr().out.splitlines() if line.strip()}
    assert "EKF" in rows and "SIR" in rows  # the registry's labels
    assert "-" in rows["EKF"] and "-" not in rows["SIR"]  # mean ESS: not a sample


def test_the_recording_draws_the_covariance_ellipse_and_no_particles(tmp_path, paper_world):
    path = tmp_path / "ekf.rrd"
    kept: dict[int, tuple[np.ndarray, np.ndarray]] = {}

    def keep(k, robot, filt):
        kept[k] = (filt.mean.copy(), filt.covariance.copy())

    robot = Robot(0.3, 0.5, (3.5, 1.5))
    simulate(robot, paper_world, 0.3, 0.5, 1, 6, filtering_algorithm="ekf", seed=2, init="start", visualize=path,
             on_step=keep)  # fmt: skip
    slug = entity_name("ExtendedKalmanFilter")
    recording = load(path)
    strips = {k: np.array(row["LineStrips2D:strips"][0]) for k, row in recording[f"/map/{slug}/covariance"].items()}
    assert sorted(strips) == list(range(1, 7))
    assert f"/map/{slug}/particles" not in recording and sorted(recording[f"/map/{slug}/estimate"]) == list(range(1, 7))
    for k, (mean, covariance) in kept.items():
        expected = covariance_ellipse(mean, covariance, COVARIANCE_SIGMAS)
        np.testing.assert_allclose(strips[k], expected, atol=1e-5)  # logged as float32
        # every vertex lies on the 2-sigma contour: (x - m)^T P^-1 (x - m) = 4
        centred = strips[k] - mean
        np.testing.assert_allclose(np.einsum("ni,ij,nj->n", centred, np.linalg.inv(covariance), centred), 4, rtol=1e-3)
