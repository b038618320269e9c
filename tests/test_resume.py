"""`study --resume` goes on from the study's journal and keeps only this study's rows: a journal of another
seed, maze or sigma is refused (its parameters differ), and so are another study's run lines put into it,
in one line naming the first (exit 2, nothing written); its inputs end as one line too: a journal whose
parameters are a list or whose root seed is text, a pipe or a device among the files, a line that is not
a run's rows, UTF-16 text, a journal too large to read. Real files, links and pipes; real processes
where a hang is the failure."""

from __future__ import annotations

import csv
import io
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from conftest import ROOT

from mazelab.cli.app import main
from mazelab.experiments.journal import foreign_row
from mazelab.experiments.study import RunRecord

try:
    import resource
except ImportError:  # not on Windows
    resource = None

STUDY = ["study", "--maze", "paper_5x5", "--runs", "3", "--steps", "5", "--particles", "30", "--filters", "sir,apf"]
STUDY += ["--workers", "1", "--no-viz"]


def one_error(capsys) -> str:
    err = capsys.readouterr().err
    (line,) = err.splitlines()
    assert line.startswith("error: ") and "Traceback" not in err
    return line


@pytest.fixture
def finished(tmp_path, capsys):
    """A finished study of seed 1 (s.csv, its journal s.runs.jsonl, s.record.json)."""
    assert main([*STUDY, "--seed", "1", "--csv", str(tmp_path / "s.csv")]) == 0
    capsys.readouterr()
    return tmp_path / "s.csv"


def snapshot(folder: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(folder.iterdir()) if p.is_file() and not p.is_symlink()}


def journal_lines(path: Path) -> list[dict]:
    return [json.loads(line) for line in path.read_text().splitlines()]


def write_lines(path: Path, lines: list[dict]) -> None:
    path.write_text("".join(json.dumps(line) + "\n" for line in lines))


# -- another study's rows -----------------------------------------------------------------------------------
def test_a_journal_of_another_seed_sigma_or_maze_is_refused_naming_the_parameter(tmp_path, finished, capsys):
    for flags, differs in ((["--seed", "2"], "root_seed: 2 -> 1"), (["--sigma", "0.5"], "sigma: [0.5] -> [0.3]")):
        other = tmp_path / "other.csv"
        assert main([*STUDY, "--seed", "1", *flags, "--csv", str(other), "--force"]) == 0
        shutil.copy(other.with_name("other.runs.jsonl"), tmp_path / "s.runs.jsonl")  # another study's journal
        before = snapshot(tmp_path)
        capsys.readouterr()
        assert main([*STUDY, "--seed", "1", "--csv", str(finished), "--resume"]) == 2
        line = one_error(capsys)
        assert f"--resume: the study differs from its journal ({differs}" in line, line
        assert snapshot(tmp_path) == before


def test_a_journal_of_another_maze_of_the_same_name_is_refused(tmp_path, capsys):
    for folder, grid in (("a", "2 0 0\n0 0 0\n0 0 2\n"), ("b", "2 0 0\n0 1 0\n0 0 2\n")):
        (tmp_path / folder).mkdir()
        (tmp_path / folder / "m.txt").write_text(grid)
    table, other = tmp_path / "s.csv", tmp_path / "o.csv"
    base = [*STUDY[3:], "--seed", "1"]
    assert main(["study", "--maze", str(tmp_path / "a" / "m.txt"), *base, "--csv", str(table)]) == 0
    assert main(["study", "--maze", str(tmp_path / "b" / "m.txt"), *base, "--csv", str(other)]) == 0
    shutil.copy(other.with_name("o.runs.jsonl"), table.with_name("s.runs.jsonl"))  # the same labels, another maze
    capsys.readouterr()
    assert main(["study", "--maze", str(tmp_path / "a" / "m.txt"), *base, "--csv", str(table), "--resume"]) == 2
    assert "--resume: the study differs from its journal (mazes: " in one_error(capsys)


def test_another_studys_run_lines_in_the_journal_are_refused_before_any_run(tmp_path, finished, capsys):
    other = tmp_path / "o.csv"
    assert main([*STUDY, "--seed", "2", "--csv", str(other), "--traces", str(tmp_path / "ot.csv")]) == 0
    journal = tmp_path / "s.runs.jsonl"
    mine, theirs = journal_lines(journal), journal_lines(other.with_name("o.runs.jsonl"))
    write_lines(journal, [line for line in mine if "run" not in line or line["run"] != [1, 3]] + theirs[3:4])
    before = snapshot(tmp_path)
    capsys.readouterr()
    assert main([*STUDY, "--csv", str(finished), "--resume"]) == 2
    captured = capsys.readouterr()
    assert "Study:" not in captured.out  # refused before the header, before any run
    (line,) = captured.err.splitlines()
    assert f"{journal} holds another study's rows (run 3 of setting 1: its seed is " in line
    assert "rows of another study are never kept" in line and snapshot(tmp_path) == before


def test_this_studys_own_rows_and_traces_are_kept(tmp_path, capsys):
    table, traces, whole = tmp_path / "s.csv", tmp_path / "t.csv", tmp_path / "whole.csv"
    assert main([*STUDY, "--seed", "1", "--csv", str(whole)]) == 0
    assert main([*STUDY, "--seed", "1", "--runs", "2", "--csv", str(table), "--traces", str(traces)]) == 0
    capsys.readouterr()
    assert main([*STUDY, "--csv", str(table), "--traces", str(traces), "--resume"]) == 0
    assert "resuming: 4 rows kept" in capsys.readouterr().out
    drop = ("ms_per_step", "run_seconds")

    def read(path: Path) -> list[dict[str, str]]:
        return [{k: v for k, v in r.items() if k not in drop} for r in csv.DictReader(io.StringIO(path.read_text()))]

    assert read(table) == read(whole)
    assert len(traces.read_text().splitlines()) == 1 + 3 * 2 * 5


def test_foreign_row_checks_every_planned_column(tmp_path):
    """Each column the plan fixes, changed alone in one row, makes that row another study's: the run's
    seeds, maze and model, and each option the row's filter ran with (or one it does not take, set)."""
    from mazelab.experiments.api import plan_study, study_mazes

    plan = plan_study(study_mazes(["paper_5x5"]), "sir", {"sigma": [0.3], "delta": [0.5], "particles": [30]},
                      runs=2, steps=5, seed=1)  # fmt: skip
    table = tmp_path / "s.csv"
    assert main([*STUDY[:3], "--runs", "2", "--steps", "5", "--particles", "30", "--filters", "sir", "--seed", "1",
                 "--workers", "1", "--csv", str(table)]) == 0  # fmt: skip
    lines = journal_lines(tmp_path / "s.runs.jsonl")
    records = [RunRecord.from_json(row) for line in lines if "run" in line for row in line["records"]]
    assert foreign_row(plan.tasks, records) is None
    changed = {"seed": 7, "maze_sha256": "0" * 64, "maze_seed": 3, "maze": "other", "wall_share": 0.3,
               "sigma": 0.31, "delta": 0.4, "particles": 31, "steps": 6, "kidnap_at": 2}  # fmt: skip
    assert set(changed) == set(plan.tasks[0].cells())  # every cell the plan fixes
    options = {"recovery": "sensor", "estimate": "mode", "resampling": "residual", "bandwidth": "multimodal"}
    for column, value in [*changed.items(), *options.items()]:
        cell = {column: value} if column in changed else {"options": {**records[1].options, column: value}}
        edited = [RunRecord(**{**vars(r), **cell}) if i == 1 else r for i, r in enumerate(records)]
        why = foreign_row(plan.tasks, edited)
        assert why.startswith(f"run 2 of setting 1: its {column} is {value}, "), (column, why)  # the row's value
    moved = [RunRecord(**{**vars(records[0]), "run": 9})]
    assert foreign_row(plan.tasks, moved) == "run 9 of setting 1 is not in this study"
    renamed = [RunRecord(**{**vars(records[0]), "filter": "AuxiliaryParticleFilter"})]
    assert "filter AuxiliaryParticleFilter is not one this study runs" in foreign_row(plan.tasks, renamed)


def test_a_journal_made_on_another_backend_is_refused_or_named(tmp_path, finished, capsys):
    """Rows of two backends never mix in one CSV: a journal of compiled rows, resumed on numpy, is refused
    in one line that says how to go on."""
    journal = tmp_path / "s.runs.jsonl"
    lines = journal_lines(journal)
    for line in lines:
        for row in line.get("records", []):
            row["backend"] = "compiled"
    write_lines(journal, [line for line in lines if line.get("run") != [1, 3]])
    assert main([*STUDY, "--csv", str(finished), "--resume", "--backend", "numpy"]) == 2
    line = one_error(capsys)
    assert "holds runs made on the compiled backend and this session runs on numpy" in line
    assert "give --backend compiled to go on" in line


# -- the inputs of --resume -----------------------------------------------------------------------------------
@pytest.mark.parametrize(
    ("edit", "expected"),
    [
        (lambda p: [1, 2], "its parameters are list, not a mapping"),
        (lambda p: {**p, "root_seed": "5"}, "root_seed must be a whole number"),
        (lambda p: {**p, "root_seed": True}, "root_seed must be a whole number"),
        (lambda p: {**p, "runs": "3"}, "runs must be a whole number >= 1"),
    ],
)
def test_a_journal_of_the_wrong_shape_is_one_line(tmp_path, finished, capsys, edit, expected):
    journal = tmp_path / "s.runs.jsonl"
    lines = journal_lines(journal)
    lines[0]["session"]["parameters"] = edit(lines[0]["session"]["parameters"])
    write_lines(journal, lines)
    before = snapshot(tmp_path)
    assert main([*STUDY, "--csv", str(finished), "--resume"]) == 2
    line = one_error(capsys)
    assert line.startswith(f"error: --resume: {journal}: ") and expected in line, line
    assert snapshot(tmp_path) == before


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("[" * 100_000 + "]" * 100_000 + "\n", "line 1: not a journal line"),
        ("1" * 5000 + "\n", "line 1: not a journal line"),
        ('{"run": [1, 1], "records": [{"seed": 1}]}\n', "not a study's journal (no session line)"),
        ("[1, 2]\n", "line 1: not a journal line (a JSON object)"),
    ],
)
def test_a_journal_that_is_not_one_is_one_line(tmp_path, finished, capsys, text, expected):
    journal = tmp_path / "s.runs.jsonl"
    journal.write_text(text)
    assert main([*STUDY, "--csv", str(finished), "--resume"]) == 2
    line = one_error(capsys)
    assert str(journal) in line and expected in line, line


def test_a_run_line_that_is_not_a_runs_rows_is_named(tmp_path, finished, capsys):
    journal = tmp_path / "s.runs.jsonl"
    lines = journal_lines(journal)
    del lines[2]["records"][0]["seed"]
    write_lines(journal, lines)
    assert main([*STUDY, "--csv", str(finished), "--resume"]) == 2
    line = one_error(capsys)
    assert f"{journal} line 3: not a run's rows" in line and "seed" in line


def resume_process(table: Path, preexec_fn=None) -> subprocess.CompletedProcess:
    """`main.py study ... --resume` as its own process: a pipe that it opened would hang it (timeout)."""
    command = [sys.executable, str(ROOT / "main.py"), *STUDY, "--csv", str(table), "--resume"]
    return subprocess.run(command, capture_output=True, text=True, timeout=60, preexec_fn=preexec_fn)


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="no named pipes here")
@pytest.mark.parametrize("name", ["s.csv", "s.runs.jsonl", "s.record.json"])
def test_a_pipe_among_the_files_is_refused_unread(tmp_path, finished, name):
    path = tmp_path / name
    path.unlink(missing_ok=True)
    os.mkfifo(path)
    done = resume_process(finished)
    assert done.returncode == 2, done.stderr
    (line,) = done.stderr.splitlines()
    assert f"{path}" in line and "is a pipe" in line


@pytest.mark.skipif(not Path("/dev/zero").exists(), reason="no /dev/zero here")
def test_a_csv_or_a_journal_linked_to_dev_zero_is_refused_unread(tmp_path, finished):
    finished.unlink()
    finished.symlink_to("/dev/zero")
    done = resume_process(finished)
    assert done.returncode == 2, done.stderr
    (line,) = done.stderr.splitlines()
    assert line == f"error: {finished}: it is a device, not a regular file; only regular files are replaced"
    journal = finished.with_name("s.runs.jsonl")
    journal.unlink()
    journal.symlink_to("/dev/zero")
    finished.unlink()
    done = resume_process(finished)
    assert done.returncode == 2 and f"{journal} is a symlink" in done.stderr, done.stderr


def test_utf16_and_nul_bytes_are_named_with_their_file(tmp_path, finished, capsys):
    journal = tmp_path / "s.runs.jsonl"
    text = journal.read_text()
    journal.write_text(text, encoding="utf-16")
    assert main([*STUDY, "--csv", str(finished), "--resume"]) == 2
    assert f"--resume: {journal}: not UTF-8 text" in one_error(capsys)
    journal.write_text(text.replace('"sir', '"s\0r', 1).replace("SIRParticleFilter", "SIR\0", 1))
    assert main([*STUDY, "--csv", str(finished), "--resume"]) == 2
    assert f"--resume: {journal}" in one_error(capsys)


@pytest.mark.skipif(resource is None or not hasattr(resource, "RLIMIT_AS"), reason="no address-space limit here")
def test_a_journal_too_large_to_read_back_is_refused_unread(tmp_path, finished):
    """A journal of 2 GB (sparse: no disk space) under `ulimit -v` 3 GB: refused in one line before it is
    read, not a MemoryError once it is."""
    journal = tmp_path / "s.runs.jsonl"
    with journal.open("r+b") as handle:
        try:
            handle.truncate(2 * 10**9)
        except OSError as error:
            pytest.skip(f"no sparse file of 2 GB here: {error}")

    def limited() -> None:
        resource.setrlimit(resource.RLIMIT_AS, (3 * 2**30, resource.getrlimit(resource.RLIMIT_AS)[1]))

    done = resume_process(finished, preexec_fn=limited)
    assert done.returncode == 2, done.stderr
    (line,) = done.stderr.splitlines()
    assert f"reading {journal} (2000000000 bytes) needs about " in line and "memory is available" in line


def test_a_study_of_an_earlier_version_is_refused_in_one_line_saying_why(tmp_path, capsys):
    """A CSV (and its partial rows) that an earlier version wrote, with no journal beside it: --resume
    says it cannot go on from it, and how to start again."""
    table = tmp_path / "s.csv"
    table.write_text("setting,run\n1,1\n")
    (tmp_path / "s.csv.partial").write_text("setting,run\n1,2\n")
    assert main([*STUDY, "--csv", str(table), "--resume"]) == 2
    line = one_error(capsys)
    assert f"no journal {tmp_path / 's.runs.jsonl'} beside {table} to go on from" in line and "--force" in line


def test_a_plugin_changed_since_the_rows_were_made_is_named_with_both_hashes(tmp_path, capsys):
    plugin = tmp_path / "mine.py"
    shutil.copy(ROOT / "tests" / "exercise_answers.py", plugin)
    table = tmp_path / "s.csv"
    args = ["study", "--maze", "paper_5x5", "--filters", f"sir,{plugin}:ReferenceFilter", "--runs", "2", "--steps",
            "5", "--particles", "30", "--workers", "1", "--seed", "1", "--no-viz", "--csv", str(table)]  # fmt: skip
    assert main(args) == 0
    table.unlink()
    plugin.write_text(plugin.read_text() + "\n# changed since\n")
    capsys.readouterr()
    assert main([*args, "--resume"]) == 2
    line = one_error(capsys)
    assert f"--resume: {plugin} is not the code that made the rows" in line and "restore it" in line
