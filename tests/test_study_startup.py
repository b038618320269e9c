"""A study's start-up: a study that draws nothing, on one worker, imports only what it runs (no drawing,
cluster or terminal library), and off a terminal its progress is one plain line at the end."""

from __future__ import annotations

import json
import os
import subprocess
import sys

from conftest import ROOT

# what such a study must not import: the figure's, the viewer's, the cluster's and the progress bar's
# libraries, numba on the numpy backend, and the code of the commands that replay or compare a scenario
NOT_NEEDED = ("matplotlib", "rerun", "dask", "distributed", "rich", "numba", "mazelab.cli.replay")
NOT_NEEDED += ("mazelab.scenario",)  # the pydantic models of a saved run


def study_process(tmp_path, *arguments: str) -> tuple[set[str], str, str]:
    """A study in a process of its own (stderr a pipe, not a terminal): the modules it imported, its stderr
    and its stdout."""
    csv = tmp_path / "s.csv"
    argv = ["study", "--maze", "paper_5x5", "--sigma", "0.4", "--runs", "2", "--steps", "5", "--particles", "50",
            "--seed", "1", "--workers", "1", "--no-viz", "--csv", str(csv), *arguments]  # fmt: skip
    code = (
        "import json, sys\nfrom mazelab.cli.app import main\n"
        f"code = main({argv!r})\nprint(json.dumps(sorted(sys.modules)))\nsys.exit(code)\n"
    )
    env = {**os.environ, "MAZELAB_BACKEND": "numpy"}
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, env=env)
    assert done.returncode == 0, done.stderr
    return set(json.loads(done.stdout.strip().splitlines()[-1])), done.stderr, done.stdout


def test_a_study_on_one_worker_without_figures_imports_only_what_it_runs(tmp_path):
    modules, _, stdout = study_process(tmp_path)
    loaded = sorted(m for m in modules if m.startswith(NOT_NEEDED))
    assert not loaded, f"the study imported {loaded}"
    assert "mazelab.experiments.executor" in modules  # it did run
    startup = next(line for line in stdout.splitlines() if " wall time on the numpy backend; start-up " in line)
    assert "(first calls; " in startup and "numba" not in startup  # nor does it say numba's kernels loaded


def test_off_a_terminal_a_studys_progress_is_one_plain_line_at_the_end(tmp_path):
    _, stderr, _ = study_process(tmp_path)
    lines = [line for line in stderr.splitlines() if line.startswith("runs ")]
    assert len(lines) == 1 and lines[0].startswith("runs 2/2 in ") and lines[0].endswith(" s")
    assert "\r" not in stderr and "\x1b" not in stderr  # no redrawn bar, no terminal codes
