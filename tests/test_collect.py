"""mazelab.simulation.record_steps: the one recording loop, for one run and for R runs together.

- a filter's own diagnostics reach RunResult (the RPF's `regularised` at exactly its regularisation
  steps, recovery's injection probability) and a study's traces, batched or not, with the same values;
- each step's values are checked where they are read (a filter handing back a bad one is stopped at
  that step, naming the part).
"""

from __future__ import annotations

import numpy as np
import pytest

from mazelab.contract import ContractError
from mazelab.experiments.study import MazeChoice, run_batch, run_task, study_settings, study_tasks
from mazelab.filters import RegularizedParticleFilter, SIRParticleFilter
from mazelab.robot import Robot
from mazelab.simulation import record_steps, simulate


def test_the_rpfs_regularisation_steps_reach_the_run_result(paper_world):
    robot = Robot.of_seed(paper_world, 0.3, 0.5, 3)
    result = simulate(robot, paper_world, 0.3, 0.5, 300, 60, None, "rpf", seed=3, threshold=0.5)
    regularised = result.extras["diagnostics"]["regularised"]
    filt_steps = [k for k in range(60) if regularised[k]]  # step k+1 began by regularising
    assert 3 <= len(filt_steps) < 60

    rpf_runs = []

    def keep(k, robot_, filt):
        rpf_runs.append(list(filt.resampled_at))

    simulate(robot, paper_world, 0.3, 0.5, 300, 60, None, "rpf", seed=3, threshold=0.5, on_step=keep)
    assert filt_steps == rpf_runs[-1]  # resampled_at lists the steps done before it regularised


def test_recoverys_injection_probability_is_recorded_per_step(paper_world):
    robot = Robot.of_seed(paper_world, 0.3, 0.5, 4)
    result = simulate(robot, paper_world, 0.3, 0.5, 300, 60, None, "sir", seed=4, recovery="sensor", kidnap_at=30)
    probability = result.extras["diagnostics"]["injection_probability"]
    assert probability.shape == (60,) and ((probability >= 0) & (probability <= 1)).all() and probability.max() > 0
    assert (
        "injection_probability"
        not in simulate(robot, paper_world, 0.3, 0.5, 300, 10, None, "sir", seed=4).extras["diagnostics"]
    )


def test_batched_and_single_runs_record_the_same_diagnostics(paper_world):
    settings = study_settings([MazeChoice.from_maze("paper", paper_world)], [0.3], [0.5], [150], {"threshold": [0.5]})
    tasks = study_tasks(settings, ["RegularizedParticleFilter"], 3, 40, 5, traces=True)
    together = run_batch(tasks)
    for task, (batched,) in zip(tasks, together, strict=True):
        (alone,) = run_task(task)
        for name in ("regularised",):
            np.testing.assert_array_equal(batched.trace["diagnostics"][name], alone.trace["diagnostics"][name])
        assert batched.trace["diagnostics"]["regularised"].any()


class BadEstimate(SIRParticleFilter):
    @property
    def estimate(self):
        return np.full(2, np.nan) if self.steps_done == 3 else super().estimate


def test_a_bad_value_is_stopped_at_the_step_that_read_it(paper_world):
    rng = np.random.default_rng(1)
    filt = BadEstimate(paper_world, 0.3, 0.5, paper_world.random_free_places(100, rng), rng)
    at = type("At", (), {"number": 0})()
    with pytest.raises(ContractError, match=r"BadEstimate.estimate must be finite"):
        record_steps(filt, 10, lambda k: (0.0, 1.0), at=at)
    assert at.number == 3


def test_r_runs_are_recorded_with_a_run_axis(paper_world):
    rngs = [np.random.default_rng(r) for r in range(3)]
    particles = np.stack([paper_world.random_free_places(80, g) for g in rngs])
    filt = RegularizedParticleFilter(paper_world, 0.3, 0.5, particles, rngs)
    recorded = record_steps(filt, 5, lambda k: (np.zeros(3), np.ones(3)), runs=3)
    assert recorded.estimates.shape == (3, 5, 2) and recorded.ess.shape == (3, 5)
    assert recorded.diagnostics["regularised"].shape == (3, 5) and recorded.counts.tolist() == [[80] * 5] * 3


class OwnDiagnostics(SIRParticleFilter):
    """Hands back a figure of its own each step: one number for every run, one per run, or a table."""

    shape = "number"

    @property
    def diagnostics(self):
        k = float(self.steps_done)
        if self.shape == "number":
            return {"k": k}
        if self.shape == "per run":
            return {"k": [k, 10 * k, 100 * k]}
        return {"k": [[k, k, k]]}


@pytest.mark.parametrize(
    ("shape", "expected"), [("number", [[1, 2], [1, 2], [1, 2]]), ("per run", [[1, 2], [10, 20], [100, 200]])]
)
def test_a_diagnostic_is_one_number_or_one_per_run_each_step(paper_world, shape, expected):
    rngs = [np.random.default_rng(r) for r in range(3)]
    particles = np.stack([paper_world.random_free_places(80, g) for g in rngs])
    filt = OwnDiagnostics(paper_world, 0.3, 0.5, particles, rngs)
    filt.shape = shape
    recorded = record_steps(filt, 2, lambda k: (np.zeros(3), np.ones(3)), runs=3)
    assert recorded.diagnostics["k"].tolist() == expected


def test_a_diagnostic_shaped_as_a_table_is_refused(paper_world):
    rngs = [np.random.default_rng(r) for r in range(3)]
    particles = np.stack([paper_world.random_free_places(80, g) for g in rngs])
    filt = OwnDiagnostics(paper_world, 0.3, 0.5, particles, rngs)
    filt.shape = "table"
    with pytest.raises(ContractError, match=r"^a diagnostic must be a number \(or one per run\) at every step$"):
        record_steps(filt, 2, lambda k: (np.zeros(3), np.ones(3)), runs=3)
