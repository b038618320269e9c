"""The exercise: StudentFilter's wiring, `exercise new`, and `exercise check`, which passes the shipped
SIR written as a StudentFilter (and a multinomial resampler), fails the unfilled skeleton on all four
parts, and fails each broken variant on the right part."""

from __future__ import annotations

import math
import subprocess
import sys

import numpy as np
import pytest
from exercise_answers import BROKEN, MultinomialFilter, ReferenceFilter

from mazelab.cli.app import main
from mazelab.contract import check_filter
from mazelab.exercise import PARTS, StudentFilter
from mazelab.exercise.parts import check_parts, kolmogorov_p, ks_uniform, resample_weights
from mazelab.exercise.report import check, progress
from mazelab.exercise.whole import sign_test_alpha
from mazelab.plugins import load_plugin
from mazelab.simulation import simulate


@pytest.fixture(scope="module")
def reference_report():
    return check(ReferenceFilter)


def test_the_shipped_sir_as_a_student_filter_passes_every_row(reference_report):
    assert [row.part for row in reference_report.rows] == [*PARTS, "whole filter"]
    assert reference_report.passed, [row for row in reference_report.rows if not row.passed]
    assert "looks systematic" in reference_report.row("resample").got
    assert len(reference_report.figures) == 12


def test_a_multinomial_resampler_passes_and_is_named():
    rows, scheme = check_parts(MultinomialFilter)
    assert all(row.passed for row in rows), rows
    assert scheme == "multinomial" and "looks multinomial" in rows[2].got


@pytest.mark.parametrize("variant", list(BROKEN), ids=lambda cls: cls.__name__)
def test_each_broken_variant_fails_its_part_only(variant):
    rows, _ = check_parts(variant)
    failed = [row.part for row in rows if not row.passed]
    assert failed == [BROKEN[variant]]
    assert next(row for row in rows if not row.passed).hint


def test_the_hints_name_what_is_wrong():
    import exercise_answers as answers

    hints = {cls.__name__: next(r.hint for r in check_parts(cls)[0] if not r.passed) for cls in BROKEN}
    assert "the sign" in hints[answers.SignFlipped.__name__]
    assert "sigma where sigma^2 belongs" in hints[answers.SigmaNotSquared.__name__]
    assert "outside penalty" in hints[answers.NoPenalty.__name__]
    assert "arange" in hints[answers.IdentityResample.__name__]
    assert "no heading noise" in hints[answers.NoHeadingNoise.__name__]
    assert "plain mean" in hints[answers.UnweightedMean.__name__]


def test_the_skeleton_fails_all_four_parts_as_not_implemented(tmp_path, capsys):
    assert main(["exercise", "new", str(tmp_path / "ex")]) == 0
    skeleton = load_plugin(str(tmp_path / "ex" / "my_filter.py"))
    report = check(skeleton)
    rows = [(row.part, row.passed, row.got) for row in report.rows[:4]]
    assert rows == [(part, False, "not implemented") for part in PARTS]
    assert report.row("whole filter").got == "not run" and not report.passed
    assert main(["exercise", "check", str(tmp_path / "ex" / "my_filter.py:MyFilter")]) == 1
    assert "To fix: predict, weigh, resample, estimate, whole filter." in capsys.readouterr().out


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


def test_a_failing_part_is_named_in_the_whole_filters_hint(monkeypatch):
    import exercise_answers as answers

    import mazelab.exercise.report as report_module
    from mazelab.exercise.parts import Row

    hint = "the parts pass alone but not together: check what weigh and predict assume of each other"

    def failing_whole(filter_class, scheme):  # a fresh row each call: check() may rewrite its hint
        return Row("whole filter", False, "", "", hint), []

    monkeypatch.setattr(report_module, "check_whole", failing_whole)
    assert check(answers.UnweightedMean).row("whole filter").hint.startswith("fix estimate first")
    assert check(ReferenceFilter).row("whole filter").hint == hint  # every part passes: the hint stands


def test_an_error_in_the_whole_filter_is_one_table_cell_naming_the_students_line():
    class Raising(ReferenceFilter):
        def predict(self, positions, compass_angle, rng):
            raise RuntimeError("my bug")

    row = check(Raising).row("whole filter")
    assert not row.passed and "\n" not in row.got and row.hint == "fix the error first"
    assert "raised RuntimeError at step 1: my bug; " in row.got and "test_exercise.py, line" in row.got


def test_new_refuses_to_overwrite_without_force(tmp_path, capsys):
    assert main(["exercise", "new", str(tmp_path)]) == 0
    (tmp_path / "my_filter.py").write_text("# my work\n")
    assert main(["exercise", "new", str(tmp_path)]) == 2
    assert "--force" in capsys.readouterr().err
    assert (tmp_path / "my_filter.py").read_text() == "# my work\n"
    assert main(["exercise", "new", str(tmp_path), "--force"]) == 0
    assert "class MyFilter(StudentFilter)" in (tmp_path / "my_filter.py").read_text()


def test_check_refuses_what_is_not_a_python_file(tmp_path, capsys):
    assert main(["exercise", "check", "sir"]) == 2
    assert main(["exercise", "check", str(tmp_path / "none.py")]) == 2
    assert "none.py" in capsys.readouterr().err


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
    assert result.filter_name == "ReferenceFilter"
    again = simulate(Robot(0.3, 0.5, (1.5, 0.5)), *args, filtering_algorithm=ReferenceFilter, seed=4)
    assert np.array_equal(result.estimates, again.estimates)  # every draw from the seeded rng


def test_student_filter_restarts_from_the_prior_when_no_particle_explains_z(paper_world):
    particles = np.tile([2.5, 1.5], (100, 1))  # all in one spot
    filt = ReferenceFilter(paper_world, 0.2, 0.5, particles, np.random.default_rng(3))
    filt.step(0.0, 1e6)  # nothing is a million units from a station
    assert filt.reinitialised_at == [1]
    assert np.isclose(filt.weights, 1 / 100).all() and len(np.unique(filt.positions, axis=0)) == 100


def test_student_filter_refuses_estimate_mode(paper_world):
    with pytest.raises(ValueError, match="estimate='mode' does not apply"):
        StudentFilter(paper_world, 0.3, 0.5, [[1.5, 0.5]], estimate="mode")


def test_the_statistics_behind_the_checks():
    n = 1000
    assert math.isclose(kolmogorov_p(1.3581 / math.sqrt(n), n), 0.05, abs_tol=0.003)  # the 5% critical value
    uniform = (np.arange(n) + 0.5) / n
    assert ks_uniform(uniform) == pytest.approx(0.5 / n)
    assert sign_test_alpha() == 13 / 4096
    weights = resample_weights()
    assert math.isclose(weights.sum(), 1) and np.all(np.abs(40 * weights % 1 - 0.5) <= 0.4 + 1e-9)
