"""mazelab.experiments.tables: per-step rows that a band plot reads without glue.

- every trace row carries its run's parameters (maze, sigma, delta, particles, the four options, any
  other option) and its filter's own diagnostics (the RPF's `regularised`; empty for a filter with none);
- the parameters agree with the study's CSV rows, and a resumed study's traces have the same columns.
"""

from __future__ import annotations

import csv

import numpy as np

from mazelab.cli.app import main
from mazelab.experiments.tables import DIAGNOSTIC_PREFIX, PARAMETER_COLUMNS, TRACE_COLUMNS
from mazelab.registry import filter_entry

STUDY = ["study", "--maze", "paper_5x5", "--filters", "sir,rpf", "--sigma", "0.3,0.5", "--runs", "2", "--steps", "15"]
STUDY += [
    "--particles",
    "100",
    "--seed",
    "3",
    "--workers",
    "1",
    "--no-viz",
    "--option",
    "resampling=systematic,residual",
]


def rows_of(path) -> list[dict[str, str]]:
    return list(csv.DictReader(path.open()))


def test_traces_carry_each_runs_parameters_and_its_filters_diagnostics(tmp_path):
    table, traces = tmp_path / "s.csv", tmp_path / "t.csv"
    assert main([*STUDY, "--csv", str(table), "--traces", str(traces)]) == 0
    header = traces.read_text().splitlines()[0].split(",")
    assert header[: len(TRACE_COLUMNS)] == TRACE_COLUMNS
    options = [o.name for name in ("sir", "rpf") for o in filter_entry(name).options.settable()]
    parameters = [*PARAMETER_COLUMNS, *dict.fromkeys(options)]  # the model's, then every option declared
    assert f"{DIAGNOSTIC_PREFIX}regularised" in header and header[-len(parameters) :] == parameters
    steps = rows_of(traces)
    by_row = {(r["setting"], r["run"], r["filter"]): r for r in rows_of(table)}
    assert len(steps) == 15 * len(by_row)
    for step in steps:
        row = by_row[(step["setting"], step["run"], step["filter"])]
        assert all(step[c] == row[c] for c in parameters)
        regularised = step[f"{DIAGNOSTIC_PREFIX}regularised"]
        assert regularised in ("0", "1") if step["filter"] == "RegularizedParticleFilter" else regularised == ""
    rpf = [s for s in steps if s["filter"] == "RegularizedParticleFilter"]
    assert any(s[f"{DIAGNOSTIC_PREFIX}regularised"] == "1" for s in rpf)


def test_a_band_plot_needs_only_the_traces_own_columns(tmp_path):
    """The 10-90% band of the error per filter, sigma, scheme and step, straight from the file's columns
    (as pandas' `groupby([...])["error"].quantile(...)` would)."""
    traces = tmp_path / "t.csv"
    assert main([*STUDY, "--traces", str(traces)]) == 0
    bands: dict[tuple[str, ...], list[float]] = {}
    for row in rows_of(traces):
        bands.setdefault((row["filter"], row["sigma"], row["resampling"], row["step"]), []).append(float(row["error"]))
    assert len(bands) == 2 * 2 * 2 * 15 and all(len(errors) == 2 for errors in bands.values())
    assert all(np.isfinite(np.quantile(errors, [0.1, 0.9])).all() for errors in bands.values())


def test_a_resumed_studys_traces_have_the_same_columns_and_rows(tmp_path):
    whole, first = tmp_path / "whole", tmp_path / "first"
    for folder in (whole, first):
        folder.mkdir()
    assert main([*STUDY, "--csv", str(whole / "s.csv"), "--traces", str(whole / "t.csv")]) == 0
    half = [*STUDY]
    half[half.index("--runs") + 1] = "1"
    assert main([*half, "--csv", str(first / "s.csv"), "--traces", str(first / "t.csv")]) == 0
    assert main([*STUDY, "--csv", str(first / "s.csv"), "--traces", str(first / "t.csv"), "--resume"]) == 0
    drop = {"step_ms"}

    def untimed(path):
        return sorted(tuple(v for k, v in r.items() if k not in drop) for r in rows_of(path))

    assert rows_of(first / "t.csv")[0].keys() == rows_of(whole / "t.csv")[0].keys()
    assert untimed(first / "t.csv") == untimed(whole / "t.csv")
