"""The one seeding rule (mazelab.seeding): a run's seed S gives its start place (default_rng(S)) and four
independent streams (default_rng(S).spawn(4): the robot, the initial particles, the filter, the
kidnapping), which simulate draws from, so `--seed S` repeats the run; adding the kidnapping's stream
changed no run without one; a study's root seed gives run r the same seeds however many runs it has.
"""

from __future__ import annotations

import numpy as np

from mazelab.filters import SIRParticleFilter
from mazelab.model import Sensor
from mazelab.robot import Robot
from mazelab.seeding import new_seed, run_streams, start_place, study_seeds
from mazelab.simulation import simulate


def test_the_kidnap_stream_leaves_the_other_streams_unchanged():
    """simulate spawns four streams where it spawned three: the first three must be the same."""
    for old, new in zip(np.random.default_rng(8).spawn(3), np.random.default_rng(8).spawn(4)[:3], strict=True):
        np.testing.assert_array_equal(old.random(5), new.random(5))


def test_a_runs_seed_gives_its_start_and_four_streams(paper_world):
    """start_place(S) is a free place drawn from default_rng(S); run_streams(S) are default_rng(S).spawn(4)
    in the order robot, particles, filter, kidnapping, each drawing its own numbers."""
    seed = 20
    assert start_place(paper_world, seed) == paper_world.random_free_place(np.random.default_rng(seed))
    sensor = Sensor(0.4)
    robot = Robot.of_seed(paper_world, 0.3, 0.5, seed, sensor=sensor)  # every command's fresh robot
    assert robot.initial_position == start_place(paper_world, seed) and robot.sensor is sensor
    assert Robot.of_seed(paper_world, 0.3, 0.5, seed).sensor.sigma == 0.3  # the paper's sensor by default
    streams, spawned = run_streams(seed), np.random.default_rng(seed).spawn(4)
    draws = [stream.random(4) for stream in streams]
    for drawn, child in zip(draws, spawned, strict=True):
        np.testing.assert_array_equal(drawn, child.random(4))
    assert len({tuple(d) for d in draws}) == 4
    np.testing.assert_array_equal(run_streams(seed).filter.random(4), draws[2])
    assert isinstance(new_seed(), int) and 0 <= new_seed() < 2**63


def test_simulate_draws_the_walk_the_particles_and_the_filter_from_the_runs_streams(paper_world):
    """simulate(seed=S) by hand: the particles from stream 2, the robot's walk from stream 1, the filter's
    draws from stream 3; the same estimates bit for bit."""
    seed, count, steps = 8, 300, 25
    start = start_place(paper_world, seed)
    result = simulate(Robot(0.3, 0.5, start), paper_world, 0.3, 0.5, count, steps, seed=seed)
    streams = run_streams(seed)
    particles = paper_world.random_free_places(count, streams.particles)
    np.testing.assert_array_equal(result.inputs.init_particles_pos, particles)
    robot = Robot(0.3, 0.5, start, rng=streams.robot)
    sir = SIRParticleFilter(paper_world, 0.3, 0.5, particles, streams.filter)
    estimates = []
    for _ in range(steps):
        sir.step(*robot.step(paper_world))
        estimates.append(sir.estimate)
    np.testing.assert_array_equal(result.true_positions[-1], robot.position)
    np.testing.assert_array_equal(result.estimates, estimates)


def test_a_studys_run_r_keeps_its_seeds_when_the_study_grows():
    """study_seeds(root, R): (seed, maze seed) of runs 1..R; the first runs of a larger study are those of a
    smaller one, the seeds differ between runs and between roots, and they are whole numbers below 2^63."""
    three, five = study_seeds(7, 3), study_seeds(7, 5)
    assert five[:3] == three
    assert len({seed for seed, _ in five}) == 5 and len({maze for _, maze in five}) == 5
    assert study_seeds(8, 3) != three and study_seeds(7, 3) == three
    assert all(isinstance(v, int) and 0 <= v < 2**63 for pair in five for v in pair)
