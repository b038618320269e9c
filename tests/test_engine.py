"""The step (mazelab.smc.SMC): one algorithm with hooks over (R, N) arrays and the `due` mask; adaptive
resampling for every particle filter; a plug-in that overrides one hook (0.2's hooks run or get one line);
no hook names the runs; the rules the step keeps, each broken on purpose in a test of its own (masked
resampling, identity ancestors, the due runs' draws, a lost run that draws nothing); what a hook returns
checked where the step receives it; the engine and what the exercise ships import no reference
implementation."""

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

from mazelab.backend import use_backend
from mazelab.filters import AuxiliaryParticleFilter, ParticleFilter, RegularizedParticleFilter, SIRParticleFilter
from mazelab.robot import Robot
from mazelab.simulation import simulate
from mazelab.smc import SMC, HookError

HOOKS = ("log_eta", "time_to_resample", "ancestors", "move", "move_resampled", "reweight_resampled")


class HalfESS(ParticleFilter):
    """A plug-in whose only method is the resampling rule (0.2's form, without W: it still runs)."""

    def time_to_resample(self):
        return self.ess < 0.5 * self.count


class PerRunHalfESS(ParticleFilter):
    """The same rule in 0.3's form: a statistic per run of W (R, N), no reshaping."""

    def time_to_resample(self, W):
        return 1 / (W.W**2).sum(axis=1) < 0.5 * W.W.shape[1]


def run(paper_world, filter_class, **options):
    rng = np.random.default_rng(8)
    robot = Robot(0.3, 0.5, paper_world.random_free_place(rng), rng=rng)
    return simulate(robot, paper_world, 0.3, 0.5, 300, 40, filtering_algorithm=filter_class, seed=8, **options)


@pytest.mark.parametrize("plugin_class", [HalfESS, PerRunHalfESS])
def test_a_plugin_that_overrides_time_to_resample_is_sir_with_that_threshold_bit_for_bit(paper_world, plugin_class):
    plugin = run(paper_world, plugin_class)
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
from mazelab.filters import ParticleFilter


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
        "import sys; import mazelab.exercise.student, mazelab.smc; "
        "print(','.join(sorted(m for m in sys.modules if m.startswith('mazelab'))))"
    )
    loaded = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, cwd=ROOT)
    modules = set(loaded.stdout.strip().split(","))
    for reference in ("mazelab.model", "mazelab.resampling", "mazelab.grid_filter", "mazelab.filters",
                      "mazelab.numpy_ops", "mazelab.backend"):  # fmt: skip
        assert reference not in modules


def test_a_scenario_of_sir_replays_with_the_rpf_at_the_rpfs_own_threshold(paper_world):
    """A saved run stores every option, defaults included; another filter replaying it takes the options
    that run chose, not its defaults (SIR's threshold 1, every step, is not the RPF's N_T = 0.2)."""
    by_default, chosen = run(paper_world, "sir").scenario, run(paper_world, "sir", threshold=0.5).scenario
    assert by_default.filter_options["threshold"] == 1.0
    assert "threshold" not in by_default.filter_kwargs(RegularizedParticleFilter)
    assert chosen.filter_kwargs(RegularizedParticleFilter)["threshold"] == 0.5
    assert by_default.filter_kwargs(by_default.maker())["threshold"] == 1.0  # the filter that made it: every option


def test_a_studys_threshold_that_none_of_its_filters_takes_is_refused_in_one_line(capsys):
    """The study's threshold reaches every filter that declares it (SIR's and the APF's adaptive
    resampling too); one none of its filters declares (the grid filter's) is refused rather than ignored."""
    from mazelab.cli.app import main

    assert main(["study", "--filters", "grid", "--threshold", "0.3", "--runs", "2", "--steps", "5", "--no-viz"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "GridBayesFilter does not take --threshold" in err


# -- the rules the step keeps, each one a test that breaking it fails ----------------------------------------
class OddRunsDue(SIRParticleFilter):
    """Runs 0 and 2 resample every step, run 1 never."""

    def time_to_resample(self, W):
        return np.array([True, False, True])


def generator_after(seed_state, *draws):
    """A Generator from `seed_state` after the given draws (callables of it)."""
    rng = np.random.default_rng()
    rng.bit_generator.state = seed_state
    for draw in draws:
        draw(rng)
    return rng.bit_generator.state


def test_a_run_not_due_keeps_its_particles_and_weights_and_draws_only_its_move(paper_world):
    """Masked resampling: the run not due gets identity ancestors (its particles moved in order), keeps
    W_{k-1} (its new weights are W_{k-1} G_k normalised) and draws its move alone; the due runs draw
    their offset, then their move, and their weights restart from G_k."""
    count = 100
    particles = np.stack([paper_world.random_free_places(count, np.random.default_rng(s)) for s in range(3)])
    filt = OddRunsDue(paper_world, 0.3, 0.5, particles, [np.random.default_rng(10 + r) for r in range(3)])
    filt.step(np.zeros(3), np.array([1.0, 1.2, 0.8]))
    x, lw, states = filt.x.copy(), filt.W.lw.copy(), [g.bit_generator.state for g in filt.rngs]
    angles, z = np.array([0.3, 0.4, 0.5]), np.array([1.1, 0.9, 1.3])
    filt.step(angles, z)
    move = lambda g: g.random(count, dtype=np.float32)  # noqa: E731
    assert filt.rngs[1].bit_generator.state == generator_after(states[1], move)
    for r in (0, 2):
        assert filt.rngs[r].bit_generator.state == generator_after(states[r], lambda g: g.random(), move)
    rng = np.random.default_rng()
    rng.bit_generator.state = states[1]
    alone, _ = filt.model.M(x[1:2], None, angles[1:2], [rng])
    np.testing.assert_array_equal(filt.x[1], alone[0])
    expected = filt.weights_class(lw[1:2]).add(filt.model.logG(alone, z[1:2]))
    np.testing.assert_array_equal(filt.W.lw[1], expected.lw[0])
    fresh = filt.weights_class.from_log(filt.model.logG(filt.x[[0, 2]], z[[0, 2]]))
    np.testing.assert_array_equal(filt.W.lw[[0, 2]], fresh.lw)
    assert filt.resampled_at == [[0, 1], [], [0, 1]]


def test_a_run_nothing_explains_at_the_first_stage_draws_nothing_before_its_restart(paper_world):
    """The APF's run 1 gets z = 400, which no auxiliary point explains: after its first stage's draws it
    draws no offset and no move, only its restart from the prior; its evidence gains the first-stage
    total; run 0 goes on as alone."""
    count = 80
    particles = np.stack([paper_world.random_free_places(count, np.random.default_rng(s)) for s in range(2)])
    filt = AuxiliaryParticleFilter(
        paper_world, 0.3, 0.5, particles, [np.random.default_rng(5), np.random.default_rng(6)]
    )
    filt.step(np.zeros(2), np.array([1.0, 1.0]))
    lw, state, evidence = filt.W.lw.copy(), filt.rngs[1].bit_generator.state, filt.run_log_evidence.copy()
    filt.step(np.zeros(2), np.array([1.0, 400.0]))
    assert filt.reinitialised_at == [[], [2]] and filt.resampled_at == [[0, 1], [0]]
    rng = np.random.default_rng()
    rng.bit_generator.state = state
    rng.random(count, dtype=np.float32)  # the auxiliary points' move
    np.testing.assert_array_equal(filt.x[1], paper_world.random_free_places(count, rng).astype(np.float32))
    assert filt.rngs[1].bit_generator.state == rng.bit_generator.state  # nothing more
    first_stage = filt.weights_class(lw[1:2]).add(filt.log_mu[1:2])
    assert first_stage.lost[0]
    assert filt.run_log_evidence[1] == evidence[1] + first_stage.log_total[0]


@pytest.mark.parametrize("filter_class", [SIRParticleFilter, AuxiliaryParticleFilter, RegularizedParticleFilter])
def test_a_threshold_above_one_is_refused_for_every_filter(paper_world, filter_class):
    with pytest.raises(ValueError, match="threshold"):
        filter_class(paper_world, 0.3, 0.5, paper_world.random_free_places(10), threshold=1.5)


# -- the boundary: what a hook returns is checked where the step receives it -----------------------------
class OutOfRange(SIRParticleFilter):
    def ancestors(self, W, due):
        return np.full(W.W.shape, W.W.shape[1])


class FloatAncestors(SIRParticleFilter):
    def ancestors(self, W, due):
        return np.zeros(W.W.shape)


class NaNLikelihood(SIRParticleFilter):
    def log_likelihood(self, x):
        return np.full(x.shape[:2], np.nan, dtype=np.float32)


class FlatLikelihood(SIRParticleFilter):
    def log_likelihood(self, x):
        return super().log_likelihood(x)[0]


class NaNMove(SIRParticleFilter):
    def move(self, x, A, due):
        moved, headings = super().move(x, A, due)
        return np.full_like(moved, np.nan), headings


class OldMove(SIRParticleFilter):
    def step(self, compass_angle, z):  # a method of the same name as nothing: the class builds
        super().step(compass_angle, z)


BACKENDS = ["numpy", pytest.param("compiled", marks=pytest.mark.skipif(
    not __import__("importlib").util.find_spec("numba"), reason="needs numba"))]  # fmt: skip


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize(
    ("plugin", "said"),
    [
        (OutOfRange, r"^ancestors returned an index outside \[0, 50\): 50\.\.50$"),
        (FloatAncestors, r"^ancestors returned a float64 array of shape \(1, 50\); expected int"),
        (NaNLikelihood, r"^log_likelihood returned NaN or \+inf \(run 0\)"),
        (FlatLikelihood, r"^log_likelihood returned a float32 array of shape \(50,\); expected float \(R, N\)"),
        (NaNMove, r"^the move returned NaN positions \(run 0\)"),
    ],
)
def test_what_a_hook_returns_is_one_line_naming_the_hook_on_either_backend(paper_world, backend, plugin, said):
    with use_backend(backend):
        filt = plugin(paper_world, 0.3, 0.5, paper_world.random_free_places(50), np.random.default_rng(1))
    with pytest.raises(HookError, match=said) as raised:
        filt.step(0.0, 1.0)
    assert "\n" not in str(raised.value)


def test_a_plugin_of_0_2s_hooks_gets_one_line_on_how_to_port_it():
    with pytest.raises(
        TypeError, match=r"^Jitter.move_after_resampling is a hook of mazelab 0.2; port it to move_resampled"
    ):
        type("Jitter", (SIRParticleFilter,), {"move_after_resampling": lambda self, ancestors: None})
    with pytest.raises(
        TypeError, match=r"^Mine.ancestors\(W\) is a hook of mazelab 0.2; port it to ancestors\(self, W, due\)"
    ):
        type("Mine", (SIRParticleFilter,), {"ancestors": lambda self, W: None})


def test_the_filter_shows_each_steps_ancestors_and_due_mask_read_only(paper_world):
    """`ancestry` after a step: the A the move received (identity rows where a run was not due) and the
    due mask, read-only; None before the first step; nothing kept from the steps before."""
    received = []

    class Recording(SIRParticleFilter):
        def move(self, x, A, due):
            received.append(None if A is None else A.copy())
            return super().move(x, A, due)

    rng = np.random.default_rng(4)
    parts = np.stack([paper_world.random_free_places(200, rng) for _ in range(3)])
    filt = Recording(paper_world, 0.3, 0.5, parts, [np.random.default_rng(s) for s in range(3)], threshold=0.5)
    assert filt.ancestry is None
    partial = False
    for k in range(25):
        filt.step(np.full(3, 0.1 * k), np.full(3, 2.0))
        A, due = filt.ancestry
        assert not A.flags.writeable and not due.flags.writeable
        np.testing.assert_array_equal(due, filt.resampled_now)
        expected = np.broadcast_to(np.arange(200), (3, 200)) if received[-1] is None else received[-1]
        np.testing.assert_array_equal(A, expected)
        np.testing.assert_array_equal(A[~due], np.broadcast_to(np.arange(200), (int((~due).sum()), 200)))
        partial |= bool(due.any() and not due.all())
    assert partial  # some steps resampled some runs and not others
