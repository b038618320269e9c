"""The Python examples of the README and of the documentation's pages run as written (shortened to a
few steps, drawing to files)."""

from __future__ import annotations

import os
import re
import tomllib

from conftest import ROOT
from packaging.requirements import Requirement

from mazelab.viz import recording as viz_recording

FILTERS = ("SIRParticleFilter", "AuxiliaryParticleFilter", "RegularizedParticleFilter")  # the lab's three, in order
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
    """Each block on its own, as a student pastes it (the second reads the first's file). The first,
    the README's lab.py, says the comparison's numbers; without a display each of its four runs says in
    one line where its recording went (the folder's size only once it passes 100 MB: not here)."""
    monkeypatch.chdir(tmp_path)
    blocks = python_blocks("## The lab, step by step")
    code = "\n".join(blocks)
    assert 'open("model_parameters.json")' in code and "load_scenario(" in code
    shorter = [block.replace("particle_count = 1500", "particle_count = 200") for block in blocks]
    exec(shorter[0].replace("steps = 200", "steps = 20"), {})
    lines = capsys.readouterr().out.splitlines()
    assert len(lines) == 8 and lines[1].startswith("scenario saved to ")
    assert all(lines[i].startswith(f"Recording saved to {viz_recording.RECORDINGS_DIR}{os.sep}") for i in (0, 2, 4, 6))
    for line, name in zip(lines[3::2], FILTERS, strict=True):
        assert re.fullmatch(rf"{name}: mean error \d+\.\d{{3}}, last-step error \d+\.\d{{3}}", line), line
    for block in shorter[1:]:
        exec(block, {})
    assert (tmp_path / "model_parameters.json").exists()
    assert capsys.readouterr().out.count("mean error") == 3


def test_the_notebook_comparison_snippet_runs(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    (code,) = [block for block in python_blocks("## In Jupyter", VIEWER_PAGE) if "open_comparison" in block]
    exec(code.replace('"notebook"', '"comparison.rrd"').replace("steps=200", "steps=5").replace("(1500,", "(200,"), {})
    assert (tmp_path / "comparison.rrd").stat().st_size > 0


def test_the_pip_route_and_uvs_dev_group_install_one_list_with_every_extra():
    """The README's pip route (`pip install -e ".[test]"`, then `pytest`) passes the same tests as `uv run
    pytest`: uv's dev group is the `test` extra itself, and that extra takes every other extra (the
    site's build, the figures, the notebooks' viewer, Dask, numba), each of which some tests need."""
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())
    name, extras = project["project"]["name"], project["project"]["optional-dependencies"]
    assert project["dependency-groups"]["dev"] == [f"{name}[test]"]
    (itself,) = [Requirement(r) for r in extras["test"] if Requirement(r).name == name]
    assert itself.extras == set(extras) - {"test"}
    assert 'pip install -e ".[test]"' in README and "`test` extra is uv's `dev` group" in README
