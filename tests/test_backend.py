"""Which backend runs (mazelab.backend): the default (compiled when numba imports, numpy when it does
not), MAZELAB_BACKEND and use_backend, --backend on the commands (one line for a wrong name), and
every RunResult and JSON record naming the backend that ran; `mazelab bench` shows both side by side;
the compiled backend's threads (the machine's cores, a study's share of them, MAZELAB_THREADS)."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import numpy as np
import pytest
from conftest import ROOT

from mazelab import bench as benchmark
from mazelab.backend import (
    ENVIRONMENT_VARIABLE,
    SAVED_PER_PARTICLE,
    SAVED_PER_STEP,
    STARTUP_SECONDS,
    THREADS_VARIABLE,
    backend_by_work,
    backend_for_work,
    backend_versions,
    check_backend,
    chosen_backend,
    cores,
    kernels_for,
    shared_threads,
    use_backend,
    use_threads,
)
from mazelab.cli.app import main
from mazelab.registry import filter_entry
from mazelab.robot import Robot
from mazelab.simulation import simulate

HAS_NUMBA = subprocess.run([sys.executable, "-c", "import numba"], capture_output=True).returncode == 0
DEFAULT = "compiled" if HAS_NUMBA else "numpy"  # the backend without a choice
needs_numba = pytest.mark.skipif(not HAS_NUMBA, reason="the compiled backend needs numba (the fast extra)")

# a Python that cannot import numba, as on an install without the fast extra
WITHOUT_NUMBA = "import sys; sys.modules['numba'] = None\n"


def python(code: str, backend: str | None = None) -> str:
    """Run `code` in a fresh interpreter with MAZELAB_BACKEND set to `backend` (None: unset)."""
    env = {k: v for k, v in os.environ.items() if k != ENVIRONMENT_VARIABLE}
    if backend is not None:
        env[ENVIRONMENT_VARIABLE] = backend
    done = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, env=env, cwd=ROOT, timeout=600, check=False
    )
    assert done.returncode == 0, done.stderr
    return done.stdout.strip()


MADE = (
    "import numpy as np\n"
    "from mazelab.maze import Maze\n"
    "from mazelab.registry import filter_entry\n"
    "w = Maze.from_file('paper_5x5')\n"
    "points = w.random_free_places(50, np.random.default_rng(1))\n"
    "f = filter_entry('sir').filter_class(w, 0.3, 0.5, points, np.random.default_rng(2))\n"
    "print(f.backend)\n"
)


@needs_numba
def test_without_a_choice_the_compiled_backend_runs_where_numba_imports():
    assert python(MADE) == "compiled"


def test_without_numba_the_numpy_backend_runs_and_compiled_is_refused_in_one_line():
    assert python(WITHOUT_NUMBA + MADE) == "numpy"
    code = WITHOUT_NUMBA + "from mazelab.cli.app import main\nprint(main(['run', '--backend', 'compiled', '--no-viz']))"
    env = {k: v for k, v in os.environ.items() if k != ENVIRONMENT_VARIABLE}
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, cwd=ROOT, timeout=120)
    assert done.stdout.strip() == "2"
    assert done.stderr.strip().splitlines() == [
        'error: --backend compiled: the compiled backend needs numba: pip install -e ".[fast]" (uv sync installs it)'
    ]


def test_the_environment_variable_chooses_and_a_wrong_name_is_one_line():
    assert python(MADE, "numpy") == "numpy"
    assert python(MADE, " NumPy ") == "numpy"
    with pytest.raises(ValueError, match=r"^MAZELAB_BACKEND must be one of numpy, compiled, got 'fortran'$"):
        check_backend("fortran", "MAZELAB_BACKEND")


def test_use_backend_chooses_for_the_filters_made_inside_and_puts_the_variable_back(paper_world):
    before = os.environ.get(ENVIRONMENT_VARIABLE)
    rng = np.random.default_rng(1)
    backend = "compiled" if HAS_NUMBA else "numpy"
    with use_backend(backend):
        assert chosen_backend() == backend
        filt = filter_entry("apf").filter_class(paper_world, 0.3, 0.5, paper_world.random_free_places(50, rng), rng)
    assert filt.backend == backend
    assert os.environ.get(ENVIRONMENT_VARIABLE) == before
    with pytest.raises(ValueError, match="must be one of"), use_backend("cuda"):
        pass
    assert os.environ.get(ENVIRONMENT_VARIABLE) == before


# a command of known work: the backend it chooses, the filter made under it, and whether numba was imported
FOR_WORK = (
    "import sys\n"
    "from mazelab.backend import backend_for_work, use_backend\n"
    "with use_backend(backend_for_work(*WORK)):\n"
    "    " + MADE.replace("\n", "\n    ").rstrip() + "\n"
    "print('numba' in sys.modules)\n"
)


def test_a_small_run_without_a_choice_runs_on_numpy_and_never_imports_numba():
    small = FOR_WORK.replace("*WORK", "1500 * 200, 200")  # `mazelab run`'s default: 200 steps of 1,500
    assert python(small).split() == ["numpy", "False"]
    assert python(small, "compiled").split() == (["compiled", "True"] if HAS_NUMBA else ["numpy", "False"])


SMALL_RUN = (
    "import sys\n"
    "from mazelab.cli.app import main\n"
    "code = main(['run', '--maze', 'paper_5x5', '--particles', '300', '--steps', '20', '--seed', '4', '--no-viz',"
    " '--quiet'])\n"
    "print(code, 'numba' in sys.modules)\n"
)


def test_a_small_run_on_the_command_line_runs_on_numpy_and_its_repeat_line_says_so():
    """`mazelab run` without a choice: the work does not repay numba's start-up, so numba is never
    imported, and the pasted command names the backend that ran."""
    out = python(SMALL_RUN).splitlines()
    assert out[-1] == "0 False"
    assert any(line.startswith("Repeat this run:") and line.endswith("--seed 4 --backend numpy") for line in out)
    chosen = python(SMALL_RUN, "compiled").splitlines() if HAS_NUMBA else None
    if chosen is not None:  # a choice overrides the work's
        assert chosen[-1] == "0 True" and chosen[-2].endswith("--seed 4 --backend compiled")


def test_the_work_choice_of_a_run_leaves_the_environment_alone_and_an_outer_choice_stands(monkeypatch):
    monkeypatch.delenv(ENVIRONMENT_VARIABLE, raising=False)
    big = STARTUP_SECONDS / SAVED_PER_PARTICLE * 2  # particle-steps that repay the start-up twice
    with backend_by_work(1500 * 200, 200) as small:
        assert small == chosen_backend() == "numpy" and ENVIRONMENT_VARIABLE not in os.environ
        with backend_by_work(big, 200) as inner:  # a run inside a small comparison keeps its choice
            assert inner == "numpy"
    with backend_by_work(big, 200) as outer:
        assert outer == DEFAULT
        with backend_by_work(1500 * 200, 200) as inner:  # the comparison's warm-up and runs: one backend
            assert inner == outer
    monkeypatch.setenv(ENVIRONMENT_VARIABLE, DEFAULT)
    with backend_by_work(1500 * 200, 200) as chosen:  # the user's choice stands
        assert chosen == DEFAULT


@needs_numba
def test_work_that_pays_back_numbas_start_up_runs_compiled_and_a_choice_overrides_it():
    study = FOR_WORK.replace("*WORK", "4 * 3 * 200 * 30 * 1500, 4 * 3 * 200")  # the paper's study, 30 runs together
    assert python(study).split() == ["compiled", "True"]
    assert python(study, "numpy").split() == ["numpy", "False"]


def test_the_compiled_backend_pays_when_its_savings_exceed_each_processs_start_up(monkeypatch):
    monkeypatch.delenv(ENVIRONMENT_VARIABLE, raising=False)
    steps = STARTUP_SECONDS / SAVED_PER_STEP  # the steps whose fixed savings alone pay the start-up
    assert backend_for_work(0, 0.99 * steps) == "numpy" and backend_for_work(0, 1.01 * steps) == DEFAULT
    moved = STARTUP_SECONDS / SAVED_PER_PARTICLE  # the particle-steps whose savings pay it
    assert backend_for_work(0.99 * moved, 0) == "numpy" and backend_for_work(1.01 * moved, 0) == DEFAULT
    assert backend_for_work(1.01 * moved, 0, processes=2) == "numpy"  # each process pays the start-up


@pytest.mark.parametrize("name", ["sir", "grid"])
def test_a_run_result_says_which_backend_ran(name, paper_world):
    robot = Robot(0.3, 0.5, paper_world.random_free_place(np.random.default_rng(3)))
    options = {"resolution": 0.1} if name == "grid" else {}
    with use_backend("numpy"):
        result = simulate(robot, paper_world, 0.3, 0.5, 100, 3, filtering_algorithm=name, seed=1, **options)
    assert result.extras["backend"] == "numpy"  # the grid filter is numpy's whatever the choice


@pytest.mark.parametrize("backend", ["numpy", pytest.param("compiled", marks=needs_numba)])
def test_backend_on_the_command_line_runs_it_and_the_record_says_so(backend, tmp_path, capsys):
    before = os.environ.get(ENVIRONMENT_VARIABLE)
    csv = tmp_path / "s.csv"
    arguments = ["--maze", "paper_5x5", "--runs", "2", "--steps", "5", "--particles", "100", "--workers", "1"]
    code = main(["study", *arguments, "--no-viz", "--csv", str(csv), "--backend", backend])
    assert code == 0, capsys.readouterr().err
    record = json.loads((tmp_path / "s.record.json").read_text())
    assert record["program"]["backend"] == backend
    assert record["program"]["numba"] == (backend_versions()["numba"])
    assert os.environ.get(ENVIRONMENT_VARIABLE) == before  # the command's choice ends with the command


def test_a_wrong_backend_on_the_command_line_is_one_line(capsys):
    for command in (["run", "--no-viz"], ["accuracy"], ["bench", "--quick"]):
        assert main([*command, "--backend", "gpu"]) == 2
        assert capsys.readouterr().err.strip().splitlines() == [
            "error: --backend must be one of numpy, compiled, got 'gpu'"
        ]


@needs_numba
def test_a_run_on_the_command_line_on_the_compiled_backend(tmp_path):
    done = subprocess.run(
        [sys.executable, str(ROOT / "main.py"), "run", "--maze", "paper_5x5", "--steps", "5", "--seed", "3",
         "--no-viz", "--quiet", "--backend", "compiled", "--save-scenario", str(tmp_path / "r.json")],
        capture_output=True, text=True, timeout=600, check=False,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    assert (tmp_path / "r.json").exists()


@needs_numba
def test_bench_shows_both_backends_side_by_side(paper_world):
    rows = list(benchmark.measure("paper", paper_world, (300,), steps=2, warmup=1, backends=("numpy", "compiled")))
    assert [(r.filter_name, r.backend) for r in rows[:6]] == [
        (name, backend)
        for name in ("SIRParticleFilter", "AuxiliaryParticleFilter", "RegularizedParticleFilter")
        for backend in ("numpy", "compiled")
    ]
    lines = benchmark.format_table(rows).splitlines()
    header = next(i for i, line in enumerate(lines) if line.startswith("maze"))
    versus = [line.split()[-2] for line in lines[header + 1 :]]  # the x numpy column
    assert versus[:6:2] == ["-"] * 3 and all(v.endswith("x") for v in versus[1:6:2])
    assert benchmark.available_backends() == ("numpy", "compiled")


@needs_numba
@pytest.mark.parametrize("spelling", ["COMPILED", " Compiled "])
def test_the_environment_variable_in_any_case_runs_and_the_repeat_line_names_the_backend(spelling, tmp_path):
    env = {**os.environ, ENVIRONMENT_VARIABLE: spelling}
    done = subprocess.run(
        [sys.executable, str(ROOT / "main.py"), "run", "--maze", "paper_5x5", "--steps", "3", "--seed", "3",
         "--no-viz", "--quiet", "--save-scenario", str(tmp_path / "r.json")],
        capture_output=True, text=True, timeout=600, check=False, env=env,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    repeat = next(line for line in done.stdout.splitlines() if line.startswith("Repeat this run: "))
    assert repeat.endswith(" --seed 3 --backend compiled")
    typed = subprocess.run(
        [sys.executable, str(ROOT / "main.py"), "run", "--maze", "paper_5x5", "--steps", "3", "--no-viz", "--quiet",
         "--backend", "numpy"],
        capture_output=True, text=True, timeout=600, check=False, env=env,
    )  # fmt: skip
    repeat = next(line for line in typed.stdout.splitlines() if line.startswith("Repeat this run: "))
    assert repeat.count("--backend") == 1 and " --backend numpy " in repeat  # the typed choice, once


def test_a_filter_takes_the_machines_cores_its_share_of_them_or_the_threads_chosen(monkeypatch):
    """shared_threads: MAZELAB_THREADS (--threads) when set, else the machine's cores for one run and, for
    a study's, cores // the runs at once (workers x threads <= cores), at least 1, unless the user chose;
    use_threads sets the count for a block."""
    monkeypatch.delenv(THREADS_VARIABLE, raising=False)
    assert shared_threads() == cores()
    assert shared_threads(2) == max(1, cores() // 2) and shared_threads(10 * cores()) == 1
    with use_threads(1) as chosen:
        assert chosen == os.environ[THREADS_VARIABLE] == "1" and shared_threads() == 1
        assert shared_threads(1) == 1  # the user's choice stands
    assert THREADS_VARIABLE not in os.environ
    monkeypatch.setenv(THREADS_VARIABLE, str(cores() + 1))
    with pytest.raises(ValueError, match=rf"^MAZELAB_THREADS must be a whole number from 1 to {cores()}"):
        shared_threads()


@needs_numba
def test_the_compiled_kernels_of_a_filter_take_the_thread_count(paper_world, monkeypatch):
    monkeypatch.delenv(THREADS_VARIABLE, raising=False)
    with use_backend("compiled"), use_threads(shared_threads(cores())):
        assert kernels_for(paper_world).threads == 1
    with use_backend("compiled"):
        assert kernels_for(paper_world).threads == cores()


def test_a_studys_runs_share_the_cores_of_their_machine_locally_and_on_a_dask_cluster(monkeypatch):
    """Each unit of a study runs on shared_threads' count (run_unit_timed inside use_threads), from the
    local workers or the Dask cluster's task threads on one host."""
    from distributed import Client, LocalCluster

    from mazelab.experiments import executor

    monkeypatch.delenv(THREADS_VARIABLE, raising=False)
    assert shared_threads(cores()) == 1
    with (
        LocalCluster(n_workers=2, threads_per_worker=1, host="127.0.0.1", dashboard_address=":0") as cluster,
        Client(cluster) as client,
    ):
        assert shared_threads(1, client) == max(1, cores() // 2)  # two workers of one task thread each, on one host
    seen = []
    monkeypatch.setattr(executor, "run_unit_safely", lambda tasks: seen.append(shared_threads()) or [])
    monkeypatch.setattr(executor, "worker_report", lambda startup: None)
    executor.run_unit_timed([], "numpy", threads=cores() + 5)  # at most this machine's cores
    assert seen == [cores()] and THREADS_VARIABLE not in os.environ
