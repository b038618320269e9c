"""A study's runs in units of work (mazelab.experiments.study): one filter object of R runs
(mazelab.smc) advances them together bit for bit as R single-run filters, restarts included; a study's
units give the records run_task gives run by run, within the particle budget; runs go together by the
declared rule (`batchable`), and an error in a batched unit is reported for its runs, not retried quietly."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from conftest import recorded_walk

from mazelab.experiments.study import (
    MazeChoice,
    RunFailure,
    batchable,
    run_batch,
    run_task,
    run_unit_safely,
    study_settings,
    study_tasks,
    study_units,
)
from mazelab.filters import SIRParticleFilter
from mazelab.registry import entries, filter_entry

SEEDS = (11, 12, 13, 14)
IMPOSSIBLE_Z = 50.0  # no place of the 5x5 maze is this far from a station: every weight underflows


def step_together_and_alone(batch, singles, walks: list, steps: int) -> None:
    """Step the R-run filter and the R single-run filters on the same walks; each step's estimate, ESS
    and confidence of run r must be the single run's, bit for bit."""
    for k in range(steps):
        compass, z = np.array([w[k][0] for w in walks]), np.array([w[k][1] for w in walks])
        batch.step(compass, z)
        for r, single in enumerate(singles):
            single.step(compass[r], z[r])
            assert np.array_equal(batch.estimate[r], single.estimate), (k, r)
            assert batch.ess[r] == single.ess and batch.is_confident[r] == single.is_confident
            assert batch.log_evidence[r] == single.log_evidence


BATCHED = [entry.name for entry in entries() if entry.batched]  # every registry entry that declares it
ADAPTIVE = {"threshold": 0.5}  # some runs resample at a step and others do not


@pytest.mark.parametrize("options", [{}, ADAPTIVE], ids=["defaults", "threshold=0.5"])
@pytest.mark.parametrize("name", BATCHED)
def test_batched_runs_equal_single_runs_bit_for_bit(name, options, paper_world):
    count, steps = 200, 40
    walks = [recorded_walk(paper_world, seed, steps) for seed in SEEDS]
    for r in (1, 3):  # two runs meet a measurement nothing explains: they restart from the prior
        walks[r][20] = (walks[r][20][0], IMPOSSIBLE_Z)
    particles = np.stack([paper_world.random_free_places(count, np.random.default_rng(s)) for s in SEEDS])
    single_class = filter_entry(name).filter_class
    singles = [
        single_class(paper_world, 0.3, 0.5, particles[r], np.random.default_rng(s + 1000), **options)
        for r, s in enumerate(SEEDS)
    ]
    batch = single_class(paper_world, 0.3, 0.5, particles, [np.random.default_rng(s + 1000) for s in SEEDS], **options)
    step_together_and_alone(batch, singles, walks, steps)
    assert [len(single.reinitialised_at) > 0 for single in singles] == [False, True, False, True]
    assert batch.reinitialised_at == [single.reinitialised_at for single in singles]


def test_a_studys_units_give_the_records_of_its_runs_one_by_one(paper_world):
    settings = study_settings([MazeChoice.from_maze("paper", paper_world)], [0.3, 0.6], [0.5], [150])
    filters = ["SIRParticleFilter", "AuxiliaryParticleFilter", "RegularizedParticleFilter"]
    tasks = study_tasks(settings, filters, 3, 30, 8, kidnap_at=15)
    units = study_units(tasks, workers=1)
    assert [len(unit) for unit in units] == [3, 3]  # each setting's runs together

    def without_timing(records):
        return [
            {k: v for k, v in dataclasses.asdict(r).items() if k not in ("ms_per_step", "run_seconds")} for r in records
        ]

    together = [without_timing(records) for unit in units for records in run_unit_safely(unit)]
    assert together == [without_timing(run_task(task)) for task in tasks]


def test_a_batch_of_one_run_gives_the_records_of_that_run(paper_world):
    """R = 1 gives the paper's shapes (a float ESS, one list of restarts): run_batch reads them as one run's."""
    settings = study_settings([MazeChoice.from_maze("paper", paper_world)], [0.3], [0.5], [5])
    filters = ["SIRParticleFilter", "AuxiliaryParticleFilter", "RegularizedParticleFilter"]
    tasks = study_tasks(settings, filters, 1, 30, 3)
    timing = ("ms_per_step", "run_seconds")

    def without_timing(records):
        return [{k: v for k, v in dataclasses.asdict(r).items() if k not in timing} for r in records]

    (records,) = run_batch(tasks)
    assert without_timing(records) == without_timing(run_task(tasks[0]))


def test_units_respect_the_particle_budget(paper_world):
    many = study_settings([MazeChoice.from_maze("paper", paper_world)], [0.3], [0.5], [400_000])
    tasks = study_tasks(many, ["SIRParticleFilter"], 5, 3, 1)
    assert [len(unit) for unit in study_units(tasks, workers=1)] == [2, 2, 1]  # 2 x 400,000 <= 10^6
    huge = study_settings([MazeChoice.from_maze("paper", paper_world)], [0.3], [0.5], [2_000_000])
    assert [len(unit) for unit in study_units(study_tasks(huge, ["SIRParticleFilter"], 3, 3, 1), 1)] == [1, 1, 1]


# -- the batched path: declared, and never quiet about a failure ----------------------------------------
def test_runs_go_together_by_the_declared_rule(paper_world):
    settings = study_settings([MazeChoice.from_maze("paper", paper_world)], [0.3], [0.5], [100])
    plain = study_tasks(settings, ["SIRParticleFilter", "RegularizedParticleFilter"], 3, 5, 1)
    assert batchable(plain[0])
    kld = study_settings([MazeChoice.from_maze("paper", paper_world)], [0.3], [0.5], [100], {"kld": [True]})
    assert not batchable(study_tasks(kld, ["SIRParticleFilter"], 3, 5, 1)[0])
    assert not batchable(study_tasks(settings, ["SIRParticleFilter", "GridBayesFilter"], 3, 5, 1)[0])
    assert SIRParticleFilter.runs_together({"bandwidth": "multimodal", "estimate": "mode"})
    assert not SIRParticleFilter.runs_together({"recovery": "sensor"})


def test_an_error_in_a_batched_unit_is_reported_for_its_runs(paper_world, monkeypatch):
    settings = study_settings([MazeChoice.from_maze("paper", paper_world)], [0.3], [0.5], [100])
    unit = tuple(study_tasks(settings, ["SIRParticleFilter"], 3, 5, 1))

    def broken(self, compass_angle, z):
        raise RuntimeError("a bug in the step")

    monkeypatch.setattr(SIRParticleFilter, "step", broken)
    outcomes = run_unit_safely(unit)
    assert len(outcomes) == 3
    assert all(isinstance(o, RunFailure) and "a bug in the step" in o.message for o in outcomes)
    assert all("runs advanced together" in o.message for o in outcomes)
