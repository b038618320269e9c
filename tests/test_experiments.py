"""compare and study: identical inputs for every filter, the CSV files, the study's statistics."""

from __future__ import annotations

import csv
import io
import itertools
import math
import signal
import statistics
import sys

import numpy as np
import pytest
from conftest import PAPER_MAZE, finished_rows

from mazelab.backend import chosen_backend
from mazelab.cli.app import main
from mazelab.cli.replay import replay_setup
from mazelab.experiments import study as experiments
from mazelab.experiments.executor import run_study
from mazelab.experiments.runs import DEFAULT_WINDOW, compare_filters, final_error, recovery_steps, relocalised
from mazelab.experiments.study import MazeChoice, RunRecord, study_settings, study_tasks
from mazelab.experiments.summary import (
    CSV_COLUMNS,
    bootstrap_interval,
    km_median,
    study_table,
    summarise_study,
    wilson_interval,
)
from mazelab.maze import Maze
from mazelab.model import CONVERGENCE_RADIUS
from mazelab.registry import filter_entry
from mazelab.robot import Robot
from mazelab.scenario import load_scenario, save_scenario
from mazelab.simulation import convergence_step, simulate

FILTERS = ["SIRParticleFilter", "AuxiliaryParticleFilter", "RegularizedParticleFilter"]


@pytest.fixture
def scenario_path(tmp_path, paper_world):
    """A saved 40-step, 200-particle scenario on the paper's maze."""
    robot = Robot(0.3, 0.5, paper_world.random_free_place(np.random.default_rng(4)))
    result = simulate(robot, paper_world, 0.3, 0.5, 200, 40, seed=4)
    return save_scenario(result.scenario, tmp_path / "scenario.json")


def read_csv(path) -> list[dict[str, str]]:
    return list(csv.DictReader(io.StringIO(path.read_text())))


# -- compare ---------------------------------------------------------------------------------------
@pytest.mark.parametrize("keep_measurements", [True, False])
def test_compare_gives_every_filter_the_same_inputs(scenario_path, keep_measurements):
    """Same start, particles, true path and measurements for all four filters; with a file holding
    only the paper's four keys the first run draws the measurements and the others replay them."""
    stored = load_scenario(scenario_path)
    if not keep_measurements:
        stored = stored.model_copy(update={"robot_measurements": None})
    setup = replay_setup(stored, None, None, None, None)
    world, robot, sigma, delta, particles = setup.world, setup.robot, setup.sigma, setup.delta, setup.initial_particles
    results = compare_filters(world, robot, sigma, delta, particles, [*FILTERS, "GridBayesFilter"], seed=9)
    assert list(results) == [*FILTERS, "GridBayesFilter"]
    first = results["SIRParticleFilter"]
    if keep_measurements:
        assert first.scenario.robot_measurements == stored.robot_measurements
    for result in results.values():
        assert np.array_equal(result.true_positions, first.true_positions)
        assert result.scenario.robot_measurements == first.scenario.robot_measurements
        assert result.scenario.robot_compass_angles == stored.robot_compass_angles
        assert result.scenario.init_particles_pos == stored.init_particles_pos
        assert len(result.errors) == 40


def test_compare_writes_the_table_csv_and_figure(scenario_path, tmp_path, capsys):
    table, figure = tmp_path / "errors.csv", tmp_path / "errors.png"
    args = ["compare", str(scenario_path), "--filters", "sir,apf,rpf,grid", "--no-viz"]
    assert main([*args, "--csv", str(table), "--plot", str(figure)]) == 0
    out = capsys.readouterr().out
    for header in ["mean error", "last-20% error", "converged at", "mean ESS", "ms/step, numpy", "grid"]:
        assert header in out
    rows = read_csv(table)
    assert list(rows[0]) == ["step", *FILTERS, "GridBayesFilter"]
    assert [int(r["step"]) for r in rows] == list(range(1, 41))
    assert figure.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert main([*args, "--csv", str(table)]) == 2  # exists: refused without --force
    assert "use --force" in capsys.readouterr().err


def test_compare_errors_match_a_plain_replay(scenario_path, tmp_path):
    """The CSV holds the errors of `simulate` replaying the scenario with the same seed."""
    table = tmp_path / "e.csv"
    assert (
        main(["compare", str(scenario_path), "--filters", "apf", "--seed", "5", "--csv", str(table), "--no-viz"]) == 0
    )
    stored = load_scenario(scenario_path)
    result = simulate(
        stored.robot(), stored.world(), 0.3, 0.5, init_particles_pos=stored.init_particles_pos, seed=5,
        filtering_algorithm="apf",
    )  # fmt: skip
    column = [float(r["AuxiliaryParticleFilter"]) for r in read_csv(table)]
    assert column == result.errors.tolist()


def test_plot_without_matplotlib_says_how_to_install_it(scenario_path, tmp_path, capsys, monkeypatch):
    monkeypatch.setitem(sys.modules, "matplotlib", None)  # import matplotlib now raises ImportError
    assert main(["compare", str(scenario_path), "--plot", str(tmp_path / "x.png"), "--no-viz"]) == 2
    err = capsys.readouterr().err
    assert 'pip install -e ".[plot]"' in err and err.count("\n") == 1
    assert main(["study", "--runs", "1", "--plot", str(tmp_path / "y.png")]) == 2


# -- study: seeds, CSV, statistics -----------------------------------------------------------------
def tiny_tasks(runs: int = 3, seed: int = 11):
    """2 sigmas x 2 filters x `runs` runs of 30 steps with 150 particles on the paper's maze."""
    settings = study_settings([MazeChoice.from_maze("paper", Maze(PAPER_MAZE))], [0.3, 0.6], [0.5], [150])
    return settings, study_tasks(settings, FILTERS[:2], runs, 30, seed)


def test_study_csv_has_a_row_per_run_and_filter(tmp_path, capsys):
    table = tmp_path / "study.csv"
    args = ["study", "--maze", "paper_5x5", "--sigma", "0.3,0.6", "--delta", "0.2,0.5", "--filters", "sir,rpf"]
    assert main([*args, "--runs", "3", "--steps", "25", "--particles", "100", "--seed", "1", "--csv", str(table)]) == 0
    rows = read_csv(table)
    assert CSV_COLUMNS == [
        "setting", "run", "seed", "maze", "maze_seed", "station_blocks", "sigma", "delta", "particles",
        "steps", "filter", "final_error", "mean_error", "converged_at", "mean_ess", "ms_per_step",
        "kidnap_at", "relocalised", "steps_to_recover", "mean_particle_count",
        "maze_sha256", "maze_rows", "maze_columns", "wall_share", "run_seconds", "distance_to_exact", "log_evidence",
        "log_evidence_caveat", "label",
        "backend",
    ]  # fmt: skip
    declared = dict.fromkeys(o.name for name in ("sir", "rpf") for o in filter_entry(name).options.settable())
    assert list(rows[0]) == [*CSV_COLUMNS, *declared]  # then every option the studied filters declare
    assert len(rows) == 4 * 3 * 2  # settings x runs x filters
    labels = {(r["filter"], r["label"]) for r in rows}
    assert labels == {("SIRParticleFilter", "SIR"), ("RegularizedParticleFilter", "RPF")}
    assert {r["backend"] for r in rows} == {chosen_backend()}
    assert {(r["sigma"], r["delta"]) for r in rows} == {("0.3", "0.2"), ("0.3", "0.5"), ("0.6", "0.2"), ("0.6", "0.5")}
    assert {r["station_blocks"] for r in rows} == {"2"} and {r["maze_seed"] for r in rows} == {""}
    assert {(r["maze_rows"], r["maze_columns"]) for r in rows} == {("5", "5")}
    assert all(float(r["run_seconds"]) > 0 for r in rows)
    out = capsys.readouterr().out
    assert "95% CI" in out and "percentile bootstrap" in out and "median conv. step" in out
    assert "varied: sigma 0.3, 0.6; delta 0.2, 0.5" in out and "fixed: maze paper_5x5, 100 particles" in out


def test_every_filter_of_a_run_sees_the_same_scenario():
    """Run 1 replayed by hand: start from default_rng(seed), particles and walk from simulate(seed=seed);
    the study's figures for both filters are those of that one scenario."""
    _, tasks = tiny_tasks(runs=1)
    records = experiments.run_task(tasks[0])
    world = Maze(PAPER_MAZE)
    robot = Robot(0.3, 0.5, world.random_free_place(np.random.default_rng(tasks[0].seed)))
    sir = simulate(robot, world, 0.3, 0.5, 150, 30, seed=tasks[0].seed)
    apf = simulate(robot, world, 0.3, 0.5, None, None, sir.scenario.init_particles_pos, "apf", seed=tasks[0].seed)
    assert np.array_equal(sir.true_positions, apf.true_positions)
    assert [r.final_error for r in records] == [final_error(sir.errors), final_error(apf.errors)]
    assert [r.converged_at for r in records] == [convergence_step(sir.errors), convergence_step(apf.errors)]


def test_study_seeds_do_not_depend_on_the_setting_or_the_workers():
    _, tasks = tiny_tasks()
    assert [t.seed for t in tasks[:3]] == [t.seed for t in tasks[3:]]  # run r: the same seed in each setting
    assert len({t.seed for t in tasks[:3]}) == 3
    one, two = run_study(tasks, workers=1), run_study(tasks, workers=2)
    strip = [(r.setting, r.run, r.filter, r.final_error, r.converged_at, r.mean_ess) for r in one.records]
    assert strip == [(r.setting, r.run, r.filter, r.final_error, r.converged_at, r.mean_ess) for r in two.records]
    assert len(one.records) == 2 * 3 * 2 and not one.failures and not one.interrupted


def test_study_statistics_on_a_tiny_seeded_study():
    """The table's figures recomputed by hand from the run records of a tiny seeded study: the mean,
    the BCa bootstrap interval (within the runs' range), the converged share and the median
    convergence step of the converged runs."""
    settings, tasks = tiny_tasks()
    outcome = run_study(tasks, workers=1)
    summaries = summarise_study(outcome.records, settings)
    assert [(s.setting_index, s.filter) for s in summaries] == [(i, f) for i in (1, 2) for f in FILTERS[:2]]
    for s in summaries:
        mine = [r for r in outcome.records if (r.setting, r.filter) == (s.setting_index, s.filter)]
        finals = np.array([r.final_error for r in mine])
        mean, sd = finals.sum() / 3, math.sqrt(((finals - finals.sum() / 3) ** 2).sum() / 2)
        assert s.runs == 3 and sd >= 0
        assert s.mean_final_error == pytest.approx(mean, rel=1e-12)
        assert s.interval == bootstrap_interval(finals, "mean", method="bca")
        assert finals.min() <= s.interval[0] <= mean <= s.interval[1] <= finals.max()
        last = mine[0].steps - max(1, int(mine[0].steps * 0.2)) + 1  # converged: the last 20% of the steps
        counted = [r.converged_at is not None and r.converged_at <= last for r in mine]
        assert s.converged_share == sum(counted) / 3
        times = [min(r.converged_at or last, last) for r in mine]  # never: censored at `last`
        median = km_median(times, counted)[0]
        assert s.median_convergence_step == (None if math.isnan(median) else median)


def record(final: float, converged: int | None, run: int) -> RunRecord:
    return RunRecord(1, run, run, "m", None, 1, 0.3, 0.5, 10, 10, "SIR", final, final, converged, 5.0, 1.0)


def test_rows_are_in_the_studys_order_however_the_runs_finished():
    """A setting that runs only the RPF (its second bandwidth) finishing first does not put the RPF first:
    the rows are in (setting, run, filter) order, the filters as the study gives them (study_order)."""
    world = Maze(PAPER_MAZE)
    settings = study_settings([MazeChoice.from_maze("m", world)], [0.3], [0.5], [10],
                              {"bandwidth": ["optimal", "multimodal"]})  # fmt: skip
    names = ["SIRParticleFilter", "AuxiliaryParticleFilter", "RegularizedParticleFilter"]
    tasks = study_tasks(settings, names, 1, 5, 1)
    assert [t.filters for t in tasks] == [tuple(names), ("RegularizedParticleFilter",)]
    finished = [(2, "RegularizedParticleFilter"), (1, "RegularizedParticleFilter"), (1, "AuxiliaryParticleFilter"),
                (1, "SIRParticleFilter")]  # fmt: skip
    rows = [RunRecord(s, 1, 1, "m", None, 1, 0.3, 0.5, 10, 5, name, 0.1, 0.1, None, 5.0, 1.0) for s, name in finished]
    ordered = [(r.setting, r.filter) for r in experiments.study_order(rows, tasks)]
    assert ordered == [(1, name) for name in names] + [(2, "RegularizedParticleFilter")]


def test_summary_of_known_numbers():
    """Final errors 0.1, 0.2, 0.6: mean 0.3, whose t-interval reaches below zero (test_stats); the
    bootstrap's resampled means lie within [0.1, 0.6] and its
    2.5% and 97.5% quantiles are resampled means of three of the values (k/3 sums). Converged at 5,
    never, 9 of 10 steps (9 still counts: below the radius for the last 2 = 20% of the steps): share
    2/3 with the Wilson interval; Kaplan-Meier median 9 (S = 2/3 after 5, 1/3 after 9: the run that
    never converged counts, where the median of the converged runs alone said 7)."""
    settings = study_settings([MazeChoice("m", grid=((0, 2),))], [0.3], [0.5], [10])
    records = [record(0.1, 5, 1), record(0.2, None, 2), record(0.6, 9, 3)]
    (summary,) = summarise_study(records, settings)
    assert summary.mean_final_error == pytest.approx(0.3)
    low, high = summary.interval
    assert 0.1 <= low < 0.3 < high <= 0.6
    means = {round(sum(c) / 3, 12) for c in itertools.product([0.1, 0.2, 0.6], repeat=3)}
    assert round(low, 12) in means and round(high, 12) in means
    assert summary.converged_share == pytest.approx(2 / 3)
    assert summary.converged_interval == wilson_interval(2, 3)
    assert summary.median_convergence_step == 9


def test_final_error_is_the_mean_of_the_last_fifth():
    assert final_error(np.arange(10.0)) == 8.5  # the last 2 of 10 steps
    assert final_error(np.array([3.0, 1.0])) == 1.0  # at least one step


# -- study: faults ---------------------------------------------------------------------------------
def test_a_crashing_run_is_reported_with_its_seed_and_the_others_kept(tmp_path, capsys, monkeypatch):
    real = experiments.run_task

    def crash_on_run_2(task, visualize=False):
        if task.run == 2:
            raise RuntimeError("boom")
        return real(task, visualize)

    monkeypatch.setattr(experiments, "run_task", crash_on_run_2)
    monkeypatch.setattr(experiments, "batchable", lambda task: False)  # run by run, through run_task
    table = tmp_path / "s.csv"
    args = ["study", "--maze", "paper_5x5", "--runs", "3", "--steps", "10", "--particles", "50", "--filters", "sir"]
    assert main([*args, "--seed", "3", "--workers", "1", "--csv", str(table)]) == 1
    err = capsys.readouterr().err
    seed = study_tasks(*tiny_tasks()[:1], ["sir"], 3, 10, 3)[1].seed
    assert f"run 2 of setting 1 (seed {seed}) failed: RuntimeError: boom" in err
    assert [r["run"] for r in read_csv(table)] == ["1", "3"]


def test_ctrl_c_keeps_the_finished_runs_and_exits_130(tmp_path, capsys, monkeypatch):
    real = experiments.run_task

    def interrupt_on_run_3(task, visualize=False):
        if task.run == 3:
            raise KeyboardInterrupt
        return real(task, visualize)

    monkeypatch.setattr(experiments, "run_task", interrupt_on_run_3)
    monkeypatch.setattr(experiments, "batchable", lambda task: False)  # run by run, through run_task
    table = tmp_path / "s.csv"
    table.write_text("old\n")
    args = ["study", "--maze", "paper_5x5", "--runs", "5", "--steps", "10", "--particles", "50", "--filters", "sir,apf"]
    assert main([*args, "--workers", "1", "--csv", str(table), "--force"]) == 130
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler  # in-process: handlers put back
    err = capsys.readouterr().err
    journal = table.with_name("s.runs.jsonl")
    assert f"interrupted after 2 of 5 runs; the finished rows are in {journal}; go on with: " in err
    assert err.rstrip().endswith(f"--csv {table} --force --resume")  # the command as typed, to paste back
    assert table.read_text() == "old\n"  # the old file, not a cut one
    assert [(r["run"], r["filter"]) for r in finished_rows(journal)] == [
        (run, name) for run in ("1", "2") for name in FILTERS[:2]
    ]


# -- kidnapping in compare and study ---------------------------------------------------------------
def test_compare_kidnaps_every_filter_alike_after_the_replayed_walk(scenario_path):
    """--kidnap-at 20 on a scenario without one: steps 1-19 replay the stored walk and measurements,
    then every filter sees the same jump and the same new walk."""
    stored = load_scenario(scenario_path)
    setup = replay_setup(stored, None, None, None, None)
    world, robot, sigma, delta, particles = setup.world, setup.robot, setup.sigma, setup.delta, setup.initial_particles
    results = compare_filters(world, robot, sigma, delta, particles, FILTERS, seed=9, kidnap_at=20, recovery="sensor")
    first = results["SIRParticleFilter"].scenario
    assert first.kidnap_at == 20 and first.robot_actual_angles[:19] == stored.robot_actual_angles[:19]
    assert first.robot_measurements[:19] == stored.robot_measurements[:19]
    for result in results.values():
        assert len(result.errors) == 40
        assert (result.scenario.kidnap_position, result.scenario.robot_actual_angles) == (
            first.kidnap_position,
            first.robot_actual_angles,
        )


def test_compare_reports_a_stored_kidnapping_without_a_flag(tmp_path, paper_world, capsys):
    path = tmp_path / "k.json"
    args = ["run", "--maze", "paper_5x5", "--steps", "50", "--particles", "300", "--seed", "3", "--quiet", "--no-viz"]
    assert main([*args, "--kidnap-at", "20", "--save-scenario", str(path)]) == 0
    capsys.readouterr()
    assert main(["compare", str(path), "--no-viz", "--filters", "sir,grid"]) == 0
    out = capsys.readouterr().out
    assert "kidnapped at step 20" in out and "re-localised" in out and "steps to recover" in out
    assert "mean N" not in out
    assert main(["compare", str(path), "--no-viz", "--sensor-resetting", "--kld"]) == 0
    assert "mean N" in capsys.readouterr().out
    assert main(["compare", str(path), "--no-viz", "--kidnap-at", "10"]) == 2  # not the stored kidnapping


def kidnap_record(relocalised: bool, steps: int | None, run: int) -> RunRecord:
    return RunRecord(1, run, run, "m", None, 1, 0.3, 0.5, 10, 10, "SIR", 0.1, 0.1, None, 5.0, 1.0,
                     5, relocalised, steps, 400.0 + run, options={"recovery": "sensor"})  # fmt: skip


def test_recovery_summary_of_known_numbers():
    """Re-localised in runs 1, 2 and 4 of 5: share 3/5. Steps to recover 10, 40, never, 20, 31 (a run can
    recover late, after the window's start, and still not count as re-localised): median of the four
    that recovered, (20 + 31) / 2 = 25.5. Mean particle count (401 + ... + 405) / 5 = 403."""
    settings = study_settings([MazeChoice("m", grid=((0, 2),))], [0.3], [0.5], [10], {"recovery": ["sensor"]})
    records = [kidnap_record(True, 10, 1), kidnap_record(True, 40, 2), kidnap_record(False, None, 3),
               kidnap_record(True, 20, 4), kidnap_record(False, 31, 5)]  # fmt: skip
    (summary,) = summarise_study(records, settings)
    assert summary.relocalised_share == pytest.approx(3 / 5)
    assert summary.median_steps_to_recover == 25.5
    assert summary.mean_particle_count == pytest.approx(403)
    (lost,) = summarise_study([kidnap_record(False, None, r) for r in (1, 2)], settings)
    assert (lost.relocalised_share, lost.median_steps_to_recover) == (0, None)


def test_a_kidnapped_study_reports_relocalisation_computed_by_hand(capsys):
    """A tiny seeded study (recovery none and sensor, 3 runs, kidnapped at step 40 of 90): each record's
    figures are those of run 1 replayed by hand, and the table's share and median are recomputed from
    the records' errors: re-localised = mean error over the last DEFAULT_WINDOW steps below
    CONVERGENCE_RADIUS, steps to recover = R - 40, R the first step from which the error stays below it."""
    world = Maze(PAPER_MAZE)
    settings = study_settings(
        [MazeChoice.from_maze("paper", world)], [0.3], [0.5], [300], {"recovery": ["none", "sensor"]}
    )
    tasks = study_tasks(settings, ["sir", "apf"], 3, 90, 5, kidnap_at=40)
    outcome = run_study(tasks, workers=1)
    task = tasks[3]  # setting 2 (sensor), run 1
    robot = Robot(0.3, 0.5, world.random_free_place(np.random.default_rng(task.seed)))
    sir = simulate(robot, world, 0.3, 0.5, 300, 90, seed=task.seed, kidnap_at=40, recovery="sensor")
    errors = sir.errors
    by_hand = errors[-DEFAULT_WINDOW:].mean() < CONVERGENCE_RADIUS
    stay = [k for k in range(40, 91) if (errors[k - 1 :] < CONVERGENCE_RADIUS).all()]
    record = next(r for r in outcome.records if (r.setting, r.run, r.filter) == (2, 1, "SIRParticleFilter"))
    assert (record.relocalised, record.steps_to_recover) == (by_hand, stay[0] - 40 if stay else None)
    assert (record.relocalised, record.steps_to_recover) == (relocalised(sir), recovery_steps(sir))
    assert (record.options["recovery"], record.kidnap_at, record.mean_particle_count) == ("sensor", 40, 300.0)
    summaries = summarise_study(outcome.records, settings)
    for s in summaries:
        mine = [r for r in outcome.records if (r.setting, r.filter) == (s.setting_index, s.filter)]
        recovered = sorted(r.steps_to_recover for r in mine if r.steps_to_recover is not None)
        assert s.relocalised_share == sum(r.relocalised for r in mine) / 3
        assert s.median_steps_to_recover == (statistics.median(recovered) if recovered else None)
    table = study_table(summaries, ["recovery"])
    assert "re-localised" in table and "median steps to recover" in table
    plain_settings, plain_tasks = tiny_tasks(runs=1)
    plain = summarise_study(run_study(plain_tasks, workers=1).records, plain_settings)
    assert "re-localised" not in study_table(plain, ["sigma"])  # no kidnapping, no such columns


def test_study_varies_recovery_from_the_command_line(tmp_path, capsys):
    table = tmp_path / "k.csv"
    args = ["study", "--maze", "paper_5x5", "--runs", "2", "--steps", "40", "--particles", "150", "--seed", "2"]
    args += ["--kidnap-at", "20", "--recovery", "none,augmented,sensor", "--kld", "--csv", str(table)]
    assert main([*args, "--filters", "sir,grid", "--workers", "1"]) == 0
    out = capsys.readouterr().out
    assert "re-localised" in out and "median steps to recover" in out and "mean N" in out
    rows = read_csv(table)
    sir = [r for r in rows if r["filter"] == "SIRParticleFilter"]
    assert [r["recovery"] for r in sir[::2]] == ["none", "augmented", "sensor"]
    assert {r["recovery"] for r in rows if r["filter"] == "GridBayesFilter"} == {""}  # it takes no recovery
    assert {r["kidnap_at"] for r in rows} == {"20"} and {r["relocalised"] for r in rows} <= {"True", "False"}
    assert main([*args[:-2], "--recovery", "sometimes"]) == 2
    assert "unknown recovery 'sometimes'" in capsys.readouterr().err
