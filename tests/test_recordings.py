"""Recordings of runs without a display: each run says where its recording went and how big it and
the folder are; `mazelab recordings` lists them and `--clean` removes old ones, only ever the lab's.

The folder is the test's own (conftest points RECORDINGS_DIR at a temporary one). The cleanup tests
write files named as the lab names them, with set modification times: what is chosen depends on
names, sizes and times only.
"""

from __future__ import annotations

import os
import re
import time
from pathlib import Path

import pytest

from mazelab.cli.app import main
from mazelab.invocation import command_prefix
from mazelab.viz import recording as viz_recording
from mazelab.viz.recording import CROWDED_BYTES, NO_DISPLAY, human_size

RUN = ["run", "--maze", "paper_5x5", "--steps", "3", "--particles", "50", "--quiet"]
DAY = 86400.0


def lab_recording(folder: Path, label: str, days_old: float, size: int) -> Path:
    """A file named as a default recording, `size` bytes, last written `days_old` days ago."""
    folder.mkdir(exist_ok=True)
    stamp = time.strftime("%Y%m%d-%H%M%S", time.localtime(time.time() - days_old * DAY))
    path = folder / f"{label}-{stamp}.rrd"
    path.write_bytes(bytes(size))
    when = time.time() - days_old * DAY
    os.utime(path, (when, when))
    return path


@pytest.fixture
def folder() -> Path:
    return viz_recording.RECORDINGS_DIR


@pytest.fixture
def five(folder) -> list[Path]:
    """Five lab recordings 5, 4, 3, 2 and 1 days old, of 1, 2, 3, 4 and 5 kB (oldest first)."""
    return [lab_recording(folder, "sir_particle_filter", 6 - k, 1000 * k) for k in range(1, 6)]


def output(capsys, argv: list[str], code: int = 0) -> str:
    assert main(argv) == code
    captured = capsys.readouterr()
    return captured.out if code == 0 else captured.err


# -- a run says where and how big ------------------------------------------------------------------
def test_a_run_without_a_display_says_in_one_line_where_its_recording_is_how_big_and_how_to_open_it(capsys, folder):
    scenario = saved_scenario(capsys, folder.parent)
    for argv in ([*RUN, "--seed", "1"], ["compare", str(scenario)]):
        out = output(capsys, argv)
        (said,) = [line for line in out.splitlines() if "recording" in line.lower()]  # one line, nothing more
        path = Path(re.match(r"Recording saved to (\S+); ", said).group(1))
        assert path.parent == folder
        size = human_size(path.stat().st_size)
        hint = f"{command_prefix()} view {path} (the web viewer, on 127.0.0.1)"
        assert said == f"Recording saved to {path}; {size}; {NO_DISPLAY}, so open it with: {hint}"
    assert sorted(path.name.split("-")[0] for path in folder.glob("*.rrd")) == ["compare", "sir_particle_filter"]


def test_once_the_folder_passes_100_mb_a_run_says_its_size_and_the_command_that_thins_it(capsys, folder):
    big = lab_recording(folder, "compare", days_old=3, size=0)
    os.truncate(big, int(CROWDED_BYTES) - 10**6)  # sparse: takes no room on the disk; with this run's, below 100 MB
    assert " holds " not in output(capsys, [*RUN, "--seed", "1"])
    os.truncate(big, int(CROWDED_BYTES) + 1)
    out = output(capsys, [*RUN, "--seed", "2"])
    total = human_size(sum(path.stat().st_size for path in folder.glob("*.rrd")))
    (said,) = [line for line in out.splitlines() if " holds " in line]
    command = f"{command_prefix()} recordings --keep 10 --clean"
    assert said == f"{folder}{os.sep} holds 3 recordings, {total}; to keep only the 10 newest: {command}"


def saved_scenario(capsys, where: Path) -> Path:
    scenario = where / "walk.json"
    output(capsys, [*RUN, "--no-viz", "--save-scenario", str(scenario)])
    return scenario


def test_a_recording_saved_under_a_name_of_ones_own_says_its_size_not_the_folders(tmp_path, capsys, folder):
    out = output(capsys, [*RUN, "--rrd", str(tmp_path / "mine.rrd")])
    assert f"Recording saved to {tmp_path / 'mine.rrd'}; {human_size((tmp_path / 'mine.rrd').stat().st_size)};" in out
    assert "holds" not in out and not folder.exists()


# -- listing ---------------------------------------------------------------------------------------
def test_recordings_lists_each_with_its_size_oldest_first_and_the_total(capsys, folder, five):
    out = output(capsys, ["recordings"])
    lines = out.splitlines()
    assert lines[0] == f"{folder}{os.sep} holds 5 recordings, 15 kB:"
    listed = [line.split()[-1] for line in lines[1:6]]
    assert listed == [str(path) for path in five]
    assert [line.split()[2:4] for line in lines[1:6]] == [[str(k), "kB"] for k in range(1, 6)]
    assert "--keep 10 (shows them), then add --clean" in lines[6]
    assert all(path.exists() for path in five)  # listing removes nothing


def test_without_recordings_it_says_so(capsys, folder):
    assert "No recordings in" in output(capsys, ["recordings"]) and "no such folder" in output(capsys, ["recordings"])


# -- cleaning --------------------------------------------------------------------------------------
def test_keep_shows_what_it_would_remove_and_clean_removes_exactly_that(capsys, folder, five):
    shown = output(capsys, ["recordings", "--keep", "2"])
    assert shown.count("(would be removed)") == 3 and "3 would be removed (6 kB)" in shown
    assert all(path.exists() for path in five)
    done = output(capsys, ["recordings", "--keep", "2", "--clean"])
    assert "Removed 3 recordings (6 kB)" in done and "holds 2 recordings, 9 kB" in done
    assert [path.exists() for path in five] == [False, False, False, True, True]


def test_older_than_removes_the_old_ones(capsys, five):
    output(capsys, ["recordings", "--older-than", "3.5d", "--clean"])
    assert [path.exists() for path in five] == [False, False, True, True, True]
    output(capsys, ["recordings", "--older-than", "36h", "--clean"])
    assert [path.exists() for path in five] == [False, False, False, False, True]


def test_max_size_keeps_the_newest_that_fit(capsys, five):
    output(capsys, ["recordings", "--max-size", "10kB", "--clean"])  # 5 + 4 kB fit, with 3 kB more it is 12 kB
    assert [path.exists() for path in five] == [False, False, False, True, True]


def test_rules_together_remove_what_any_of_them_names(capsys, five):
    output(capsys, ["recordings", "--keep", "4", "--older-than", "2.5d", "--clean"])
    assert [path.exists() for path in five] == [False, False, False, True, True]


def test_clean_removes_only_the_labs_own_regular_files(tmp_path, capsys, folder, five):
    mine = folder / "my_best_run.rrd"
    mine.write_bytes(b"x")
    outside = tmp_path / "elsewhere.rrd"
    outside.write_bytes(b"keep me")
    link = folder / "sir_particle_filter-20200101-000000.rrd"
    link.symlink_to(outside)
    (folder / "apf-20200101-000000.rrd").mkdir()
    hidden = folder / ".sir_particle_filter-20200101-000000.rrd.123-abc.tmp"
    hidden.write_bytes(b"a run writing")
    listed = output(capsys, ["recordings", "--keep", "0"])
    assert f"{mine}  (your name: kept)" in listed and str(link) not in listed
    output(capsys, ["recordings", "--keep", "0", "--clean"])
    assert not any(path.exists() for path in five)
    assert mine.exists() and link.is_symlink() and outside.read_bytes() == b"keep me"
    assert (folder / "apf-20200101-000000.rrd").is_dir() and hidden.exists()


def test_another_folder_can_be_named(tmp_path, capsys):
    other = tmp_path / "old_runs"
    paths = [lab_recording(other, "compare", days, 10) for days in (3, 2, 1)]
    out = output(capsys, ["recordings", str(other), "--keep", "1"])
    assert f"recordings {other} --keep 1 --clean" in out
    output(capsys, ["recordings", str(other), "--keep", "1", "--clean"])
    assert [path.exists() for path in paths] == [False, False, True]


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--clean"], "--clean needs what to remove: --keep N"),
        (["--older-than", "3x"], "--older-than '3x': write a number and a unit: 30m, 12h, 7d or 2w"),
        (["--older-than", "7"], "--older-than '7': write a number and a unit"),
        (["--max-size", "lots"], "--max-size 'lots': write a number and a unit: 500kB, 100MB or 1.5GB"),
        (["--keep", "-1"], "Invalid value for '--keep'"),
    ],
)
def test_bad_choices_are_one_line_and_remove_nothing(capsys, five, argv, message):
    err = output(capsys, ["recordings", *argv], code=2)
    assert message in err and err.count("\n") == 1
    assert all(path.exists() for path in five)


def test_a_file_for_the_folder_is_one_line(tmp_path, capsys):
    (tmp_path / "f").write_text("")
    err = output(capsys, ["recordings", str(tmp_path / "f")], code=2)
    assert "is not a folder" in err and err.count("\n") == 1


@pytest.mark.parametrize(
    ("size", "written"),
    [(532, "532 B"), (12_400, "12.4 kB"), (3_100_000, "3.1 MB"), (140_000_000, "140 MB"), (1_250_000_000, "1.25 GB")],
)
def test_sizes_are_written_as_people_write_them(size, written):
    assert human_size(size) == written
