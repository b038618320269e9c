"""mazelab.declaration: a filter's options, declared once.

- the constructor's values are the declaration's: its defaults, and given values checked by it only;
- an undeclared option, a bad value, a tuning option without its part, or a bad combination is one line;
- `extend` and `with_defaults` make new declarations (a subclass that changes a default runs that default
  and stores it);
- the JSON form of every shipped option goes there and back, objects (Recovery, KLDSampling) included;
- command-line text is read by the same declaration (`--option NAME=TEXT` and the named flags agree).
"""

from __future__ import annotations

import dataclasses
import json
from typing import ClassVar

import numpy as np
import pytest

from mazelab.declaration import Option, Options, number_in, options_of, parse_literal, with_options_section
from mazelab.filters import RegularizedParticleFilter, SIRParticleFilter
from mazelab.recovery import Recovery
from mazelab.registry import SHIPPED
from mazelab.resampling import KLDSampling


def small_options() -> Options:
    return Options(
        Option("spread", 0.1, "the jitter's std", check=number_in("spread", 0.0, 1.0)),
        Option("mode", "on", "a word"),
        Option("rate", 0.5, "tunes mode", tunes="mode", check=number_in("rate", 0.0, 1.0)),
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


def test_a_tuning_option_is_refused_while_what_it_tunes_is_off():
    options = small_options()
    options.resolve({"rate": 0.7}, "F")  # mode is on: fine
    with pytest.raises(ValueError, match="F: rate tunes mode, which is off"):
        options.resolve({"mode": None, "rate": 0.7}, "F")
    options.resolve({"mode": None, "rate": 0.5}, "F")  # its default changes nothing: not refused


def test_a_combination_is_checked_together():
    seen = []
    options = Options(Option("a", 1, "a"), Option("b", 2, "b"), check=lambda values: seen.append(dict(values)))
    options.resolve({"b": 5}, "F")
    assert seen == [{"a": 1, "b": 5}]
    with pytest.raises(ValueError, match="alpha_slow < alpha_fast"):
        SIRParticleFilter.options.resolve({"recovery": "augmented", "alpha_slow": 0.5, "alpha_fast": 0.1}, "SIR")


def test_extend_replaces_in_place_and_with_defaults_keeps_the_checks():
    options = small_options()
    extended = options.extend(Option("spread", 0.2, "wider"), Option("new", 1, "new"))
    assert list(extended) == ["spread", "mode", "rate", "new"] and extended["spread"].default == 0.2
    changed = options.with_defaults(spread=0.4)
    assert changed["spread"].default == 0.4 and options["spread"].default == 0.1  # a new value, the old intact
    with pytest.raises(ValueError, match="spread must be in"):
        changed.resolve({"spread": -1}, "F")
    with pytest.raises(ValueError, match="no option 'nope'"):
        options.with_defaults(nope=1)
    with pytest.raises(ValueError, match="declared twice"):
        Options(Option("a", 1, "a"), Option("a", 2, "a"))
    with pytest.raises(AttributeError):
        options.declared = ()


def test_a_subclass_that_changes_a_declared_default_runs_it_and_stores_it(paper_world):
    from mazelab.robot import Robot
    from mazelab.seeding import start_place
    from mazelab.simulation import simulate

    class StratifiedSIR(SIRParticleFilter):
        options = SIRParticleFilter.options.with_defaults(resampling="stratified")

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
    assert option.validate(option.parse_text(text)) == value


def test_a_decimal_comma_names_what_to_write():
    with pytest.raises(ValueError, match=r"option threshold: expected a number, got '0,3' \(write 0.3\)"):
        RegularizedParticleFilter.options["threshold"].parse_text("0,3")


def test_a_plug_ins_plain_mapping_of_defaults_is_read_by_each_defaults_type():
    class Plain:
        options: ClassVar[dict] = {"alpha": 0.5, "count": 3, "flag": False, "word": "x", "nothing": None}

    options = options_of(Plain)
    assert [options[n].parse_text(t) for n, t in (("alpha", "0.7"), ("count", "4"), ("flag", "yes"))] == [0.7, 4, True]
    assert options["word"].parse_text("y") == "y" and parse_literal("none") is None and parse_literal("2") == 2
    with pytest.raises(ValueError, match="expected a whole number"):
        options["count"].parse_text("3.5")


def test_the_filters_docstring_lists_its_declared_options():
    doc = RegularizedParticleFilter.__doc__
    assert "Options\n    -------" in doc
    for option in RegularizedParticleFilter.options.settable():
        assert f"    {option.name} : default" in doc
    assert with_options_section(doc, RegularizedParticleFilter.options).count("Options\n") == 1  # never twice
