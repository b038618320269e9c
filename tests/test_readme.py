"""The Python examples of the README and of the documentation's pages run as written (shortened to a
few steps, drawing to files)."""

from __future__ import annotations

import re

from conftest import ROOT

README = (ROOT / "README.md").read_text(encoding="utf-8")
VIEWER_PAGE = (ROOT / "docs" / "viewer.md").read_text(encoding="utf-8")


def python_blocks(section: str, text: str = README) -> list[str]:
    """The ```python blocks of the section of `text` (the README's by default) that starts with `section`
    (up to the next heading of the same level)."""
    start = text.index(section)
    level = section.split(" ")[0]
    end = text.find(f"\n{level} ", start + len(section))
    return re.findall(r"```python\n(.*?)```", text[start : end if end > 0 else None], re.S)


def test_the_lab_steps_run_as_written(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    blocks = python_blocks("## The lab, step by step")
    code = "\n".join(blocks)
    assert 'open("model_parameters.json")' in code and "load_scenario(" in code
    for block in blocks:  # each block on its own, as a student pastes it (the second reads the first's file)
        exec(block.replace("particle_count = 1500", "particle_count = 200").replace("steps = 200", "steps = 20"), {})
    assert (tmp_path / "model_parameters.json").exists()
    assert capsys.readouterr().out.count("mean error") == 3


def test_the_notebook_comparison_snippet_runs(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    (code,) = [block for block in python_blocks("## In Jupyter", VIEWER_PAGE) if "open_comparison" in block]
    exec(code.replace('"notebook"', '"comparison.rrd"').replace("steps=200", "steps=5").replace("(1500,", "(200,"), {})
    assert (tmp_path / "comparison.rrd").stat().st_size > 0
