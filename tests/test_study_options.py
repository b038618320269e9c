"""The study carries every option generically: its option columns are the union of the options the
studied filters declare (rows, summary, traces), a row's cell the value its filter ran with, empty where
its filter does not declare the option; a plug-in's own option is a column like the lab's."""

from __future__ import annotations

import csv
import textwrap

import mazelab
from mazelab.cli.app import main
from mazelab.registry import filter_entry

QUICK = ["--maze", "paper_5x5", "--runs", "2", "--steps", "5", "--particles", "30", "--seed", "1", "--workers", "1"]

PLUGIN = """
from mazelab.filters import SIRParticleFilter


class Inflated(SIRParticleFilter):
    options = {**SIRParticleFilter.options, "inflation": 1.0}
"""


def declared(name: str) -> list[str]:
    """The options a filter declares that a user sets, read from its declaration."""
    return [o.name for o in filter_entry(name).options.settable()]


def rows_of(path) -> list[dict[str, str]]:
    with path.open() as handle:
        return list(csv.DictReader(handle))


def header_of(path) -> list[str]:
    return path.read_text().splitlines()[0].split(",")


def test_a_study_of_sir_alone_has_no_column_of_an_option_only_the_rpf_declares(tmp_path, capsys):
    rpf_only = set(declared("rpf")) - set(declared("sir"))
    assert rpf_only  # the RPF's threshold and bandwidth
    table, traces = tmp_path / "s.csv", tmp_path / "t.csv"
    assert main(["study", *QUICK, "--filters", "sir", "--no-viz", "--csv", str(table), "--traces", str(traces)]) == 0
    assert "threshold" not in capsys.readouterr().out
    for path in (table, tmp_path / "s.summary.csv", traces):
        header = header_of(path)
        assert not rpf_only & set(header), path.name
        assert set(declared("sir")) <= set(header), path.name  # each the value SIR ran with
    assert {row["recovery"] for row in rows_of(table)} == {"none"} and {r["estimate"] for r in rows_of(table)} == {
        "mean"
    }
    result = mazelab.study("paper_5x5", filters=["sir"], runs=1, steps=5, particles=30, seed=1, traces=True)
    assert not rpf_only & {*result.rows[0], *result.summary[0], *result.traces}


def test_a_plugins_own_option_is_a_column_varied_by_option(tmp_path, capsys):
    """A plug-in declaring `inflation` by a plain mapping, with `--option inflation=1.0,2.0`: its rows
    carry each value, SIR's (which does not take it, and runs once) an empty cell, and the RPF's own
    options are empty on SIR's and the plug-in's rows."""
    plugin = tmp_path / "inflated.py"
    plugin.write_text(textwrap.dedent(PLUGIN))
    table, traces = tmp_path / "s.csv", tmp_path / "t.csv"
    filters = f"sir,rpf,{plugin}:Inflated"
    args = ["study", *QUICK, "--filters", filters, "--option", "inflation=1.0,2.0", "--no-viz"]
    assert main([*args, "--csv", str(table), "--traces", str(traces)]) == 0
    rows = rows_of(table)
    by_filter: dict[str, list[tuple[str, str, str]]] = {}
    for row in rows:
        by_filter.setdefault(row["label"], []).append((row["setting"], row["inflation"], row["bandwidth"]))
    assert by_filter["Inflated"] == [("1", "1.0", ""), ("1", "1.0", ""), ("2", "2.0", ""), ("2", "2.0", "")]
    assert by_filter["SIR"] == [("1", "", ""), ("1", "", "")]
    assert by_filter["RPF"] == [("1", "", "optimal"), ("1", "", "optimal")]
    assert header_of(table)[-1] == "inflation"  # the filters' order: SIR's, the RPF's own, then the plug-in's
    summary = {(r["label"], r["setting"]): r["inflation"] for r in rows_of(tmp_path / "s.summary.csv")}
    assert summary == {("SIR", "1"): "", ("RPF", "1"): "", ("Inflated", "1"): "1.0", ("Inflated", "2"): "2.0"}
    steps = rows_of(traces)
    assert {(s["filter"].rsplit(":", 1)[-1], s["inflation"]) for s in steps} == {
        ("SIRParticleFilter", ""),
        ("RegularizedParticleFilter", ""),
        ("Inflated", "1.0"),
        ("Inflated", "2.0"),
    }


def test_a_plugin_study_resumes_with_its_option_cells(tmp_path, capsys):
    """Its rows' `filter` is the plug-in's class name (the study runs it by its file's spec): `--resume`
    keeps them, with their option cells, and the resumed CSV is the uninterrupted study's."""
    plugin = tmp_path / "inflated.py"
    plugin.write_text(textwrap.dedent(PLUGIN))
    table, whole = tmp_path / "s.csv", tmp_path / "whole.csv"
    args = ["study", "--maze", "paper_5x5", "--steps", "5", "--particles", "30", "--seed", "1", "--workers", "1"]
    args += ["--filters", f"sir,{plugin}:Inflated", "--option", "inflation=1.0,2.0", "--no-viz", "--csv"]
    assert main([*args, str(whole), "--runs", "3"]) == 0
    assert main([*args, str(table), "--runs", "2"]) == 0
    capsys.readouterr()
    assert main([*args, str(table), "--runs", "3", "--resume"]) == 0
    assert "resuming: 6 rows kept" in capsys.readouterr().out  # runs 1-2: SIR once, the plug-in per value
    timings = ("ms_per_step", "run_seconds")
    assert [{k: v for k, v in r.items() if k not in timings} for r in rows_of(table)] == [
        {k: v for k, v in r.items() if k not in timings} for r in rows_of(whole)
    ]
