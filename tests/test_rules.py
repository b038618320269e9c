"""The rules of the filters and of the figures, each checked on its own (not through pinned numbers):
break one in the code and its test here fails.

- the RPF regularises exactly at the steps whose previous ESS fell below N_T;
- the APF's second-stage weight is p(z | x) / p(z | mu);
- the green circle counts weight, not particles;
- the kidnap study's "re-localised" looks at the last DEFAULT_WINDOW steps;
- recovery injects nothing once the filter is localised and before the kidnapping;
- recovery_steps counts from the kidnapping;
- every filter refuses an option it does not declare, and every filter meets the contract;
- a batched unit that raises is reported, not retried quietly.
"""

from __future__ import annotations

import math
from types import SimpleNamespace
from typing import ClassVar

import numpy as np
import pytest

from mazelab.contract import Density, Gaussian, Particles, check_filter, missing_parts
from mazelab.experiments import batch_runs
from mazelab.experiments.kidnapping import DEFAULT_WINDOW, recovery_steps, relocalised
from mazelab.experiments.study import MazeChoice, study_settings, study_tasks
from mazelab.filters import AuxiliaryParticleFilter, RegularizedParticleFilter, SIRParticleFilter
from mazelab.grid_filter import GridBayesFilter
from mazelab.kalman import ExtendedKalmanFilter
from mazelab.model import CONFIDENCE_SHARE, CONVERGENCE_RADIUS, ROBOT_SPEED, log_likelihood
from mazelab.registry import FILTERS
from mazelab.robot import Robot
from mazelab.simulation import simulate


def recorded_walk(world, seed: int, steps: int) -> list[tuple[float, float]]:
    """(compass angle, z) of each step of a seeded robot."""
    rng = np.random.default_rng(seed)
    robot = Robot(0.3, 0.5, world.random_free_place(rng), rng=rng)
    return [robot.step(world) for _ in range(steps)]


# -- the RPF: regularise exactly when N_eff < N_T ------------------------------------------------------
@pytest.mark.parametrize("threshold", [0.2, 0.5])
def test_the_rpf_regularises_exactly_at_the_steps_whose_ess_fell_below_n_t(paper_world, threshold):
    """Algorithm 6: IF N_eff < N_T, resample and jitter; so step k+1 regularises iff the ESS after step
    k is below threshold * N (the first step never: the initial weights are uniform, ESS = N)."""
    count = 600
    rpf = RegularizedParticleFilter(
        paper_world, 0.3, 0.5, paper_world.random_free_places(count, np.random.default_rng(1)),
        np.random.default_rng(2), threshold=threshold,
    )  # fmt: skip
    expected, ess_before = [], rpf.ess
    for k, (compass, z) in enumerate(recorded_walk(paper_world, 7, 80)):
        if ess_before < threshold * count:
            expected.append(k)  # regularised_at holds the steps done before it
        rpf.step(compass, z)
        ess_before = rpf.ess
    assert 3 <= len(expected) < 80  # both branches taken
    assert rpf.regularised_at == expected


def test_the_rpf_regularises_each_of_r_runs_by_its_own_ess(paper_world):
    """R runs together: run r regularises at its own steps, as the single run r would."""
    seeds = (3, 4, 5)
    walks = [recorded_walk(paper_world, s, 50) for s in seeds]
    particles = np.stack([paper_world.random_free_places(300, np.random.default_rng(s)) for s in seeds])
    together = RegularizedParticleFilter(paper_world, 0.3, 0.5, particles, [np.random.default_rng(s) for s in seeds])
    alone = [
        RegularizedParticleFilter(paper_world, 0.3, 0.5, p, np.random.default_rng(s))
        for p, s in zip(particles, seeds, strict=True)
    ]
    for k in range(50):
        together.step(np.array([w[k][0] for w in walks]), np.array([w[k][1] for w in walks]))
        for r, filt in enumerate(alone):
            filt.step(*walks[r][k])
    assert together.regularised_at == [filt.regularised_at for filt in alone]
    assert len({len(steps) for steps in together.regularised_at}) > 1 or together.regularised_at[0]


# -- the effective sample size: N_eff = 1 / sum_i W_i^2 (Arulampalam et al., eq. 51) -----------------------
@pytest.mark.parametrize("cls", [SIRParticleFilter, AuxiliaryParticleFilter, RegularizedParticleFilter])
def test_the_ess_is_one_over_the_sum_of_the_squared_normalised_weights(paper_world, cls):
    """Known weights (1/2, 1/4, 1/4) give 1 / (1/4 + 1/16 + 1/16) = 8/3, for one run and per run of R;
    after real steps the ESS is that of the weights the filter holds, computed here independently."""
    one = cls(paper_world, 0.3, 0.5, np.full((3, 2), 2.5), np.random.default_rng(1))
    one.log_weights = np.log([0.5, 0.25, 0.25])
    assert one.ess == pytest.approx(8 / 3, rel=1e-12) and isinstance(one.ess, float)
    two = cls(paper_world, 0.3, 0.5, np.full((2, 3, 2), 2.5), [np.random.default_rng(1), np.random.default_rng(2)])
    two.log_weights = np.log([[0.5, 0.25, 0.25], [1 / 3, 1 / 3, 1 / 3]])
    np.testing.assert_allclose(two.ess, [8 / 3, 3.0], rtol=1e-12)
    filt = cls(paper_world, 0.3, 0.5, paper_world.random_free_places(400, np.random.default_rng(3)),
               np.random.default_rng(4))  # fmt: skip
    for compass, z in recorded_walk(paper_world, 5, 12):
        filt.step(compass, z)
        weights = np.exp(np.asarray(filt.log_weights, dtype=float))
        assert weights.sum() == pytest.approx(1.0, rel=1e-5)  # normalised in float32 arithmetic
        assert filt.ess == pytest.approx(1.0 / np.sum(weights**2), rel=1e-9)


# -- a restart: from the prior, weighted by the run's own z ---------------------------------------------
@pytest.mark.parametrize("cls", [SIRParticleFilter, AuxiliaryParticleFilter, RegularizedParticleFilter])
def test_a_run_that_restarts_weights_the_prior_by_its_own_measurement(paper_world, cls):
    """No particle explains z_k (here 50, beyond any station of the 5x5 maze): that run, and only it,
    restarts from the prior with W_i proportional to p(z_k | x_i) of its own z_k (not another run's)."""
    seeds = (3, 4, 5)
    particles = np.stack([paper_world.random_free_places(200, np.random.default_rng(s)) for s in seeds])
    filt = cls(paper_world, 0.3, 0.5, particles, [np.random.default_rng(s) for s in seeds])
    filt.step(np.zeros(3), np.array([1.0, 1.0, 1.0]))
    filt.step(np.zeros(3), np.array([1.0, 50.0, 1.0]))
    assert filt.reinitialised_at == [[], [2], []]
    # run 1's fresh prior weighted by p(50 | x), which underflows everywhere: uniform (z = 1 would not be)
    np.testing.assert_allclose(filt.weights[1], 1 / 200, rtol=1e-12)
    assert not np.allclose(filt.weights[0], 1 / 200)
    filt.step(np.zeros(3), np.array([1.0, 1.0, 1.0]))
    filt.step(np.zeros(3), np.array([1.2, 1.5, 50.0]))
    assert filt.reinitialised_at == [[], [2], [4]]
    np.testing.assert_allclose(filt.weights[2], 1 / 200, rtol=1e-12)


# -- the APF: the second-stage weight ---------------------------------------------------------------
def test_the_apfs_second_stage_weight_is_the_likelihood_ratio(paper_world):
    """Algorithm 5 with mu_i one draw of the transition: x^j ~ p(x_k | x^{i^j}) and w^j = p(z | x^j) /
    p(z | mu^{i^j}). Computed here independently: the same draws replayed from a copy of the filter's
    Generator, in the order the step makes them (mu's headings, the resampling offset, x's headings)."""
    count, compass, z, delta = 400, 0.7, 1.3, 0.5
    start = paper_world.random_free_places(count, np.random.default_rng(5)).astype(np.float32)
    rng = np.random.default_rng(6)
    replay = np.random.default_rng(6)
    apf = AuxiliaryParticleFilter(paper_world, 0.3, delta, start, rng)
    apf.step(compass, z)

    def moved(points, uniforms):
        headings = (uniforms - np.float32(0.5)) * np.float32(delta) + np.float32(compass)
        return points + ROBOT_SPEED * np.column_stack([np.cos(headings), np.sin(headings)])

    mu = moved(start.astype(float), replay.random(count, dtype=np.float32).astype(float))
    first = log_likelihood(z, mu, paper_world, 0.3)
    w_first = np.exp(first - first.max())
    w_first /= w_first.sum()
    u = replay.random()  # systematic resampling: ancestors from one offset
    ancestors = np.searchsorted(np.cumsum(w_first), (np.arange(count) + u) / count, side="right")
    x = moved(start.astype(float)[ancestors], replay.random(count, dtype=np.float32).astype(float))
    log_w = log_likelihood(z, x, paper_world, 0.3) - first[ancestors]  # p(z | x^j) / p(z | mu^{i^j})
    expected = np.exp(log_w - log_w.max())
    expected /= expected.sum()
    np.testing.assert_allclose(apf.positions, x, atol=1e-4)
    np.testing.assert_allclose(apf.weights, expected, rtol=2e-3, atol=1e-9)


def test_without_compass_noise_the_apfs_second_stage_weights_are_equal(paper_world):
    """With Delta = 0 the move is deterministic, so x^j = mu^{i^j} and every ratio p(z|x^j) / p(z|mu^{i^j})
    is 1: the weights after the step are uniform (without the division they would be p(z | x^j))."""
    particles = paper_world.random_free_places(500, np.random.default_rng(8))
    apf = AuxiliaryParticleFilter(paper_world, 0.3, 0.0, particles, np.random.default_rng(9))
    apf.step(0.4, 1.1)
    np.testing.assert_allclose(apf.weights, 1 / 500, rtol=1e-5)


# -- the green circle: weight, not particles --------------------------------------------------------
def cloud(world, near: int, far: int, near_weight: float) -> SIRParticleFilter:
    """`near` particles at (2, 2) sharing `near_weight`, `far` at (4.5, 4.5) sharing the rest."""
    positions = np.array([[2.0, 2.0]] * near + [[4.5, 4.5]] * far)
    filt = SIRParticleFilter(world, 0.3, 0.5, positions, np.random.default_rng(0))
    weights = np.r_[np.full(near, near_weight / near), np.full(far, (1 - near_weight) / far)]
    filt.log_weights = np.log(weights)
    return filt


def test_the_green_circle_counts_the_weight_within_one_not_the_particles(paper_world):
    """95% of the weight within distance 1 of the estimate: 90 of 100 particles holding 96% of the
    weight is confident; 97 of 100 holding 90% is not."""
    heavy = cloud(paper_world, 90, 10, 0.96)
    assert np.hypot(*(heavy.estimate - 2.0)) < 1 and heavy.is_confident
    light = cloud(paper_world, 97, 3, 0.90)
    assert np.hypot(*(light.estimate - 2.0)) < 1 and not light.is_confident
    assert CONFIDENCE_SHARE == 0.95


# -- the kidnap study's windows ---------------------------------------------------------------------
def kidnapped(errors, kidnap_at=5):
    return SimpleNamespace(errors=np.asarray(errors, dtype=float), kidnap_at=kidnap_at)


def test_relocalised_means_the_mean_error_of_the_last_window_steps_is_small():
    """The last DEFAULT_WINDOW (30) steps: 10 good final steps after 20 bad ones is not re-localised."""
    assert DEFAULT_WINDOW == 30
    bad, good = 3 * CONVERGENCE_RADIUS, 0.1 * CONVERGENCE_RADIUS
    assert relocalised(kidnapped([bad] * 40 + [good] * 30))
    assert not relocalised(kidnapped([bad] * 40 + [bad] * 20 + [good] * 10))
    assert relocalised(kidnapped([bad] * 60 + [good] * 30))  # what came before the window does not count


def test_recovery_steps_count_from_the_kidnapping_step():
    """R - K: the error stays below the radius from step R on, K the kidnap step (1-based)."""
    errors = [0.1] * 4 + [2.0] * 6 + [0.1] * 10  # kidnapped at step 5; good again from step 11
    assert recovery_steps(kidnapped(errors, kidnap_at=5)) == 6
    assert recovery_steps(kidnapped([0.1] * 20, kidnap_at=5)) == 0
    assert recovery_steps(kidnapped([0.1] * 10 + [2.0] * 10, kidnap_at=5)) is None


def test_a_seeded_sensor_resetting_run_recovers_and_recovery_steps_say_when(paper_world):
    """Seed 9 (sigma 0.3, 200 particles, kidnapped at step 12 of 30): localised before, lost after,
    found again; recovery_steps marks the first step of the final good stretch."""
    robot = Robot(0.3, 0.5, (3.5, 1.5))
    result = simulate(robot, paper_world, 0.3, 0.5, 200, 30, filtering_algorithm="sir", seed=9, kidnap_at=12,
                      recovery="sensor")  # fmt: skip
    errors, steps = result.errors, recovery_steps(result)
    assert errors[10] < CONVERGENCE_RADIUS and errors[11] >= CONVERGENCE_RADIUS  # found, then carried off
    assert steps is not None and steps > 0
    assert (errors[11 + steps :] < CONVERGENCE_RADIUS).all() and errors[11 + steps - 1] >= CONVERGENCE_RADIUS


# -- recovery: nothing injected while the filter is localised -----------------------------------------
@pytest.mark.parametrize("name", ["sir", "apf", "rpf"])
@pytest.mark.parametrize("mode", ["augmented", "sensor"])
def test_recovery_injects_nothing_between_localisation_and_the_kidnapping(paper_world, name, mode):
    """Once the filter has found the robot (error below the radius from step 10 to 39), w_fast stays at
    its localised level, so recovery injects no particle until the kidnapping at step 40; after it,
    the measurements stop matching and it does."""
    injected = {}

    def watch(k, robot, filt):
        injected[k] = 0 if filt.injected is None else int(filt.injected.sum())

    robot = Robot(0.3, 0.5, (3.5, 1.5))
    result = simulate(robot, paper_world, 0.3, 0.5, 500, 60, filtering_algorithm=name, seed=3, kidnap_at=40,
                      recovery=mode, on_step=watch)  # fmt: skip
    assert (result.errors[9:39] < CONVERGENCE_RADIUS).all()
    assert sum(injected[k] for k in range(10, 40)) == 0
    assert sum(injected[k] for k in range(40, 61)) > 0


# -- the contract --------------------------------------------------------------------------------------
BAD_OPTIONS = {"recovery": True, "resampling": "nonsense", "bandwidth": "typo", "threshold": 0.3, "init": "prior"}


@pytest.mark.parametrize("cls", list(FILTERS.values()), ids=list(FILTERS))
def test_every_filter_refuses_each_option_it_does_not_declare_naming_it(paper_world, cls, monkeypatch):
    robot = Robot(0.3, 0.5, (3.5, 1.5))
    refused = [option for option in BAD_OPTIONS if option not in cls.options]
    assert refused, f"{cls.name} declares every option tried"
    for option in refused:
        with pytest.raises(ValueError, match=rf"^{cls.name} does not take the option {option} \(it takes: "):
            simulate(robot, paper_world, 0.3, 0.5, 50, 2, filtering_algorithm=cls, seed=1,
                     **{option: BAD_OPTIONS[option]})  # fmt: skip


@pytest.mark.parametrize("cls", list(FILTERS.values()), ids=list(FILTERS))
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


# -- the batched path: declared, and never quiet about a failure ----------------------------------------
def test_runs_go_together_by_the_declared_rule(paper_world):
    settings = study_settings([MazeChoice.from_maze("paper", paper_world)], [0.3], [0.5], [100], [0.2])
    plain = study_tasks(settings, ["SIRParticleFilter", "RegularizedParticleFilter"], 3, 5, 1)
    assert batch_runs.batchable(plain[0])
    assert not batch_runs.batchable(study_tasks(settings, ["SIRParticleFilter"], 3, 5, 1, kld=True)[0])
    assert not batch_runs.batchable(study_tasks(settings, ["SIRParticleFilter", "GridBayesFilter"], 3, 5, 1)[0])
    assert SIRParticleFilter.runs_together({"bandwidth": "multimodal", "estimate": "mode"})
    assert not SIRParticleFilter.runs_together({"recovery": "sensor"})


def test_an_error_in_a_batched_unit_is_reported_for_its_runs(paper_world, monkeypatch):
    settings = study_settings([MazeChoice.from_maze("paper", paper_world)], [0.3], [0.5], [100], [0.2])
    unit = tuple(study_tasks(settings, ["SIRParticleFilter"], 3, 5, 1))

    def broken(self, compass_angle, z):
        raise RuntimeError("a bug in the step")

    monkeypatch.setattr(SIRParticleFilter, "step", broken)
    outcomes = batch_runs.run_unit_safely(unit)
    assert len(outcomes) == 3
    assert all(isinstance(o, batch_runs.RunFailure) and "a bug in the step" in o.message for o in outcomes)
    assert all("runs advanced together" in o.message for o in outcomes)


# -- the command line reads the same declaration --------------------------------------------------
@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["run", "--filter", "grid", "--recovery"], "GridBayesFilter does not take --recovery"),
        (["run", "--filter", "grid", "--resampling", "systematic"], "GridBayesFilter does not take --resampling"),
        (["run", "--filter", "ekf", "--bandwidth", "multimodal"], "ExtendedKalmanFilter does not take --bandwidth"),
        (["run", "--filter", "apf", "--init", "start"], "AuxiliaryParticleFilter does not take --init"),
        (["study", "--filters", "sir", "--bandwidth", "multimodal"], "SIRParticleFilter does not take --bandwidth"),
        (["study", "--filters", "sir,apf", "--threshold", "0.3"], "SIRParticleFilter and AuxiliaryParticleFilter do"),
        (["study", "--filters", "grid,ekf", "--kld"], "GridBayesFilter and ExtendedKalmanFilter do not take --kld"),
        # a flag that tunes an option (recovery's rates, KLD's bounds) is refused where the option is
        (["run", "--filter", "grid", "--alpha-fast", "0.2"], "GridBayesFilter does not take --alpha-fast"),
        (["run", "--filter", "ekf", "--alpha-slow", "0.01"], "ExtendedKalmanFilter does not take --alpha-slow"),
        (["run", "--filter", "grid", "--kld-epsilon", "0.1"], "GridBayesFilter does not take --kld-epsilon"),
        (["run", "--filter", "ekf", "--kld-z", "1.5"], "ExtendedKalmanFilter does not take --kld-z"),
        (["compare", "s.json", "--filters", "grid,ekf", "--alpha-fast", "0.2"], "ExtendedKalmanFilter do not take"),
    ],
)
def test_the_command_line_refuses_an_option_no_chosen_filter_takes(tmp_path, capsys, args, message):
    from mazelab.cli.app import main

    if args[0] == "compare":  # a scenario to compare on
        scenario = tmp_path / "s.json"
        assert main(["run", "--steps", "3", "--particles", "20", "--seed", "1", "--quiet", "--no-viz",
                     "--save-scenario", str(scenario)]) == 0  # fmt: skip
        capsys.readouterr()
        args = [args[0], str(scenario), *args[2:]]
    assert main([*args, "--no-viz"]) == 2
    err = capsys.readouterr().err
    assert message in err and err.count("\n") == 1


def test_a_refusal_names_the_flags_of_the_command_it_refuses(capsys):
    """study has --recovery NAMES and no --sensor-resetting: its refusals name only its own flags."""
    from mazelab.cli.app import main

    assert main(["study", "--filters", "grid", "--recovery", "augmented", "--no-viz"]) == 2
    err = capsys.readouterr().err
    assert "GridBayesFilter does not take --recovery (it takes: resolution, " in err and "--sensor-resetting" not in err


def test_an_option_some_chosen_filters_take_goes_to_those(tmp_path, capsys):
    from mazelab.cli.app import main

    args = ["study", "--maze", "paper_5x5", "--filters", "sir,grid", "--estimate", "mode", "--runs", "1"]
    assert main([*args, "--steps", "4", "--particles", "50", "--seed", "1", "--no-viz", "--workers", "1"]) == 0


# -- accuracy: the second half of the steps --------------------------------------------------------
def test_accuracy_averages_the_distance_over_the_second_half_of_the_steps():
    """The first localisation is not accuracy: 10 steps 3 units off, then 10 steps 0.1 off gives 0.1."""
    from mazelab.experiments.accuracy import distance_to_exact

    exact = np.zeros((20, 2))
    estimates = np.r_[np.full((10, 2), [3.0, 0.0]), np.full((10, 2), [0.0, 0.1])]
    assert distance_to_exact(estimates, exact) == pytest.approx(0.1)
    assert distance_to_exact(estimates[:19], exact[:19]) == pytest.approx((3.0 + 9 * 0.1) / 10)  # steps 10-19
