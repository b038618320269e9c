"""The filter contract (mazelab.contract), each rule on its own:

- every shipped filter meets it and says what to draw (Particles, a Density or a Gaussian);
- a class missing a part of it is refused naming the part; an object with a mistyped part is refused
  before its first step, and each step's values (estimate, ess, is_confident, count) where they are read;
- every filter refuses an option it does not declare, naming the option and what it takes; of several
  filters each gets the options it declares, and an option none declares is refused naming them all.
"""

from __future__ import annotations

import math
from typing import ClassVar

import numpy as np
import pytest

from mazelab.contract import (
    ContractError,
    Density,
    Gaussian,
    Particles,
    check_filter,
    check_step_values,
    missing_parts,
)
from mazelab.experiments.runs import options_per_filter
from mazelab.filters import RegularizedParticleFilter, SIRParticleFilter
from mazelab.grid_filter import GridBayesFilter
from mazelab.kalman import ExtendedKalmanFilter
from mazelab.registry import SHIPPED
from mazelab.robot import Robot
from mazelab.simulation import simulate

SHIPPED_CLASSES = {entry.filter_class.__name__: entry.filter_class for entry in SHIPPED}
BAD_OPTIONS = {"recovery": True, "resampling": "nonsense", "bandwidth": "typo", "threshold": 0.3, "init": "prior"}


@pytest.mark.parametrize("cls", list(SHIPPED_CLASSES.values()), ids=list(SHIPPED_CLASSES))
def test_every_filter_refuses_each_option_it_does_not_declare_naming_it(paper_world, cls, monkeypatch):
    robot = Robot(0.3, 0.5, (3.5, 1.5))
    refused = [option for option in BAD_OPTIONS if option not in cls.options]
    assert refused, f"{cls.name} declares every option tried"
    for option in refused:
        with pytest.raises(ValueError, match=rf"^{cls.name} does not take the option {option} \(it takes: "):
            simulate(robot, paper_world, 0.3, 0.5, 50, 2, filtering_algorithm=cls, seed=1,
                     **{option: BAD_OPTIONS[option]})  # fmt: skip


@pytest.mark.parametrize("cls", list(SHIPPED_CLASSES.values()), ids=list(SHIPPED_CLASSES))
def test_every_shipped_filter_meets_the_contract_and_says_what_to_draw(paper_world, cls):
    assert missing_parts(cls) == []
    options = {"resolution": 0.1} if cls is GridBayesFilter else {}
    filt = cls(paper_world, 0.3, 0.5, paper_world.random_free_places(50, np.random.default_rng(1)),
               np.random.default_rng(2), **options)  # fmt: skip
    filt.step(0.3, 1.0)
    check_filter(filt)
    expected = {GridBayesFilter: Density, ExtendedKalmanFilter: Gaussian}.get(cls, Particles)
    assert isinstance(filt.belief(), expected)
    assert filt.estimate.shape == (2,) and isinstance(filt.is_confident, bool)
    assert math.isnan(filt.ess) == (cls in (GridBayesFilter, ExtendedKalmanFilter))


def test_a_class_missing_part_of_the_contract_is_named():
    class Half:
        name = "Half"
        options: ClassVar[dict] = {}

        def step(self, compass_angle, z):
            pass

    assert missing_parts(Half) == ["method belief()"]
    with pytest.raises(TypeError, match=r"Half does not meet the filter contract: it has no method belief\(\), "):
        check_filter(Half())


class Tiny:
    """The least object that meets the contract: a Gaussian belief, its values set by the test."""

    name = "Tiny"
    options: ClassVar[dict] = {}

    def step(self, compass_angle, z):
        pass

    def belief(self):
        return Gaussian(self.estimate, np.eye(2))


def tiny(**parts) -> Tiny:
    filt = Tiny()
    values = {"estimate": np.zeros(2), "ess": math.nan, "is_confident": False, "count": 1, "reinitialised_at": []}
    for part, value in {**values, **parts}.items():
        if value is not None:
            setattr(filt, part, value)
    return filt


@pytest.mark.parametrize(
    ("parts", "message"),
    [
        ({"count": None}, r"^Tiny does not meet the filter contract: it has no attribute 'count'$"),
        ({"reinitialised_at": 3}, r"^Tiny.reinitialised_at must be a list of step numbers \(whole numbers\), got 3$"),
        ({"reinitialised_at": [1.5]}, r"^Tiny.reinitialised_at must be a list of step numbers .*, got \[1.5\]$"),
    ],
)
def test_a_missing_or_mistyped_part_of_an_object_is_named_before_the_first_step(parts, message):
    check_filter(tiny())  # the parts all there and well typed
    with pytest.raises(ContractError, match=message):
        check_filter(tiny(**parts))


@pytest.mark.parametrize(
    ("values", "message"),
    [
        (([1.0, np.nan], 3.0, True, 10), r"^F.estimate must be finite, got "),
        (([1.0, 2.0, 3.0], 3.0, True, 10), r"^F.estimate must have shape \(2,\), got \(3,\)$"),
        (("here", 3.0, True, 10), r"^F.estimate must be a point \(x, y\), got 'here'$"),
        (([1.0, 2.0], "many", True, 10), r"^F.ess must be a number >= 0 \(or NaN when not a sample\), got 'many'$"),
        (([1.0, 2.0], True, True, 10), r"^F.ess must be a number >= 0"),
        (([1.0, 2.0], -1.0, True, 10), r"^F.ess must be a number >= 0"),
        (([1.0, 2.0], 3.0, 1, 10), r"^F.is_confident must be True or False, got 1$"),
        (([1.0, 2.0], 3.0, False, 0), r"^F.count must be a whole number >= 1, got 0$"),
        (([1.0, 2.0], 3.0, False, 2.5), r"^F.count must be a whole number >= 1, got 2.5$"),
        (([1.0, 2.0], 3.0, False, True), r"^F.count must be a whole number >= 1, got True$"),
    ],
)
def test_each_steps_values_are_checked_where_they_are_read(values, message):
    class F:
        name = "F"

    with pytest.raises(ContractError, match=message):
        check_step_values(F, values)


def test_good_step_values_come_back_as_the_run_keeps_them():
    estimate, ess, confident, count = check_step_values(SIRParticleFilter, ([1, 2], np.float32(3.5), np.True_, 7))
    assert estimate.dtype == np.float64 and estimate.tolist() == [1.0, 2.0]
    assert type(ess) is float and ess == 3.5 and confident and type(count) is int and count == 7
    assert math.isnan(check_step_values(GridBayesFilter, ([1, 2], math.nan, False, 1))[1])  # not a sample
    runs = check_step_values(SIRParticleFilter, (np.zeros((3, 2)), np.ones(3), np.ones(3, bool), 5), runs=3)
    assert runs[0].shape == (3, 2)
    with pytest.raises(ContractError, match=r"estimate must have shape \(3, 2\), got \(2,\)"):
        check_step_values(SIRParticleFilter, (np.zeros(2), np.ones(3), np.ones(3, bool), 5), runs=3)


def test_several_filters_each_get_the_options_they_declare():
    """The RPF declares bandwidth and threshold, the SIR neither: the SIR gets only what it takes; an
    option neither declares is refused naming both and what each takes (`--spread` as the user wrote it)."""
    filters = [SIRParticleFilter, RegularizedParticleFilter]
    given = {"bandwidth": 0.1, "resampling": "residual", "threshold": None}
    assert options_per_filter(filters, given) == {
        "SIRParticleFilter": {"resampling": "residual"},
        "RegularizedParticleFilter": {"bandwidth": 0.1, "resampling": "residual"},
    }
    with pytest.raises(ValueError, match=r"^SIRParticleFilter and RegularizedParticleFilter do not take --spread \("):
        options_per_filter(filters, {"spread": 1.0}, spelled={"spread": "--spread"})
