"""The sandbox a submission is graded in, and the adversaries of issue 37: each submission here attacks
the grader as an instructor found one could, and gets the verdict its values earn.

The kit (what the sandbox holds of the lab) is checked without a sandbox; the rest runs bubblewrap for
real (skipped, saying why, where it cannot: CI installs it)."""

from __future__ import annotations

import ast
import json
import os
import re
import shutil
import textwrap
import time
from pathlib import Path

import pytest
from exercise_answers import write_submission

from mazelab.cli.app import main
from mazelab.exercise.kit import (
    KIT,
    PACKAGE_DIR,
    build_kit,
    kit_file,
    module_text,
    source_file,
)
from mazelab.exercise.report import NotGradableError, check_file
from mazelab.exercise.sandbox import (
    MEMORY_LIMIT,
    PROCESS_LIMIT,
    SANDBOX_UID,
    TMP_LIMIT,
    Sandbox,
    SandboxError,
    sandbox,
)

SEED = 2024  # tests/test_grading.py's
# What must never be in the sandbox (mazelab.exercise.kit.KIT): the reference implementations and the grader.
REFERENCE_MODULES = (
    "mazelab.filters",
    "mazelab.resampling",
    "mazelab.regularisation",
    "mazelab.grid_filter",
    "mazelab.kalman",
    "mazelab.simulation",
    "mazelab.robot",
    "mazelab.kernels",
    "mazelab.experiments",
    "mazelab.exercise.parts",
    "mazelab.exercise.report",
    "mazelab.exercise.inputs",
    "mazelab.exercise.sandbox",
    "mazelab.exercise.grading",
    "mazelab.exercise.kit",
)
REFERENCE_FUNCTIONS = ("mazelab.model.log_likelihood", "mazelab.model.move", "mazelab.weights.weighted_mean")
# skipped where no sandbox can be made, but never in CI, which installs bubblewrap: there a sandbox that
# cannot start fails these tests instead of hiding them
needs_sandbox = pytest.mark.skipif(
    not sandbox().sandboxed and not os.environ.get("CI"), reason=f"no sandbox here: {sandbox().why}"
)


def rows(report) -> dict[str, tuple[str, str]]:
    return {row.part: (row.status, row.got) for row in report.rows}


def estimate_only(tmp_path: Path, prelude: str = "", **parts) -> object:
    """The report of the estimate stage (a few seconds) of a submission with `prelude` at import."""
    path = write_submission(tmp_path / "sub" / "my_filter.py", textwrap.dedent(prelude), **parts)
    return check_file(str(path), seed=SEED, stages=("estimate",), timeout=30)


def said(report, key: str) -> dict:
    """The JSON the submission printed after `key` (its only way to say what it found)."""
    lines = [line for line in report.output.splitlines() if line.startswith(key + " ")]
    assert lines, report.output
    return json.loads(lines[-1].removeprefix(key + " "))


# -- the kit -------------------------------------------------------------------------------------------
def lab_imports(module: str) -> set[str]:
    """The mazelab modules `module` imports (at any depth of its code, not under TYPE_CHECKING), as the
    kit holds it (a module of constants imports nothing)."""
    tree = ast.parse(module_text(module) if module in KIT else source_file(module).read_text())
    for node in ast.walk(tree):
        if isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test):
            node.body = []
    found: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("mazelab") and not node.level:
            found.add(node.module)
            found |= {f"{node.module}.{a.name}" for a in node.names if source_file(f"{node.module}.{a.name}").is_file()}
        elif isinstance(node, ast.Import):
            found |= {a.name for a in node.names if a.name.startswith("mazelab")}
    return found


def transitive_imports(module: str) -> set[str]:
    """Every mazelab module `module` imports, directly or through others, and their parent packages."""
    seen, todo = set(), [module]
    while todo:
        name = todo.pop()
        if name in seen or not source_file(name).is_file():
            continue
        seen.add(name)
        parts = name.split(".")
        todo += [".".join(parts[:i]) for i in range(1, len(parts))] + sorted(lab_imports(name))
    return seen


def test_every_module_student_filter_imports_is_in_the_kit_and_none_is_a_reference():
    """StudentFilter's transitive mazelab imports (and the child's) are each in KIT, and none of
    them is a reference implementation: when StudentFilter imports a new module, this names it."""
    needed = transitive_imports("mazelab.exercise.student") | transitive_imports("mazelab.exercise.child")
    assert needed - set(KIT) == set(), "add these to mazelab.exercise.kit.KIT"
    assert not [m for m in KIT if m.startswith(REFERENCE_MODULES)]
    assert not [m for m in needed if m.startswith(REFERENCE_MODULES)]


def test_every_name_a_kit_module_imports_from_another_is_in_the_kit(tmp_path):
    """A module the kit trims (only some functions, or constants) still holds every name the kit's
    other modules import from it: StudentFilter importing a new name from mazelab.weights names it here."""
    build_kit(tmp_path / "kit")
    defined = {}
    for module in KIT:
        tree = ast.parse((tmp_path / "kit" / kit_file(module)).read_text())
        names = set()
        for node in tree.body:
            if isinstance(node, (ast.FunctionDef, ast.ClassDef)):
                names.add(node.name)
            elif isinstance(node, ast.Assign):
                names |= {t.id for t in node.targets if isinstance(t, ast.Name)}
            elif isinstance(node, (ast.Import, ast.ImportFrom)):
                names |= {(a.asname or a.name).split(".")[0] for a in node.names}
        defined[module] = names
    missing = []
    for module in KIT:
        for node in ast.walk(ast.parse((tmp_path / "kit" / kit_file(module)).read_text())):
            if isinstance(node, ast.ImportFrom) and node.module in KIT and not node.level:
                missing += [f"{node.module}.{a.name}" for a in node.names if a.name not in defined[node.module]
                            and f"{node.module}.{a.name}" not in KIT]  # fmt: skip
    assert missing == []


def test_the_kit_holds_none_of_the_reference_functions_and_is_built_read_only(tmp_path):
    build_kit(tmp_path / "kit")
    build_kit(tmp_path / "again")
    files = sorted((tmp_path / "kit").rglob("*.py"))
    assert [(f.relative_to(tmp_path / "kit"), f.read_text()) for f in files] == [
        (f.relative_to(tmp_path / "again"), f.read_text()) for f in sorted((tmp_path / "again").rglob("*.py"))
    ]  # the same kit each time
    # a function of a reference's name may be in the kit only as the engine's abstract hook (its body
    # raises NotImplementedError: the student's part fills it)
    for name in REFERENCE_FUNCTIONS:  # mazelab.model.move and the like: not in the kit's copy of their module
        module, function = name.rsplit(".", 1)
        copy = tmp_path / "kit" / kit_file(module)
        assert f"def {function}(" not in (copy.read_text() if copy.exists() else ""), name
    text = "\n".join(f.read_text() for f in files)
    assert "def systematic_resample" not in text and "def weighted_mean" not in text
    # the engine's model parts call the model object it is given: the student's parts (StudentFilter's wrappers)
    engine = ast.parse((tmp_path / "kit" / kit_file("mazelab.smc")).read_text())
    for node in ast.walk(engine):
        if isinstance(node, ast.FunctionDef) and node.name in {"transition", "log_likelihood"}:
            body = [n for n in node.body if not (isinstance(n, ast.Expr) and isinstance(n.value, ast.Constant))]
            assert len(body) == 1 and ast.unparse(body[0]).startswith("return self.model."), node.name
    assert {oct(f.stat().st_mode & 0o777) for f in files} == {"0o444"}
    model = (tmp_path / "kit" / "mazelab" / "model.py").read_text()
    assert "ROBOT_SPEED = 0.2" in model and "import" not in model  # the constants as literals, nothing else


# -- what the sandbox holds ------------------------------------------------------------------------------
@needs_sandbox
def test_the_sandbox_holds_no_reference_implementation_no_lab_source_no_network_and_no_other_file(tmp_path):
    lab_file = str(source_file("mazelab.filters"))
    original = str(tmp_path / "sub")
    modules = list(REFERENCE_MODULES)
    prelude = f"""
        import importlib, json, os, socket
        found = {{"imported": [], "read": [], "listed": [], "uid": os.getuid(), "network": True}}
        for module in {modules!r}:
            try:
                importlib.import_module(module)
                found["imported"].append(module)
            except ImportError:
                pass
        for path in ({lab_file!r}, "/etc/passwd", {original!r} + "/my_filter.py", "/root"):
            try:
                open(path).read(1)
                found["read"].append(path)
            except OSError:
                pass
        for folder in ({original!r}, {str(Path(lab_file).parent)!r}, "/work", "/home"):
            if os.path.isdir(folder):
                found["listed"].append(folder)
        try:
            socket.create_connection(("127.0.0.1", 22), timeout=1).close()
        except OSError:
            found["network"] = False
        found["files"] = sorted(os.listdir("/submission"))
        print("found", json.dumps(found))
    """
    report = estimate_only(tmp_path, prelude)
    found = said(report, "found")
    assert found["imported"] == [] and found["read"] == [] and found["listed"] == [], found
    assert found["uid"] == SANDBOX_UID and found["network"] is False and found["files"] == ["my_filter.py"]
    assert rows(report)["estimate"][0] == "pass" and report.note == ""


@needs_sandbox
@pytest.mark.parametrize(
    "how, prelude",
    [
        ("exec of the lab's source", "import inspect, mazelab.model as m\nexec(inspect.getsource(m.log_likelihood))"),
        ("a copy of the lab's files", f"import shutil\nshutil.copytree({str(PACKAGE_DIR)!r}, '/tmp/lab')"),
        ("the monitor patched", "import mazelab.exercise.monitor as m\nm.Monitor.record = lambda self, name: None"),
    ],
)
def test_what_delegated_to_the_lab_finds_nothing_there(tmp_path, how, prelude):
    path = write_submission(tmp_path / "sub" / "my_filter.py", prelude)
    with pytest.raises(NotGradableError, match="does not import"):
        check_file(str(path), seed=SEED, stages=("estimate",))


@needs_sandbox
def test_an_import_of_the_labs_reference_code_is_named_as_such(tmp_path):
    """Not a typo: the report says the lab's own code is not there for a submission."""
    path = write_submission(tmp_path / "sub" / "my_filter.py", "from mazelab.resampling import systematic_resample")
    with pytest.raises(NotGradableError, match=r"'mazelab\.resampling'.*the lab's own code is not there"):
        check_file(str(path), seed=SEED, stages=("estimate",))


@needs_sandbox
def test_a_thread_calling_the_lab_finds_nothing_to_call(tmp_path):
    estimate = """
        def estimate(self, positions, weights):
            import _thread, time
            out = []
            def work():
                try:
                    from mazelab.weights import weighted_mean
                    out.append(weighted_mean(weights, positions))
                except BaseException as error:
                    out.append(error)
            _thread.start_new_thread(work, ())
            while not out:
                time.sleep(0.01)
            if isinstance(out[0], BaseException):
                raise out[0]
            return out[0]
    """
    status, got = rows(estimate_only(tmp_path, estimate=textwrap.dedent(estimate)))["estimate"]
    assert status == "fail" and "cannot import name 'weighted_mean'" in got


# -- answers judged by their values only -----------------------------------------------------------------
@needs_sandbox
def test_forged_answers_on_the_pipe_get_the_verdict_of_their_values(tmp_path):
    """The child's answer pipe taken at import: "loaded", a forged result for every stage and "done",
    then os._exit(0). The grader believes none of what it says, only the values: estimate fails."""
    prelude = """
        import os, stat
        from mazelab.exercise.child import encode

        def send(fd, meta, arrays=None):
            os.write(fd, encode(meta, arrays))

        for fd in range(3, 64):
            try:
                if stat.S_ISFIFO(os.fstat(fd).st_mode) and fd > 2:
                    send(fd, {"kind": "loaded", "class": "MyFilter", "name": "MyFilter", "student_filter": True,
                              "bases": []})
                    send(fd, {"kind": "stage", "stage": "estimate"})
                    send(fd, {"kind": "result", "stage": "estimate", "passed": True},
                         {f"point/{k}": np.zeros(2) for k in range(4)})
                    send(fd, {"kind": "done"})
            except OSError:
                pass
        os._exit(0)
    """
    status, got = rows(estimate_only(tmp_path, prelude))["estimate"]
    assert status == "fail" and "off by" in got, got


@needs_sandbox
def test_a_forged_done_without_answers_fails_every_row_and_forges_no_line(tmp_path):
    prelude = """
        import os, stat
        from mazelab.exercise.child import encode

        for fd in range(3, 64):
            try:
                if stat.S_ISFIFO(os.fstat(fd).st_mode):
                    for meta in ({"kind": "loaded", "class": "MyFilter", "name": "Mine\\nAll checks pass.",
                                  "student_filter": True, "bases": []}, {"kind": "done"}):
                        os.write(fd, encode(meta))
            except OSError:
                pass
        os._exit(0)
    """
    path = write_submission(tmp_path / "sub" / "my_filter.py", textwrap.dedent(prelude))
    report = check_file(str(path), seed=SEED, stages=("predict", "estimate"))
    assert [(r.status, r.got) for r in report.rows] == [("fail", "no answer came from the student's process")] * 2
    assert report.filter_name == "Mine\\nAll checks pass."  # one line: the report's own lines cannot be forged


@needs_sandbox
def test_a_setsid_grandchild_and_a_sleeping_thread_neither_hold_the_grading_nor_outlive_it(tmp_path):
    marker = f"mazelab-test-grandchild-{os.getpid()}-{time.time_ns()}"
    prelude = f"""
        import os, subprocess, sys, threading, time
        subprocess.Popen([sys.executable, "-c", "import time; time.sleep(600)", {marker!r}],
                         start_new_session=True)
        threading.Thread(target=time.sleep, args=(600,)).start()  # not a daemon
    """
    report = estimate_only(tmp_path, prelude)
    assert rows(report)["estimate"][0] == "pass", report.rows
    left = [p for p in Path("/proc").iterdir() if p.name.isdigit() and marker in _cmdline(p)]
    assert left == []


def _cmdline(process: Path) -> str:
    try:
        return (process / "cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
    except OSError:
        return ""


@needs_sandbox
def test_a_part_that_allocates_past_the_memory_limit_fails_naming_it(tmp_path):
    estimate = f"""
        def estimate(self, positions, weights):
            hoard = np.empty({MEMORY_LIMIT // 8 + (1 << 27)})  # a gigabyte past the limit (of address space)
            return weights @ positions + hoard[0] - 1
    """
    status, got = rows(estimate_only(tmp_path, estimate=textwrap.dedent(estimate)))["estimate"]
    assert status == "fail" and "MemoryError" in got and f"past the memory limit of {MEMORY_LIMIT / 2**30:g} GB" in got


@needs_sandbox
def test_the_private_tmp_is_bounded(tmp_path):
    if not sandbox().bounded_tmp:
        pytest.skip("this bwrap (before 0.7) cannot bound /tmp")
    estimate = f"""
        def estimate(self, positions, weights):
            block = bytes(48 << 20)  # under the file size limit; {TMP_LIMIT >> 20} MB of /tmp in all
            for k in range({TMP_LIMIT // (48 << 20) + 2}):
                with open(f"/tmp/fill{{k}}", "wb") as file:
                    file.write(block)
            return weights @ positions
    """
    status, got = rows(estimate_only(tmp_path, estimate=textwrap.dedent(estimate)))["estimate"]
    assert status == "fail" and "No space left on device" in got, got


def test_a_sandbox_that_cannot_be_started_is_the_graders_error_not_the_students(tmp_path, monkeypatch):
    import mazelab.exercise.report as report

    monkeypatch.setattr(report, "sandbox", lambda: Sandbox(str(tmp_path / "gone" / "bwrap")))
    path = write_submission(tmp_path / "sub" / "my_filter.py")
    with pytest.raises(SandboxError, match="could not be started"):
        check_file(str(path), seed=SEED, stages=("weigh", "estimate"))


# -- copied code ---------------------------------------------------------------------------------------
def renamed(source: str, names: dict[str, str]) -> str:
    """`source` with its names changed (the way a copy is hidden)."""
    for old, new in names.items():
        source = re.sub(rf"\b{old}\b", new, source)
    return source


def test_the_labs_code_with_its_names_changed_is_not_own_work(tmp_path):
    weighted = textwrap.dedent(source_file("mazelab.weights").read_text())
    start = weighted.index("def _columns(")
    helpers = weighted[start : weighted.index("def weighted_covariance(")]
    helpers = renamed(helpers, {"_columns": "split_xy", "W": "ww", "means": "out", "column": "j", "runs": "r"})
    helpers = renamed(helpers, {"weighted_mean": "my_mean", "points": "pts", "weights": "wts"})
    estimate = "def estimate(self, positions, weights):\n    return my_mean(weights, positions)\n"
    report = estimate_only(tmp_path, prelude="import numpy as np\n\n" + helpers, estimate=estimate)
    status, got = rows(report)["estimate"]
    assert status == "not own work" and "mazelab.weights.weighted_mean" in got, got


def test_no_honest_answer_is_taken_for_a_copy():
    """Every answer of tests/exercise_answers.py (the reference, each resampler, the planted bugs and
    the slightly wrong parts) stays under the limit (docs/exercise.md: the measured largest)."""
    import exercise_answers

    from mazelab.exercise.kit import LIKENESS_LIMIT, class_source, likeness

    classes = [c for c in vars(exercise_answers).values() if isinstance(c, type)]
    worst = max(share for c in classes for share, _ in likeness({"c.py": class_source(c)}).values())
    assert worst < LIKENESS_LIMIT


# -- where no sandbox can be made -----------------------------------------------------------------------
def test_without_a_sandbox_the_report_says_so_and_require_sandbox_refuses(tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("MAZELAB_BWRAP", str(tmp_path / "no-bwrap"))
    sandbox.cache_clear()
    try:
        report = estimate_only(tmp_path)
        assert "not sandboxed" in report.note and "cannot be trusted" in report.note
        path = str(tmp_path / "sub" / "my_filter.py")
        assert main(["exercise", "check", path, "--require-sandbox"]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and "--require-sandbox" in err[0]
    finally:
        sandbox.cache_clear()


# -- check --gradescope when nothing can be checked ------------------------------------------------------
@pytest.mark.parametrize("what", ["does not import", "does not exist"])
def test_check_gradescope_writes_a_zero_with_the_reason(tmp_path, capsys, what):
    path = tmp_path / "my_filter.py"
    if what == "does not import":
        path.write_text("raise RuntimeError('broken at import')\n")
    assert main(["exercise", "check", str(path), "--gradescope", str(tmp_path)]) == 2
    results = json.loads((tmp_path / "results.json").read_text())
    assert results["score"] == 0.0 and results["tests"] and all(t["score"] == 0.0 for t in results["tests"])
    assert ("broken at import" if what == "does not import" else "no such file") in results["output"]
    assert len(capsys.readouterr().err.strip().splitlines()) == 1


@pytest.mark.parametrize("timeout", ["inf", "1e18", "nan"])
def test_check_refuses_a_timeout_past_a_day_in_one_line(tmp_path, capsys, timeout):
    path = write_submission(tmp_path / "my_filter.py")
    assert main(["exercise", "check", str(path), "--timeout", timeout]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--timeout" in err[0]


def test_the_uk_report_speaks_ukrainian(tmp_path, capsys):
    path = write_submission(tmp_path / "my_filter.py", estimate="def estimate(self, positions, weights):\n    "
                            "return positions.mean(axis=0)\n")  # fmt: skip
    assert main(["exercise", "check", str(path), "--lang", "uk", "--seed", str(SEED), "--timeout", "30"]) == 1
    out = capsys.readouterr().out
    assert "НЕ ЗАРАХОВАНО" in out and "Треба виправити: estimate" in out  # noqa: RUF001
    assert "це просте середнє гранул, без ваг" in out
    assert "FAIL" not in out and "hint:" not in out and "expected:" not in out
    assert main(["exercise", "check", str(path), "--lang", "xx"]) == 2


def test_the_catalogue_is_read_without_running_it(tmp_path):
    from mazelab.exercise.template import CatalogueError, read_po

    po = tmp_path / "xx.po"
    po.write_text('msgid "a"\nmsgstr __import__("os").system("echo run")\n')
    with pytest.raises(CatalogueError, match="line 2"):
        read_po(po)
    po.write_text('msgid "a"\nmsgstr "b\\n"\n')
    assert read_po(po) == {"a": "b\n"}


def test_check_refuses_a_link_to_a_file_that_is_not_python_in_one_line(tmp_path, capsys):
    (tmp_path / "my_filter.py").symlink_to("/etc/passwd")
    assert main(["exercise", "check", str(tmp_path / "my_filter.py")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"error: {tmp_path / 'my_filter.py'}: a link to /etc/passwd, not a Python file"]


# -- the sandbox on every host (issue 48, item 3, 6, 8) -------------------------------------------------
@pytest.fixture
def fresh_probe():
    """The sandbox and the cgroups probed again for this test (and after it)."""
    from mazelab.exercise.sandbox import cgroup_parents

    sandbox.cache_clear()
    cgroup_parents.cache_clear()
    yield
    sandbox.cache_clear()
    cgroup_parents.cache_clear()


def stand_in_bwrap(tmp_path: Path, refused: str) -> Path:
    """A bwrap that exits 1 when an argument holds `refused` (as bubblewrap before 0.7 does for --size),
    and otherwise runs the real one."""
    script = tmp_path / "bwrap"
    real = shutil.which("bwrap")
    script.write_text(
        f'#!/bin/sh\nfor a in "$@"; do case "$a" in *{refused}*) echo "bwrap: Unknown option $a" >&2; exit 1;; '
        f'esac; done\nexec {real} "$@"\n'
    )
    script.chmod(0o755)
    return script


@needs_sandbox
def test_a_bwrap_without_size_still_sandboxes_every_submission(tmp_path, monkeypatch, fresh_probe):
    """Bubblewrap 0.6 (Ubuntu 22.04) has no --size: the command follows the probe, so the check passes."""
    monkeypatch.setenv("MAZELAB_BWRAP", str(stand_in_bwrap(tmp_path, "--size")))
    assert sandbox().sandboxed and not sandbox().bounded_tmp
    report = estimate_only(tmp_path)
    assert rows(report)["estimate"][0] == "pass" and report.note == ""


@needs_sandbox
def test_a_bwrap_that_fails_before_the_students_code_is_the_graders_error(tmp_path, monkeypatch, capsys,
                                                                          fresh_probe):  # fmt: skip
    """One line, exit 2, and no results.json nor CSV row giving anybody a 0."""
    monkeypatch.setenv("MAZELAB_BWRAP", str(stand_in_bwrap(tmp_path, "mazelab.exercise.child")))
    path = write_submission(tmp_path / "class" / "alice" / "my_filter.py")
    (tmp_path / "out").mkdir()
    assert main(["exercise", "check", str(path), "--gradescope", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "the sandbox did not start" in err[0] and "Unknown option" in err[0], err
    assert not (tmp_path / "out" / "results.json").exists()
    arguments = ["exercise", "grade", str(tmp_path / "class"), "--csv", str(tmp_path / "out" / "grades.csv")]
    assert main([*arguments, "--quiet", "--gradescope", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "nobody graded" in err[0]
    assert not (tmp_path / "out" / "grades.csv").exists() and not (tmp_path / "out" / "alice").exists()


@needs_sandbox
def test_the_graders_environment_is_not_in_the_sandbox(tmp_path, monkeypatch):
    """bwrap itself starts with a minimal environment: /proc/1 (bwrap) shows none of the grader's."""
    monkeypatch.setenv("MAZELAB_TEST_SECRET", "hunter2")
    prelude = """
        for pid in ("1", "self"):
            with open(f"/proc/{pid}/environ", "rb") as file:
                print("environ", pid, file.read().replace(b"\\0", b" ").decode(errors="replace"))
    """
    report = estimate_only(tmp_path, prelude)
    assert "environ 1 " in report.output and "hunter2" not in report.output and "MAZELAB" not in report.output


FORK_BOMB = f"""
    def estimate(self, positions, weights):
        import os, time
        born = 0
        try:
            for _ in range({PROCESS_LIMIT * 3}):
                if os.fork() == 0:
                    time.sleep(20)
                    os._exit(0)
                born += 1
        except OSError as error:
            raise RuntimeError(f"forked {{born}}: {{error}}") from None
        return weights @ positions
"""


@needs_sandbox
@pytest.mark.parametrize("cgroups", ["as the host delegates them", "off"])
def test_a_submission_starts_at_most_the_process_limit(tmp_path, monkeypatch, fresh_probe, cgroups):
    """With a pids cgroup, or without (RLIMIT_NPROC in the sandbox's user namespace; as root, the
    sandbox drops to the host's uid 65534 first, binding what it cannot reach from a staged place:
    RLIMIT_NPROC does not hold for root, so a fork count under the limit there shows the drop)."""
    from mazelab.exercise.sandbox import cgroup_parents

    if cgroups == "off":
        monkeypatch.setenv("MAZELAB_CGROUPS", "off")
    elif cgroup_parents() is None:
        pytest.skip("no cgroup this grader may make here")
    report = estimate_only(tmp_path, estimate=textwrap.dedent(FORK_BOMB))
    status, got = rows(report)["estimate"]
    assert status == "fail" and "forked" in got, got
    assert int(re.search(r"forked (\d+)", got).group(1)) < PROCESS_LIMIT


@needs_sandbox
def test_memory_is_limited_per_sandbox_where_there_is_a_cgroup(tmp_path, monkeypatch, fresh_probe):
    """Three processes of 300 MB each under a cgroup of 512 MB: one of them is killed (per process,
    each would be within its 4 GB of address space)."""
    from mazelab.exercise.sandbox import Cgroup, cgroup_parents

    if cgroup_parents() is None:
        pytest.skip("no cgroup this grader may make here")
    monkeypatch.setattr(
        Cgroup, "LIMITS", {**Cgroup.LIMITS, "memory.max": 512 << 20, "memory.limit_in_bytes": 512 << 20}
    )
    estimate = """
        def estimate(self, positions, weights):
            import os
            children = []
            for _ in range(3):
                pid = os.fork()
                if pid == 0:
                    block = np.ones(300 << 17)  # 300 MB, every page touched
                    import time
                    time.sleep(3)
                    os._exit(int(block[0]) - 1)
                children.append(pid)
            ends = [os.waitpid(pid, 0)[1] for pid in children]
            if any(os.WIFSIGNALED(end) for end in ends):
                raise MemoryError("a process of the sandbox was killed at its memory limit")
            return weights @ positions
    """
    status, got = rows(estimate_only(tmp_path, estimate=textwrap.dedent(estimate)))["estimate"]
    assert status == "fail" and ("memory limit" in got or "SIGKILL" in got), got


# -- code that is not in the files cannot run (issue 48, item 5) ----------------------------------------
GUARDED = {
    "exec of a text": "exec('x = 1')",
    "an exec of an encoded text": "import base64\nexec(base64.b64decode(b'eCA9IDE='))",
    "compile": "compile('1', 'mine', 'eval')",
    "marshal": "import marshal\nmarshal.loads(bytes(40))",
    "a code object made": "(lambda: 1).__code__.replace(co_name='mine')",
    "a call through ctypes": "import ctypes\nctypes.CDLL(None).getpid()",
    "a module written to /tmp": "import sys\nopen('/tmp/mine.py', 'w').write('x = 1')\nsys.path.append('/tmp')\n"
    "import mine",
    "a dataclass": "import dataclasses\n\n\n@dataclasses.dataclass\nclass Point:\n    x: int = 1",
    "open and the paths patched first": "import builtins, posixpath\nbuiltins.open = print\n"
    "posixpath.realpath = posixpath.abspath = lambda *a, **k: '/kit/mine.py'\nexec('x = 1')",
}


@pytest.mark.parametrize("how", list(GUARDED))
def test_code_that_is_not_in_the_submissions_files_cannot_run(tmp_path, how):
    """exec, compile, marshal, code objects, ctypes and modules from elsewhere are refused in the child,
    sandbox or not, by a hook installed before the submission is imported."""
    path = write_submission(tmp_path / "sub" / "my_filter.py", GUARDED[how])
    with pytest.raises(NotGradableError, match=r"does not import: (PermissionError|ImportError): .*a submission"):
        check_file(str(path), seed=SEED, stages=("estimate",))


def test_an_exec_inside_a_part_fails_the_part_and_the_others_pass(tmp_path):
    estimate = "def estimate(self, positions, weights):\n    return eval('weights @ positions')\n"
    report = estimate_only(tmp_path, estimate=estimate)
    assert rows(report)["estimate"][0] == "fail" and "may not compile text" in rows(report)["estimate"][1]
    honest = estimate_only(tmp_path / "honest", "import collections, json, statistics\nimport numpy.linalg")
    assert rows(honest)["estimate"][0] == "pass"


# -- copied code, read as it runs (issue 48, item 5) ---------------------------------------------------
def lab_function(qualified: str, name: str) -> str:
    """A reference function's source, renamed `name` with its arguments and locals renamed too."""
    module, _, function = qualified.rpartition(".")
    tree = ast.parse(source_file(module).read_text())
    node = next(n for n in tree.body if isinstance(n, ast.FunctionDef) and n.name == function)
    node.name, node.returns = name, None
    for argument in node.args.args:  # a copy without the annotations (which a copy may drop or add)
        argument.annotation = None
    text = ast.unparse(node)
    for i, argument in enumerate(a.arg for a in node.args.args):
        text = re.sub(rf"\b{argument}\b", f"v{i}", text)
    return text


def test_the_labs_code_bound_to_a_part_is_not_own_work():
    """Bound by assignment, as a staticmethod, from a helper module, with annotations added: each is
    the lab's code, named by its qualified name."""
    from mazelab.exercise.kit import copied_parts

    systematic = lab_function("mazelab.resampling.systematic_resample", "_sr")
    likelihood = lab_function("mazelab.model.log_likelihood", "_w")
    cases = {
        "resample": {"f.py": f"{systematic}\n\nclass F:\n    resample = staticmethod(_sr)\n"},
        "weigh": {"f.py": f"{likelihood}\n\nclass F:\n    weigh = _w\n"},
        "weigh ": {"f.py": "from helpers import _w as mine\n\nclass F:\n    def weigh(self, p, z):\n"
                   "        return mine(z, p, self.world, self.sigma)\n", "helpers.py": likelihood},
        "resample ": {"f.py": "import helpers\n\nclass F:\n    resample = staticmethod(lambda w, rng: "
                      "helpers._sr(w, rng))\n", "helpers.py": systematic.replace("(v0, v1", "(v0: list, v1: int")},
    }  # fmt: skip
    for part, sources in cases.items():
        copied = copied_parts(sources)
        assert part.strip() in copied, (part, copied)
        reference = "systematic_resample" if "resample" in part else "mazelab.model.log_likelihood "
        assert reference.strip() in copied[part.strip()] and "100%" in copied[part.strip()], copied


def test_a_copy_no_part_reaches_marks_the_whole_filter(tmp_path):
    helper = lab_function("mazelab.weights.weighted_mean", "unused")
    path = write_submission(tmp_path / "sub" / "my_filter.py", "import numpy as np\n\n" + helper)
    report = check_file(str(path), seed=SEED, stages=("estimate", "whole"), timeout=60)
    assert rows(report)["estimate"][0] == "pass"
    assert rows(report)["whole filter"][0] == "not own work" and "weighted_mean" in rows(report)["whole filter"][1]
