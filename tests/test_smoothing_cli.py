"""`mazelab smooth` and `mazelab learn` as a researcher runs them on a saved scenario: the rows mean what
the library computes, the record names the scenario, bad input is one line and exit 2."""

from __future__ import annotations

import csv
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

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
        (["smooth", "{s}", "--filters", "sir", "--option", "bandwidth=0.05"], "does not take --option bandwidth"),
        (["learn", "{s}", "--resume"], "--resume: no journal of the cells beside"),
        (["learn", "{s}", "--resolution", "0.0001", "--workers", "2"], "cells (resolution 0.0001) needs about"),
        (["learn", "{s}", "--dask", "tcp://127.0.0.1:1"], "cannot reach the Dask scheduler"),
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


def recorded_points(path, timeline="step"):
    """{entity: {time: (positions (M, 2), radii (M,))}} of the Points2D an .rrd file holds on `timeline`."""
    reader = RrdReader(path)
    (store,) = reader.recordings()
    found = {}
    for chunk in reader.stream(store=store):
        batch = chunk.to_record_batch()
        if "Points2D:positions" not in batch.schema.names or timeline not in batch.schema.names:
            continue
        columns = [batch.column(name).to_pylist() for name in (timeline, "Points2D:positions", "Points2D:radii")]
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


def test_smooth_gives_each_filter_the_options_it_declares(scenario, tmp_path):
    """--option rpf.bandwidth reaches the RPF alone: its rows are the library's with that option, SIR's are
    those of a run without it."""
    argv = ["smooth", str(scenario), "--filters", "sir,rpf", "--lag", "5", "--resolution", "0.2"]
    assert main([*argv, "--csv", str(tmp_path / "plain.csv")]) == 0
    assert main([*argv, "--option", "rpf.bandwidth=0.05", "--csv", str(tmp_path / "narrow.csv")]) == 0
    plain, narrow = read_rows(tmp_path / "plain.csv"), read_rows(tmp_path / "narrow.csv")
    stored = load_scenario(scenario)
    filters = {"sir": {}, "rpf": {"bandwidth": 0.05}}  # each filter's own options
    expected = score_smoothers(load_maze("paper_5x5"), stored.robot(), stored.sigma, stored.delta, filters, lag=5,
                               seed=stored.seed, initial_particles=stored.init_particles_pos,
                               grid_options={"resolution": 0.2})  # fmt: skip
    for row, want in zip(narrow, expected.rows, strict=True):
        assert {k: float(v) if k != "filter" else v for k, v in row.items()} == pytest.approx(want, abs=0)
    assert [r for r in narrow if r["filter"] == "SIR"] == [r for r in plain if r["filter"] == "SIR"]
    assert [r for r in narrow if r["filter"] == "RPF"] != [r for r in plain if r["filter"] == "RPF"]
    record = json.loads((tmp_path / "narrow.record.json").read_text())
    assert record["parameters"]["options"] == {"sir": {}, "rpf": {"bandwidth": "0.05"}}  # as given


LEARN = ["--cells", "3", "--resolution", "0.2"]


def test_learn_goes_on_from_its_journal_and_refuses_a_changed_input(scenario, tmp_path, capsys):
    """A journal cut by a kill (its last line half written) keeps its whole cells: --resume computes only
    the others (a kept cell's value is read, not computed again); a changed input is refused in one line."""
    whole, cut = tmp_path / "whole.csv", tmp_path / "cut.csv"
    assert main(["learn", str(scenario), *LEARN, "--workers", "2", "--csv", str(whole)]) == 0
    assert main(["learn", str(scenario), *LEARN, "--workers", "1", "--csv", str(cut)]) == 0
    journal = tmp_path / "cut.runs.jsonl"
    lines = journal.read_text().splitlines()
    assert [json.loads(line)["cell"] for line in lines[1:10]] == list(range(9))
    cut.unlink()
    (tmp_path / "cut.record.json").unlink()  # what a killed command leaves: its journal alone
    journal.write_text(f'{lines[0]}\n{{"cell": "first", "log_evidence": 1}}\n')
    capsys.readouterr()
    assert main(["learn", str(scenario), *LEARN, "--csv", str(cut), "--resume"]) == 2
    assert "holds a line that is not a cell's" in capsys.readouterr().err
    kept = [lines[0], json.dumps({"cell": 0, "log_evidence": -123.0}), *lines[2:5], lines[5][:12]]
    journal.write_text("\n".join(kept))
    assert main(["learn", str(scenario), *LEARN, "--resolution", "0.1", "--csv", str(cut), "--resume"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--resume: the command differs from" in err and "resolution: 0.2 -> 0.1" in err
    assert main(["learn", str(scenario), *LEARN, "--csv", str(cut)]) == 2
    assert "holds the runs of an earlier study: add --resume" in capsys.readouterr().err
    assert main(["learn", str(scenario), *LEARN, "--csv", str(cut), "--resume"]) == 0
    assert "resuming: 4 cell(s) kept" in capsys.readouterr().out
    resumed, first = read_rows(cut), read_rows(whole)
    assert resumed[0]["log_evidence"] == "-123.0"
    assert [r["log_evidence"] for r in resumed[1:]] == [r["log_evidence"] for r in first[1:]]
    sessions = [json.loads(line) for line in journal.read_text().splitlines() if "session" in line]
    assert len(sessions) == 2


@pytest.mark.parametrize(("stop", "code"), [(signal.SIGINT, 130), (signal.SIGTERM, 143)])
def test_a_stop_keeps_the_finished_cells_and_resume_finishes_them(scenario, tmp_path, capsys, stop, code):
    table = tmp_path / "l.csv"
    journal = tmp_path / "l.runs.jsonl"
    argv = ["learn", str(scenario), "--cells", "20", "--resolution", "0.1", "--csv", str(table)]
    process = subprocess.Popen([sys.executable, str(Path(__file__).parents[1] / "main.py"), *argv, "--workers", "1"],
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True,
                               preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))  # fmt: skip
    deadline = time.monotonic() + 60
    while (not journal.exists() or journal.read_text().count('"cell"') < 3) and time.monotonic() < deadline:
        time.sleep(0.05)
    os.killpg(process.pid, stop)
    _, err = process.communicate(timeout=60)
    assert process.returncode == code and "interrupted after" in err and "--resume" in err, err
    done = journal.read_text().count('"cell"')
    assert 3 <= done < 400 and not table.exists()
    assert main([*argv, "--resume"]) == 0
    assert f"resuming: {done} cell(s) kept" in capsys.readouterr().out
    rows, stored = read_rows(table), load_scenario(scenario)
    for row in (rows[0], rows[-1]):  # one of the first session, one of the second
        log_z = grid_log_evidence(load_maze("paper_5x5"), stored.robot_compass_angles, stored.robot_measurements,
                                  float(row["sigma"]), float(row["delta"]), resolution=0.1)  # fmt: skip
        assert float(row["log_evidence"]) == log_z


def test_learn_on_a_dask_cluster_gives_the_local_cells(scenario, tmp_path, capsys):
    distributed = pytest.importorskip("distributed")
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=False, protocol="tcp",
                                  host="127.0.0.1", dashboard_address=None) as cluster:  # fmt: skip
        address = cluster.scheduler_address
        assert main(["learn", str(scenario), *LEARN, "--dask", address, "--csv", str(tmp_path / "d.csv")]) == 0
    assert f"on the Dask cluster at {address}" in capsys.readouterr().out
    assert main(["learn", str(scenario), *LEARN, "--workers", "1", "--csv", str(tmp_path / "l.csv")]) == 0
    assert read_rows(tmp_path / "d.csv") == read_rows(tmp_path / "l.csv")


def test_learn_records_the_chain_over_the_exact_posterior(scenario, tmp_path):
    """Read back from the recording: a dot per cell at its centre, its area the cell's mass; the chain's
    state at every iteration, whose mean after the burn-in is the record's PMMH mean."""
    rows_file, rrd = tmp_path / "l.csv", tmp_path / "l.rrd"
    argv = ["learn", str(scenario), *LEARN, "--pmmh", "40", "--particles", "30", "--csv", str(rows_file)]
    assert main([*argv, "--rrd", str(rrd)]) == 0
    rows, points = read_rows(rows_file), recorded_points(rrd, "iteration")
    record = json.loads((tmp_path / "l.record.json").read_text())
    positions, radii = points["/posterior/cells"][0]
    np.testing.assert_allclose(positions, [[float(r["sigma"]), float(r["delta"])] for r in rows], rtol=1e-6)
    mass = np.array([float(r["mass"]) for r in rows])
    np.testing.assert_allclose(radii**2 / (radii**2).max(), mass / mass.max(), rtol=1e-5)
    chain = points["/posterior/chain"]
    assert sorted(chain) == list(range(1, 41))
    kept = np.array([chain[i][0][0] for i in range(5, 41)])  # after the burn-in, 40 // 10 iterations
    np.testing.assert_allclose(kept.mean(axis=0), record["summary"]["pmmh"]["mean"], rtol=1e-6)
