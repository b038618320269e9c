"""The exercise's verdicts, in this process (the student's own self-check, mazelab.exercise.selfcheck;
the isolated grade is tests/test_grading.py): correct parts pass, each broken part fails with the hint
that names its bug, and each tolerance is pinned by a slightly wrong part that fails (and would pass
if the check were ten times looser); StudentFilter's wiring, `exercise new` and the self-check."""

from __future__ import annotations

import math
import subprocess
import sys

import exercise_answers as answers
import numpy as np
import pytest
from exercise_answers import BROKEN, MultinomialFilter, ReferenceFilter, row_of

from mazelab.cli.app import main
from mazelab.contract import check_filter
from mazelab.exercise import PARTS, StudentFilter
from mazelab.exercise.inputs import (
    RESAMPLE_KINDS,
    default_seed,
    draw_part_inputs,
    draw_scenarios,
    resample_vector,
)
from mazelab.exercise.parts import (
    critical_z,
    judge_resample,
    judge_whole,
    kolmogorov_p,
    ks_uniform,
    magnitude_p,
    offspring_counts,
    scheme_variances,
    sign_test_alpha,
    take,
    z_scores,
)
from mazelab.exercise.report import WIDTH, check, collect_in_process, format_report
from mazelab.exercise.selfcheck import progress
from mazelab.registry import load_plugin
from mazelab.resampling import RESAMPLING_SCHEMES
from mazelab.simulation import simulate

SEEDS = (3, 4)  # the part checks' inputs of two seeds (different mazes, sigma, delta, sizes)
WHOLE_SEED = 2024  # the whole filter's scenarios (the exact runs are computed once per process)
BONFERRONI_SEED = 107  # a correct multinomial resampler's largest |z| there is 3.55: past 3.29, the
# two-sided normal quantile at 0.001, but within the corrected quantile (about 4.6 for ~250 particles)


def failing(cls: type, seed: int, stages: tuple[str, ...] = tuple(PARTS)) -> list[tuple[str, str, str]]:
    """(part, got, hint) of each row of `stages` that does not pass."""
    return [(r.part, r.got, r.hint) for r in check(cls, seed=seed, stages=stages).rows if not r.passed]


@pytest.mark.parametrize("seed", SEEDS)
def test_the_shipped_sir_as_a_student_filter_passes_every_part(seed):
    report = check(ReferenceFilter, seed=seed, stages=tuple(PARTS))
    assert [row.part for row in report.rows] == list(PARTS)
    assert report.passed, [row for row in report.rows if not row.passed]
    assert "looks systematic" in row_of(report, "resample").got


@pytest.mark.parametrize("cls", [MultinomialFilter, answers.StratifiedFilter, answers.ResidualFilter])
def test_any_unbiased_resampler_passes_and_is_named(cls):
    row = row_of(check(cls, seed=SEEDS[0], stages=("resample",)), "resample")
    assert row.passed, row
    assert f"looks {cls.__name__.removesuffix('Filter').lower()}" in row.got


@pytest.mark.parametrize("variant", list(BROKEN), ids=lambda cls: cls.__name__)
def test_each_broken_part_fails_with_the_hint_that_names_its_bug(variant):
    part, phrase = BROKEN[variant]
    rows = failing(variant, SEEDS[1], (part,))
    assert [row[0] for row in rows] == [part]
    assert phrase in rows[0][2], rows[0]


@pytest.mark.parametrize("share", [0.5, 0.9])
def test_an_ess_gate_inside_resample_fails_whatever_its_threshold(share):
    """Under the mild weights the ESS is 0.99 N: a gate at N/2 or at 0.9 N keeps every particle there."""
    (_, got, hint), *_ = failing(answers.ess_gate(share), SEEDS[0], ("resample",))
    assert "resample always draws" in hint and ("mild" in got or share == 0.5)


def test_a_wrong_station_is_not_told_a_scale_of_the_exponent():
    (_, _, hint), *_ = failing(answers.WrongStation, SEEDS[0], ("weigh",))
    assert "times -(z - d)^2" not in hint and "distance_to_nearest_station" in hint


def test_one_heading_for_all_particles_is_not_called_no_noise():
    (_, got, hint), *_ = failing(answers.SharedHeading, SEEDS[0], ("predict",))
    assert "no heading noise" not in hint and "same heading" in got


# -- each tolerance pinned: a slightly wrong part fails, and would pass were the check 10x looser ----
def test_a_likelihood_one_percent_off_outside_the_free_area_fails_weigh():
    (part, got, hint), *_ = failing(answers.PenaltyOnePercentOff, SEEDS[0], ("weigh",))
    assert part == "weigh" and got == "largest deviation 0.00995"  # log(1.01): 10x the tolerance 1e-3
    assert "outside penalty" in hint and "-0.6832" in hint  # yours adds log(0.505)


def test_an_exponent_one_percent_off_fails_weigh_and_is_named():
    (_, _, hint), *_ = failing(answers.ExponentOnePercentOff, SEEDS[1], ("weigh",))
    assert "1.01 times" in hint


def test_a_step_three_ten_thousandths_long_fails_predict():
    (_, got, _), *_ = failing(answers.StepSlightlyLong, SEEDS[0], ("predict",))
    assert got.startswith("step lengths 0.20030..0.20030")  # 3e-4 off: 3x the tolerance 1e-4


def test_a_heading_spread_ten_percent_too_wide_fails_predict():
    (_, got, hint), *_ = failing(answers.SpreadTenPercentWide, SEEDS[0], ("predict",))
    assert "KS p" in got and "1.1 times the compass error's width" in hint


def test_the_ks_test_sits_at_its_stated_level():
    """A heading grid of scaled KS distance 2.25 (p 7.7e-5) fails the test at 0.00025 (it would pass
    at 0.000025); one at 1.98 (p 7.6e-4) passes (it would fail at 0.001, without the correction for
    predict's four tests)."""
    assert [p for p, *_ in failing(answers.ks_distance_predict(2.25), SEEDS[0], ("predict",))] == ["predict"]
    assert failing(answers.ks_distance_predict(1.98), SEEDS[0], ("predict",)) == []


def test_an_estimate_three_ten_thousandths_off_fails():
    (_, got, _), *_ = failing(answers.EstimateSlightlyOff, SEEDS[0], ("estimate",))
    assert got.startswith("off by 0.000424")  # hypot(3e-4, 3e-4): 4x the tolerance 1e-4


def test_a_resampler_biased_by_seven_standard_errors_fails():
    (_, got, _), *_ = failing(answers.biased_resampler(7.0), SEEDS[1], ("resample",))
    assert "particle 0 has mean offspring" in got


def test_the_resample_check_is_corrected_for_its_many_particles():
    """Without the Bonferroni correction (3.29 for each particle), a correct resampler would fail here."""
    parts = draw_part_inputs(BONFERRONI_SEED)
    answer = collect_in_process(MultinomialFilter, parts, [], ["resample"]).results["resample"]
    worst = max(
        float(np.abs(z_scores(offspring_counts(take(answer, f"ancestors/{k}", None, "<i8"), len(w)), w)).max())
        for k, w in enumerate(parts.resample.weights)
    )
    assert 3.29 < worst < critical_z(sum(len(w) for w in parts.resample.weights))
    assert judge_resample(parts, answer)[0].passed


@pytest.mark.parametrize("seed", [10006, 10035])
def test_a_systematic_resampler_passes_where_a_count_rarely_or_never_varies(seed):
    """Correct systematic resampling failed these seeds' mild vectors: N W_i = 0.99995 gives 1 offspring
    at all 4000 calls (probability 0.82), and N W_i = 1.0018 gave 2 offspring once where about 7 calls do
    on average (the sample variance then makes a correct count look 6.4 standard errors off)."""
    parts = draw_part_inputs(seed)
    answer = collect_in_process(ReferenceFilter, parts, [], ["resample"]).results["resample"]
    assert judge_resample(parts, answer)[0].passed


def test_a_count_that_never_varies_is_judged_by_its_probability():
    """Always 1 offspring: fine for N W = 0.99995 (p = 0.82), a bias for N W = 0.99 (p = 4e-18) and for
    1.01005 (below N W, the sign says so); exactly N W is z = 0; a p below the smallest double is inf."""
    counts = np.ones((4000, 4), dtype=np.int64)
    weights = np.array([0.99995, 0.99, 1.0, 1.01005]) / 4
    z = z_scores(counts, weights)
    critical = critical_z(4)
    assert abs(z[0]) < 1 and z[1] > critical and z[2] == 0 and z[3] < -critical
    assert np.isinf(z_scores(np.ones((4000, 2), dtype=np.int64), np.array([0.25, 1.75]) / 2)[1])


# -- the whole filter ------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def reference_report():
    return check(ReferenceFilter, seed=WHOLE_SEED)


def test_the_shipped_sir_as_a_student_filter_passes_the_whole_filter(reference_report):
    assert [row.part for row in reference_report.rows] == [*PARTS, "whole filter"]
    assert reference_report.passed, [row for row in reference_report.rows if not row.passed]
    assert len(reference_report.figures) == 12
    assert {f.scenario.maze for f in reference_report.figures} <= {"paper_5x5", "maze_10x10"}


def test_the_report_fits_in_a_hundred_columns(reference_report):
    text = format_report(reference_report)
    assert max(map(len, text.splitlines())) <= WIDTH
    broken = format_report(check(answers.WrongStation, seed=SEEDS[0], stages=tuple(PARTS)))
    assert max(map(len, broken.splitlines())) <= WIDTH and "\n" + " " * 28 + "hint: " in broken


def test_parts_that_pass_alone_but_not_together_fail_the_whole_filter(reference_report):
    report = check(answers.ForgetsResampling, seed=WHOLE_SEED)
    assert [row.passed for row in report.rows] == [True] * 4 + [False]
    assert "farther on" in row_of(report, "whole filter").got


def test_a_nan_estimate_never_passes_the_whole_filter(reference_report):
    class NanWhole(ReferenceFilter):
        """Its estimate part is right; the estimate the filter reports is not a number."""

        @property
        def estimate(self):
            return np.array([np.nan, np.nan])

    NanWhole.estimate_part = ReferenceFilter.estimate_part
    row = row_of(check(NanWhole, seed=WHOLE_SEED), "whole filter")
    assert not row.passed and "nan" in row.got and "a number at every step" in row.hint


def test_an_error_in_the_whole_filter_is_one_cell_naming_the_students_line():
    class Raising(ReferenceFilter):
        def step(self, compass_angle, z):
            raise RuntimeError("my bug")

    row = row_of(check(Raising, seed=WHOLE_SEED), "whole filter")
    assert not row.passed and "\n" not in row.got and row.hint == "fix the error first"
    assert "raised RuntimeError at step 1: my bug (test_exercise.py, line " in row.got


def test_a_failing_part_is_named_in_the_whole_filters_hint():
    row = row_of(check(answers.SignFlipped, seed=WHOLE_SEED), "whole filter")
    assert not row.passed and row.hint.startswith("fix weigh first")


# -- fresh inputs from a seed ------------------------------------------------------------------------
def test_each_seed_draws_fresh_inputs_and_the_same_seed_the_same():
    first, again, other = draw_part_inputs(5), draw_part_inputs(5), draw_part_inputs(6)
    assert np.array_equal(first.predict.start, again.predict.start) and first.sigma == again.sigma
    assert len(first.estimate.points) != len(other.estimate.points) and first.delta != other.delta
    assert first.predict.angles != other.predict.angles
    assert [len(w) for w in first.resample.weights] != [len(w) for w in other.resample.weights]
    assert 0.4 <= first.sigma <= 0.8 and 0.1 <= first.delta <= 0.4  # away from the example's 0.3, 0.5
    walks = draw_scenarios(5, count=2, steps=5), draw_scenarios(6, count=2, steps=5)
    assert walks[0][0].measurements != walks[1][0].measurements
    assert default_seed(b"a") == default_seed(b"a") != default_seed(b"b") and 0 <= default_seed(b"a") < 2**63


def test_the_weight_vectors_are_of_their_kinds():
    rng = np.random.default_rng(1)
    for kind in RESAMPLE_KINDS:
        weights = resample_vector(kind, 51, rng)
        assert math.isclose(weights.sum(), 1) and (kind == "even") == np.allclose(weights, 1 / 51)
        assert (51 * weights).min() >= 0.19  # every particle's offspring count averages near normal
    ess = 1 / np.sum(resample_vector("mild", 1000, rng) ** 2)
    assert ess > 950  # keeping every particle is wrong even where the ESS is high
    assert resample_vector("one dominant", 51, rng).max() == pytest.approx(0.5)


def test_the_scheme_variances_are_those_of_the_shipped_schemes():
    weights = resample_vector("fractional", 41, np.random.default_rng(2))
    exact = scheme_variances(weights)
    for name, scheme in RESAMPLING_SCHEMES.items():
        rng = np.random.default_rng(3)
        counts = offspring_counts(np.stack([scheme(weights, rng) for _ in range(4000)]), 41)
        measured = counts.var(axis=0, ddof=1).sum()
        assert measured == pytest.approx(exact[name], rel=0.06), name  # a variance's error over 4000: ~2%


def test_the_statistics_behind_the_checks():
    n = 1000
    assert math.isclose(kolmogorov_p(1.3581 / math.sqrt(n), n), 0.05, abs_tol=0.003)  # the 5% critical value
    uniform = (np.arange(n) + 0.5) / n
    assert ks_uniform(uniform) == pytest.approx(0.5 / n)
    assert ks_uniform(np.concatenate([uniform, [-5.0]])) < 0.002  # below 0 the CDF is 0, not negative
    assert sign_test_alpha() == 13 / 4096
    assert critical_z(1) == pytest.approx(3.2905, abs=1e-4)


# -- StudentFilter, exercise new, the self-check -------------------------------------------------------
def test_the_skeleton_fails_all_four_parts_as_not_written(tmp_path):
    assert main(["exercise", "new", str(tmp_path / "ex")]) == 0
    skeleton = load_plugin(str(tmp_path / "ex" / "my_filter.py"))
    report = check(skeleton, seed=SEEDS[0], stages=tuple(PARTS))
    assert [(row.part, row.status, row.got) for row in report.rows] == [
        (part, "not written", "not implemented") for part in PARTS
    ]


def test_running_the_skeleton_says_what_is_left(tmp_path):
    assert main(["exercise", "new", str(tmp_path)]) == 0
    done = subprocess.run([sys.executable, "my_filter.py"], cwd=tmp_path, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert "MyFilter: still to write: predict, weigh, resample, estimate" in done.stdout
    assert (tmp_path / "README.md").read_text().startswith("# Your own particle filter")


def test_progress_checks_the_parts_written():
    class Half(ReferenceFilter):
        def resample(self, weights, rng):
            raise NotImplementedError

    text = progress(Half)
    assert "still to write: resample" in text and "weigh" in text and "pass" in text


def test_progress_prints_the_check_command_of_this_file(tmp_path, monkeypatch):
    (tmp_path / "mine.py").write_text(
        "from exercise_answers import ReferenceFilter\n\n\n"
        "class MyFilter(ReferenceFilter):\n    pass\n\n\n"
        "class Other(ReferenceFilter):\n    pass\n"
    )
    monkeypatch.chdir(tmp_path)
    monkeypatch.delenv("UV", raising=False)
    lines = [progress(load_plugin(f"mine.py:{name}")).splitlines()[-1] for name in ("MyFilter", "Other")]
    assert lines[0].endswith(" exercise check mine.py") and "FILE" not in lines[0]
    assert lines[1].endswith(" exercise check mine.py:Other")


def test_new_refuses_to_overwrite_without_force(tmp_path, capsys):
    assert main(["exercise", "new", str(tmp_path)]) == 0
    (tmp_path / "my_filter.py").write_text("# my work\n")
    assert main(["exercise", "new", str(tmp_path)]) == 2
    assert "--force" in capsys.readouterr().err
    assert (tmp_path / "my_filter.py").read_text() == "# my work\n"
    assert main(["exercise", "new", str(tmp_path), "--force"]) == 0
    assert "class MyFilter(StudentFilter)" in (tmp_path / "my_filter.py").read_text()


def test_the_skeleton_docstrings_name_the_equation_and_the_line():
    from mazelab.exercise.template import FILTER_TEMPLATE

    lines = ('"Draw x_k^i ~ p(x_k | x_(k-1)^i)": the paper\'s equation (1)', "equation (3)", '"RESAMPLE"')
    for text in (*lines, "posterior mean"):
        assert text in FILTER_TEMPLATE


def test_student_filter_meets_the_contract_and_runs(paper_world):
    from mazelab.robot import Robot

    particles = paper_world.random_free_places(300, np.random.default_rng(1))
    filt = ReferenceFilter(paper_world, 0.3, 0.5, particles, np.random.default_rng(2))
    check_filter(filt)
    assert ReferenceFilter.name == "ReferenceFilter" and ReferenceFilter.options.defaults() == {"estimate": "mean"}
    filt.step(0.3, 1.0)
    assert filt.estimate.shape == (2,) and 1 <= filt.ess <= 300 and math.isclose(filt.belief().weights.sum(), 1)
    args = (paper_world, 0.3, 0.5, 300, 40)
    result = simulate(Robot(0.3, 0.5, (1.5, 0.5)), *args, filtering_algorithm=ReferenceFilter, seed=4)
    assert result.inputs.filtering_algorithm == "ReferenceFilter"
    again = simulate(Robot(0.3, 0.5, (1.5, 0.5)), *args, filtering_algorithm=ReferenceFilter, seed=4)
    assert np.array_equal(result.estimates, again.estimates)  # every draw from the seeded rng
    # the student's weigh may leave out p(z | x)'s constant: no log evidence is claimed ('-' in compare)
    assert np.isnan(result.log_evidence).all()


def test_student_filter_restarts_from_the_prior_when_no_particle_explains_z(paper_world):
    particles = np.tile([2.5, 1.5], (100, 1))  # all in one spot
    filt = ReferenceFilter(paper_world, 0.2, 0.5, particles, np.random.default_rng(3))
    filt.step(0.0, 1e6)  # nothing is a million units from a station
    assert filt.reinitialised_at == [1]
    assert np.isclose(filt.weights, 1 / 100).all() and len(np.unique(filt.positions, axis=0)) == 100


def test_student_filter_refuses_estimate_mode(paper_world):
    with pytest.raises(ValueError, match="estimate='mode' does not apply"):
        StudentFilter(paper_world, 0.3, 0.5, [[1.5, 0.5]], estimate="mode")


# -- the whole filter judged by magnitude too (issue 48, item 10) -----------------------------------------
def whole_verdict(distances: list[float], sir_distances: list[float]) -> tuple[str, str]:
    """The whole filter's (status, got) for these distances to the exact mean (steady offsets along x)."""
    scenarios = draw_scenarios(WHOLE_SEED, count=len(distances), steps=4)
    exact = [np.zeros((4, 2)) for _ in scenarios]
    mine = [np.column_stack([np.full(4, d), np.zeros(4)]) for d in distances]
    sir = [np.column_stack([np.full(4, d), np.zeros(4)]) for d in sir_distances]
    row, _ = judge_whole(scenarios, mine, exact, sir, "systematic")
    return row.status, row.got


def test_a_filter_far_off_fails_though_the_sir_lost_the_robot_twice():
    """Nine times the SIR's distance on ten walks, closer only on the two where the SIR itself lost the
    robot: the sign test alone passes it (farther on 10 < 11); the magnitude test fails it."""
    sir = [0.05] * 10 + [6.0, 5.5]
    mine = [0.45] * 10 + [5.0, 4.0]
    status, got = whole_verdict(mine, sir)
    assert status == "fail" and "farther on 10 of 12" in got and "p 0.00098" in got


def test_an_honest_filter_that_loses_the_robot_once_passes():
    """One walk 10 units off where the SIR is 0.07 (the catastrophe an honest filter can meet): one log
    ratio moves, not the verdict."""
    rng = np.random.default_rng(1)
    sir = list(rng.uniform(0.03, 0.08, 12))
    mine = [s * f for s, f in zip(sir, rng.uniform(0.8, 1.25, 12), strict=True)]
    mine[3] = 10.0
    assert whole_verdict(mine, sir)[0] == "pass"


def test_the_magnitude_test_is_exact_under_exchangeable_pairs():
    """Its p-value is the share of the 4096 sign patterns reaching the observed sum: all twelve ratios
    positive is 1/4096 whatever their sizes; a symmetric set of ratios is about 1/2."""
    assert magnitude_p(np.full(12, 2.0), np.ones(12))[1] == 1 / 4096
    ratio, p = magnitude_p(np.array([2.0, 0.5] * 6), np.ones(12))
    assert ratio == pytest.approx(1.0) and 0.4 < p < 0.7


# -- the exercise in Ukrainian (issue 49, item 10) --------------------------------------------------------
def test_new_writes_the_exercise_in_ukrainian_and_the_folder_keeps_its_language(tmp_path, capsys):
    import ast

    from mazelab.exercise.template import FILTER_TEMPLATE, exercise_texts

    assert main(["exercise", "new", str(tmp_path), "--lang", "uk"]) == 0
    mine = (tmp_path / "my_filter.py").read_text()
    assert 'LANGUAGE = "uk"' in mine and "гранул" in mine and "still to write" not in mine
    assert (tmp_path / "README.md").read_text().startswith("# Ваш власний гранулярний фільтр")

    def code(text: str) -> str:  # the code without its strings (docstrings, error texts) and the language
        tree = ast.parse(text.replace('LANGUAGE = "uk"', 'LANGUAGE = "en"'))
        for node in ast.walk(tree):
            if isinstance(node, ast.Constant) and isinstance(node.value, str):
                node.value = ""
        return ast.dump(tree)

    assert code(mine) == code(FILTER_TEMPLATE) and exercise_texts("en") == exercise_texts()
    done = subprocess.run([sys.executable, "my_filter.py"], cwd=tmp_path, capture_output=True, text=True, timeout=120)
    assert "MyFilter: ще треба написати: predict, weigh, resample, estimate" in done.stdout, done.stderr
    assert main(["exercise", "check", str(tmp_path / "my_filter.py"), "--timeout", "30"]) == 1  # no --lang
    assert "Перевірка MyFilter" in capsys.readouterr().out
    assert main(["exercise", "new", str(tmp_path / "x"), "--lang", "xx"]) == 2
