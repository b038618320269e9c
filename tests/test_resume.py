"""`study --resume` keeps only this study's rows: a CSV of another seed or maze, a partial file copied
from another study and another study's traces are refused in one line naming the first foreign row
(exit 2, nothing written); and its inputs end as one line too: a record whose parameters are a list
or whose root seed is text, a pipe or /dev/zero as the CSV, a row short of cells, UTF-16 text.
Real files, links and pipes; real processes where a hang is the failure."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from conftest import ROOT

from mazelab.cli.app import main
from mazelab.experiments.resume import PLANNED_COLUMNS, foreign_row, read_study_csv
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
    """A finished study of seed 1 (s.csv, s.record.json) and the bytes of each of its files."""
    assert main([*STUDY, "--seed", "1", "--csv", str(tmp_path / "s.csv")]) == 0
    capsys.readouterr()
    return tmp_path / "s.csv"


def snapshot(folder: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(folder.iterdir()) if p.is_file() and not p.is_symlink()}


# -- item 3: another study's rows -------------------------------------------------------------------------
def test_a_csv_of_another_seed_is_refused_naming_its_first_row(tmp_path, finished, capsys):
    other = tmp_path / "other.csv"
    assert main([*STUDY, "--seed", "2", "--csv", str(other)]) == 0
    shutil.copy(other, finished)  # another seed's rows beside this study's record
    before = snapshot(tmp_path)
    capsys.readouterr()
    assert main([*STUDY, "--csv", str(finished), "--resume"]) == 2
    line = one_error(capsys)
    assert f"{finished} row 2 is another study's (its seed is " in line
    assert "where this study's run 1 of setting 1 has" in line
    assert snapshot(tmp_path) == before


def test_a_csv_of_another_maze_of_the_same_name_is_refused(tmp_path, capsys):
    for folder, grid in (("a", "2 0 0\n0 0 0\n0 0 2\n"), ("b", "2 0 0\n0 1 0\n0 0 2\n")):
        (tmp_path / folder).mkdir()
        (tmp_path / folder / "m.txt").write_text(grid)
    table, other = tmp_path / "s.csv", tmp_path / "o.csv"
    base = [*STUDY[3:], "--seed", "1"]
    assert main(["study", "--maze", str(tmp_path / "a" / "m.txt"), *base, "--csv", str(table)]) == 0
    assert main(["study", "--maze", str(tmp_path / "b" / "m.txt"), *base, "--csv", str(other)]) == 0
    shutil.copy(other, table)  # the same labels and seeds, another maze
    capsys.readouterr()
    assert main(["study", "--maze", str(tmp_path / "a" / "m.txt"), *base, "--csv", str(table), "--resume"]) == 2
    assert f"{table} row 2 is another study's (its maze_sha256 is " in one_error(capsys)


def test_a_partial_file_copied_from_another_study_is_refused(tmp_path, finished, capsys):
    other = tmp_path / "other.csv"
    assert main([*STUDY, "--seed", "1", "--sigma", "0.5", "--csv", str(other)]) == 0
    shutil.copy(other, tmp_path / "s.csv.partial")  # as if this study had been stopped with these rows
    capsys.readouterr()
    assert main([*STUDY, "--csv", str(finished), "--resume"]) == 2
    line = one_error(capsys)
    assert f"{finished}.partial row 2 is another study's (its sigma is 0.5, where" in line and "has 0.3" in line
    assert (tmp_path / "s.csv.partial").read_bytes() == other.read_bytes()


def test_another_studys_traces_are_refused_before_any_run(tmp_path, capsys):
    table, traces = tmp_path / "s.csv", tmp_path / "t.csv"
    assert main([*STUDY, "--seed", "1", "--csv", str(table), "--traces", str(traces)]) == 0
    assert main([*STUDY, "--seed", "2", "--csv", str(tmp_path / "o.csv"), "--traces", str(tmp_path / "ot.csv")]) == 0
    shutil.copy(tmp_path / "ot.csv", traces)
    lines = table.read_text().splitlines(keepends=True)
    table.write_text("".join(lines[:-2]))  # run 3 to go
    before = snapshot(tmp_path)
    capsys.readouterr()
    assert main([*STUDY, "--csv", str(table), "--traces", str(traces), "--resume"]) == 2
    captured = capsys.readouterr()
    assert "Study:" not in captured.out  # refused before the header, before any run
    (line,) = captured.err.splitlines()
    assert f"{traces} row 2 is another study's (its seed is " in line and "traces of another study" in line
    assert snapshot(tmp_path) == before


def test_this_studys_own_rows_and_traces_are_kept(tmp_path, capsys):
    table, traces, whole = tmp_path / "s.csv", tmp_path / "t.csv", tmp_path / "whole.csv"
    assert main([*STUDY, "--seed", "1", "--csv", str(whole)]) == 0
    assert main([*STUDY, "--seed", "1", "--runs", "2", "--csv", str(table), "--traces", str(traces)]) == 0
    capsys.readouterr()
    assert main([*STUDY, "--csv", str(table), "--traces", str(traces), "--resume"]) == 0
    assert "resuming: 4 rows kept" in capsys.readouterr().out
    drop = ("ms_per_step", "run_seconds")
    assert [{k: v for k, v in vars(r).items() if k not in drop} for r in read_study_csv(table)] == [
        {k: v for k, v in vars(r).items() if k not in drop} for r in read_study_csv(whole)
    ]
    assert len(traces.read_text().splitlines()) == 1 + 3 * 2 * 5


def test_foreign_row_checks_every_planned_column(tmp_path):
    """Each column the plan fixes, changed alone in one row, makes that row another study's: the run's
    seeds, maze and model, and each option the row's filter ran with (or one it does not take, set)."""
    from mazelab.experiments.plan import plan_study, study_mazes

    plan = plan_study(study_mazes(["paper_5x5"]), "sir", sigma=[0.3], delta=[0.5], particles=[30],
                      runs=2, steps=5, seed=1)  # fmt: skip
    table = tmp_path / "s.csv"
    assert main([*STUDY[:3], "--runs", "2", "--steps", "5", "--particles", "30", "--filters", "sir", "--seed", "1",
                 "--workers", "1", "--csv", str(table)]) == 0  # fmt: skip
    records = read_study_csv(table)
    assert foreign_row(plan.tasks(), records) is None
    changed = {"seed": 7, "maze_sha256": "0" * 64, "maze_seed": 3, "maze": "other", "wall_share": 0.3,
               "sigma": 0.31, "delta": 0.4, "particles": 31, "steps": 6, "kidnap_at": 2}  # fmt: skip
    assert set(changed) == set(PLANNED_COLUMNS)
    options = {"recovery": "sensor", "estimate": "mode", "resampling": "residual", "bandwidth": "multimodal"}
    for column, value in [*changed.items(), *options.items()]:
        cell = {column: value} if column in PLANNED_COLUMNS else {"options": {**records[1].options, column: value}}
        edited = [RunRecord(**{**vars(r), **cell}) if i == 1 else r for i, r in enumerate(records)]
        index, why = foreign_row(plan.tasks(), edited)
        assert index == 1 and why.startswith(f"its {column} is "), column
    moved = [RunRecord(**{**vars(records[0]), "run": 9})]
    assert foreign_row(plan.tasks(), moved) == (0, "run 9 of setting 1 is not in this study")
    renamed = [RunRecord(**{**vars(records[0]), "filter": "AuxiliaryParticleFilter"})]
    assert "filter AuxiliaryParticleFilter is not one this study runs" in foreign_row(plan.tasks(), renamed)[1]


# -- item 4: the inputs of --resume -------------------------------------------------------------------------
@pytest.mark.parametrize(
    ("edit", "expected"),
    [
        (lambda r: {**r, "parameters": [1, 2]}, "its parameters are list, not a mapping"),
        (lambda r: {**r, "parameters": {**r["parameters"], "root_seed": "5"}}, "root_seed must be a whole number"),
        (lambda r: {**r, "parameters": {**r["parameters"], "root_seed": True}}, "root_seed must be a whole number"),
        (lambda r: {**r, "parameters": {**r["parameters"], "runs": "3"}}, "runs must be a whole number >= 1"),
        (lambda r: {**r, "sessions": {"a": 1}}, "its sessions must be a list"),
        (lambda r: {**r, "kind": "accuracy"}, "not a study's record (its kind is 'accuracy')"),
        (lambda r: [r], "not a record of this program"),
    ],
)
def test_a_record_of_the_wrong_shape_is_one_line(tmp_path, finished, capsys, edit, expected):
    record = tmp_path / "s.record.json"
    record.write_text(json.dumps(edit(json.loads(record.read_text()))))
    before = snapshot(tmp_path)
    assert main([*STUDY, "--csv", str(finished), "--resume"]) == 2
    line = one_error(capsys)
    assert line.startswith(f"error: --resume: {record}: ") and expected in line, line
    assert snapshot(tmp_path) == before


def test_a_record_nested_too_deep_or_with_a_huge_number_is_one_line(tmp_path, finished, capsys):
    record = tmp_path / "s.record.json"
    for text, expected in (("[" * 100_000 + "]" * 100_000, "nested too deep"), ("1" * 5000, "not a readable record")):
        record.write_text(text)
        assert main([*STUDY, "--csv", str(finished), "--resume"]) == 2
        line = one_error(capsys)
        assert str(record) in line and expected in line


def resume_process(table: Path, preexec_fn=None) -> subprocess.CompletedProcess:
    """`main.py study ... --resume` as its own process: a pipe that it opened would hang it (timeout)."""
    command = [sys.executable, str(ROOT / "main.py"), *STUDY, "--csv", str(table), "--resume"]
    return subprocess.run(command, capture_output=True, text=True, timeout=60, preexec_fn=preexec_fn)


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="no named pipes here")
@pytest.mark.parametrize("name", ["s.csv", "s.csv.partial", "s.record.json"])
def test_a_pipe_among_the_inputs_is_refused_unread(tmp_path, finished, name):
    path = tmp_path / name
    path.unlink(missing_ok=True)
    os.mkfifo(path)
    done = resume_process(finished)
    assert done.returncode == 2, done.stderr
    (line,) = done.stderr.splitlines()
    assert f"{path}" in line and "is a pipe" in line


@pytest.mark.skipif(not Path("/dev/zero").exists(), reason="no /dev/zero here")
def test_a_csv_linked_to_dev_zero_is_refused_unread(tmp_path, finished):
    finished.unlink()
    finished.symlink_to("/dev/zero")
    done = resume_process(finished)
    assert done.returncode == 2, done.stderr
    (line,) = done.stderr.splitlines()
    assert line == f"error: --resume: {finished}: it is a device, not a regular file; a study CSV is a regular file"


def test_a_row_short_of_cells_is_named(tmp_path, finished, capsys):
    lines = finished.read_text().splitlines(keepends=True)
    lines[2] = ",".join(lines[2].split(",")[:5]) + "\n"
    finished.write_text("".join(lines))
    assert main([*STUDY, "--csv", str(finished), "--resume"]) == 2
    line = one_error(capsys)
    assert f"{finished} row 3 has 5 cells, the header " in line and "zip()" not in line


def test_utf16_and_nul_bytes_are_named_with_their_file(tmp_path, finished, capsys):
    text = finished.read_text()
    finished.write_text(text, encoding="utf-16")
    assert main([*STUDY, "--csv", str(finished), "--resume"]) == 2
    assert f"--resume: {finished}: not UTF-8 text" in one_error(capsys)
    finished.write_text(text.replace("sir", "s\0r", 1).replace("SIRParticleFilter", "SIR\0", 1))
    assert main([*STUDY, "--csv", str(finished), "--resume"]) == 2
    assert f"--resume: {finished}" in one_error(capsys)


@pytest.mark.skipif(resource is None or not hasattr(resource, "RLIMIT_AS"), reason="no address-space limit here")
def test_a_csv_too_large_to_read_back_is_refused_unread(tmp_path, finished):
    """A CSV of 2 GB (sparse: no disk space) under `ulimit -v` 3 GB: refused in one line before it is read,
    not a MemoryError once it is."""
    with finished.open("r+b") as handle:
        try:
            handle.truncate(2 * 10**9)
        except OSError as error:
            pytest.skip(f"no sparse file of 2 GB here: {error}")

    def limited() -> None:
        resource.setrlimit(resource.RLIMIT_AS, (3 * 2**30, resource.getrlimit(resource.RLIMIT_AS)[1]))

    done = resume_process(finished, preexec_fn=limited)
    assert done.returncode == 2, done.stderr
    (line,) = done.stderr.splitlines()
    assert f"reading {finished} (2000000000 bytes) needs about " in line and "memory is available" in line
