"""notebooks/exercise.ipynb: committed unfilled and without outputs; with the reference answers put in
by this test (never shipped in the notebook), it runs top to bottom in a fresh kernel and every check
cell passes."""

from __future__ import annotations

import inspect
import textwrap

import nbformat
import pytest
from conftest import ROOT
from exercise_answers import ReferenceFilter
from nbclient import NotebookClient
from test_notebook import CELL_TIMEOUT, kernel_spec, stdout_of  # noqa: F401 (kernel_spec is a fixture)

from mazelab.exercise import PARTS

NOTEBOOK = ROOT / "notebooks" / "exercise.ipynb"


def read() -> nbformat.NotebookNode:
    return nbformat.read(NOTEBOOK, as_version=nbformat.NO_CONVERT)


def cell(notebook: nbformat.NotebookNode, cell_id: str) -> nbformat.NotebookNode:
    return next(c for c in notebook.cells if c.get("id") == cell_id)


def answer(part: str) -> str:
    """The reference answer to one part, as the top-level function the notebook's cell defines."""
    method = getattr(ReferenceFilter, "estimate_part" if part == "estimate" else part)
    return textwrap.dedent(inspect.getsource(method))


def test_committed_notebook_is_unfilled_and_has_no_outputs():
    notebook = read()
    nbformat.validate(notebook)
    assert set(notebook.metadata) == {"kernelspec", "language_info"}
    for c in notebook.cells:
        assert not c.metadata
        if c.cell_type == "code":
            assert c.outputs == [] and c.execution_count is None
    for part in PARTS:
        assert "raise NotImplementedError" in cell(notebook, f"answer-{part}").source
        assert f'check_part("{part}", {part})' in cell(notebook, f"check-{part}").source


@pytest.mark.slow  # a kernel and the whole check: about 15 s (it still runs by default)
def test_notebook_with_the_reference_answers_passes_every_check(kernel_spec, tmp_path):  # noqa: F811
    notebook = read()
    for part in PARTS:
        cell(notebook, f"answer-{part}").source = answer(part)
    client = NotebookClient(
        notebook, kernel_name=kernel_spec, timeout=CELL_TIMEOUT, resources={"metadata": {"path": str(tmp_path)}}
    )
    client.execute()  # raises CellExecutionError, naming the cell, if any cell fails
    for part in PARTS:
        out = stdout_of(cell(notebook, f"check-{part}"))
        assert f"{part}" in out and "pass" in out and "FAIL" not in out, out
    assert "All checks pass." in stdout_of(cell(notebook, "check-whole"))
