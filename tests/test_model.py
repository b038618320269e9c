"""The state-space model (mazelab.model): the move is equation (1), the headings are uniform on the
compass interval, the likelihood is equation (3) with the outside penalty, and impossible sigma or delta
are refused (sigma outside the lab's range only warns). The robot that walks it is in test_robot.py."""

from __future__ import annotations

import math

import numpy as np
import pytest

from mazelab.backend import NUMPY_KERNELS
from mazelab.filters import SIRParticleFilter
from mazelab.model import (
    CONVERGENCE_RADIUS,
    OUTSIDE_PENALTY,
    ROBOT_SPEED,
    LostRobot,
    Sensor,
    headings_from_uniforms,
    log_likelihood,
    move,
)
from mazelab.robot import Robot
from mazelab.simulation import simulate


def test_move_is_equation_one():
    start = np.array([[1.0, 2.0], [0.0, 0.0]])
    moved = move(start, np.array([0.0, math.pi / 2]))
    np.testing.assert_allclose(moved, [[1.0 + ROBOT_SPEED, 2.0], [0.0, ROBOT_SPEED]], atol=1e-15)


def test_headings_are_uniform_on_the_compass_interval(rng):
    headings = headings_from_uniforms(rng.random(100_000), 1.0, 0.5)
    assert headings.min() >= 0.75 and headings.max() <= 1.25
    # U(a, b) has mean (a+b)/2 and std (b-a)/sqrt(12); the sample mean's std is that over sqrt(n)
    assert abs(headings.mean() - 1.0) < 5 * 0.5 / math.sqrt(12) / math.sqrt(len(headings))
    assert headings.std() == pytest.approx(0.5 / math.sqrt(12), rel=0.01)


def test_log_likelihood_is_equation_three_with_the_outside_penalty(paper_world):
    sigma, z = 0.3, 1.2
    inside, outside = np.array([[1.5, 3.5]]), np.array([[-0.5, 3.5]])
    d = paper_world.distance_to_nearest_station(inside)[0]
    gauss = math.exp(-0.5 * ((z - d) / sigma) ** 2) / (sigma * math.sqrt(2 * math.pi))
    assert math.exp(log_likelihood(z, inside, paper_world, sigma)[0]) == pytest.approx(gauss, rel=1e-12)
    d_out = paper_world.distance_to_nearest_station(outside)[0]
    gauss_out = math.exp(-0.5 * ((z - d_out) / sigma) ** 2) / (sigma * math.sqrt(2 * math.pi))
    assert math.exp(log_likelihood(z, outside, paper_world, sigma)[0]) == pytest.approx(
        OUTSIDE_PENALTY * gauss_out, rel=1e-12
    )


@pytest.mark.parametrize(("sigma", "delta"), [(0, 0.5), (-1, 0.5), (float("inf"), 0.5), (0.3, -0.1), (0.3, 7.0)])
def test_impossible_sigma_or_delta_is_refused(sigma, delta):
    with pytest.raises(ValueError):
        Robot(sigma, delta, (1.5, 1.5))


def test_sigma_outside_the_lab_range_warns():
    with pytest.warns(UserWarning, match="outside the lab's range"):
        Robot(1.5, 0.5, (1.5, 1.5))


def test_the_lost_robot_moves_and_weighs_r_runs_as_each_run_alone(paper_world):
    """LostRobot (the model the step calls: M0, M, logG): R runs' particles (R, N, 2), run r's draws from
    rngs[r]; the transition and the log-likelihood of the runs are each run's own, bit for bit, and the
    transition moves every point by exactly L; a run without a Generator draws nothing."""
    model = LostRobot(paper_world, 0.3, 0.5, NUMPY_KERNELS)
    runs = np.stack([model.M0(50, np.random.default_rng(s)) for s in (1, 2, 3)]).astype(np.float32)
    angles, z = np.array([0.1, 1.0, 2.0]), np.array([0.5, 1.0, 1.5])
    together, headings = model.M(runs, None, angles, [np.random.default_rng(s) for s in (4, 5, 6)])
    weights = model.logG(together, z)
    for r, seed in enumerate((4, 5, 6)):
        alone, _ = model.M(runs[r : r + 1], None, angles[r : r + 1], [np.random.default_rng(seed)])
        np.testing.assert_array_equal(together[r], alone[0])
        np.testing.assert_array_equal(weights[r], model.logG(alone, z[r : r + 1])[0])
        steps = np.hypot(*(alone[0] - runs[r]).T)
        np.testing.assert_allclose(steps, ROBOT_SPEED, rtol=1e-5)
        assert np.all(np.abs(headings[r] - angles[r]) <= 0.25 + 1e-6)
    rng = np.random.default_rng(7)
    state = rng.bit_generator.state
    still, _ = model.M(runs, None, angles, [rng, None, rng])  # no Generator: no draw (a lost run restarts)
    assert rng.bit_generator.state != state
    np.testing.assert_allclose(np.hypot(*(still[1] - runs[1]).T), ROBOT_SPEED, rtol=1e-5)
    untouched = np.random.default_rng(8)
    before = untouched.bit_generator.state
    model.M(runs[:1], None, angles[:1], [None])
    assert untouched.bit_generator.state == before


class _TwoRanges(Sensor):
    """A second range sensor beside the paper's (noise sigma2): what a maintainer adds to the model."""

    def __init__(self, sigma, outside_penalty=OUTSIDE_PENALTY, sigma2=0.2):
        super().__init__(sigma, outside_penalty)
        self.sigma2 = sigma2

    def sample(self, world, x, y, rng):
        return (super().sample(world, x, y, rng), world.distance_at(x, y) + rng.normal(0.0, self.sigma2))

    def log_pdf(self, z, x, world, ops):
        second = log_likelihood(z[:, 1], x.reshape(-1, 2), world, self.sigma2, 1.0).reshape(x.shape[:2])
        return super().log_pdf(np.ascontiguousarray(z[:, 0]), x, world, ops) + second


def test_the_robot_reads_and_the_filters_weigh_with_one_measurement_model(paper_world):
    """The robot's reading and the filters' likelihood are one definition (Sensor): the robot measures with
    its sensor's `sample` (the paper's by default, equation (2)), LostRobot's logG is its sensor's
    `log_pdf`, and a sensor of two readings runs through the step (z (R, 2)) with no other change."""
    robot = Robot(0.3, 0.5, (1.5, 1.5), rng=np.random.default_rng(1))
    alone = np.random.default_rng(1)
    assert robot.measure(paper_world) == paper_world.distance_at(1.5, 1.5) + alone.normal(0.0, 0.3)
    model = LostRobot(paper_world, 0.3, 0.5, NUMPY_KERNELS, outside_penalty=0.25)
    points = model.M0(40, np.random.default_rng(2)).astype(np.float32)[None]
    expected = log_likelihood(1.0, points[0], paper_world, 0.3, 0.25)
    np.testing.assert_array_equal(model.logG(points, np.array([1.0]))[0], expected)

    class TwoRangeSIR(SIRParticleFilter):
        def __init__(self, *args, **options):
            super().__init__(*args, **options)
            self.model.sensor = _TwoRanges(self.sigma)

    robot = Robot(0.3, 0.5, (1.5, 1.5), sensor=_TwoRanges(0.3))
    result = simulate(robot, paper_world, 0.3, 0.5, 500, 60, filtering_algorithm=TwoRangeSIR, seed=3)
    assert all(len(z) == 2 for z in robot.measurements)
    assert result.errors[-10:].mean() < CONVERGENCE_RADIUS  # both readings weighed: it finds the robot
