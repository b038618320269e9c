"""The statistics a reviewer asks of a study, checked against known cases: Kaplan-Meier against a
hand-worked example and a textbook data set, the converged share's window, BCa's formula and its
direction on skewed data, the paired interval against the unpaired one on correlated data, and the
study's own columns: the paired difference, distance_to_exact (--reference grid) and the summary CSV."""

from __future__ import annotations

import csv
import io
import math
import statistics

import numpy as np
import pytest

import mazelab
from mazelab.cli.app import main
from mazelab.experiments import runs as run_module
from mazelab.experiments import study as study_module
from mazelab.experiments.study import MazeChoice, RunRecord, distance_to_exact, study_settings
from mazelab.experiments.summary import (
    BOOTSTRAP_SAMPLES,
    BOOTSTRAP_SEED,
    SUMMARY_STATISTICS,
    bca_levels,
    bootstrap_interval,
    converged_within,
    kaplan_meier,
    km_median,
    last_convergence_step,
    leave_one_out,
    paired_difference,
    resampled,
    summarise_study,
    summary_csv,
)
from mazelab.grid_filter import GridBayesFilter
from mazelab.maze import find_maze, load_maze
from mazelab.robot import Robot
from mazelab.seeding import start_place
from mazelab.simulation import simulate

Z = 1.959963984540054  # the normal 97.5% quantile
TINY = ["--runs", "3", "--steps", "20", "--particles", "100", "--seed", "5", "--workers", "1", "--no-viz"]


def read_csv(text: str) -> list[dict[str, str]]:
    return list(csv.DictReader(io.StringIO(text)))


def unpaired_difference(values, reference, level=0.95, samples=BOOTSTRAP_SAMPLES, seed=BOOTSTRAP_SEED):
    """What the paired interval is measured against: the difference of the two means with its percentile
    bootstrap interval, each sample resampled on its own (two independent groups)."""
    a, b = (np.asarray(v, dtype=float) for v in (values, reference))
    rng = np.random.default_rng(seed)
    means = [x[rng.integers(0, len(x), size=(samples, len(x)))].mean(axis=1) for x in (a, b)]
    low, high = np.quantile(means[0] - means[1], [(1 - level) / 2, (1 + level) / 2])
    return float(a.mean() - b.mean()), (float(low), float(high))


# -- Kaplan-Meier ------------------------------------------------------------------------------------
def test_kaplan_meier_of_a_hand_worked_example():
    """Six runs: events at 3, 5, 8 and 12, censored at 5 and 10 (* below).

    t   n  d   S(t)                    Greenwood sum          log-log band (z = 1.96)
    3   6  1   5/6     = 0.8333        1/30      = 0.03333    [0.2732, 0.9747]
    5   5  1   4/6     = 0.6667        + 1/20    = 0.08333    [0.1946, 0.9044]
    8   3  1   4/6*2/3 = 0.4444        + 1/6     = 0.25       [0.0662, 0.7849]
    12  1  1   0                       (inf)                  [0, 0]

    with 5* and 10* at risk until they leave. The band at t: S^exp(+-z sqrt(G) / |log S|), e.g. at 3:
    sqrt(1/30) / |log 5/6| = 1.00138, exp(1.96 * 1.00138) = 7.117, (5/6)^7.117 = 0.2732. The median:
    S first <= 0.5 at 8; its interval: the band's low end first <= 0.5 at 3, its high end at 12."""
    times, observed = [3, 5, 5, 8, 10, 12], [True, True, False, True, False, True]
    curve = kaplan_meier(times, observed)
    assert curve.times.tolist() == [3, 5, 8, 12]
    assert curve.at_risk.tolist() == [6, 5, 3, 1] and curve.events.tolist() == [1, 1, 1, 1]
    assert curve.survival == pytest.approx([5 / 6, 4 / 6, 8 / 18, 0.0])
    assert curve.low == pytest.approx([0.2732, 0.1946, 0.0662, 0.0], abs=1e-4)
    assert curve.high == pytest.approx([0.9747, 0.9044, 0.7849, 0.0], abs=1e-4)
    assert km_median(times, observed) == (8.0, (3.0, 12.0))


def test_kaplan_meier_of_the_6mp_leukaemia_data():
    """Freireich's 6-MP arm (Gehan 1965; Klein & Moeschberger, Table 4.1A): 21 patients, weeks in
    remission, 12 censored. The textbook's S(t): 0.857 at 6, 0.807 at 7, 0.753 at 10, 0.690 at 13,
    0.627 at 16, 0.538 at 22, 0.448 at 23; the median 23."""
    times = [6, 6, 6, 6, 7, 9, 10, 10, 11, 13, 16, 17, 19, 20, 22, 23, 25, 32, 32, 34, 35]
    censored = {3, 5, 7, 8, 11, 12, 13, 16, 17, 18, 19, 20}  # the indices of 6+, 9+, 10+, 11+, 17+, ...
    observed = [i not in censored for i in range(len(times))]
    curve = kaplan_meier(times, observed)
    assert curve.times.tolist() == [6, 7, 10, 13, 16, 22, 23]
    assert curve.survival == pytest.approx([0.857, 0.807, 0.753, 0.690, 0.627, 0.538, 0.448], abs=5e-4)
    assert km_median(times, observed)[0] == 23


def test_kaplan_meier_without_censoring_is_the_ordinary_median():
    for values in ([4, 1, 9, 7, 3], [1, 2, 3, 4, 5, 6, 7, 8, 9, 10], [5, 5, 5, 8]):
        assert km_median(values, [True] * len(values))[0] == statistics.median(values)


def test_kaplan_meier_median_not_reached():
    """Two of five reach the event: S never gets to 0.5, the median is not reached (NaN)."""
    median, (low, high) = km_median([2, 4, 9, 9, 9], [True, True, False, False, False])
    assert math.isnan(median) and math.isnan(high) and low == 2


# -- converged, and the convergence step --------------------------------------------------------------
def record(final: float, converged: int | None, run: int, steps: int = 10, name: str = "SIR") -> RunRecord:
    return RunRecord(1, run, run, "m", None, 1, 0.3, 0.5, 10, steps, name, final, final, converged, 5.0, 1.0)


def test_converged_means_below_the_radius_for_the_last_twenty_percent():
    """200 steps: K = 40 (the last-20% window), so a convergence counts from step 161 at the latest; a
    run converging at the last step, or at 162, does not."""
    assert last_convergence_step(200) == 161 and last_convergence_step(3) == 3
    assert converged_within(161, 200) and not converged_within(162, 200) and not converged_within(200, 200)
    assert not converged_within(None, 200) and converged_within(1, 200)


def test_the_summary_counts_the_runs_that_never_converge():
    """10 steps, K = 2: a convergence counts from step 9 at the latest. Converged at 2, at 10 (not
    counted), never, at 9 (counted): share 2/4. Kaplan-Meier on (2, event), (9, censored) twice,
    (9, event): S = 3/4 after step 2, 3/4 * 2/3 = 1/2 after step 9, so the median is 9 (no later event
    to take a midpoint with). With the last one never converging too, S stays at 3/4: not reached,
    where the median of the converged runs alone would have said 2."""
    settings = study_settings([MazeChoice("m", grid=((0, 2),))], [0.3], [0.5], [10])
    records = [record(0.1, 2, 1), record(0.9, 10, 2), record(0.8, None, 3), record(0.2, 9, 4)]
    (summary,) = summarise_study(records, settings)
    assert summary.converged_share == 0.5 and summary.last_convergence_step == 9
    assert summary.median_convergence_step == 9
    (fewer,) = summarise_study([record(0.1, 2, 1), record(0.9, 10, 2), record(0.8, None, 3), record(0.2, None, 4)],
                               settings)  # fmt: skip
    assert fewer.converged_share == 0.25 and fewer.median_convergence_step is None  # not reached
    assert math.isnan(fewer.convergence_interval[1])


# -- BCa -------------------------------------------------------------------------------------------------
def test_bca_levels_follow_efrons_formula():
    """z0 from the share of resampled means below the observed one, a from the jackknife, computed here
    apart (np.delete), and the interval is the resamples' quantiles at the moved levels."""
    data = np.random.default_rng(11).exponential(size=15)
    estimates = resampled(data, np.mean, 2000, 7)
    below = np.mean(estimates < data.mean())
    jack = np.array([np.delete(data, i).mean() for i in range(len(data))])
    d = jack.mean() - jack
    a = (d**3).sum() / (6 * (d**2).sum() ** 1.5)
    nd = statistics.NormalDist()
    z0 = nd.inv_cdf(below)
    expected = [nd.cdf(z0 + (z0 + nd.inv_cdf(q)) / (1 - a * (z0 + nd.inv_cdf(q)))) for q in (0.025, 0.975)]
    assert bca_levels(data, np.mean, estimates, [0.025, 0.975]) == pytest.approx(expected, rel=1e-9)
    low, high = bootstrap_interval(data, "mean", seed=7, method="bca")
    assert (low, high) == tuple(np.quantile(estimates, expected))
    assert a > 0 and high > bootstrap_interval(data, "mean", seed=7)[1]  # right skew: BCa reaches further up


def test_the_jackknife_of_the_median():
    rng = np.random.default_rng(2)
    for n in (2, 3, 8, 9):
        data = rng.normal(size=n)
        assert leave_one_out(data, np.median) == pytest.approx([np.median(np.delete(data, i)) for i in range(n)])


# -- paired against unpaired --------------------------------------------------------------------------
def test_the_paired_interval_is_narrower_on_correlated_runs():
    """Two filters on the same 30 walks: a walk's difficulty (lognormal, shared) dominates both errors,
    the filters differ by 0.05 and some noise of their own. The paired interval's width is that of the
    differences' mean, sd(a - b) / sqrt(n) times a constant; the unpaired one's sqrt(var a + var b) /
    sqrt(n) times the same: their ratio is sd(a - b) / sqrt(var a + var b), here about 0.1, within the
    bootstrap's own noise (15%). The paired interval excludes 0, the unpaired one does not."""
    rng = np.random.default_rng(5)
    walk = rng.lognormal(np.log(0.3), 0.8, 30)
    a, b = walk + 0.05 + rng.normal(0, 0.02, 30), walk + rng.normal(0, 0.02, 30)
    mean, (low, high) = paired_difference(a, b)
    unpaired, (u_low, u_high) = unpaired_difference(a, b)
    assert mean == pytest.approx(np.mean(a - b)) and unpaired == pytest.approx(mean)
    expected = np.std(a - b, ddof=1) / math.sqrt(np.var(a, ddof=1) + np.var(b, ddof=1))
    assert (high - low) / (u_high - u_low) == pytest.approx(expected, rel=0.15)
    assert 0 < low < mean < high and u_low < 0 < u_high


def test_paired_and_unpaired_agree_on_independent_runs():
    """Without shared luck (independent samples) the two intervals are alike: the width ratio is
    sd(a - b) / sqrt(var a + var b), near 1."""
    rng = np.random.default_rng(8)
    a, b = rng.normal(1.0, 0.3, 40), rng.normal(1.0, 0.3, 40)
    (_, (low, high)), (_, (u_low, u_high)) = paired_difference(a, b), unpaired_difference(a, b)
    expected = np.std(a - b, ddof=1) / math.sqrt(np.var(a, ddof=1) + np.var(b, ddof=1))
    assert (high - low) / (u_high - u_low) == pytest.approx(expected, rel=0.15)


# -- the study's columns ----------------------------------------------------------------------------
def test_paired_differences_in_a_study_pair_each_run_with_the_same_scenario():
    """SIR runs once per sigma (not per RPF bandwidth): each RPF row is paired with SIR's rows of the
    same sigma and run, whichever setting they were recorded in."""
    result = mazelab.study("paper_5x5", sigma=[0.3, 0.5], filters=["sir", "rpf"], bandwidth=["optimal", "multimodal"],
                           runs=3, steps=15, particles=80, seed=4, paired="sir")  # fmt: skip
    rows = result.rows
    sir = {(r["sigma"], r["run"]): r["final_error"] for r in rows if r["filter"] == "SIRParticleFilter"}
    for s in result.summary:
        mine = [r for r in rows if r["setting"] == s["setting"] and r["filter"] == s["filter"]]
        if s["filter"] == "SIRParticleFilter":
            assert s["paired_with"] is None
            continue
        differences = [r["final_error"] - sir[r["sigma"], r["run"]] for r in mine]
        assert s["paired_with"] == "SIRParticleFilter" and s["paired_runs"] == 3
        assert s["mean_difference"] == pytest.approx(statistics.fmean(differences), rel=1e-12)
        assert (s["difference_low"], s["difference_high"]) == bootstrap_interval(differences, "mean", method="bca")
    assert len({s["bandwidth"] for s in result.summary if s["filter"] == "RegularizedParticleFilter"}) == 2


def test_reference_grid_gives_every_row_its_distance_to_the_exact_posterior(monkeypatch):
    """--reference grid: each row's distance_to_exact is accuracy's measure against the grid filter's
    posterior means on that run's walk (recomputed here by hand for run 1's SIR row); the grid runs once
    per run, not once per particle count."""
    made = []
    real_init = GridBayesFilter.__init__

    def counting(self, *args, **kwargs):
        made.append(1)
        real_init(self, *args, **kwargs)

    monkeypatch.setattr(GridBayesFilter, "__init__", counting)
    monkeypatch.setattr(study_module, "_EXACT_MEANS", {})
    monkeypatch.setattr(run_module, "_warmed", set())  # as in a new process: the grid is warmed up once, untimed
    result = mazelab.study("paper_5x5", filters=["sir"], particles=[60, 90], runs=2, steps=16, seed=6,
                           reference="grid")  # fmt: skip
    assert len(made) == 2 + 1  # two runs' scenarios, shared by both particle counts; the warm-up
    assert all(r["distance_to_exact"] >= 0 for r in result.rows) and len(result.rows) == 4
    first = result.rows[0]
    world = load_maze(find_maze("paper_5x5"))
    robot = Robot(0.3, 0.5, start_place(world, first["seed"]))
    sir = simulate(robot, world, 0.3, 0.5, 60, 16, seed=first["seed"])
    exact = simulate(robot, world, 0.3, 0.5, None, 16, None, "grid", seed=first["seed"])
    assert first["distance_to_exact"] == distance_to_exact(sir.estimates, exact.estimates)
    distances = [r["distance_to_exact"] for r in result.rows if r["setting"] == 1]
    assert result.summary[0]["distance_to_exact"] == pytest.approx(statistics.fmean(distances))
    made.clear()
    mazelab.study("paper_5x5", filters=["sir", "grid"], runs=2, steps=16, seed=7, reference="grid")
    assert len(made) == 2  # the study's own grid row is the reference: not run a second time


def test_the_study_writes_a_summary_csv_beside_its_rows(tmp_path, capsys):
    table = tmp_path / "s.csv"
    args = ["study", "--maze", "paper_5x5", "--filters", "sir,apf,grid", "--paired", "sir", "--reference", "grid"]
    assert main([*args, *TINY, "--csv", str(table)]) == 0
    out = capsys.readouterr().out
    assert "diff. vs SIR" in out and "dist. to exact" in out and "Kaplan-Meier" in out
    rows = read_csv(table.read_text())
    grid = [r for r in rows if r["filter"] == "GridBayesFilter"]
    assert len(grid) == 3 and all(float(r["distance_to_exact"]) == 0 for r in grid)
    summary = read_csv((tmp_path / "s.summary.csv").read_text())
    assert [s["filter"] for s in summary] == ["SIRParticleFilter", "AuxiliaryParticleFilter", "GridBayesFilter"]
    assert list(summary[0])[-len(SUMMARY_STATISTICS) :] == list(SUMMARY_STATISTICS) == [
        "runs", "mean_final_error", "mean_final_error_low", "mean_final_error_high", "median_final_error",
        "median_final_error_low", "median_final_error_high", "converged_share", "converged_low", "converged_high",
        "last_convergence_step", "median_convergence_step", "median_convergence_step_low",
        "median_convergence_step_high", "mean_log_evidence", "log_evidence_se", "log_evidence_caveat", "ms_per_step",
        "backend", "run_seconds", "mean_particle_count", "relocalised_share", "relocalised_low", "relocalised_high",
        "median_steps_to_recover", "distance_to_exact", "distance_to_exact_low", "distance_to_exact_high",
        "paired_with", "paired_runs", "mean_difference", "difference_low", "difference_high",
    ]  # fmt: skip
    assert summary[2]["particles"] == "" and summary[0]["particles"] == "100"  # the grid takes no N
    for s in summary:
        mine = [float(r["final_error"]) for r in rows if r["filter"] == s["filter"]]
        assert float(s["mean_final_error"]) == statistics.fmean(mine)
        low, high = bootstrap_interval(mine, "mean", method="bca")
        assert (float(s["mean_final_error_low"]), float(s["mean_final_error_high"])) == (low, high)
    assert summary[0]["paired_with"] == "" and summary[1]["paired_with"] == "SIRParticleFilter"
    assert main([*args, *TINY, "--csv", str(table)]) == 2  # the files exist: refused without --force
    assert "use --force to discard it" in capsys.readouterr().err
    chosen = tmp_path / "chosen.csv"
    assert main(["study", "--filters", "sir", *TINY, "--summary-csv", str(chosen)]) == 0
    assert read_csv(chosen.read_text())[0]["runs"] == "3"


def test_summary_csv_keeps_every_interval_as_written():
    settings = study_settings([MazeChoice("m", grid=((0, 2),))], [0.3], [0.5], [10])
    (summary,) = summarise_study([record(0.1, 5, 1), record(0.2, None, 2), record(0.6, 9, 3)], settings)
    (row,) = read_csv(summary_csv([summary]))
    assert float(row["median_final_error_low"]) == summary.median_interval[0]
    assert float(row["converged_high"]) == summary.converged_interval[1]
    assert float(row["median_convergence_step"]) == 9 and row["last_convergence_step"] == "9"


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--paired", "ekf"], "--paired ekf: not one of the study's --filters (sir)"),
        (["--reference", "ekf"], "--reference ekf: the reference is the exact grid filter, --reference grid"),
    ],
)
def test_bad_statistics_flags_are_one_line(args, message, capsys):
    assert main(["study", "--filters", "sir", "--runs", "1", "--steps", "5", *args]) == 2
    assert capsys.readouterr().err.strip() == f"error: {message}"


def test_a_pair_needs_the_reference_fixed_by_the_filters_setting():
    """The grid filter takes no particle count: against SIR at two particle counts it has no single
    partner (which N?), so no paired difference; at one particle count it has one."""
    maze = MazeChoice("m", grid=((0, 2),))

    def rows(setting: int, name: str) -> list[RunRecord]:
        return [RunRecord(setting, r, r, "m", None, 1, 0.3, 0.5, 10, 10, name, 0.1 * r + setting, 0.1, None, 5.0,
                          1.0) for r in (1, 2)]  # fmt: skip

    two = study_settings([maze], [0.3], [0.5], [10, 20])
    records = [*rows(1, "SIRParticleFilter"), *rows(1, "GridBayesFilter"), *rows(2, "SIRParticleFilter")]
    grid = [s for s in summarise_study(records, two, paired="sir") if s.filter == "GridBayesFilter"]
    assert grid[0].paired_with is None and math.isnan(grid[0].mean_difference)
    one = study_settings([maze], [0.3], [0.5], [10])
    grid = [s for s in summarise_study(records[:4], one, paired="sir") if s.filter == "GridBayesFilter"]
    assert grid[0].paired_with == "SIRParticleFilter" and grid[0].mean_difference == pytest.approx(0.0)
