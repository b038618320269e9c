"""Numbers a paper can print (issue 38): the one-off costs of a process kept out of ms/step in any order,
a plug-in's code carried to the workers of a real Dask cluster and pinned in the record, and the
figure's points at their own x."""

from __future__ import annotations

import csv
import json
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

import mazelab
from mazelab.cli.app import main
from mazelab.experiments import runs as run_module
from mazelab.experiments.api import plan_study, study_mazes
from mazelab.experiments.executor import run_study
from mazelab.experiments.runs import run_filters
from mazelab.maze import load_maze
from mazelab.registry import file_sha256
from mazelab.robot import Robot
from mazelab.seeding import start_place

ONE_OFF_SECONDS = 0.5  # the plug-in's first step in a process: a stand-in for loading compiled kernels

SLOW_START = f'''
"""SIR whose first step in a process pays a one-off cost, as a kernel load does."""
import time

from mazelab.filters import SIRParticleFilter


class SlowStart(SIRParticleFilter):
    """The shipped SIR, but its first step in a process sleeps {ONE_OFF_SECONDS} s."""

    name = "Slow start"
    started = False

    def step(self, compass_angle, z):
        if not SlowStart.started:
            SlowStart.started = True
            time.sleep({ONE_OFF_SECONDS})
        super().step(compass_angle, z)
'''


def slow_resampling(name: str) -> str:
    """A plug-in: the RPF whose first resampling in a process pays a one-off cost, as loading its jitter's
    kernel does (a class of its own per test: the flag is the class's)."""
    return f'''
import time

from mazelab.filters import RegularizedParticleFilter


class {name}(RegularizedParticleFilter):
    """The shipped RPF resampling when N_eff < 0.05 N (from the 5th step on, not in the warm-up's 3), and
    its first resampling in a process sleeps {ONE_OFF_SECONDS} s."""

    name = "{name}"
    options = {{"threshold": 0.05}}
    started = False

    def move_resampled(self, x, A, due):
        if not {name}.started:
            {name}.started = True
            time.sleep({ONE_OFF_SECONDS})
        return super().move_resampled(x, A, due)
'''


MY_SIR = '''
"""The shipped SIR under a name of its own."""
from mazelab.filters import SIRParticleFilter


class MySIR(SIRParticleFilter):
    """The shipped SIR, as a plug-in."""

    name = "My SIR"
'''

TIMING = ("ms_per_step", "run_seconds")


def plugin(folder: Path, text: str, name: str) -> str:
    path = folder / f"{name.lower()}.py"
    path.write_text(text)
    return f"{path}:{name}"


def rows_of(path: Path) -> list[dict[str, str]]:
    with path.open(newline="") as handle:
        return [{k: v for k, v in row.items() if k not in TIMING} for row in csv.DictReader(handle)]


@pytest.mark.parametrize("first", [True, False])
def test_a_one_off_cost_is_in_no_timed_step_whichever_filter_runs_first(tmp_path, first, monkeypatch):
    """By construction: the plug-in's one-off cost (its first step in this process) falls in the untimed
    warm-up, never in a timed step, whether it runs before or after SIR; it is the start-up instead."""
    monkeypatch.setattr(run_module, "_warmed", set())  # a fresh process's state
    run_module.take_startup_seconds()
    spec = plugin(tmp_path, SLOW_START, "SlowStart")
    world = load_maze("paper_5x5")
    order = [spec, "sir"] if first else ["sir", spec]
    robot = Robot(0.3, 0.5, start_place(world, 1))
    results = run_filters(world, robot, 0.3, 0.5, order, seed=1, particle_count=50, steps=10)
    assert max(results["Slow start"].step_seconds) < ONE_OFF_SECONDS
    assert run_module.take_startup_seconds() >= ONE_OFF_SECONDS


def test_the_warm_up_reaches_a_resampling_that_waits_for_n_eff(tmp_path, monkeypatch):
    """A filter that resamples only when N_eff < threshold N may not in the warm-up's few steps: it is warmed
    with threshold 1 too, so its first resampling's one-off cost is start-up, never a timed step's (a
    study's batch of runs, and a run of its own)."""
    monkeypatch.setattr(run_module, "_warmed", set())
    run_module.take_startup_seconds()
    batch = plugin(tmp_path, slow_resampling("SlowBatch"), "SlowBatch")
    plan = plan_study(study_mazes(["paper_5x5"]), batch, {"sigma": [0.3], "delta": [0.5], "particles": [300]}, runs=3,
                      steps=30, seed=1)  # fmt: skip
    outcome = run_study(plan.tasks, 1)
    assert all(record.run_seconds < ONE_OFF_SECONDS for record in outcome.records)
    assert outcome.startup_seconds >= ONE_OFF_SECONDS
    single = plugin(tmp_path, slow_resampling("SlowSingle"), "SlowSingle")
    robot = Robot(0.3, 0.5, start_place(load_maze("paper_5x5"), 1))
    results = run_filters(load_maze("paper_5x5"), robot, 0.3, 0.5, [single], seed=1, particle_count=300, steps=30)
    assert max(results["SlowSingle"].step_seconds) < ONE_OFF_SECONDS


def test_a_study_reports_the_start_up_apart_from_ms_per_step(tmp_path):
    spec = plugin(tmp_path, SLOW_START, "SlowStart")
    plan = plan_study(study_mazes(["paper_5x5"]), f"{spec},sir", {"sigma": [0.3], "delta": [0.5], "particles": [50]},
                      runs=2, steps=10, seed=1)  # fmt: skip
    outcome = run_study(plan.tasks, 2)  # two fresh worker processes: each pays the one-off cost once
    assert all(record.ms_per_step < 1e3 * ONE_OFF_SECONDS / 10 for record in outcome.records)
    assert all(record.run_seconds < ONE_OFF_SECONDS for record in outcome.records)
    assert outcome.startup_seconds >= ONE_OFF_SECONDS and len(outcome.workers) >= 1


# -- plug-ins on a real cluster ------------------------------------------------------------------------
distributed = pytest.importorskip("distributed")


@pytest.fixture(scope="module")
def cluster():
    """Worker processes of their own (not threads of this one): they import nothing this process loaded."""
    with distributed.LocalCluster(
        n_workers=1, threads_per_worker=1, processes=True, protocol="tcp", host="127.0.0.1", dashboard_address=None
    ) as local:
        yield local


STUDY = ["study", "--maze", "paper_5x5", "--runs", "3", "--steps", "10", "--particles", "60", "--seed", "5", "--no-viz"]


def test_a_plugin_study_on_dask_gives_the_local_rows(cluster, tmp_path):
    spec = plugin(tmp_path, MY_SIR, "MySIR")
    args = [*STUDY, "--filters", f"sir,{spec}"]
    assert main([*args, "--workers", "1", "--csv", str(tmp_path / "local.csv")]) == 0
    assert main([*args, "--dask", cluster.scheduler_address, "--csv", str(tmp_path / "dask.csv")]) == 0
    local, remote = rows_of(tmp_path / "local.csv"), rows_of(tmp_path / "dask.csv")
    assert len(local) == 6 and remote == local
    assert {r["label"] for r in local} == {"SIR", "My SIR"}
    record = json.loads((tmp_path / "dask.record.json").read_text())
    (pinned,) = record["parameters"]["plugins"]
    assert pinned["filter"] == "My SIR" and pinned["sha256"] == file_sha256(tmp_path / "mysir.py")


def test_the_plugins_code_travels_with_the_runs(cluster, tmp_path):
    """The plug-in's file has changed by the time the runs start (its step now raises): the workers run
    the bytes the study was planned with (checked by their sha256), as the local study did."""
    spec = plugin(tmp_path, MY_SIR, "MySIR")
    plan = plan_study(study_mazes(["paper_5x5"]), f"sir,{spec}", {"sigma": [0.3], "delta": [0.5], "particles": [60]},
                      runs=2, steps=10, seed=5)  # fmt: skip
    local = run_study(plan.tasks, 1)
    broken = MY_SIR + "\n    def step(self, compass_angle, z):\n        raise RuntimeError('not the planned code')\n"
    (tmp_path / "mysir.py").write_text(broken)
    with distributed.Client(cluster.scheduler_address) as client:
        remote = run_study(plan.tasks, dask=client)
    assert not remote.failures and len(remote.records) == 4
    assert [r.final_error for r in remote.records] == [r.final_error for r in local.records]


def test_resume_refuses_rows_of_other_code(tmp_path, capsys):
    spec = plugin(tmp_path, MY_SIR, "MySIR")
    csv_path = tmp_path / "s.csv"
    assert main([*STUDY, "--filters", spec, "--workers", "1", "--csv", str(csv_path)]) == 0
    before = file_sha256(tmp_path / "mysir.py")
    (tmp_path / "mysir.py").write_text(MY_SIR + "\n# changed\n")
    after = file_sha256(tmp_path / "mysir.py")
    capsys.readouterr()
    args = [*STUDY, "--filters", spec, "--workers", "1", "--csv", str(csv_path), "--resume"]
    assert main([*args[:4], "4", *args[5:]]) == 2
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert "mysir.py" in line and before in line and after in line


def test_the_chosen_backend_reaches_every_dask_worker_whatever_its_own(tmp_path, capsys):
    """Workers started with different MAZELAB_BACKEND run the study's one backend (--backend, sent with
    every unit): every row says it, and the rows are the local study's bit for bit."""
    # its HTTP routes on 127.0.0.1 and a free port (None would take 8787 on every interface)
    scheduler = {"cls": distributed.Scheduler, "options": {"host": "127.0.0.1", "dashboard_address": "127.0.0.1:0"}}
    workers = {
        name: {"cls": distributed.Nanny, "options": {"nthreads": 1, "env": {"MAZELAB_BACKEND": backend}}}
        for name, backend in (("a", "numpy"), ("b", "compiled"))
    }
    with distributed.SpecCluster(workers=workers, scheduler=scheduler) as two:
        two.wait_for_workers(2)
        code = main([*STUDY, "--dask", two.scheduler_address, "--backend", "numpy", "--csv", str(tmp_path / "d.csv")])
    assert code == 0, capsys.readouterr().err
    assert main([*STUDY, "--workers", "2", "--backend", "numpy", "--csv", str(tmp_path / "l.csv")]) == 0
    remote, local = (rows_of(tmp_path / name) for name in ("d.csv", "l.csv"))
    assert {r["backend"] for r in remote} == {"numpy"} and remote == local


# -- the figure ----------------------------------------------------------------------------------------
SVG = "{http://www.w3.org/2000/svg}"


def vertices_x(svg: Path, gid: str) -> list[float]:
    """The x coordinates of a line's vertices in an SVG the figure wrote (its path's M and L points)."""
    group = next(e for e in ET.parse(svg).iter(f"{SVG}g") if e.get("id") == gid)
    path = next(group.iter(f"{SVG}path"))
    numbers = path.get("d").replace("M", " ").replace("L", " ").split()
    return [round(float(v), 3) for v in numbers[0::2]]


def test_points_of_a_numeric_axis_are_set_a_little_apart_and_a_2x2_design_is_2x2(tmp_path):
    result = mazelab.study(["paper_5x5", "maze_10x10"], delta=[0.2, 0.5], particles=[50, 200], filters=["sir", "apf"],
                           runs=2, steps=10, seed=3)  # fmt: skip
    path = result.figure(tmp_path / "f.svg")
    sir, apf = (vertices_x(path, f"panel-1:line:{name}") for name in ("SIR", "APF"))
    assert len(sir) == len(apf) == 2 and all(a < b for a, b in zip(sir, apf, strict=True))  # set apart, in order
    assert apf[0] - sir[0] < 0.2 * (sir[1] - sir[0])  # by a small share of the spacing of the x values
    from mazelab.experiments.study_plot import figure_layout

    layout, _ = figure_layout(result.summaries, result.varied)
    assert layout.shape == (2, 2) and layout.x == "delta"


@pytest.mark.parametrize("y", ["median", "converged", "exact", "paired"])
def test_each_y_draws_its_statistic(tmp_path, y):
    result = mazelab.study("paper_5x5", sigma=[0.3, 0.5], filters=["sir", "apf"], runs=3, steps=12, particles=60,
                           seed=4, reference="grid", paired="sir")  # fmt: skip
    path = result.figure(tmp_path / f"{y}.svg", y=y)
    text = " ".join(t.text or "" for t in ET.parse(path).iter(f"{SVG}text"))
    words = {"median": "median", "converged": "converged", "exact": "exact", "paired": "paired"}
    assert words[y] in text.lower()
