"""notebooks/exercise.ipynb and its Ukrainian twin exercise_uk.ipynb: committed unfilled and without
outputs, the same code (their docstrings and comments aside), each stub with the docstring the
checker's hint sends the student to; with the reference answers put in by this test (never shipped in
the notebooks), each runs top to bottom in a fresh kernel, every check cell passes, and no line of
what it prints is wider than the report's 100 columns."""

from __future__ import annotations

import ast
import inspect
import textwrap

import nbformat
import pytest
from conftest import ROOT
from exercise_answers import ReferenceFilter
from nbclient import NotebookClient
from test_notebook import CELL_TIMEOUT, kernel_spec, stdout_of  # noqa: F401 (kernel_spec is a fixture)

from mazelab.exercise import PARTS
from mazelab.exercise.report import WIDTH
from mazelab.exercise.template import catalogue

NOTEBOOKS = {"en": ROOT / "notebooks" / "exercise.ipynb", "uk": ROOT / "notebooks" / "exercise_uk.ipynb"}


def read(language: str) -> nbformat.NotebookNode:
    return nbformat.read(NOTEBOOKS[language], as_version=nbformat.NO_CONVERT)


def cell(notebook: nbformat.NotebookNode, cell_id: str) -> nbformat.NotebookNode:
    return next(c for c in notebook.cells if c.get("id") == cell_id)


def answer(part: str) -> str:
    """The reference answer to one part, as the top-level function the notebook's cell defines."""
    method = getattr(ReferenceFilter, "estimate_part" if part == "estimate" else part)
    return textwrap.dedent(inspect.getsource(method))


def code_without_words(source: str) -> str:
    """The code of a cell with its texts (docstrings, error messages), comments and report language
    (`lang=`) gone (ast drops the comments)."""
    tree = ast.parse(source)
    for node in ast.walk(tree):
        if isinstance(node, ast.Constant) and isinstance(node.value, str):
            node.value = ""
        if isinstance(node, ast.Call):
            node.keywords = [k for k in node.keywords if k.arg != "lang"]
    return ast.dump(tree)


@pytest.mark.parametrize("language", NOTEBOOKS)
def test_committed_notebook_is_unfilled_and_has_no_outputs(language):
    notebook = read(language)
    nbformat.validate(notebook)
    assert set(notebook.metadata) == {"kernelspec", "language_info"}
    for c in notebook.cells:
        assert not c.metadata
        if c.cell_type == "code":
            assert c.outputs == [] and c.execution_count is None
    for part in PARTS:
        assert "raise NotImplementedError" in cell(notebook, f"answer-{part}").source
        assert f'check_part("{part}", {part}' in cell(notebook, f"check-{part}").source


@pytest.mark.parametrize("language", NOTEBOOKS)
def test_each_stub_has_the_docstring_the_hint_names(language):
    """An unwritten part's hint says "write predict (see its docstring)": the stub has one."""
    for part in PARTS:
        (function,) = ast.parse(cell(read(language), f"answer-{part}").source).body
        assert function.name == part and len(ast.get_docstring(function) or "") > 40


def test_the_two_notebooks_hold_the_same_code():
    english, ukrainian = read("en"), read("uk")
    assert [c.id for c in english.cells] == [c.id for c in ukrainian.cells]
    for mine, theirs in zip(english.cells, ukrainian.cells, strict=True):
        if mine.cell_type == "code":
            assert code_without_words(mine.source) == code_without_words(theirs.source), mine.id
    intro = cell(ukrainian, "intro").source
    assert "гранулярний фільтр" in intro and "гранула" in intro


@pytest.mark.slow  # a kernel and the whole check, each notebook: about a minute (it still runs by default)
@pytest.mark.parametrize("language", NOTEBOOKS)
def test_notebook_with_the_reference_answers_passes_every_check(kernel_spec, tmp_path, language):  # noqa: F811
    notebook = read(language)
    for part in PARTS:
        cell(notebook, f"answer-{part}").source = answer(part)
    client = NotebookClient(
        notebook, kernel_name=kernel_spec, timeout=CELL_TIMEOUT, resources={"metadata": {"path": str(tmp_path)}}
    )
    client.execute()  # raises CellExecutionError, naming the cell, if any cell fails
    words = catalogue(language)
    passed, failed = words.gettext("pass"), words.gettext("FAIL")
    for part in PARTS:
        out = stdout_of(cell(notebook, f"check-{part}"))
        assert f"{part}" in out and passed in out and failed not in out, out
        assert max(map(len, out.splitlines())) <= WIDTH
    whole = stdout_of(cell(notebook, "check-whole"))
    assert words.gettext("All checks pass.") in whole and max(map(len, whole.splitlines())) <= WIDTH, whole
    if language == "uk":  # the report speaks the notebook's language
        assert "частина" in whole and "що вийшло" in whole and "весь фільтр" in whole, whole
