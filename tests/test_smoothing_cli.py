"""`mazelab smooth` and `mazelab learn` as a researcher runs them on a saved scenario: the rows mean what
the library computes, the record names the scenario, bad input is one line and exit 2."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest
from rerun.chunk import RrdReader

from mazelab.cli.app import main
from mazelab.learning import grid_log_evidence
from mazelab.maze import load_maze
from mazelab.registry import file_sha256
from mazelab.scenario import load_scenario
from mazelab.smoothing import SCORE_COLUMNS, score_smoothers

STEPS = 25


@pytest.fixture(scope="module")
def scenario(tmp_path_factory):
    """A saved 25-step run of 300 particles on the paper's maze, with its measurements."""
    path = tmp_path_factory.mktemp("scenario") / "walk.json"
    argv = ["run", "--maze", "paper_5x5", "--steps", str(STEPS), "--particles", "300", "--seed", "3", "--quiet"]
    assert main([*argv, "--no-viz", "--save-scenario", str(path)]) == 0
    return path


def read_rows(path):
    with open(path, newline="") as file:
        return list(csv.DictReader(file))


def test_smooth_writes_the_scores_rows_a_figure_and_a_record(scenario, tmp_path, capsys):
    rows_file, figure = tmp_path / "s.csv", tmp_path / "s.png"
    argv = [
        "smooth",
        str(scenario),
        "--lag",
        "5",
        "--resolution",
        "0.1",
        "--csv",
        str(rows_file),
        "--plot",
        str(figure),
    ]
    assert main(argv) == 0
    table = capsys.readouterr().out
    assert all(label in table for label in ("SIR", "APF", "RPF", "path_ancestors_fewest"))
    rows = read_rows(rows_file)
    assert list(rows[0]) == list(SCORE_COLUMNS) and len(rows) == 3 * STEPS
    stored = load_scenario(scenario)
    filters = ["sir", "apf", "rpf"]
    particles, grid = stored.init_particles_pos, {"resolution": 0.1}
    expected = score_smoothers(load_maze("paper_5x5"), stored.robot(), stored.sigma, stored.delta, filters, lag=5,
                               seed=stored.seed, initial_particles=particles, grid_options=grid)  # fmt: skip
    for row, want in zip(rows, expected.rows, strict=True):  # the file's numbers are the library's, in full
        assert {k: float(v) if k != "filter" else v for k, v in row.items()} == pytest.approx(want, abs=0)
    assert figure.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    record = json.loads((tmp_path / "s.record.json").read_text())
    assert record["kind"] == "smooth" and record["status"] == "finished"
    assert record["scenario_sha256"] == file_sha256(scenario)
    assert record["parameters"]["lag"] == 5 and record["parameters"]["seed"] == stored.seed
    assert [r["filter"] for r in record["summary"]][1:] == ["SIR", "APF", "RPF"]


def test_learn_writes_the_exact_posterior_and_the_chain(scenario, tmp_path, capsys):
    rows_file = tmp_path / "l.csv"
    argv = ["learn", str(scenario), "--cells", "3", "--resolution", "0.1", "--pmmh", "40", "--particles", "50",
            "--csv", str(rows_file), "--plot", str(tmp_path / "l.png")]  # fmt: skip
    assert main(argv) == 0
    assert "PMMH: acceptance rate" in capsys.readouterr().out
    rows = read_rows(rows_file)
    assert len(rows) == 9 and sum(float(r["mass"]) for r in rows) == pytest.approx(1, abs=1e-12)
    stored, first = load_scenario(scenario), rows[0]
    log_z = grid_log_evidence(load_maze("paper_5x5"), stored.robot_compass_angles, stored.robot_measurements,
                              float(first["sigma"]), float(first["delta"]), resolution=0.1)  # fmt: skip
    assert float(first["log_evidence"]) == log_z
    record = json.loads((tmp_path / "l.record.json").read_text())
    assert record["kind"] == "learn" and 0 <= record["summary"]["pmmh"]["acceptance_rate"] <= 1
    (sigma, delta), cells = record["summary"]["exact"]["mean"], [r for r in rows if float(r["mass"]) > 0]
    assert sigma == pytest.approx(sum(float(r["sigma"]) * float(r["mass"]) for r in cells), abs=1e-12)
    assert delta == pytest.approx(sum(float(r["delta"]) * float(r["mass"]) for r in cells), abs=1e-12)


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["learn", "{s}", "--sigma-range", "0,0.5"], "sigma must be > 0"),
        (["learn", "{s}", "--sigma-range", "0.5"], "--sigma-range takes LOW,HIGH (two numbers)"),
        (["learn", "{s}", "--pmmh", "5", "--filter", "rpf"], "PMMH needs a filter whose evidence estimates p(z_1:K)"),
        (["smooth", "{s}", "--resolution", "0.0001"], "cells (resolution 0.0001) needs about"),
        (["smooth", "{s}", "--filters", "grid"], "a particle smoother needs a filter's genealogy: grid keeps"),
        (["smooth", "{bare}"], "stores no measurements (robot_measurements)"),
        (["smooth", "{s}", "--csv", "{s}"], "exists"),
    ],
)
def test_bad_input_is_one_line_and_exit_2(scenario, tmp_path, capsys, argv, message):
    data = json.loads(scenario.read_text())
    del data["robot_measurements"]
    bare = tmp_path / "bare.json"
    bare.write_text(json.dumps(data))
    assert main([a.format(s=scenario, bare=bare) for a in argv]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("error: ") and message in err


def recorded_points(path):
    """{entity: {step: (positions (M, 2), radii (M,))}} of the Points2D an .rrd file holds."""
    reader = RrdReader(path)
    (store,) = reader.recordings()
    found = {}
    for chunk in reader.stream(store=store):
        batch = chunk.to_record_batch()
        if "Points2D:positions" not in batch.schema.names or "step" not in batch.schema.names:
            continue
        columns = [batch.column(name).to_pylist() for name in ("step", "Points2D:positions", "Points2D:radii")]
        for step, positions, radii in zip(*columns, strict=True):
            found.setdefault(chunk.entity_path, {})[step] = (np.array(positions), np.array(radii))
    return found


def test_smooth_records_each_filters_cloud_beside_its_path_smoothers_as_the_rows_score_them(scenario, tmp_path):
    """Read back from the recording: each view's cloud, weighted by its dots' areas, lies as far from the
    exact smoothed mean drawn with it as the rows say (float32 positions: 1e-5 map units)."""
    rows_file, rrd = tmp_path / "s.csv", tmp_path / "s.rrd"
    argv = ["smooth", str(scenario), "--filters", "sir", "--resolution", "0.1", "--csv", str(rows_file)]
    assert main([*argv, "--rrd", str(rrd)]) == 0
    rows, points = read_rows(rows_file), recorded_points(rrd)
    for view, column in (("sir_filtered", "filter_error"), ("sir_smoothed", "path_error")):
        clouds, means = points[f"/map/{view}/particles"], points[f"/map/{view}/exact_smoothed_mean"]
        assert sorted(clouds) == list(range(1, STEPS + 1))
        for row in rows:
            positions, radii = clouds[int(row["step"])]
            mean = (radii**2) @ positions / (radii**2).sum()  # a dot's area is its weight
            distance = np.hypot(*(mean - means[int(row["step"])][0][0]))
            assert distance == pytest.approx(float(row[column]), abs=1e-5), (view, row["step"])
