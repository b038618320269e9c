"""The grade that 200 students will try to fool: `mazelab exercise check` runs the student's file in a
sandbox of its own and judges, in the grader, only the values it returned. Each cheat of issue 29 has a
test (a report patched at import, an exit in a part, a class that is not a StudentFilter, delegation
to the lab's reference implementation, NaN in the estimate, an ESS gate, reused heading noise, the
public inputs special-cased), and so has each way a child can end (an exit, a signal, a hang, output
that is not an answer). The sandbox and the adversaries of issue 37 are tests/test_grading_sandbox.py;
the folder grader is tests/test_grading_folder.py."""

from __future__ import annotations

import json
import re
import textwrap
import time

import pytest
from exercise_answers import row_of, write_submission

from mazelab.cli.app import main
from mazelab.exercise.inputs import default_seed, draw_scenarios, files_seed
from mazelab.exercise.report import NotGradableError, check_file

SEED = 2024  # the seed of tests/test_exercise.py's whole-filter tests: the exact runs are computed once
ALL = ("predict", "weigh", "resample", "estimate", "whole")


def rows(report) -> dict[str, tuple[str, str]]:
    return {row.part: (row.status, row.got) for row in report.rows}


def checked(tmp_path, *, stages=ALL, timeout=60.0, prelude="", class_line=None, **parts):
    """The report of a submission of the reference parts, `parts` replaced (a method's source)."""
    options = {} if class_line is None else {"class_line": class_line}
    path = write_submission(tmp_path / "my_filter.py", prelude, **options, **parts)
    return check_file(str(path), seed=SEED, timeout=timeout, stages=stages)


# -- an honest submission -----------------------------------------------------------------------------
def test_a_correct_submission_passes_and_its_seed_repeats_the_report_exactly(tmp_path, capsys):
    path = write_submission(tmp_path / "my_filter.py")
    assert main(["exercise", "check", str(path), "--seed", str(SEED)]) == 0
    first = capsys.readouterr().out
    assert "All checks pass." in first and f"inputs from seed {SEED} (given)" in first
    assert main(["exercise", "check", str(path), "--seed", str(SEED)]) == 0
    again = capsys.readouterr().out

    def without_time(text: str) -> list[str]:
        return [line for line in text.splitlines() if not line.startswith("checked in")]

    assert without_time(first) == without_time(again)
    assert max(map(len, first.splitlines())) <= 100


def test_the_default_seed_is_every_file_copied_with_the_submission(tmp_path):
    """Alone, the seed of the file's bytes; with a helper module beside it, of both: a fixed my_filter.py
    with a table module beside it gets new inputs whenever the table changes."""
    path = write_submission(tmp_path / "my_filter.py")
    report = check_file(str(path), stages=("estimate",))
    assert report.seed == default_seed(path.read_bytes()) and report.source == "files"
    path.write_text(path.read_text() + "# an edit\n")
    assert check_file(str(path), stages=("estimate",)).seed == default_seed(path.read_bytes()) != report.seed
    alone = default_seed(path.read_bytes())
    (tmp_path / "table.py").write_text("ANSWERS = {}\n")
    with_table = check_file(str(path), stages=("estimate",)).seed
    assert with_table == files_seed({p.name: p.read_bytes() for p in (path, tmp_path / "table.py")}) != alone
    (tmp_path / "table.py").write_text("ANSWERS = {1: 2}\n")
    assert check_file(str(path), stages=("estimate",)).seed != with_table


# -- the cheats of the issue ----------------------------------------------------------------------------
def test_a_report_patched_at_import_changes_nothing(tmp_path, capsys):
    prelude = """
        import mazelab.exercise.layout as layout
        import mazelab.exercise.report as report
        import mazelab.exercise.rows as rows

        report.Report.passed = property(lambda self: True)
        rows.Row.passed = property(lambda self: True)
        layout.format_report = lambda *args, **kwargs: "All checks pass."
    """
    path = write_submission(tmp_path / "my_filter.py", prelude, predict=None, weigh=None, resample=None, estimate=None)
    assert main(["exercise", "check", str(path), "--seed", str(SEED)]) == 2  # the grader is not in the sandbox
    captured = capsys.readouterr()
    assert "All checks pass." not in captured.out and "No module named 'mazelab.exercise.layout'" in captured.err


@pytest.mark.parametrize(
    "code, happened",
    [("import os; os._exit(0)", "exited with code 0 in weigh"), ("import sys; sys.exit(0)", "called sys.exit(0)")],
)
def test_an_exit_in_a_part_fails_that_part_and_the_others_are_still_judged(tmp_path, code, happened):
    weigh = f"def weigh(self, positions, z):\n    {code}\n"
    report = checked(tmp_path, stages=("predict", "weigh", "estimate"), weigh=weigh)
    assert rows(report)["weigh"][0] == "fail" and happened in rows(report)["weigh"][1]
    assert rows(report)["predict"][0] == rows(report)["estimate"][0] == "pass"
    assert not report.passed


@pytest.mark.parametrize("code", ["import os; os._exit(0)", "import sys; sys.exit(0)", "raise SystemExit(3)"])
def test_an_exit_while_the_file_is_imported_fails_every_row(tmp_path, capsys, code):
    path = write_submission(tmp_path / "my_filter.py", code)
    result = main(["exercise", "check", str(path), "--seed", str(SEED)])
    captured = capsys.readouterr()
    if "_exit" in code:  # the child ends: every row fails, naming it
        assert result == 1 and "exited with code 0 while importing the file" in captured.out
    else:  # the import fails: one line, exit 2
        assert result == 2 and "while being imported" in captured.err and captured.out == ""


def test_a_class_that_is_not_a_student_filter_is_one_line_and_exit_2(tmp_path, capsys):
    (tmp_path / "mine.py").write_text(
        "from mazelab.filters import SIRParticleFilter\n\n\nclass MyFilter(SIRParticleFilter):\n    pass\n"
    )
    (tmp_path / "own.py").write_text("class Filter:\n    name = 'mine'\n\n\nclass MyFilter(Filter):\n    pass\n")
    assert main(["exercise", "check", f"{tmp_path / 'own.py'}:MyFilter"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "MyFilter is not a StudentFilter" in err[0] and "own.Filter" not in err[0], err
    assert "(it subclasses submission.Filter)" in err[0]
    assert main(["exercise", "check", str(tmp_path / "mine.py")]) == 2  # the shipped filters are not there
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "No module named 'mazelab.filters'" in err[0]


DELEGATIONS = {
    "log_likelihood": (
        "weigh",
        """
        def weigh(self, positions, z):
            from mazelab.model import log_likelihood
            return log_likelihood(z, positions, self.world, self.sigma)
        """,
        "mazelab.model.log_likelihood",
    ),
    "reloaded": (
        "weigh",
        """
        def weigh(self, positions, z):
            import importlib
            import mazelab.model
            fresh = importlib.reload(mazelab.model)
            return fresh.log_likelihood(z, positions, self.world, self.sigma)
        """,
        "mazelab.model.log_likelihood",
    ),
    "copied code": (
        "weigh",
        """
        def weigh(self, positions, z):
            import types
            from mazelab.model import log_likelihood as original
            copy = types.FunctionType(original.__code__, original.__globals__, "mine", original.__defaults__)
            return copy(z, positions, self.world, self.sigma)
        """,
        "mazelab.model.log_likelihood",
    ),
    "in a thread": (
        "weigh",
        """
        def weigh(self, positions, z):
            import threading
            from mazelab.model import log_likelihood
            out = []
            worker = threading.Thread(target=lambda: out.append(log_likelihood(z, positions, self.world, self.sigma)))
            worker.start()
            worker.join()
            return out[0]
        """,
        "mazelab.model.log_likelihood",
    ),
    "the resampling schemes": (
        "resample",
        """
        def resample(self, weights, rng):
            from mazelab.resampling import RESAMPLING_SCHEMES
            return RESAMPLING_SCHEMES["multinomial"](weights, rng)
        """,
        "mazelab.resampling.multinomial_resample",
    ),
    "the weights' helpers": (
        "estimate",
        """
        def estimate(self, positions, weights):
            from mazelab.weights import weighted_mean
            return weighted_mean(weights, positions)
        """,
        "mazelab.weights.weighted_mean",
    ),
    "the model's motion": (
        "predict",
        """
        def predict(self, positions, compass_angle, rng):
            from mazelab.model import headings_from_uniforms, move
            return move(positions, headings_from_uniforms(rng.random(len(positions)), compass_angle, self.delta))
        """,
        "mazelab.model.headings_from_uniforms",
    ),
}


@pytest.mark.parametrize("how", list(DELEGATIONS))
def test_a_part_that_calls_the_labs_reference_implementation_finds_nothing_to_call(tmp_path, how):
    """The reference implementations do not exist in the sandbox: the import is the part's error."""
    part, code, name = DELEGATIONS[how]
    report = checked(tmp_path, stages=(part,), **{part: textwrap.dedent(code)})
    status, got = rows(report)[part]
    module = name.rsplit(".", 1)[0]
    missing = (f"No module named '{module}'", "cannot import name", "has no attribute")
    assert status == "fail" and any(text in got for text in missing), got


def test_a_filter_whose_step_runs_the_shipped_sir_does_not_import(tmp_path):
    path = write_submission(tmp_path / "my_filter.py", "from mazelab.filters import SIRParticleFilter")
    with pytest.raises(NotGradableError, match=r"No module named 'mazelab\.filters'"):
        check_file(str(path), seed=SEED, stages=("whole",))


def test_a_nan_estimate_never_passes_the_whole_filter(tmp_path):
    """estimate is right alone; the estimate the filter reports is not a number."""
    path = write_submission(tmp_path / "my_filter.py")
    nan = "\n\nclass NanFilter(MyFilter):\n    estimate = property(lambda self: np.array([np.nan, np.nan]))\n"
    path.write_text(path.read_text() + nan)
    report = check_file(f"{path}:NanFilter", seed=SEED, stages=("estimate", "whole"))
    assert rows(report)["estimate"][0] == "pass"
    status, got = rows(report)["whole filter"]
    assert status == "fail" and "nan" in got and "a number at every step" in row_of(report, "whole filter").hint


def test_the_child_holds_none_of_the_graders_objects(tmp_path):
    """The student's code looks for the grader's objects and the true path in its own process: none."""
    truth = draw_scenarios(SEED)[0]
    prelude = """
        import gc, json


        def snoop(scenario_truth):
            names = {"RunResult", "GridBayesFilter", "ScenarioInputs", "PartInputs", "Report", "References", "Row"}
            objects = gc.get_objects()
            kinds = sorted({type(o).__name__ for o in objects if type(o).__name__ in names})
            arrays, seen, todo = [], set(), list(objects)  # every array any object holds, however deep
            while todo:
                thing = todo.pop()
                if id(thing) in seen:
                    continue
                seen.add(id(thing))
                if isinstance(thing, np.ndarray):
                    arrays.append(thing)
                    continue
                try:
                    todo.extend(gc.get_referents(thing))
                except Exception:
                    pass
            others = [a for a in arrays if a is not scenario_truth and a.shape == scenario_truth.shape]
            paths = sum(np.allclose(a, scenario_truth) for a in others)
            print("snooped", json.dumps({"kinds": kinds, "paths": int(paths), "arrays": len(arrays)}))
    """
    step = f"""
        def step(self, compass_angle, z):
            if not hasattr(self, "snooped"):
                self.snooped = snoop(np.array({truth.true_positions.tolist()!r}))
            super().step(compass_angle, z)
    """
    report = checked(tmp_path, stages=("whole",), prelude=prelude, step=textwrap.dedent(step))
    said = [line for line in report.output.splitlines() if line.startswith("snooped ")]
    assert said, report.rows
    seen = json.loads(said[0].removeprefix("snooped "))
    assert seen["kinds"] == [] and seen["paths"] == 0 and seen["arrays"] > 0, seen


# -- how a child can end -------------------------------------------------------------------------------
def test_a_signal_names_the_signal_and_the_part(tmp_path):
    estimate = (
        "def estimate(self, positions, weights):\n    import os, signal\n    os.kill(os.getpid(), signal.SIGKILL)\n"
    )
    status, got = rows(checked(tmp_path, stages=("estimate",), estimate=estimate))["estimate"]
    assert status == "fail" and "killed by signal 9 (SIGKILL) in estimate" in got


def test_output_that_is_not_an_answer_is_named(tmp_path):
    estimate = """
        def estimate(self, positions, weights):
            import gc
            import io
            for thing in gc.get_objects():
                if isinstance(thing, io.FileIO) and thing.writable() and thing.fileno() > 2:
                    thing.write(b"All checks pass.")
            return weights @ positions
    """
    status, got = rows(checked(tmp_path, stages=("estimate",), estimate=textwrap.dedent(estimate)))["estimate"]
    assert status == "fail" and "sent output the grader cannot read" in got


def test_the_wire_reads_whole_messages_of_its_own_format_only(monkeypatch):
    """Both ways one format (child.encode, child.messages): messages read back as sent, one after
    another; a foreign start, a cut header or array, a header past its limit, JSON's NaN, a name twice
    and more than the limit in all are each one WireError naming it, before any array is made."""
    import io

    import numpy as np

    from mazelab.exercise.child import MAGIC, WireError, encode, messages

    sent = encode({"kind": "result"}, {"a": np.arange(3), "b": np.ones((2, 2), bool), "c": np.zeros(0)})
    (first, second) = messages(io.BytesIO(sent + encode({"kind": "done"})))
    assert first.meta == {"kind": "result"} and second.meta == {"kind": "done"} and second.arrays == {}
    assert [(v.dtype.str, v.shape) for v in first.arrays.values()] == [("<i8", (3,)), ("|b1", (2, 2)), ("<f8", (0,))]
    twice = sent.replace(b'"name":"b"', b'"name":"a"')
    header = b'{"meta":{"x":NaN},"arrays":[]}'
    nan = MAGIC + len(header).to_bytes(4, "big") + header
    for data, said in (
        (b"MZL0" + sent[4:], "no header"),
        (sent[:20], "cut short"),
        (sent[:-1], "cut short"),
        (MAGIC + (1 << 21).to_bytes(4, "big"), f"a header of {1 << 21} bytes"),
        (nan, "not JSON"),
        (twice, "names each given once"),
    ):
        with pytest.raises(WireError, match=said):
            list(messages(io.BytesIO(data)))
    monkeypatch.setattr("mazelab.exercise.child.MAX_MESSAGE_BYTES", len(sent) - 1)
    with pytest.raises(WireError, match="more than 0 MB"):
        list(messages(io.BytesIO(sent)))


def test_a_hang_is_stopped_within_the_budget_and_the_next_parts_still_run(tmp_path):
    """A budget of 10 s for two stages keeps 2.5 s for the estimate: the hang in predict gets 6 s of
    processor time (a second under its 7.5 s), then a new process checks the estimate."""
    predict = "def predict(self, positions, compass_angle, rng):\n    while True:\n        pass\n"
    started = time.perf_counter()
    report = checked(tmp_path, stages=("predict", "estimate"), timeout=10, predict=predict)
    assert rows(report)["predict"][0] == "fail"  # its processor limit, or under load the clock's first
    limits = r"the time limit \(6 s of processor time|its time \(8 s of the budget"
    assert re.search(rf"ran past ({limits})\) in predict and was stopped", rows(report)["predict"][1])
    assert rows(report)["estimate"][0] == "pass" and time.perf_counter() - started < 10 + 5


def test_a_child_that_waits_without_working_is_stopped_too(tmp_path):
    estimate = "def estimate(self, positions, weights):\n    import time\n    time.sleep(600)\n"
    status, got = rows(checked(tmp_path, stages=("estimate",), timeout=1, estimate=estimate))["estimate"]
    assert status == "fail" and "ran past its time (1 s of the budget) in estimate" in got


def test_one_submission_holds_the_grader_at_most_its_budget(tmp_path):
    """Every stage sleeps: the first process gets the budget less the others' reserve, the next ones
    what is left; the check ends within the budget (and its processes' starts), every row failed."""
    sleep = "\n    import time\n    time.sleep(600)\n"
    parts = {part: f"def {part}(self, *arguments):{sleep}" for part in ("predict", "weigh", "resample", "estimate")}
    started = time.perf_counter()
    report = checked(tmp_path, timeout=20, step=f"def step(self, *arguments):{sleep}", **parts)
    assert [r.status for r in report.rows] == ["fail"] * 5 and time.perf_counter() - started < 20 + 10
    assert "the time budget (20 s) is spent" in report.rows[-1].got


def test_what_the_student_prints_is_kept_and_its_last_line_shown_when_it_dies(tmp_path):
    weigh = "def weigh(self, positions, z):\n    print('about to fail')\n    import os\n    os._exit(3)\n"
    status, got = rows(checked(tmp_path, stages=("weigh",), weigh=weigh))["weigh"]
    assert status == "fail" and "exited with code 3 in weigh" in got and "its last line: about to fail" in got


def test_a_file_that_does_not_import_is_one_line_and_exit_2(tmp_path, capsys):
    (tmp_path / "my_filter.py").write_text("def broken(:\n")
    assert main(["exercise", "check", str(tmp_path / "my_filter.py")]) == 2
    assert "does not import" in capsys.readouterr().err
    with pytest.raises(NotGradableError, match="no such file"):
        check_file(str(tmp_path / "none.py"))


def test_check_writes_gradescopes_results(tmp_path, capsys):
    path = write_submission(
        tmp_path / "my_filter.py", weigh="def weigh(self, positions, z):\n    raise NotImplementedError\n"
    )
    (tmp_path / "results").mkdir()
    assert main(["exercise", "check", str(path), "--seed", str(SEED), "--gradescope", str(tmp_path / "results")]) == 1
    results = json.loads((tmp_path / "results" / "results.json").read_text())
    assert [t["name"] for t in results["tests"]] == ["predict", "weigh", "resample", "estimate", "whole filter"]
    assert [t["status"] for t in results["tests"]] == ["passed", "failed", "passed", "passed", "failed"]
    assert results["score"] == 3.0 and "Checking MyFilter" in results["output"]
    capsys.readouterr()
    assert main(["exercise", "check", str(path), "--gradescope", str(tmp_path / "results")]) == 2  # exists
    assert "--force" in capsys.readouterr().err


def test_an_error_of_the_grader_itself_on_one_submission_is_that_submissions_row(monkeypatch, tmp_path):
    """A bug in the grader's own code while checking one submission becomes its row ("the grader could
    not check it: ..."), shown as it is; the others are graded."""
    from mazelab.exercise import grading

    real = grading.check_file

    def broken(spec, **options):
        if "bad" in spec:
            raise RuntimeError("the grader's own bug")
        return real(spec, **options)

    monkeypatch.setattr(grading, "check_file", broken)
    bad, good = write_submission(tmp_path / "bad.py"), write_submission(tmp_path / "good.py")
    submissions = [grading.Submission("bad", bad), grading.Submission("good", good)]
    graded = grading.grade_folder(submissions, key=bytes(16), jobs=1)
    assert graded[0].problem == "the grader could not check it: RuntimeError: the grader's own bug"
    assert graded[1].passed and "1 could not be checked by the grader itself" in grading.summary(graded)
