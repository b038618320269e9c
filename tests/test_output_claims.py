"""Every writer's output name: created exclusively without --force (of concurrent writers one wins,
the others are refused in one line), replaced only when it is a regular file (never a device, pipe
or folder, --force or not), and never announced as saved when the file there is not this writer's."""

from __future__ import annotations

import multiprocessing
import os
import signal
import stat
import subprocess
from pathlib import Path

import pytest
from conftest import ROOT
from test_output_files import NO_DISPLAY, RUN, _wait_for_line

from mazelab import atomic
from mazelab.atomic import NameTakenError, NotRegularFileError, ReplacedMeanwhileError, write_atomically
from mazelab.cli.app import main

RUN_ARGS = ["run", "--maze", "paper_5x5", "--steps", "4", "--particles", "50", "--seed", "1", "--quiet"]


def _claim(path: str, mark: bytes, start: multiprocessing.synchronize.Barrier, results: multiprocessing.Queue) -> None:
    start.wait()
    try:
        write_atomically(path, mark, replace=False)
        results.put(mark)
    except NameTakenError:
        results.put(b"refused")


def test_of_six_concurrent_writers_without_replace_exactly_one_creates_the_file(tmp_path):
    target = str(tmp_path / "same.json")
    context = multiprocessing.get_context("fork" if hasattr(os, "fork") else "spawn")
    start, results = context.Barrier(6), context.Queue()
    writers = [context.Process(target=_claim, args=(target, b"writer %d" % i, start, results)) for i in range(6)]
    for writer in writers:
        writer.start()
    outcomes = [results.get(timeout=60) for _ in writers]
    for writer in writers:
        writer.join(timeout=60)
    winners = [o for o in outcomes if o != b"refused"]
    assert len(winners) == 1
    assert Path(target).read_bytes() == winners[0]
    assert [p.name for p in tmp_path.iterdir()] == ["same.json"]  # no temporaries left


def _created_meanwhile(original):
    """A writer that finds its name taken by another process between the command's check and its write."""

    def write(path, *args, **kwargs):
        Path(path).write_text("the other run's file\n")
        return original(path, *args, **kwargs)

    return write


def test_a_scenario_name_taken_meanwhile_is_refused_and_not_announced(tmp_path, monkeypatch, capsys):
    import mazelab.scenario

    monkeypatch.setattr(mazelab.scenario, "write_atomically", _created_meanwhile(atomic.write_atomically))
    target = tmp_path / "same.json"
    assert main([*RUN_ARGS, "--no-viz", "--save-scenario", str(target)]) == 1
    captured = capsys.readouterr()
    assert "scenario saved" not in captured.out
    (line,) = captured.err.strip().splitlines()
    assert line.startswith(f"error: cannot write {target}: ") and line.endswith("; use --force to replace it")
    assert target.read_text() == "the other run's file\n"


def test_a_recording_name_taken_meanwhile_is_refused_and_not_announced(tmp_path, monkeypatch, capsys):
    import mazelab.viz.recording

    monkeypatch.setattr(mazelab.viz.recording, "write_atomically", _created_meanwhile(write_atomically))
    target = tmp_path / "same.rrd"
    assert main([*RUN_ARGS, "--rrd", str(target)]) == 1
    captured = capsys.readouterr()
    assert "Recording saved" not in captured.out
    assert "use --force to replace it" in captured.err
    assert target.read_text() == "the other run's file\n"


def test_a_forced_file_replaced_by_another_writer_right_after_is_not_claimed(tmp_path, monkeypatch):
    target = tmp_path / "out.csv"

    def another_writer_wins(folder: Path) -> None:
        (folder / "other").write_text("theirs")
        os.replace(folder / "other", target)

    monkeypatch.setattr(atomic, "sync_folder", another_writer_wins)
    with pytest.raises(ReplacedMeanwhileError, match="replaced by another process meanwhile"):
        write_atomically(target, b"mine")
    assert target.read_text() == "theirs"


def _device(tmp_path: Path) -> Path:
    """A character device like /dev/full (skipped where mknod is not allowed)."""
    device = tmp_path / "full"
    try:
        os.mknod(device, stat.S_IFCHR | 0o666, os.makedev(1, 7))
    except (PermissionError, AttributeError, OSError):
        pytest.skip("mknod is not allowed here")
    return device


@pytest.mark.parametrize("kind", ["device", "fifo", "folder"])
@pytest.mark.parametrize("force", [False, True], ids=["", "--force"])
def test_a_device_pipe_or_folder_is_never_an_output(tmp_path, kind, force, capsys):
    if kind == "device":
        target = _device(tmp_path)
    elif kind == "fifo":
        target = tmp_path / "pipe"
        os.mkfifo(target)
    else:
        target = tmp_path / "folder"
        target.mkdir()
    mode = os.lstat(target).st_mode
    for command in (
        [*RUN_ARGS, "--no-viz", "--save-scenario", str(target)],
        ["maze", "generate", "--size", "5x5", "--seed", "1", "--out", str(target)],
        ["study", "--runs", "1", "--steps", "3", "--maze", "paper_5x5", "--csv", str(target)],
    ):
        assert main(command + (["--force"] if force else [])) == 2, command
        err = capsys.readouterr().err.strip().splitlines()
        said = "is a folder: name a file in it" if kind == "folder" else "not a regular file"
        assert len(err) == 1 and said in err[0] and str(target) in err[0], err
        assert os.lstat(target).st_mode == mode
    with pytest.raises(NotRegularFileError):
        write_atomically(target, b"x", replace=True)
    assert os.lstat(target).st_mode == mode


def test_a_symlink_to_a_device_is_refused_too(tmp_path):
    link = tmp_path / "link"
    link.symlink_to(_device(tmp_path))
    with pytest.raises(NotRegularFileError):
        write_atomically(link, b"x", replace=True)
    assert stat.S_ISCHR(os.stat(link).st_mode)


def test_a_dangling_symlink_is_written_through_only_with_force(tmp_path, capsys):
    link = tmp_path / "link.json"
    link.symlink_to(tmp_path / "missing.json")
    assert main([*RUN_ARGS, "--no-viz", "--save-scenario", str(link)]) == 2
    assert "symlink to a missing file; use --force" in capsys.readouterr().err
    assert not (tmp_path / "missing.json").exists()
    assert main([*RUN_ARGS, "--no-viz", "--save-scenario", str(link), "--force"]) == 0
    assert link.is_symlink() and (tmp_path / "missing.json").is_file()


def test_an_unknown_figure_format_is_refused_before_any_filter_runs(tmp_path, capsys):
    scenario = tmp_path / "s.json"
    assert main([*RUN_ARGS, "--no-viz", "--save-scenario", str(scenario)]) == 0
    capsys.readouterr()
    assert main(["compare", str(scenario), "--no-viz", "--plot", str(tmp_path / "p.weird")]) == 2
    captured = capsys.readouterr()
    assert captured.out == ""  # no filter ran
    assert captured.err.startswith("error: --plot") and "cannot draw .weird files" in captured.err


@pytest.mark.skipif(os.name == "nt", reason="POSIX signals")
def test_sigterm_during_a_recorded_run_says_the_scenario_was_not_saved(tmp_path):
    command = [*RUN[:-4], "--steps", "100000", "--particles", "100", "--rrd", "r.rrd", "--save-scenario", "s.json"]
    process = subprocess.Popen(command, cwd=tmp_path, env=NO_DISPLAY, stdout=subprocess.PIPE,
                               stderr=subprocess.PIPE, text=True)  # fmt: skip
    try:
        _wait_for_line(process, "step   40/")
        process.send_signal(signal.SIGTERM)
        out, err = process.communicate(timeout=60)
    finally:
        if process.poll() is None:
            process.kill()
    assert process.returncode == 128 + signal.SIGTERM, err
    assert "Recording saved to r.rrd" in out
    assert "no scenario saved to s.json" in err and "Traceback" not in err
    assert not (tmp_path / "s.json").exists()
    assert ROOT.exists()
