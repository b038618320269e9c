"""Studies a researcher can publish from: the JSON record, faithful replays, mazes told apart, each
filter once per setting of its own options, resume, per-step traces, the faceted figure and the Python
entry point. (The intervals are checked in test_stats.py, accuracy's CSV in test_accuracy.py.)"""

from __future__ import annotations

import csv
import hashlib
import json
import shutil
from pathlib import Path

import numpy as np
import pytest

import mazelab
from mazelab.cli.app import main
from mazelab.experiments.runs import final_error
from mazelab.experiments.study import MazeChoice, StudySetting, filters_per_setting
from mazelab.experiments.study_plot import figure_layout
from mazelab.experiments.summary import StudySummary
from mazelab.maze import MAZES_DIR
from mazelab.scenario import ScenarioError, load_scenario

TINY = ["--runs", "3", "--steps", "20", "--particles", "120", "--seed", "5", "--workers", "1", "--no-viz"]


def read_csv(path: Path) -> list[dict[str, str]]:
    with path.open(newline="") as handle:
        return list(csv.DictReader(handle))


def values(row: dict[str, str]) -> dict[str, str]:
    """A row without its timings (which differ between any two runs)."""
    return {k: v for k, v in row.items() if k not in ("ms_per_step", "run_seconds")}


# -- item 1: the record ------------------------------------------------------------------------------
def test_study_writes_a_record_beside_its_csv(tmp_path, capsys):
    table = tmp_path / "s.csv"
    assert (
        main(["study", "--maze", "paper_5x5", "--sigma", "0.3,0.5", "--filters", "sir", *TINY, "--csv", str(table)])
        == 0
    )
    record = json.loads((tmp_path / "s.record.json").read_text())
    assert record["command"][1:4] == ["study", "--maze", "paper_5x5"] and "--csv" in record["command"]
    assert record["status"] == "finished" and record["duration_seconds"] >= 0 and record["ended"] >= record["started"]
    assert record["parameters"]["root_seed"] == 5 and record["parameters"]["sigma"] == [0.3, 0.5]
    (maze,) = record["parameters"]["mazes"]
    assert maze["sha256"] == hashlib.sha256((MAZES_DIR / "paper_5x5.txt").read_bytes()).hexdigest()
    assert record["program"]["numpy"] == np.__version__ and record["program"]["mazelab"] == mazelab.__version__
    assert "bootstrap" in record["intervals"]["mean"] and "Wilson" in record["intervals"]["share"]
    assert [s["sigma"] for s in record["summary"]] == [0.3, 0.5] and record["summary"][0]["runs"] == 3
    assert record["peak_memory_bytes"]["this_process"] > 0
    capsys.readouterr()
    assert main(["--version"]) == 0
    assert capsys.readouterr().out.startswith(f"mazelab {mazelab.__version__}")


# -- item 2: a replay repeats the run that made the scenario ------------------------------------------
def test_a_replay_repeats_the_saved_filter_and_options(tmp_path, capsys):
    saved = tmp_path / "sb.json"
    run = ["run", "--maze", "paper_5x5", "--steps", "40", "--particles", "300", "--seed", "3", "--no-viz", "--quiet"]
    assert main([*run, "--filter", "rpf", "--bandwidth", "0.05", "--recovery", "--save-scenario", str(saved)]) == 0
    original = capsys.readouterr().out.splitlines()[0]
    stored = load_scenario(saved)
    assert stored.filtering_algorithm == "RegularizedParticleFilter" and stored.format_version == 3
    assert stored.filter_options["bandwidth"] == 0.05 and stored.filter_options["recovery"] == "augmented"
    assert main(["run", "--scenario", str(saved), "--no-viz", "--quiet"]) == 0
    replay = capsys.readouterr()
    assert replay.out.splitlines()[0] == original and replay.err == ""  # bit for bit, nothing overridden
    assert main(["run", "--scenario", str(saved), "--no-viz", "--quiet", "--bandwidth", "optimal"]) == 0
    changed = capsys.readouterr()
    assert changed.err.count("\n") == 1 and "bandwidth 0.05 -> optimal" in changed.err
    assert changed.out.splitlines()[0] != original
    assert main(["run", "--scenario", str(saved), "--no-viz", "--quiet", "--filter", "sir"]) == 0
    assert "filter RegularizedParticleFilter -> SIRParticleFilter" in capsys.readouterr().err


def test_stored_filter_options_are_validated(tmp_path):
    saved = tmp_path / "s.json"
    assert main(["run", "--maze", "paper_5x5", "--steps", "5", "--particles", "50", "--seed", "1", "--no-viz",
                 "--quiet", "--save-scenario", str(saved)]) == 0  # fmt: skip
    data = json.loads(saved.read_text())
    for options, message in (
        ({"bandwidth": 0.1}, r"SIRParticleFilter does not take the option bandwidth \(it takes: threshold, "),
        ({"recovery": {"mode": "augmented", "alpha_slow": 0.5, "alpha_fast": 0.1}}, "alpha_slow < alpha_fast"),
        ({"recovery": {"mode": "augmented", "speed": 1}}, "has no field 'speed'"),
        ({"resampling": [1, 2]}, "filter_options.resampling"),
    ):
        (tmp_path / "bad.json").write_text(json.dumps({**data, "filter_options": options}))
        with pytest.raises(ScenarioError, match=message):
            load_scenario(tmp_path / "bad.json")
    del data["filter_options"], data["format_version"]  # an older file: still loads
    (tmp_path / "old.json").write_text(json.dumps(data))
    assert load_scenario(tmp_path / "old.json").filter_options is None


# -- item 3: two maze files with one name ------------------------------------------------------------
def test_same_named_mazes_stay_apart(tmp_path):
    for folder, source in (("a", "paper_5x5.txt"), ("b", "maze_10x10.txt")):
        (tmp_path / folder).mkdir()
        shutil.copy(MAZES_DIR / source, tmp_path / folder / "m.txt")
    table = tmp_path / "s.csv"
    mazes = f"{tmp_path / 'a' / 'm.txt'},{tmp_path / 'b' / 'm.txt'}"
    assert main(["study", "--maze", mazes, "--filters", "sir", *TINY, "--csv", str(table)]) == 0
    rows = read_csv(table)
    assert {r["maze"] for r in rows} == {"a/m", "b/m"} and len({r["maze_sha256"] for r in rows}) == 2
    assert {(r["maze_rows"], r["station_blocks"]) for r in rows} == {("5", "2"), ("10", "5")}


def test_generated_mazes_have_their_size_blocks_and_wall_share_as_columns(tmp_path):
    table = tmp_path / "g.csv"
    args = ["study", "--maze-size", "8x9", "--stations", "3", "--wall-share", "0.2,0.35", "--filters", "sir"]
    assert main([*args, *TINY, "--csv", str(table)]) == 0
    rows = read_csv(table)
    assert {(r["maze_rows"], r["maze_columns"], r["station_blocks"]) for r in rows} == {("8", "9", "3")}
    assert {r["wall_share"] for r in rows} == {"0.2", "0.35"} and all(r["maze_seed"] for r in rows)


# -- item 4: each filter once per setting of the options it takes ------------------------------------
def test_sir_is_not_rerun_for_the_rpfs_bandwidth(tmp_path):
    plain, varied = tmp_path / "plain.csv", tmp_path / "varied.csv"
    base = ["study", "--maze", "paper_5x5", "--sigma", "0.3,0.5", "--filters", "sir,rpf,grid", *TINY]
    assert main([*base, "--csv", str(plain)]) == 0
    assert main([*base, "--bandwidth", "optimal,multimodal", "--csv", str(varied)]) == 0
    rows = read_csv(varied)
    count = {name: sum(r["filter"] == name for r in rows) for name in ("SIRParticleFilter", "GridBayesFilter")}
    assert count == {"SIRParticleFilter": 2 * 3, "GridBayesFilter": 2 * 3}  # per sigma and run, not per bandwidth
    assert sum(r["filter"] == "RegularizedParticleFilter" for r in rows) == 2 * 2 * 3
    before = {(r["sigma"], r["run"], r["filter"]): values(r) for r in read_csv(plain)}
    for r in rows:  # the rows both studies have are the same, bit for bit (setting numbers aside)
        if r["bandwidth"] == "optimal":
            assert {**values(r), "setting": ""} == {**before[r["sigma"], r["run"], r["filter"]], "setting": ""}


def test_the_grid_filter_runs_once_for_all_particle_counts():
    maze = MazeChoice("m", grid=((0, 2), (0, 0)))
    settings = [StudySetting(maze, 0.3, 0.5, n) for n in (100, 200)]
    assert filters_per_setting(settings, ["SIRParticleFilter", "GridBayesFilter"]) == [
        ("SIRParticleFilter", "GridBayesFilter"),
        ("SIRParticleFilter",),
    ]


# -- item 5: resume and extend --------------------------------------------------------------------------
def test_an_interrupted_study_resumes_to_the_rows_of_an_uninterrupted_one(tmp_path, capsys):
    base = ["study", "--maze", "paper_5x5", "--sigma", "0.3,0.5", "--filters", "sir,apf", *TINY[2:]]
    whole, part = tmp_path / "whole.csv", tmp_path / "part.csv"
    assert main([*base, "--runs", "5", "--csv", str(whole)]) == 0
    assert main([*base, "--runs", "3", "--csv", str(part)]) == 0
    lines = part.read_text().splitlines(keepends=True)
    part.write_text("".join(lines[:3] + lines[5:-1]) + lines[-1][:-30])  # rows lost, the last one cut short
    capsys.readouterr()
    assert main([*base, "--runs", "5", "--csv", str(part), "--resume"]) == 0  # resumes and extends to 5 runs
    assert "resuming:" in capsys.readouterr().out
    assert [values(r) for r in read_csv(part)] == [values(r) for r in read_csv(whole)]
    record = json.loads((tmp_path / "part.record.json").read_text())
    assert record["parameters"]["runs"] == 5 and len(record["sessions"]) == 1
    assert main([*base, "--runs", "5", "--csv", str(part), "--resume", "--sigma", "0.3"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "differs from its journal (sigma" in err
    assert main([*base, "--runs", "2", "--csv", str(part), "--resume"]) == 2
    assert "fewer than the study's 5" in capsys.readouterr().err


# -- item 6: per-step traces ---------------------------------------------------------------------------
@pytest.mark.parametrize("suffix", [".csv", ".parquet"])
def test_traces_hold_every_step_and_agree_with_the_rows(tmp_path, suffix):
    if suffix == ".parquet":
        pytest.importorskip("pyarrow")
    table, traces = tmp_path / "s.csv", tmp_path / f"t{suffix}"
    assert main(["study", "--maze", "paper_5x5", "--filters", "sir,grid", *TINY, "--csv", str(table),
                 "--traces", str(traces)]) == 0  # fmt: skip
    if suffix == ".csv":
        columns = {k: np.array([row[k] for row in read_csv(traces)]) for k in ("run", "filter", "step")}
        data = np.genfromtxt(traces, delimiter=",", names=True, dtype=None, encoding="utf-8")
        numbers = {k: data[k].astype(float) for k in ("true_x", "true_y", "estimate_x", "estimate_y", "error", "ess")}
    else:
        import pyarrow.parquet as pq

        loaded = pq.read_table(traces).to_pydict()
        columns = {k: np.array(loaded[k]).astype(str) for k in ("run", "filter", "step")}
        numbers = {k: np.array(loaded[k], dtype=float) for k in ("true_x", "true_y", "estimate_x", "estimate_y",
                                                                  "error", "ess")}  # fmt: skip
    assert len(columns["step"]) == 3 * 2 * 20
    error = np.hypot(numbers["estimate_x"] - numbers["true_x"], numbers["estimate_y"] - numbers["true_y"])
    np.testing.assert_allclose(numbers["error"], error, rtol=1e-12)
    assert np.isnan(numbers["ess"][columns["filter"] == "GridBayesFilter"]).all()
    for row in read_csv(table):
        mine = (columns["run"] == row["run"]) & (columns["filter"] == row["filter"])
        assert final_error(numbers["error"][mine]) == pytest.approx(float(row["final_error"]), rel=1e-12)


def test_compare_writes_traces_and_a_record(tmp_path):
    scenario = Path(__file__).parents[1] / "model_parameters" / "paper_5x5.json"
    traces = tmp_path / "c.csv"
    assert main(["compare", str(scenario), "--filters", "sir,apf", "--traces", str(traces), "--no-viz"]) == 0
    rows = read_csv(traces)
    assert len(rows) == 2 * 200 and {r["setting"] for r in rows} == {""}
    record = json.loads((tmp_path / "c.record.json").read_text())
    assert (
        record["kind"] == "compare" and record["scenario_sha256"] == hashlib.sha256(scenario.read_bytes()).hexdigest()
    )


# -- item 8: the faceted figure ------------------------------------------------------------------------
def test_study_figure_has_a_panel_per_maze_and_a_line_per_filter_and_option(tmp_path):
    figure = tmp_path / "f.png"
    args = ["study", "--maze", "paper_5x5,twin_rooms_6x12", "--sigma", "0.3,0.5", "--filters", "sir,rpf"]
    assert main([*args, "--bandwidth", "optimal,multimodal", *TINY, "--plot", str(figure)]) == 0
    import matplotlib.image

    pixels = matplotlib.image.imread(figure)
    assert pixels.ndim == 3 and pixels.shape[1] > pixels.shape[0] and pixels.std() > 0
    mazes = [MazeChoice("m", grid=((0, 2),)), MazeChoice("n", grid=((2, 0),))]
    combinations = [(m, s, b) for m in mazes for s in (0.3, 0.5) for b in ("optimal", "multimodal")]
    summaries = [
        StudySummary(i, StudySetting(m, s, 0.5, 10, (("bandwidth", b),)), f, 3, 0.1, (0.05, 0.2), 1.0, 5, 1.0)
        for i, (m, s, b) in enumerate(combinations, start=1)
        for f in ("SIRParticleFilter", "RegularizedParticleFilter")
    ]
    layout, _ = figure_layout(summaries, ["maze", "sigma", "bandwidth"])
    assert layout.x == "sigma" and layout.panels == ["m", "n"]
    assert layout.lines == ["SIR", "RPF, bandwidth optimal", "RPF, bandwidth multimodal"]


# -- item 10: the Python entry point ----------------------------------------------------------------------
def test_python_entry_point_returns_rows_summary_and_record():
    result = mazelab.study("paper_5x5", sigma=[0.3, 0.5], filters=["sir"], runs=2, steps=15, particles=80, seed=3)
    assert len(result.rows) == 4 and result.rows[0]["filter"] == "SIRParticleFilter"
    assert {row["sigma"] for row in result.summary} == {0.3, 0.5}
    assert result.record["parameters"]["root_seed"] == 3 and result.record["status"] == "finished"
    again = mazelab.study("paper_5x5", sigma=[0.3, 0.5], filters=["sir"], runs=2, steps=15, particles=80, seed=3)
    assert [values(r) for r in again.rows] == [values(r) for r in result.rows]
