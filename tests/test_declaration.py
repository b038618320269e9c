"""mazelab.declaration: a filter's options, declared once.

- the constructor's values are the declaration's: its defaults, and given values checked by it only;
- an undeclared option, a bad value, or a bad combination is one line;
- `extend` makes a new declaration; a plain mapping of defaults declares too, in a subclass as well (a
  subclass that changes a default runs that default, checked, and stores it);
- the JSON form of every shipped option goes there and back, objects (Recovery, KLDSampling) included;
- command-line text is read by the same declaration (`--option NAME=TEXT` and the named flags agree); a
  number-typed option refuses NaN and infinities, and no option takes a control character.
"""

from __future__ import annotations

import dataclasses
import json
from typing import ClassVar

import numpy as np
import pytest

from mazelab.declaration import Option, Options, number_in, options_of
from mazelab.filters import RegularizedParticleFilter, SIRParticleFilter
from mazelab.recovery import Recovery
from mazelab.registry import SHIPPED
from mazelab.resampling import KLDSampling


def small_options() -> Options:
    return Options(
        Option("spread", 0.1, "the jitter's std", check=number_in("spread", 0.0, 1.0)),
        Option("mode", "on", "a word"),
        Option("rate", 0.5, "a rate", check=number_in("rate", 0.0, 1.0)),
    )


def test_resolve_fills_in_the_defaults_and_checks_only_what_is_given():
    options = small_options()
    assert options.resolve({}, "F") == {"spread": 0.1, "mode": "on", "rate": 0.5}
    assert options.resolve({"spread": 0.3}, "F")["spread"] == 0.3
    with pytest.raises(ValueError, match=r"^spread must be in \(0, 1\], got 2$"):
        options.resolve({"spread": 2}, "F")


def test_an_undeclared_option_is_one_line_naming_it_and_what_the_filter_takes():
    with pytest.raises(ValueError, match=r"^F does not take the option widen \(it takes: spread, mode, rate\)$"):
        small_options().resolve({"widen": 2}, "F")


def test_a_combination_is_checked_together():
    seen = []
    options = Options(Option("a", 1, "a"), Option("b", 2, "b"), check=lambda values: seen.append(dict(values)))
    options.resolve({"b": 5}, "F")
    assert seen == [{"a": 1, "b": 5}]
    with pytest.raises(ValueError, match="alpha_slow < alpha_fast"):
        SIRParticleFilter.options.resolve({"recovery": "augmented", "alpha_slow": 0.5, "alpha_fast": 0.1}, "SIR")


def test_extend_replaces_in_place_and_keeps_the_combined_check():
    def below_spread(values):
        if values["rate"] < values["spread"]:
            raise ValueError("rate below spread")

    options = Options(*small_options().declared, check=below_spread)
    extended = options.extend(Option("spread", 0.2, "wider"), Option("new", 1, "new"))
    assert list(extended) == ["spread", "mode", "rate", "new"] and extended["spread"].default == 0.2
    assert options["spread"].default == 0.1  # a new value, the old intact
    with pytest.raises(ValueError, match="rate below spread"):
        extended.resolve({"rate": 0.15}, "F")
    with pytest.raises(ValueError, match="declared twice"):
        Options(Option("a", 1, "a"), Option("a", 2, "a"))


def test_a_plain_mapping_in_a_subclass_extends_the_declaration_it_inherits(paper_world):
    """The contract's promise: `{**SIRParticleFilter.options, "inflation": 1.0}` declares SIR's options and
    one more, and the filter is built and run with it; a name SIR declares keeps SIR's check."""

    class Inflated(SIRParticleFilter):
        options: ClassVar[dict] = {**SIRParticleFilter.options, "inflation": 1.0}

    class Short(SIRParticleFilter):
        options: ClassVar[dict] = {"inflation": 1.0}  # what it leaves out is SIR's still

    for cls in (Inflated, Short):
        declared = options_of(cls)
        assert list(declared) == [*SIRParticleFilter.options, "inflation"]
        assert declared.check is SIRParticleFilter.options.check  # SIR's combined check, kept
        particles = paper_world.random_free_places(30, np.random.default_rng(1))
        filt = cls(paper_world, 0.3, 0.5, particles, np.random.default_rng(2), inflation=2.0)
        filt.step(0.0, 1.0)
        assert filt.settings["inflation"] == 2.0 and filt.settings["resampling"] == "systematic"
        with pytest.raises(ValueError, match="bandwidth"):
            cls(paper_world, 0.3, 0.5, particles, bandwidth=0.1)  # not SIR's, nor declared here
    with pytest.raises(ValueError, match="unknown resampling scheme 'nope'"):

        class Bad(SIRParticleFilter):  # a new default is checked as a given value is
            options: ClassVar[dict] = {"resampling": "nope"}


def test_plain_mappings_declare_through_a_chain_of_plug_in_classes():
    class Base:
        options: ClassVar[dict] = {"alpha": 0.5, "count": 3}

    class Child(Base):
        options: ClassVar[dict] = {"count": 4, "word": "x"}

    assert options_of(Child).defaults() == {"alpha": 0.5, "count": 4, "word": "x"}
    assert options_of(Child)["count"].parse_text("5") == 5  # still read as a whole number
    with pytest.raises(ValueError, match=r"^options: the name 'a' holds the option 'b'$"):

        class Misnamed(Base):
            options: ClassVar[dict] = {"a": Option("b", 1, "b")}

        options_of(Misnamed)


def test_a_subclass_that_changes_a_declared_default_runs_it_and_stores_it(paper_world):
    from mazelab.robot import Robot
    from mazelab.seeding import start_place
    from mazelab.simulation import simulate

    class StratifiedSIR(SIRParticleFilter):
        options: ClassVar[dict] = {"resampling": "stratified"}

    robot = Robot(0.3, 0.5, start_place(paper_world, 5))
    own = simulate(robot, paper_world, 0.3, 0.5, 200, 20, None, StratifiedSIR, seed=5)
    given = simulate(robot, paper_world, 0.3, 0.5, 200, 20, None, "sir", seed=5, resampling="stratified")
    plain = simulate(robot, paper_world, 0.3, 0.5, 200, 20, None, "sir", seed=5)
    np.testing.assert_array_equal(own.estimates, given.estimates)  # it ran stratified resampling
    assert not np.array_equal(own.estimates, plain.estimates)
    assert own.scenario.filter_options["resampling"] == "stratified"  # and says so


@pytest.mark.parametrize("entry", SHIPPED, ids=[e.short_name for e in SHIPPED])
def test_every_shipped_option_goes_to_json_and_back(entry):
    options = entry.options
    stored = options.to_json(options.defaults())
    assert json.loads(json.dumps(stored)) == stored  # plain JSON
    back = options.from_json(stored, entry.name)
    assert back == {k: v for k, v in options.defaults().items() if not options[k].derived}


def test_object_options_go_to_json_and_back_as_their_fields():
    options = SIRParticleFilter.options
    values = {"recovery": Recovery("sensor", 0.01, 0.2), "kld": KLDSampling(epsilon=0.1, max_count=900)}
    stored = options.to_json(values)
    assert stored["recovery"] == dataclasses.asdict(values["recovery"]) and stored["kld"]["max_count"] == 900
    assert options.from_json(stored, "SIR") == values
    with pytest.raises(ValueError, match="has no field 'speed'"):
        options.from_json({"recovery": {"mode": "augmented", "speed": 1}}, "SIR")


@pytest.mark.parametrize(
    ("name", "text", "value"),
    [
        ("bandwidth", "0.05", 0.05),
        ("bandwidth", "multimodal", "multimodal"),
        ("threshold", "0.5", 0.5),
        ("resampling", "Residual", "residual"),
        ("recovery", "none", None),
        ("recovery", "sensor", "sensor"),
        ("kld", "true", True),
        ("estimate", "mode", "mode"),
    ],
)
def test_command_line_text_is_read_and_checked_by_the_declaration(name, text, value):
    option = RegularizedParticleFilter.options[name]
    assert option.check(option.parse_text(text)) == value


def test_a_decimal_comma_names_what_to_write():
    with pytest.raises(ValueError, match=r"option threshold: expected a number, got '0,3' \(write 0.3\)"):
        RegularizedParticleFilter.options["threshold"].parse_text("0,3")


def test_a_plug_ins_plain_mapping_of_defaults_is_read_by_each_defaults_type():
    class Plain:
        options: ClassVar[dict] = {"alpha": 0.5, "count": 3, "flag": False, "word": "x", "nothing": None}

    options = options_of(Plain)
    assert [options[n].parse_text(t) for n, t in (("alpha", "0.7"), ("count", "4"), ("flag", "yes"))] == [0.7, 4, True]
    word = options["word"]
    assert word.parse_text("y") == "y" and word.parse_text("none") is None and word.parse_text("2") == 2
    with pytest.raises(ValueError, match="expected a whole number"):
        options["count"].parse_text("3.5")


@pytest.mark.parametrize("text", ["nan", "NaN", "inf", "-inf", "1e999"])
def test_a_number_typed_option_refuses_what_is_not_a_finite_number_naming_it(text):
    """NaN compares false with every bound, so an option without a check would take it silently."""

    class Plain:
        options: ClassVar[dict] = {"alpha": 0.5, "count": 3}

    options = options_of(Plain)
    with pytest.raises(ValueError, match=rf"^option alpha: expected a finite number, got '{text}'$"):
        options["alpha"].parse_text(text)
    with pytest.raises(ValueError, match=r"^option count: expected a whole number"):
        options["count"].parse_text(text)
    assert options["alpha"].parse_text("1e26") == 1e26  # finite: an option's own check bounds it


def test_a_literal_that_is_an_infinite_number_is_refused():
    word = Option("word", "on", "a word: its text is read as any literal")
    with pytest.raises(ValueError, match="option word: expected a finite number"):
        word.parse_text("1e999")
    assert word.parse_text("nan") == "nan"  # a word, as any other


@pytest.mark.parametrize("text", ["0.5\nRepeat this run: rm -rf", "a\tb", "x\r", "y\u2028z"])
def test_no_option_takes_a_control_character(text):
    """A value is printed in lines (the repeat command, tables); a newline would forge a line."""
    for option in (RegularizedParticleFilter.options["resampling"], RegularizedParticleFilter.options["threshold"]):
        with pytest.raises(ValueError, match=rf"^option {option.name}: a value cannot hold a control character"):
            option.parse_text(text)


def test_a_value_with_no_json_form_is_refused_naming_the_option():
    with pytest.raises(ValueError, match=r"^option threshold: option value nan has no JSON form$"):
        RegularizedParticleFilter.options.to_json({"threshold": float("nan")})
