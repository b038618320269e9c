"""What a researcher collects from a study and a comparison beyond the errors: the log evidence log
p(z_1:K) as a study column, per step in the traces (study and compare), its standard error in the
summary, and the RPF's estimate marked in every table, file and figure with the reason it is not of
p(z_1:K) under the model (declared once, in its registry entry); every timing named with the backend it
ran on, which a study chooses once and sends to every worker (the local pool and Dask alike), and which
a --resume refuses to mix. Real commands, real files."""

from __future__ import annotations

import csv
import io
import json
import math
import re
import statistics
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

from mazelab import registry
from mazelab.cli.app import main
from mazelab.registry import RPF_EVIDENCE, described, filter_entry

SMALL = ["--maze", "paper_5x5", "--runs", "3", "--steps", "12", "--particles", "80", "--seed", "4", "--no-viz"]
SCENARIO = Path(__file__).resolve().parent.parent / "model_parameters" / "paper_5x5.json"


def read_csv(path: Path) -> list[dict[str, str]]:
    return list(csv.DictReader(io.StringIO(path.read_text())))


@pytest.fixture(scope="module")
def study(tmp_path_factory):
    """A small study of the three particle filters and the grid filter with every file it writes."""
    folder = tmp_path_factory.mktemp("study")
    args = ["study", *SMALL, "--filters", "sir,apf,rpf,grid", "--workers", "1", "--csv", str(folder / "s.csv")]
    assert (
        main([*args, "--traces", str(folder / "t.csv"), "--plot", str(folder / "e.svg"), "--plot-y", "evidence"]) == 0
    )
    return folder


def test_the_rpfs_caveat_is_declared_once_in_its_registry_entry():
    assert filter_entry("rpf").evidence == RPF_EVIDENCE and described("RegularizedParticleFilter").evidence
    assert [e.short_name for e in registry.entries() if e.evidence] == ["rpf"]


def test_a_studys_rows_carry_the_log_evidence_and_the_rpfs_caveat(study):
    rows = read_csv(study / "s.csv")
    for row in rows:
        caveat = row["log_evidence_caveat"]
        assert (caveat == RPF_EVIDENCE) == (row["filter"] == "RegularizedParticleFilter"), row["filter"]
        assert math.isfinite(float(row["log_evidence"]))  # every filter here keeps one; the grid's is exact
    traces = read_csv(study / "t.csv")
    for row in rows:  # the traces' last step is the row's log evidence, bit for bit
        mine = [t for t in traces if (t["run"], t["filter"]) == (row["run"], row["filter"])]
        assert len(mine) == 12 and float(mine[-1]["log_evidence"]) == float(row["log_evidence"])
        assert {t["log_evidence_caveat"] for t in mine} == {row["log_evidence_caveat"]}


def test_the_summary_gives_the_mean_log_evidence_and_its_standard_error(study, capsys):
    rows, summary = read_csv(study / "s.csv"), read_csv(study / "s.summary.csv")
    for entry in summary:
        mine = [float(r["log_evidence"]) for r in rows if r["filter"] == entry["filter"]]
        assert float(entry["mean_log_evidence"]) == pytest.approx(statistics.fmean(mine), rel=1e-12)
        assert float(entry["log_evidence_se"]) == pytest.approx(statistics.stdev(mine) / math.sqrt(3), rel=1e-12)
        assert (entry["log_evidence_caveat"] == RPF_EVIDENCE) == (entry["label"] == "RPF")
    record = json.loads((study / "s.record.json").read_text())
    assert {s["filter"]: bool(s["log_evidence_caveat"]) for s in record["summary"]}["RegularizedParticleFilter"]


def test_the_study_table_marks_the_rpf_and_says_why(tmp_path, capsys):
    assert main(["study", *SMALL, "--filters", "sir,rpf", "--workers", "1"]) == 0
    out = capsys.readouterr().out
    header = next(line for line in out.splitlines() if line.startswith("filter"))
    assert "log p(z_1:K) (SE)" in header and "ms/step, numpy" in header  # the backend beside the timing
    (rpf,) = [line for line in out.splitlines() if line.startswith("RPF")]
    (sir,) = [line for line in out.splitlines() if line.startswith("SIR")]
    assert ")*" in rpf and "*" not in sir
    assert f"[* RPF: the log evidence is {RPF_EVIDENCE}]" in out


def test_the_evidence_figure_marks_the_rpf_in_its_legend_and_caption(study):
    texts = " ".join(
        "".join(t.itertext()) for t in ET.parse(study / "e.svg").getroot().iter("{http://www.w3.org/2000/svg}text")
    )
    assert "RPF*" in " ".join(texts.split()) and "its log evidence is not an estimate of p(z_1:K)" in " ".join(
        texts.split()
    )


def test_compare_marks_the_rpf_names_the_backend_and_traces_the_evidence(tmp_path, capsys):
    traces = tmp_path / "c.csv"
    assert main(["compare", str(SCENARIO), "--filters", "sir,rpf", "--traces", str(traces), "--no-viz"]) == 0
    out = capsys.readouterr().out
    assert "ms/step, numpy" in out and "on the backend named" in out
    (rpf,) = [line for line in out.splitlines() if line.startswith("RPF")]
    assert re.search(r"\s-?\d+\.\d\*\s", rpf) and f"[* RPF: the log evidence is {RPF_EVIDENCE}]" in out
    rows = read_csv(traces)
    assert {r["log_evidence_caveat"] for r in rows if r["filter"] == "RegularizedParticleFilter"} == {RPF_EVIDENCE}
    assert all(math.isfinite(float(r["log_evidence"])) for r in rows)
    record = json.loads((tmp_path / "c.record.json").read_text())
    assert {s["filter"]: s["log_evidence_caveat"] for s in record["summary"]}["RegularizedParticleFilter"]
    assert {s["backend"] for s in record["summary"]} == {"numpy"}


@pytest.mark.parametrize("backend", ["numpy", "compiled"])
def test_the_chosen_backend_reaches_the_local_pools_workers(tmp_path, backend, monkeypatch):
    """--backend is chosen once and sent with every unit: the pool's workers run it whatever their own
    MAZELAB_BACKEND says (set here to the other one), and every row and the header say it."""
    pytest.importorskip("numba") if backend == "compiled" else None
    monkeypatch.setenv("MAZELAB_BACKEND", "compiled" if backend == "numpy" else "numpy")
    table = tmp_path / "s.csv"
    assert main(["study", *SMALL, "--filters", "sir,apf", "--workers", "2", "--backend", backend,
                 "--csv", str(table)]) == 0  # fmt: skip
    assert {r["backend"] for r in read_csv(table)} == {backend}
    assert json.loads(table.with_name("s.record.json").read_text())["backend"] == backend


def test_a_study_threshold_reaches_sir_and_the_apf_and_a_scoped_one_one_filter(tmp_path, capsys):
    """Adaptive resampling everywhere it is declared: --threshold varies SIR's and the APF's too (their rows
    differ, their cells say it); rpf.threshold varies the RPF's alone, SIR running once at its default."""
    table = tmp_path / "s.csv"
    assert main(["study", *SMALL, "--filters", "sir,apf", "--threshold", "0.3,1", "--workers", "1",
                 "--csv", str(table)]) == 0  # fmt: skip
    rows = read_csv(table)
    for name in ("SIRParticleFilter", "AuxiliaryParticleFilter"):
        mine = {r["threshold"]: r["mean_ess"] for r in rows if r["filter"] == name and r["run"] == "1"}
        assert set(mine) == {"0.3", "1.0"} and mine["0.3"] != mine["1.0"]
    scoped = tmp_path / "r.csv"
    assert main(["study", *SMALL, "--filters", "sir,rpf", "--option", "rpf.threshold=0.1,0.5", "--workers", "1",
                 "--csv", str(scoped)]) == 0  # fmt: skip
    rows = read_csv(scoped)
    assert {r["threshold"] for r in rows if r["filter"] == "SIRParticleFilter"} == {"1.0"}
    assert len([r for r in rows if r["filter"] == "SIRParticleFilter"]) == 3  # once per run, not per threshold
    assert {r["threshold"] for r in rows if r["filter"] == "RegularizedParticleFilter"} == {"0.1", "0.5"}
    capsys.readouterr()
    assert main(["study", *SMALL, "--filters", "sir", "--option", "rpf.threshold=0.1"]) == 2
    assert "rpf is not one of the filters" in capsys.readouterr().err


def test_a_studys_threshold_in_python_reaches_sir_too():
    import mazelab

    result = mazelab.study("paper_5x5", filters="sir", threshold=[0.3, 1.0], runs=1, steps=8, particles=60, seed=2)
    assert sorted(r["threshold"] for r in result.rows) == [0.3, 1.0]


def test_a_value_outside_the_labs_range_is_one_line_of_warning(capsys):
    assert main(["run", "--sigma", "5", "--steps", "5", "--particles", "30", "--seed", "1", "--no-viz", "--quiet"]) == 0
    warnings_ = [line for line in capsys.readouterr().err.splitlines() if line.startswith("warning:")]
    assert warnings_ == ["warning: sigma = 5.0 is outside the lab's range [0.2, 0.8]"]
    import mazelab

    with pytest.warns(UserWarning, match="outside the lab's range") as caught:
        mazelab.study("paper_5x5", sigma=5, filters="sir", runs=2, steps=4, particles=30, seed=1)
    assert len([w for w in caught if "outside the lab's range" in str(w.message)]) == 1
