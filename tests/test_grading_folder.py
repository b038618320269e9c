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
import re
import shlex
import shutil
import signal
import subprocess
import sys
import textwrap
import threading
import time
from pathlib import Path

import pytest
from conftest import ROOT
from exercise_answers import PARTS_SOURCE, write_submission

from mazelab.cli.app import main
from mazelab.exercise.grading import CSV_COLUMNS, discover
from mazelab.exercise.template import FILTER_TEMPLATE

TIMEOUT = 30  # seconds of a submission's processes in all (a correct one needs about 1)
KEY = "00112233445566778899aabbccddeeff"  # the tests' secret key (a grading makes one of 256 bits)
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
    "heidi": ("fail",) * 5,  # the reference implementation is not in the sandbox: it does not import
    "ivan": ("pass", "fail", "pass", "pass", "*"),
    "judy": ("pass", "pass", "fail", "pass", "*"),
    "mallory": ("pass", "pass", "pass", "pass", "fail"),
    "niaj": ("pass", "pass", "fail", "pass", "fail"),
    "olivia": ("fail",) * 5,  # nor is the grader
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


def key_file(folder: Path) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "grading.key").write_text(KEY + "\n")
    return folder / "grading.key"


@pytest.fixture(scope="module")
def graded(class_folder, tmp_path_factory):
    out = tmp_path_factory.mktemp("out")
    (out / "gradescope").mkdir()
    arguments = ["exercise", "grade", str(class_folder), "--key", str(key_file(out)), "--timeout", str(TIMEOUT)]
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
    # a busy part meets its processor limit, or under load the grader's clock first (docs/exercise.md)
    assert re.search(r"ran past (its time|the time limit) .* and was stopped", table["dave"]["problem"])
    assert "exited with code 0 while importing" in table["frank"]["problem"]
    assert "does not import" in table["erin"]["problem"] and "mazelab.filters" in table["grace"]["problem"]
    assert "cannot import name 'log_likelihood'" in table["heidi"]["problem"]  # the kit's model: constants only
    assert "SIGKILL" in table["xavier"]["problem"]
    assert int(table["alice"]["farther_on"]) < 11 and "seed" not in table["alice"]
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
    assert lines[at].split()[1:6] == ["pass", "pass", "pass", "pass", "FAIL"] and "ran past" in lines[at + 1]


def test_grade_refuses_to_overwrite_outputs_without_force(graded, class_folder, capsys):
    _, out, _ = graded
    before = (out / "grades.csv").read_text()
    assert main(["exercise", "grade", str(class_folder), "--csv", str(out / "grades.csv"), "--quiet"]) == 2
    assert "--force" in capsys.readouterr().err and (out / "grades.csv").read_text() == before
    assert main(["exercise", "grade", str(out / "nothing")]) == 2


# -- a class with saboteurs: links, a student writing others' files, outputs where they must not be -------
@pytest.fixture(scope="module")
def small_class(tmp_path_factory):
    """alice (honest); bob, a link to alice's folder; eve.py, a link to /etc/passwd; zed.py, a link to a
    text file; adam.py, a link to zoe's file; mallory, who appends an exit to alice's file and plants a
    results.json for alice, then does honest work; zoe (honest)."""
    root = tmp_path_factory.mktemp("small")
    folder, out = root / "class", root / "out"
    out.mkdir()
    alice = write_submission(folder / "alice" / "my_filter.py")
    (folder / "bob").symlink_to(folder / "alice")
    (folder / "eve.py").symlink_to("/etc/passwd")
    (folder / "_notes.txt").write_text("not Python\n")
    (folder / "zed.py").symlink_to(folder / "_notes.txt")
    write_submission(folder / "zoe" / "my_filter.py")
    (folder / "adam.py").symlink_to(folder / "zoe" / "my_filter.py")
    prelude = f"""
        for target, text in (({str(alice)!r}, "\\nraise SystemExit(3)\\n"),
                             ({str(out / "alice" / "results.json")!r}, '{{"score": 0}}')):
            try:
                import os
                os.makedirs(os.path.dirname(target), exist_ok=True)
                with open(target, "a") as file:
                    file.write(text)
                print("wrote", target)
            except OSError as error:
                print("could not write", target, type(error).__name__)
    """
    write_submission(folder / "mallory" / "my_filter.py", textwrap.dedent(prelude))
    before = alice.read_text()
    code = main(["exercise", "grade", str(folder), "--key", str(key_file(root)), "--csv", str(out / "grades.csv"),
                 "--gradescope", str(out), "--quiet", "--timeout", str(TIMEOUT)])  # fmt: skip
    return folder, out, code, before


def test_no_student_changes_anothers_file_or_grade(small_class):
    folder, out, code, before = small_class
    assert code == 0 and (folder / "alice" / "my_filter.py").read_text() == before
    table = {row["submission"]: row for row in csv.DictReader(io.StringIO((out / "grades.csv").read_text()))}
    assert table["alice"]["whole_filter"] == "pass" and table["mallory"]["whole_filter"] == "pass"
    assert json.loads((out / "alice" / "results.json").read_text())["score"] == 5.0


def test_a_link_is_no_submission_and_its_target_keeps_its_own_grade(small_class):
    """bob -> alice and adam.py -> zoe/my_filter.py take nobody's grade: refused, named; alice and zoe
    graded under their own names. A link to a system file is never read."""
    _, out, _, _ = small_class
    table = {row["submission"]: row for row in csv.DictReader(io.StringIO((out / "grades.csv").read_text()))}
    for link in ("bob", "adam.py", "eve.py", "zed.py"):
        assert "a link" in table[link]["problem"] and "not a submission" in table[link]["problem"]
        assert json.loads((out / link / "results.json").read_text())["score"] == 0.0
    for owner in ("alice", "zoe"):
        assert table[owner]["whole_filter"] == "pass" and table[owner]["problem"] == ""
    assert json.loads((out / "zoe" / "results.json").read_text())["score"] == 5.0
    assert "root:" not in (out / "grades.csv").read_text()


def test_outputs_inside_the_class_folder_and_a_claimed_csv_are_refused_before_grading(small_class, capsys):
    folder, out, _, _ = small_class
    alice = folder / "alice" / "my_filter.py"
    before = alice.read_text()
    for options in (["--csv", str(alice), "--force"], ["--gradescope", str(folder / "alice")], ["--csv", "x.csv"]):
        args = ["exercise", "grade", str(folder), "--quiet", *options]
        if options == ["--csv", "x.csv"]:
            args = ["exercise", "grade", str(folder), "--quiet", "--csv", str(folder / "x.csv")]
        assert main(args) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and "inside the class folder" in err[0], err
    assert alice.read_text() == before
    from mazelab.exercise.grading import claimed

    with claimed([(out / "again.csv", "--csv")]):
        assert main(["exercise", "grade", str(folder), "--quiet", "--csv", str(out / "again.csv")]) == 2
    err = capsys.readouterr().err
    assert "another grader is writing it now" in err and not (out / "again.csv").exists()


def test_grade_names_a_path_that_does_not_exist_in_one_line(tmp_path, capsys):
    assert main(["exercise", "grade", str(tmp_path / "nowhere")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"error: {tmp_path / 'nowhere'}: no such folder of submissions (check the path)"]


def descendants(pid: int) -> dict[int, str]:
    """The processes below `pid` (any depth) and their command lines."""
    parents, lines = {}, {}
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            with contextlib.suppress(OSError, ValueError, IndexError):
                parents[int(entry.name)] = int((entry / "stat").read_text().rsplit(")", 1)[1].split()[1])
                lines[int(entry.name)] = (entry / "cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
    found, todo = {}, [pid]
    while todo:
        parent = todo.pop()
        for child, its_parent in parents.items():
            if its_parent == parent and child not in found:
                found[child] = lines.get(child, "")
                todo.append(child)
    return found


def alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state != "Z"


def start_grading(folder, *options):
    return subprocess.Popen(
        [sys.executable, str(ROOT / "main.py"), "exercise", "grade", str(folder), "--quiet", *options],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )


def wait_for_child(grading, file_name: str) -> dict[int, str]:
    """Wait (at most two minutes) until the grader runs the student's process of the submission whose
    file is `file_name` (its run folder holds the copy); then the grader's processes."""
    for _ in range(1200):
        below = descendants(grading.pid)
        for line in below.values():
            runs = re.findall(r"(\S*mazelab-run-\w+)", line)
            if "mazelab.exercise.child" in line and any((Path(r) / "submission" / file_name).exists() for r in runs):
                return below
            if "mazelab.exercise.child" in line and not runs:  # inside bwrap: the run folder is its bind's
                binds = [d for d in below.values() if "bwrap" in d and "mazelab-run-" in d]
                if any(file_name in os.listdir(r) for b in binds for r in _submission_binds(b)):
                    return below
        time.sleep(0.1)
    raise AssertionError("the student's process never started")


def _submission_binds(line: str) -> list[str]:
    return [r for r in re.findall(r"(\S*mazelab-run-\w+/submission)", line) if Path(r).is_dir()]


def test_ctrl_c_ends_the_grading_and_its_childrens_processes(tmp_path):
    """A submission that waits forever at import; Ctrl-C ends the grade (exit 130) and every process below it."""
    write_submission(tmp_path / "class" / "slow" / "my_filter.py", "import time\ntime.sleep(600)")
    grading = start_grading(tmp_path / "class")
    try:
        below = wait_for_child(grading, "my_filter.py")
        grading.send_signal(signal.SIGINT)
        _, err = grading.communicate(timeout=60)
    finally:
        grading.kill()
    assert grading.returncode == 130, err
    time.sleep(0.5)
    assert [line for pid, line in below.items() if alive(pid)] == []


def test_sigterm_ends_every_sandbox_and_keeps_what_was_graded(tmp_path):
    """One at a time: alice is graded, then b_slow waits forever; SIGTERM ends the grading (exit 143),
    every process below it, and alice's row and results.json are written."""
    write_submission(tmp_path / "class" / "alice" / "my_filter.py")
    write_submission(tmp_path / "class" / "b_slow.py", "import time\ntime.sleep(600)")
    (tmp_path / "out").mkdir()
    csv_file, results = tmp_path / "out" / "grades.csv", tmp_path / "out"
    grading = start_grading(tmp_path / "class", "--jobs", "1", "--csv", str(csv_file), "--gradescope", str(results))
    try:
        below = wait_for_child(grading, "b_slow.py")
        grading.send_signal(signal.SIGTERM)
        _, err = grading.communicate(timeout=60)
    finally:
        grading.kill()
    assert grading.returncode == 143, err
    assert "stopped: 1 of 2 submissions graded" in err and "grades.partial.csv" in err
    assert not csv_file.exists()  # an incomplete gradebook is never taken for the complete one
    rows = list(csv.DictReader(io.StringIO((tmp_path / "out" / "grades.partial.csv").read_text())))
    assert [(r["submission"], r["whole_filter"]) for r in rows] == [("alice", "pass")]
    assert json.loads((results / "alice" / "results.json").read_text())["score"] == 5.0
    time.sleep(0.5)
    assert [line for pid, line in below.items() if alive(pid)] == []


def test_sigterm_ends_a_check_and_its_sandbox(tmp_path):
    path = write_submission(tmp_path / "hang" / "my_filter.py", "import time\ntime.sleep(600)")
    checking = subprocess.Popen(
        [sys.executable, str(ROOT / "main.py"), "exercise", "check", str(path)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        below = wait_for_child(checking, "my_filter.py")
        checking.send_signal(signal.SIGTERM)
        _, err = checking.communicate(timeout=60)
    finally:
        checking.kill()
    assert checking.returncode == 143 and "stopped: nothing graded" in err, err
    time.sleep(0.5)
    assert [line for pid, line in below.items() if alive(pid)] == []


# -- a class is never lost, links and names are data (issue 48, items 2, 4, 7) ---------------------------
FORGER = """
    import os, stat
    from mazelab.exercise.child import encode

    def send(fd, meta, arrays=None):
        os.write(fd, encode(meta, arrays))

    for fd in range(3, 64):
        try:
            if stat.S_ISFIFO(os.fstat(fd).st_mode):
                send(fd, {"kind": "loaded", "class": "MyFilter", "name": "MyFilter", "student_filter": True,
                          "bases": []})
                for stage in ("predict", "weigh", "resample", "estimate", "whole"):
                    send(fd, {"kind": "result", "stage": stage})
        except OSError:
            pass
    os._exit(3)
"""
TWINS = "import os\nos.fork()"  # two processes answering on one pipe


@pytest.fixture(scope="module")
def odd_class(tmp_path_factory):
    """An honest student, one whose file answers every stage at import and exits, one that forks at
    import, a link thief sorted before its victim, and names and errors that would forge lines."""
    root = tmp_path_factory.mktemp("odd")
    folder, out = root / "class", root / "out"
    write_submission(folder / "alice" / "my_filter.py")
    write_submission(folder / "forger" / "my_filter.py", textwrap.dedent(FORGER))
    write_submission(folder / "twins" / "my_filter.py", TWINS)
    write_submission(folder / "zzz_victim" / "my_filter.py")
    (folder / "aaa_thief").symlink_to(folder / "zzz_victim")
    odd = {
        "a\rmallory": "def broken(:\n",
        "b\nfake    pass": "raise RuntimeError('\\b\\b\\b\\bpass')\n",
        "c\x1b[32mgreen": "raise RuntimeError('\\x1b[2J\\r')\n",
    }
    for name, text in odd.items():
        (folder / name).mkdir()
        (folder / name / "my_filter.py").write_text(text)
    printed = io.StringIO()
    with contextlib.redirect_stdout(printed):
        code = main(["exercise", "grade", str(folder), "--csv", str(out / "grades.csv"), "--gradescope", str(out),
                     "--quiet", "--timeout", str(TIMEOUT)])  # fmt: skip
    return folder, out, code, printed.getvalue()


def test_a_submission_that_answers_and_exits_or_forks_loses_nobody_else(odd_class):
    """Every stage answered on the pipe at import, then os._exit(3): judged by those values (none is a
    pass), the ending noted; the forked pair: its stages answered twice count for nothing. The grading
    ends with every row and every results.json written."""
    _, out, code, _ = odd_class
    assert code == 0
    table = {row["submission"]: row for row in csv.DictReader(io.StringIO((out / "grades.csv").read_text()))}
    assert len(table) == 8 and table["alice"]["whole_filter"] == "pass"
    assert "pass" not in [table["forger"][p] for p in ("predict", "weigh", "resample", "estimate", "whole_filter")]
    assert "exited with code 3" in table["forger"]["problem"]
    assert table["twins"]["whole_filter"] == "fail", table["twins"]
    assert len(list(out.glob("*/results.json"))) == 8


def test_a_link_sorted_before_its_target_takes_nothing(odd_class):
    _, out, _, _ = odd_class
    table = {row["submission"]: row for row in csv.DictReader(io.StringIO((out / "grades.csv").read_text()))}
    assert table["zzz_victim"]["whole_filter"] == "pass" and table["zzz_victim"]["problem"] == ""
    assert table["aaa_thief"]["whole_filter"] == "fail" and "a link" in table["aaa_thief"]["problem"]
    assert json.loads((out / "zzz_victim" / "results.json").read_text())["score"] == 5.0


def test_names_and_errors_are_data_everywhere(odd_class):
    """A CR or a newline in a folder's name, backspaces and escapes in an error: in the CSV (every field
    quoted: a reader gets one row per submission, under its own name), the summary and results.json,
    each shows as an escape, never as a new line, a rub-out or a colour."""
    _, out, _, printed = odd_class
    text = (out / "grades.csv").read_text()
    assert all(line.startswith('"') for line in text.splitlines())
    names = [row["submission"] for row in csv.DictReader(io.StringIO(text))]
    assert {"a\\rmallory", "b\\nfake    pass", "c\\x1b[32mgreen"} <= set(names) and len(names) == 8
    for shown in (text, printed, *(p.read_text() for p in out.glob("*/results.json"))):
        assert not set(shown) & {"\r", "\b", "\x1b"}, shown
    assert "\\x08\\x08\\x08\\x08pass" in text and not any(line.startswith("fake") for line in printed.splitlines())
    results = json.loads((out / "b\\nfake    pass" / "results.json").read_text())
    assert results["score"] == 0.0 and "\\x08" in results["output"]


# -- the secret key (issue 48, item 1) -----------------------------------------------------------------
def test_the_key_is_made_once_kept_with_the_outputs_and_shown_nowhere(odd_class, tmp_path, capsys):
    folder, out, _, printed = odd_class
    key = (out / ".grading.key").read_text().strip()
    assert len(bytes.fromhex(key)) >= 16 and (out / ".grading.key").stat().st_mode & 0o077 == 0
    shown = [printed, (out / "grades.csv").read_text(), *(p.read_text() for p in out.glob("*/results.json"))]
    assert not [text for text in shown if key in text or key[:12] in text]
    assert "seed" not in json.loads((out / "alice" / "results.json").read_text()).get("extra_data", {})
    # a regrade reuses the key: the same inputs, so the same figures
    again = tmp_path / "again"
    again.mkdir()
    (again / "grading.key").write_text(key + "\n")
    alice = [sub for sub in discover(folder) if sub.name == "alice"]
    assert main(["exercise", "grade", str(folder / "alice" / ".."), "--key", str(again / "grading.key"), "--quiet",
                 "--csv", str(again / "grades.csv"), "--timeout", str(TIMEOUT)]) == 0  # fmt: skip
    rows = {r["submission"]: r for r in csv.DictReader(io.StringIO((again / "grades.csv").read_text()))}
    first = {r["submission"]: r for r in csv.DictReader(io.StringIO((out / "grades.csv").read_text()))}
    assert alice and rows["alice"]["to_exact"] == first["alice"]["to_exact"] != ""
    assert main(["exercise", "grade", str(folder), "--seed", "4711"]) == 2  # a small seed makes no grading inputs
    capsys.readouterr()


# -- what the instructor had stays (issue 48, item 9) ----------------------------------------------------
def test_an_interrupted_regrade_keeps_the_complete_gradebook_beside_the_partial_one(tmp_path):
    write_submission(tmp_path / "class" / "alice" / "my_filter.py")
    out = tmp_path / "out"
    out.mkdir()
    assert main(["exercise", "grade", str(tmp_path / "class"), "--csv", str(out / "grades.csv"), "--quiet"]) == 0
    complete = (out / "grades.csv").read_text()
    write_submission(tmp_path / "class" / "b_slow.py", "import time\ntime.sleep(600)")
    grading = start_grading(tmp_path / "class", "--jobs", "1", "--csv", str(out / "grades.csv"), "--force")
    try:
        wait_for_child(grading, "b_slow.py")
        grading.send_signal(signal.SIGTERM)
        _, err = grading.communicate(timeout=60)
    finally:
        grading.kill()
    assert grading.returncode == 143 and (out / "grades.csv").read_text() == complete, err
    assert "grades.partial.csv" in err and len((out / "grades.partial.csv").read_text().splitlines()) == 2


def test_ctrl_c_on_a_parallel_grading_prints_one_line(tmp_path):
    """Ctrl-C at the terminal reaches every process of the group (the grader, its reference workers):
    one line, no worker's traceback."""
    for name in ("a_slow", "b_slow"):
        write_submission(tmp_path / "class" / name / "my_filter.py", "import time\ntime.sleep(600)")
    grading = subprocess.Popen(
        [sys.executable, str(ROOT / "main.py"), "exercise", "grade", str(tmp_path / "class"), "--quiet", "--jobs", "2"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True,
    )  # fmt: skip
    try:
        wait_for_child(grading, "my_filter.py")
        time.sleep(1)
        os.killpg(grading.pid, signal.SIGINT)  # as a terminal does
        _, err = grading.communicate(timeout=60)
    finally:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(grading.pid, signal.SIGKILL)
    assert grading.returncode == 130 and err.strip().splitlines() == ["stopped: 0 of 2 submissions graded"], err


@pytest.mark.skipif(os.geteuid() != 0 or not shutil.which("unshare"), reason="a full disk needs root (a tmpfs)")
def test_a_full_disk_names_the_file_it_could_not_write(tmp_path):
    write_submission(tmp_path / "class" / "alice" / "my_filter.py")
    out = tmp_path / "out"
    out.mkdir()
    grade = [sys.executable, str(ROOT / "main.py"), "exercise", "grade", str(tmp_path / "class"), "--quiet",
             "--gradescope", str(out), "--csv", str(out / "grades.csv")]  # fmt: skip
    script = f"mount -t tmpfs -o size=8k none {out} && exec {shlex.join(grade)}"
    done = subprocess.run(["unshare", "--mount", "sh", "-c", script], capture_output=True, text=True, timeout=300)
    assert done.returncode == 1 and "[Errno" not in done.stderr, done.stderr
    assert re.search(rf"cannot write {re.escape(str(out))}\S*: No space left on device", done.stderr), done.stderr


def test_a_link_to_a_pipe_in_a_submission_folder_is_never_read(tmp_path):
    """A student's folder with its file and a link to a named pipe: discovery would block forever on
    reading the pipe; it reads no link."""
    write_submission(tmp_path / "class" / "eve" / "mine.py")
    os.mkfifo(tmp_path / "pipe")
    (tmp_path / "class" / "eve" / "other.py").symlink_to(tmp_path / "pipe")
    found = []
    worker = threading.Thread(target=lambda: found.extend(discover(tmp_path / "class")), daemon=True)
    worker.start()
    worker.join(20)
    assert not worker.is_alive() and [(s.name, s.file.name) for s in found] == [("eve", "mine.py")]


def test_check_takes_a_seed_or_a_key_not_both(tmp_path, capsys):
    path = write_submission(tmp_path / "my_filter.py")
    (tmp_path / "k").write_text(KEY + "\n")
    assert main(["exercise", "check", str(path), "--seed", "1", "--key", str(tmp_path / "k")]) == 2
    assert "--seed and --key" in capsys.readouterr().err
