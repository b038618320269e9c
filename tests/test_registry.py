"""mazelab.registry: one entry per filter, read by every layer.

- each shipped entry is whole and its own (short name, name, label, colour), and its class's declared
  defaults are the values its constructor runs with;
- names resolve (short, class, the paper's spaced names), an unknown one is one line with the choices;
- a plug-in gets an entry of its own (the next free colour, not batched until it says so);
- the filters that declare `batched` give in R runs together what they give run by run, bit for bit;
- a filter added to the package is one entry: run, compare, study and a replay take it, its option too;
- the CLI's help and `mazelab filters`, and the figures' colours, come from the registry.
"""

from __future__ import annotations

import csv
import inspect
import itertools
import textwrap

import numpy as np
import pytest

from mazelab import registry
from mazelab.cli.app import main
from mazelab.declaration import Option, number_in
from mazelab.experiments.study import MazeChoice, batchable, run_batch, run_task, study_settings, study_tasks
from mazelab.filters import AuxiliaryParticleFilter, ParticleFilter, RegularizedParticleFilter, SIRParticleFilter
from mazelab.grid_filter import GridBayesFilter
from mazelab.registry import (
    SHIPPED,
    FilterEntry,
    check_declared_defaults,
    entries,
    filter_entry,
    register,
)
from mazelab.scenario import load_scenario


def test_every_shipped_entry_is_whole_and_its_own():
    for attribute in ("short_name", "name", "label", "colour", "filter_class"):
        values = [getattr(entry, attribute) for entry in SHIPPED]
        assert len(set(values)) == len(values), attribute
    for entry in SHIPPED:
        assert entry.help and entry.name == entry.filter_class.name and len(entry.colour) == 3


@pytest.mark.parametrize("entry", SHIPPED, ids=[e.short_name for e in SHIPPED])
def test_every_declared_default_is_the_constructors(paper_world, entry):
    """The constructor takes its defaults from the declaration: built with no options, it runs with
    exactly the declared values (and spells no default of its own that differs)."""
    particles = paper_world.random_free_places(50, np.random.default_rng(1))
    filt = entry.filter_class(paper_world, 0.3, 0.5, particles, np.random.default_rng(2))
    assert dict(filt.settings) == entry.options.defaults()
    check_declared_defaults(entry.filter_class, entry.short_name)
    for name, parameter in inspect.signature(entry.filter_class.__init__).parameters.items():
        if name in entry.options and parameter.default is not inspect.Parameter.empty:
            assert parameter.default == entry.options[name].default, name
    if entry.batched:  # R runs take the same declaration
        runs = entry.filter_class(paper_world, 0.3, 0.5, np.stack([particles] * 2), [np.random.default_rng(3)] * 2)
        assert dict(runs.settings) == entry.options.defaults()


@pytest.mark.parametrize(
    "name", ["sir", "SIR", "SIRParticleFilter", "SIR Particle Filter", "sir particle filter", " sir "]
)
def test_the_names_of_a_filter_resolve_to_its_entry(name):
    assert filter_entry(name) is SHIPPED[0]


# -- names of the classes ------------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    ("name", "cls"),
    [
        ("SIRParticleFilter", SIRParticleFilter),
        ("sir", SIRParticleFilter),
        ("SIR Particle Filter", SIRParticleFilter),
        ("Auxiliary Particle Filter", AuxiliaryParticleFilter),
        ("APF", AuxiliaryParticleFilter),
        ("regularizedparticlefilter", RegularizedParticleFilter),
        ("grid", GridBayesFilter),
    ],
)
def test_filter_names(name, cls):
    assert filter_entry(name).filter_class is cls


@pytest.mark.parametrize("added", [False, True], ids=["shipped", "one-added"])
def test_an_unknown_name_is_one_line_with_the_registrys_choices(added, request):
    """The choices are the registry's, whatever it holds: a filter added to it is among them."""
    if added:
        request.getfixturevalue("wide_registered")
    valid = ", ".join(entry.short_name for entry in entries())
    assert ("wide" in valid) == added
    with pytest.raises(ValueError, match=rf"^unknown filter 'kalman' \(choose from {valid}, or FILE.py:Class\)$"):
        filter_entry("kalman")
    with pytest.raises(ValueError, match=r"^unknown filter 'sri'; did you mean sir\? \(choose from "):
        filter_entry("sri")


def test_plug_ins_never_take_a_shipped_filters_colour_even_when_the_palette_is_used_up():
    """Twelve plug-in classes in one process: more than the palette's free colours; none looks like SIR."""
    shipped = {entry.colour for entry in SHIPPED}
    made = [filter_entry(type(f"Many{i}", (SIRParticleFilter,), {"__doc__": "one of many."})) for i in range(12)]
    assert not shipped & {entry.colour for entry in made}
    assert all(a.colour != b.colour for a, b in itertools.pairwise(made))  # two in a row differ


def test_a_plug_in_gets_an_entry_of_its_own_not_batched_until_it_says_so(tmp_path):
    (tmp_path / "mine.py").write_text(
        textwrap.dedent(
            """
            from mazelab.filters import SIRParticleFilter

            class Mine(SIRParticleFilter):
                '''SIR of my own.'''
                label = "mine"

            class MineTogether(SIRParticleFilter):
                '''SIR that says its step works on R runs.'''
                batched = True
            """
        )
    )
    mine, together = filter_entry(f"{tmp_path}/mine.py:Mine"), filter_entry(f"{tmp_path}/mine.py:MineTogether")
    assert mine.label == "mine" and mine.help == "SIR of my own." and not mine.batched and together.batched
    assert mine.plugin is not None and mine.plugin.class_name == "Mine" and len(mine.plugin.sha256) == 64
    assert mine.colour not in {entry.colour for entry in SHIPPED} and mine.colour != together.colour
    assert mine.name == "Mine"  # named after itself, not the SIR it subclasses


@pytest.mark.parametrize("entry", [e for e in SHIPPED if e.batched], ids=lambda e: e.short_name)
def test_every_filter_that_declares_batched_gives_r_runs_bit_for_bit(paper_world, entry):
    settings = study_settings([MazeChoice.from_maze("paper", paper_world)], [0.3], [0.5], [120])
    tasks = study_tasks(settings, [entry.name], 3, 25, 6)
    assert batchable(tasks[0])
    together = run_batch(tasks)
    for task, records in zip(tasks, together, strict=True):
        (alone,) = run_task(task)
        (batched,) = records
        assert (alone.final_error, alone.mean_error, alone.converged_at, alone.mean_ess) == (
            batched.final_error, batched.mean_error, batched.converged_at, batched.mean_ess,
        )  # fmt: skip


class WideSIR(ParticleFilter):
    """SIR whose likelihood is flattened by an exponent of its own (a tempered likelihood)."""

    options = ParticleFilter.options.extend(
        Option("temper", 1.0, "the likelihood's exponent, 1: the paper's", check=number_in("temper", 0.0, 1.0))
    )

    def log_likelihood(self, points):
        return self.settings["temper"] * super().log_likelihood(points)  # p(z_k | x)^temper


@pytest.fixture
def wide_registered(monkeypatch):
    """WideSIR registered for the test (the registry's tables as they were afterwards)."""
    monkeypatch.setattr(registry, "_ENTRIES", registry._ENTRIES.copy())
    return register(FilterEntry(WideSIR, "wide", "wide SIR", (23, 190, 207), "SIR with a tempered likelihood"))


@pytest.mark.parametrize(
    ("short_name", "name", "message"),
    [
        ("sir", "WideSIR", "the short name 'sir' is taken by SIRParticleFilter"),
        ("rpf", "WideSIR", "the short name 'rpf' is taken by RegularizedParticleFilter"),
        ("wide", "SIRParticleFilter", "the name 'SIRParticleFilter' is taken by SIRParticleFilter"),
        ("wide", "SIR Particle Filter", "the name 'SIR Particle Filter' is taken by SIRParticleFilter"),
        ("Wide", "WideSIR", "the short name 'Wide' is not one lower-case word"),
    ],
)
def test_register_refuses_a_name_already_taken(short_name, name, message):
    """A second entry under a taken name would be unreachable (the first answers to it) or take over
    the lab's own filter's results; refused in one line, the registry as it was."""
    before = entries()
    filter_class = type(name, (WideSIR,), {"name": name})
    with pytest.raises(ValueError, match=rf"^{message}"):
        register(FilterEntry(filter_class, short_name, "wide SIR", (23, 190, 207), "SIR with a tempered likelihood"))
    assert entries() == before


def test_register_refuses_a_constructor_that_spells_another_default():
    class Spelled(WideSIR):
        def __init__(self, world, sigma, delta, particles, rng=None, temper=0.5, **options):
            super().__init__(world, sigma, delta, particles, rng, temper=temper, **options)

    with pytest.raises(
        ValueError, match=r"^spelled: the constructor's default temper=0.5 is not the declared default 1.0"
    ):
        register(FilterEntry(Spelled, "spelled", "spelled", (23, 190, 207), "SIR with its own default"))
    assert "spelled" not in [entry.short_name for entry in entries()]


def test_a_filter_added_to_the_package_is_one_entry_and_every_command_takes_it(tmp_path, capsys, wide_registered):
    saved, table = tmp_path / "w.json", tmp_path / "s.csv"
    common = ["--maze", "paper_5x5", "--steps", "25", "--particles", "150", "--seed", "2", "--no-viz"]
    assert (
        main(["run", "--filter", "wide", "--option", "temper=0.5", *common, "--quiet", "--save-scenario", str(saved)])
        == 0
    )
    first = capsys.readouterr().out.splitlines()[0]
    assert load_scenario(saved).filter_options["temper"] == 0.5 and load_scenario(saved).filter_plugin is None
    assert main(["run", "--scenario", str(saved), "--no-viz", "--quiet"]) == 0  # the replay: the same run
    assert capsys.readouterr().out.splitlines()[0] == first
    assert main(["compare", str(saved), "--filters", "sir,wide", "--option", "temper=0.5", "--no-viz"]) == 0
    assert "wide SIR" in capsys.readouterr().out  # its label in the table, as the registry entry says
    args = ["study", "--filters", "sir,wide", "--option", "temper=0.5,1", "--runs", "2", "--workers", "1"]
    assert main([*args, *common, "--csv", str(table)]) == 0
    rows = list(csv.DictReader(table.open()))
    assert [(r["filter"], r["temper"]) for r in rows if r["run"] == "1"] == [
        ("SIRParticleFilter", ""), ("WideSIR", "0.5"), ("WideSIR", "1.0")  # SIR does not take it: once, empty
    ]  # fmt: skip
    assert main(["run", "--filter", "wide", "--option", "temper=2", *common]) == 2
    assert "temper must be in (0, 1]" in capsys.readouterr().err


def test_the_help_lists_the_registrys_filters(capsys):
    assert main(["run", "--help"]) == 0
    text = " ".join(capsys.readouterr().out.split())
    assert ", ".join(entry.short_name for entry in SHIPPED) in text
    assert main(["filters"]) == 0
    listing = capsys.readouterr().out
    assert all(entry.help in listing for entry in SHIPPED)
    assert main(["filters", "rpf"]) == 0
    options = capsys.readouterr().out
    assert all(f"  {o.name} " in options for o in filter_entry("rpf").filter_class.options.settable())
    assert main(["filters", "nope"]) == 2


def test_the_figures_draw_each_filter_in_its_registry_colour(tmp_path):
    from matplotlib.image import imread

    saved, figure = tmp_path / "s.json", tmp_path / "errors.png"
    assert main(["run", "--maze", "paper_5x5", "--steps", "30", "--seed", "1", "--no-viz", "--quiet",
                 "--save-scenario", str(saved)]) == 0  # fmt: skip
    assert main(["compare", str(saved), "--filters", "sir,apf", "--no-viz", "--plot", str(figure)]) == 0
    pixels = (imread(figure)[..., :3] * 255).round().astype(int).reshape(-1, 3)
    for entry in SHIPPED:
        present = bool((np.abs(pixels - np.array(entry.colour)).max(axis=1) <= 2).any())
        assert present == (entry.short_name in ("sir", "apf")), entry.short_name
