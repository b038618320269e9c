"""The step template (mazelab.engine.SMC): one algorithm with hooks; adaptive
resampling for every particle filter; a plug-in that overrides one hook; no hook names the runs; the
template and what the exercise ships import no reference implementation."""

from __future__ import annotations

import ast
import inspect
import math
import subprocess
import sys
import textwrap

import numpy as np
import pytest
from conftest import ROOT

from mazelab.cloud import ParticleFilter
from mazelab.engine import SMC
from mazelab.filters import AuxiliaryParticleFilter, RegularizedParticleFilter, SIRParticleFilter
from mazelab.lab import simulate
from mazelab.robot import Robot

HOOKS = ("step", "log_eta", "time_to_resample", "ancestors", "move_after_resampling", "reweight_resampled")


class HalfESS(ParticleFilter):
    """A plug-in whose only method is the resampling rule."""

    def time_to_resample(self):
        return self.ess < 0.5 * self.count


def run(paper_world, filter_class, **options):
    rng = np.random.default_rng(8)
    robot = Robot(0.3, 0.5, paper_world.random_free_place(rng), rng=rng)
    return simulate(robot, paper_world, 0.3, 0.5, 300, 40, filtering_algorithm=filter_class, seed=8, **options)


def test_a_plugin_that_overrides_time_to_resample_is_sir_with_that_threshold_bit_for_bit(paper_world):
    plugin = run(paper_world, HalfESS)
    declared = run(paper_world, "sir", threshold=0.5)
    every_step = run(paper_world, "sir")
    for field in ("estimates", "ess", "confident", "log_evidence"):
        np.testing.assert_array_equal(getattr(plugin, field), getattr(declared, field))
    assert not np.array_equal(plugin.estimates, every_step.estimates)  # the rule changed the run


def test_the_one_hook_plugin_from_a_file_runs_as_sir_with_threshold_on_the_command_line(tmp_path, capsys):
    from mazelab.cli.app import main

    (tmp_path / "half.py").write_text(HALF_ESS_FILE)
    common = ["--maze", "paper_5x5", "--steps", "40", "--particles", "300", "--seed", "6", "--no-viz", "--quiet"]
    assert main(["run", "--filter", f"{tmp_path}/half.py:HalfESS", *common]) == 0
    plugin = capsys.readouterr().out.splitlines()[0]
    assert main(["run", "--filter", "sir", "--option", "threshold=0.5", *common]) == 0
    declared = capsys.readouterr().out.splitlines()[0]
    assert plugin.startswith("HalfESS: ") and declared.startswith("SIRParticleFilter: ")
    assert plugin.split(": ", 1)[1] == declared.split(": ", 1)[1]


HALF_ESS_FILE = """
from mazelab.cloud import ParticleFilter


class HalfESS(ParticleFilter):
    def time_to_resample(self):
        return self.ess < 0.5 * self.count
"""


@pytest.mark.parametrize("filter_class", [SIRParticleFilter, AuxiliaryParticleFilter, RegularizedParticleFilter])
def test_every_particle_filter_resamples_when_the_ess_falls_below_threshold_times_n(paper_world, filter_class):
    """threshold 1 (SIR's and the APF's default, the paper's): every step; below 1: exactly the steps
    that began with N_eff < threshold N; below 1 / N: never (N_eff >= 1)."""
    walk = [(0.3 * k, 1.0 + 0.1 * math.sin(k)) for k in range(30)]
    for threshold in (1.0, 0.5, 0.001):
        filt = filter_class(paper_world, 0.3, 0.5, paper_world.random_free_places(300, np.random.default_rng(1)),
                            np.random.default_rng(2), threshold=threshold)  # fmt: skip
        degenerate = []
        for k, (compass_angle, z) in enumerate(walk):
            if threshold >= 1 or filt.ess < threshold * filt.count:
                degenerate.append(k)
            filt.step(compass_angle, z)
        assert filt.resampled_at == degenerate
        assert (threshold == 1.0) == (degenerate == list(range(30)))
        assert (threshold == 0.001) == (degenerate == [])


def test_sir_and_the_apf_resample_every_step_by_default_and_the_rpf_at_its_threshold():
    assert SIRParticleFilter.options["threshold"].default == AuxiliaryParticleFilter.options["threshold"].default == 1
    assert RegularizedParticleFilter.options["threshold"].default == 0.2


@pytest.mark.parametrize("filter_class", [SMC, ParticleFilter, SIRParticleFilter, AuxiliaryParticleFilter,
                                          RegularizedParticleFilter])  # fmt: skip
def test_no_step_or_hook_names_the_runs(filter_class):
    """The runs live below the hooks: the template's step and every hook a filter writes read as one run."""
    for name in HOOKS:
        method = filter_class.__dict__.get(name)
        if method is None:
            continue
        tree = ast.parse(textwrap.dedent(inspect.getsource(method)))  # code only: docstrings are strings
        names = {node.id for node in ast.walk(tree) if isinstance(node, ast.Name)}
        attributes = {node.attr for node in ast.walk(tree) if isinstance(node, ast.Attribute)}
        arguments = {node.arg for node in ast.walk(tree) if isinstance(node, ast.arg)}
        said = {word for word in names | attributes | arguments if "run" in word.lower()}
        assert not said, f"{filter_class.__name__}.{name} names the runs: {sorted(said)}"


def test_the_template_and_the_exercise_import_no_reference_implementation():
    """The grading sandbox ships StudentFilter and what it imports: none of the model's code, of the
    resampling schemes or of the grid filter may come along (their constants may)."""
    code = (
        "import sys; import mazelab.exercise.student, mazelab.engine; "
        "print(','.join(sorted(m for m in sys.modules if m.startswith('mazelab'))))"
    )
    loaded = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, cwd=ROOT)
    modules = set(loaded.stdout.strip().split(","))
    for reference in ("mazelab.model", "mazelab.resampling", "mazelab.grid_filter", "mazelab.cloud",
                      "mazelab.filters", "mazelab.numpy_ops"):  # fmt: skip
        assert reference not in modules


def test_a_scenario_of_sir_replays_with_the_rpf_at_the_rpfs_own_threshold(paper_world):
    """A saved run stores every option, defaults included; another filter replaying it takes the options
    that run chose, not its defaults (SIR's threshold 1, every step, is not the RPF's N_T = 0.2)."""
    by_default, chosen = run(paper_world, "sir").scenario, run(paper_world, "sir", threshold=0.5).scenario
    assert by_default.filter_options["threshold"] == 1.0
    assert "threshold" not in by_default.filter_kwargs(RegularizedParticleFilter)
    assert chosen.filter_kwargs(RegularizedParticleFilter)["threshold"] == 0.5
    assert by_default.filter_kwargs()["threshold"] == 1.0  # the filter that made it: every option


def test_a_studys_threshold_that_none_of_its_filters_takes_is_refused_in_one_line(capsys):
    """The study's threshold reaches every filter that declares it (SIR's and the APF's adaptive
    resampling too); one none of its filters declares (the grid filter's) is refused rather than ignored."""
    from mazelab.cli.app import main

    assert main(["study", "--filters", "grid", "--threshold", "0.3", "--runs", "2", "--steps", "5", "--no-viz"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "GridBayesFilter does not take --threshold" in err
