"""Shared fixtures: the shipped mazes and a seeded robot walk on the paper's maze; a real study process."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pytest
from hypothesis import settings

from mazelab.maze import Maze
from mazelab.robot import Robot

ROOT = Path(__file__).resolve().parent.parent

# The suite's pinned numbers and bit-for-bit comparisons are the numpy backend's, the reference: the
# filters run on it unless MAZELAB_BACKEND says otherwise (set here, before any filter is made, so that the
# subprocesses the tests start inherit it too). tests/test_kernels.py and test_backend.py run the compiled one.
os.environ.setdefault("MAZELAB_BACKEND", "numpy")

# The property tests draw their examples from a fixed seed: the suite gives the same verdict on the
# same code every time (a failure found once is found again).
settings.register_profile("derandomized", derandomize=True, print_blob=True)
settings.load_profile("derandomized")

# A shell's background job starts its children with SIGINT ignored, and Python then installs no Ctrl-C
# handler: the tests of Ctrl-C (in this process and in the processes it starts, which inherit the
# disposition) would fail for how the suite was started, not for the code. Python's own handler is restored.
if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
    signal.signal(signal.SIGINT, signal.default_int_handler)


def _writes_anywhere() -> bool:
    """Whether this process may write into a folder whose mode forbids it (root with the capability
    CAP_DAC_OVERRIDE, as CI runs): then a refusal of an unwritable folder cannot be seen."""
    with tempfile.TemporaryDirectory() as folder:
        locked = Path(folder) / "locked"
        locked.mkdir(mode=0o500)
        try:
            return os.access(locked, os.W_OK)
        finally:
            locked.chmod(0o700)


# the tests of an unwritable folder: skipped where nothing is unwritable (.ci/run runs them again as root
# without the capabilities that override file permissions)
needs_unwritable_folders = pytest.mark.skipif(
    _writes_anywhere(),
    reason="this process may write anywhere (root with CAP_DAC_OVERRIDE): .ci/run runs this test without it",
)

MAZES = sorted((ROOT / "mazes").glob("*.txt"))
PAPER_MAZE = (
    (2, 0, 1, 0, 0),
    (0, 0, 0, 0, 1),
    (1, 1, 1, 0, 0),
    (1, 0, 0, 0, 0),
    (0, 0, 2, 0, 1),
)


def recorded_walk(world: Maze, seed: int, steps: int) -> list[tuple[float, float]]:
    """(compass angle, z) of each step of a seeded robot."""
    rng = np.random.default_rng(seed)
    robot = Robot(0.3, 0.5, world.random_free_place(rng), rng=rng)
    return [robot.step(world) for _ in range(steps)]


def start_study_process(arguments: list[str]) -> subprocess.Popen:
    """`main.py study ARGUMENTS` in its own session (so killpg reaches its workers), Ctrl-C at its default."""
    return subprocess.Popen(
        [sys.executable, str(ROOT / "main.py"), "study", *arguments],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )


def finished_rows(journal: Path) -> list[dict[str, str]]:
    """The rows a study's journal (NAME.runs.jsonl) holds so far, each as the CSV writes it (text cells;
    none before it exists): whole lines only, as a study that goes on reads them."""
    try:
        text = journal.read_text()
    except FileNotFoundError:
        return []
    lines = [json.loads(line) for line in text[: text.rfind("\n") + 1].splitlines()]
    rows = [row for line in lines if "run" in line for row in line["records"]]
    return [{k: "" if v is None else str(v) for k, v in row.items() if k not in ("options", "trace")} for row in rows]


def wait_for_rows(journal: Path, count: int, process: subprocess.Popen, timeout: float = 60) -> None:
    """Wait until the study's journal holds `count` finished rows, the study ends, or `timeout` seconds pass."""
    deadline = time.monotonic() + timeout
    while len(finished_rows(journal)) < count and process.poll() is None and time.monotonic() < deadline:
        time.sleep(0.1)


@pytest.fixture
def paper_world() -> Maze:
    return Maze(PAPER_MAZE)


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(12345)


@pytest.fixture(autouse=True)
def _no_viewer_and_recordings_in_tmp(tmp_path, monkeypatch):
    """Runs that draw by default (run_model, the CLI) never open a viewer during the tests, and
    their default recordings go to a temporary folder, not into the working tree."""
    from mazelab.viz import recording as viz_recording

    monkeypatch.setattr(viz_recording, "has_display", lambda: False)
    monkeypatch.setattr(viz_recording, "RECORDINGS_DIR", tmp_path / "recordings")


def pytest_addoption(parser):
    parser.addoption("--rendering", action="store_true", help="also run the headless-viewer rendering checks")


def pytest_collection_modifyitems(config, items):
    if config.getoption("--rendering"):
        return
    skip = pytest.mark.skip(reason="renders in the headless viewer: run with --rendering")
    for item in items:
        if "rendering" in item.keywords:
            item.add_marker(skip)
