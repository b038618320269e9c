"""`mazelab exercise grade DIR`: a class's folder of twenty submissions (correct ones, broken ones,
cheats, an unfinished one, one that hangs, ones that cannot be checked) graded in parallel, each in
processes of its own with the time limit; one CSV row and one Gradescope results.json each, and a
summary table. Nothing here passes that should not, and nothing stops the rest."""

from __future__ import annotations

import contextlib
import csv
import io
import json
import os
import signal
import subprocess
import sys
import textwrap
import time

import pytest
from conftest import ROOT
from exercise_answers import PARTS_SOURCE, write_submission

from mazelab.cli.app import main
from mazelab.exercise.grading import CSV_COLUMNS, discover
from mazelab.exercise.template import FILTER_TEMPLATE

SEED = 2024  # tests/test_exercise.py's: the exact runs are computed once per process
TIMEOUT = 15  # processor seconds per run of a student's process (a correct one needs about 6)
NOT_WRITTEN = dict.fromkeys(("predict", "weigh", "resample", "estimate"))


def _method(code: str) -> str:
    return textwrap.dedent(code).strip() + "\n"


SYSTEMATIC = "np.minimum(np.searchsorted(np.cumsum(weights), (rng.random() + np.arange(n)) / n), n - 1)"
SUBMISSIONS = {  # name: (prelude, parts replaced), each written as NAME/my_filter.py
    "alice": ("", {}),
    "bob": ("", {"resample": _method("""
        def resample(self, weights, rng):
            return rng.choice(len(weights), len(weights), p=weights)
    """)}),
    "dave": ("", {"step": "def step(self, compass_angle, z):\n    while True:\n        pass\n"}),
    "frank": ("import os\nos._exit(0)", {}),
    "heidi": ("from mazelab.model import log_likelihood", {"weigh": _method("""
        def weigh(self, positions, z):
            return log_likelihood(z, positions, self.world, self.sigma)
    """)}),
    "ivan": ("", {"weigh": _method("""
        def weigh(self, positions, z):
            return 0.5 * ((z - self.world.distance_to_nearest_station(positions)) / self.sigma) ** 2
    """)}),
    "judy": ("", {"resample": "def resample(self, weights, rng):\n    return np.arange(len(weights))\n"}),
    "mallory": ("", {
        "estimate": None,
        "estimate_part": PARTS_SOURCE["estimate"].replace("def estimate(", "def estimate_part("),
        "nan": "estimate = property(lambda self: np.array([np.nan, np.nan]))\n",
    }),
    "niaj": ("import sys", {"resample": "def resample(self, weights, rng):\n    sys.exit(0)\n"}),
    "olivia": ("import mazelab.exercise.report as r\nr.Report.passed = property(lambda self: True)", NOT_WRITTEN),
    "victor": ("", {"predict": _method("""
        def predict(self, positions, compass_angle, rng):
            if getattr(self, "noise", None) is None or len(self.noise) != len(positions):
                self.noise = rng.random(len(positions)) - 0.5
            headings = compass_angle + self.delta * self.noise
            return positions + ROBOT_SPEED * np.column_stack([np.cos(headings), np.sin(headings)])
    """)}),
    "walter": ("", {"resample": _method(f"""
        def resample(self, weights, rng):
            n = len(weights)
            if 1 / np.sum(weights**2) > n / 2:
                return np.arange(n)
            return {SYSTEMATIC}
    """)}),
    "xavier": ("import os, signal", {"estimate": _method("""
        def estimate(self, positions, weights):
            os.kill(os.getpid(), signal.SIGKILL)
    """)}),
}  # fmt: skip
EXPECTED = {  # the statuses of predict, weigh, resample, estimate, whole filter ("*": not pass, "?": any)
    "alice": ("pass", "pass", "pass", "pass", "pass"),
    "bob": ("pass", "pass", "pass", "pass", "pass"),
    "carol": ("not written",) * 4 + ("not run",),
    "dave": ("pass", "pass", "pass", "pass", "fail"),
    "erin": ("fail",) * 5,
    "frank": ("fail",) * 5,
    "grace": ("fail",) * 5,
    "heidi": ("pass", "not own work", "pass", "pass", "not own work"),
    "ivan": ("pass", "fail", "pass", "pass", "*"),
    "judy": ("pass", "pass", "fail", "pass", "*"),
    "mallory": ("pass", "pass", "pass", "pass", "fail"),
    "niaj": ("pass", "pass", "fail", "pass", "fail"),
    "olivia": ("not written",) * 4 + ("not run",),
    "peggy": ("pass", "pass", "pass", "pass", "pass"),
    "rupert": ("fail",) * 5,
    "sybil.py": ("pass", "pass", "pass", "pass", "pass"),
    "trent": ("fail",) * 5,
    "victor": ("fail", "pass", "pass", "pass", "?"),  # its noise, reused by index, reads as fresh after resampling
    "walter": ("pass", "pass", "fail", "pass", "*"),
    "xavier": ("pass", "pass", "pass", "fail", "fail"),
}


def matches(got: str, expected: str) -> bool:
    """Whether a status is the one expected ("*": anything but pass, "?": anything)."""
    return got == expected or expected == "?" or (expected == "*" and got != "pass")


@pytest.fixture(scope="module")
def class_folder(tmp_path_factory):
    """Twenty submissions, and what grading is not to take for one (hidden and private folders, a README)."""
    folder = tmp_path_factory.mktemp("submissions")
    for name, (prelude, parts) in SUBMISSIONS.items():
        write_submission(folder / name / "my_filter.py", prelude, **parts)
    (folder / "carol").mkdir()
    (folder / "carol" / "my_filter.py").write_text(FILTER_TEMPLATE)
    (folder / "erin").mkdir()
    (folder / "erin" / "my_filter.py").write_text("def predict(self:\n")
    (folder / "grace").mkdir()
    (folder / "grace" / "filter.py").write_text(
        "from mazelab.filters import SIRParticleFilter\n\n\nclass MyFilter(SIRParticleFilter):\n    pass\n"
    )
    helper = "import numpy as np\n\n\ndef mean(positions, weights):\n    return weights @ positions\n"
    write_submission(folder / "peggy" / "my_filter.py", "from helpers import mean", estimate=_method("""
        def estimate(self, positions, weights):
            return mean(positions, weights)
    """))  # fmt: skip
    (folder / "peggy" / "helpers.py").write_text(helper)
    write_submission(folder / "rupert" / "a.py")
    write_submission(folder / "rupert" / "b.py")
    write_submission(folder / "sybil.py")
    (folder / "trent").mkdir()
    for skipped in (".git", "_private"):
        write_submission(folder / skipped / "my_filter.py", weigh=None)
    (folder / "README.md").write_text("the class of 2026\n")
    return folder


def test_the_submissions_are_found_and_the_rest_skipped(class_folder):
    found = discover(class_folder)
    assert [s.name for s in found] == sorted(EXPECTED)
    by_name = {s.name: s for s in found}
    assert by_name["peggy"].file.name == "my_filter.py" and by_name["grace"].file.name == "filter.py"
    assert by_name["rupert"].file is None and "which file? a.py, b.py" in by_name["rupert"].problem
    assert by_name["trent"].file is None and "no Python file" in by_name["trent"].problem


@pytest.fixture(scope="module")
def graded(class_folder, tmp_path_factory):
    out = tmp_path_factory.mktemp("out")
    (out / "gradescope").mkdir()
    arguments = ["exercise", "grade", str(class_folder), "--seed", str(SEED), "--timeout", str(TIMEOUT)]
    arguments += ["--jobs", "2", "--csv", str(out / "grades.csv"), "--gradescope", str(out / "gradescope"), "--quiet"]
    printed = io.StringIO()
    with contextlib.redirect_stdout(printed):
        code = main(arguments)
    return code, out, printed.getvalue()


def test_grading_the_folder_exits_0_once_every_submission_is_graded(graded):
    code, out, _ = graded
    assert code == 0
    assert (out / "grades.csv").is_file() and len(list((out / "gradescope").glob("*/results.json"))) == 20


def test_each_submission_gets_the_statuses_it_earned(graded):
    _, out, _ = graded
    with open(out / "grades.csv", newline="") as file:
        table = {row["submission"]: row for row in csv.DictReader(file)}
    assert list(table) == sorted(EXPECTED) and list(next(iter(table.values()))) == list(CSV_COLUMNS)
    for name, statuses in EXPECTED.items():
        got = tuple(table[name][part] for part in ("predict", "weigh", "resample", "estimate", "whole_filter"))
        assert all(map(matches, got, statuses)), (name, got)
    assert "time limit" in table["dave"]["problem"]
    assert "exited with code 0 while importing" in table["frank"]["problem"]
    assert "does not import" in table["erin"]["problem"] and "not a StudentFilter" in table["grace"]["problem"]
    assert "mazelab.model.log_likelihood" in table["heidi"]["problem"] and "SIGKILL" in table["xavier"]["problem"]
    assert table["alice"]["seed"] == str(SEED) and int(table["alice"]["farther_on"]) < 11
    assert float(table["alice"]["to_exact"]) > 0 and table["alice"]["problem"] == ""


def test_each_submission_gets_gradescopes_results(graded):
    _, out, _ = graded
    for name, statuses in EXPECTED.items():
        results = json.loads((out / "gradescope" / name / "results.json").read_text())
        assert set(results) >= {"score", "execution_time", "output", "tests"}
        tests = results["tests"]
        assert [t["name"] for t in tests] == ["predict", "weigh", "resample", "estimate", "whole filter"]
        got = ["pass" if t["status"] == "passed" else "fail" for t in tests]
        assert all(map(matches, got, [s if s in ("pass", "?") else "*" for s in statuses])), (name, got)
        assert all(t["max_score"] == 1.0 and t["score"] in (0.0, 1.0) and isinstance(t["output"], str) for t in tests)
        assert results["score"] == sum(t["score"] for t in tests)


def test_the_summary_table_fits_in_a_hundred_columns_and_counts(graded):
    _, _, printed = graded
    lines = printed.splitlines()
    assert max(map(len, lines)) <= 100
    assert "20 submissions, 4 pass every row" in printed
    at = next(i for i, line in enumerate(lines) if line.startswith("dave "))
    assert lines[at].split()[1:6] == ["pass", "pass", "pass", "pass", "FAIL"] and "time limit" in lines[at + 1]


def test_grade_refuses_to_overwrite_outputs_without_force(graded, class_folder, capsys):
    _, out, _ = graded
    before = (out / "grades.csv").read_text()
    assert main(["exercise", "grade", str(class_folder), "--csv", str(out / "grades.csv"), "--quiet"]) == 2
    assert "--force" in capsys.readouterr().err and (out / "grades.csv").read_text() == before
    assert main(["exercise", "grade", str(out / "nothing")]) == 2


def test_ctrl_c_ends_the_grading_and_its_childrens_processes(tmp_path):
    """A submission that waits forever at import; Ctrl-C ends the grade (exit 130) and its child."""
    marker = tmp_path / "child.pid"
    prelude = f"import os, time\nopen({str(marker)!r}, 'w').write(str(os.getpid()))\ntime.sleep(600)"
    write_submission(tmp_path / "class" / "slow" / "my_filter.py", prelude)
    grading = subprocess.Popen(
        [sys.executable, str(ROOT / "main.py"), "exercise", "grade", str(tmp_path / "class"), "--quiet"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )
    try:
        for _ in range(600):  # until the child has imported the file (at most a minute)
            if marker.exists() and marker.read_text():
                break
            time.sleep(0.1)
        child = int(marker.read_text())
        grading.send_signal(signal.SIGINT)
        _, err = grading.communicate(timeout=60)
    finally:
        grading.kill()
    assert grading.returncode == 130, err
    with pytest.raises(ProcessLookupError):
        os.kill(child, 0)
