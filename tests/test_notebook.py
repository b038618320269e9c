"""notebooks/lab.ipynb and its Ukrainian twin lab_uk.ipynb: committed without outputs, the same code,
and each run top to bottom in a fresh kernel of this interpreter (nbclient, ipykernel) in a temporary
folder, without a display or a network."""

from __future__ import annotations

import ast
import base64
import importlib.util
import io
import json
import shlex
import sys
import tomllib
from pathlib import Path

import matplotlib.image
import nbformat
import numpy as np
import pytest
from conftest import ROOT
from nbclient import NotebookClient

from mazelab.cli.app import main
from mazelab.invocation import PROJECT_DIR
from mazelab.registry import described, rgb
from mazelab.scenario import load_scenario
from mazelab.viz.recording import notebook_viewer_installed

NOTEBOOKS = {"en": ROOT / "notebooks" / "lab.ipynb", "uk": ROOT / "notebooks" / "lab_uk.ipynb"}
# what step 12 prints when the three filters walked the same true path, in each notebook's language
SAME_PATH = {"en": "the same true path for all three: yes", "uk": "справжній шлях однаковий для всіх трьох: так"}
KERNEL_NAME = "mazelab-test"  # a kernel spec of our own (see `kernel_spec`): no other "python3" can shadow it
CELL_TIMEOUT = 180  # seconds per cell; the whole notebook takes about 23 s on two cores
WIDGET = "application/vnd.jupyter.widget-view+json"
# run after each figure cell of an executed lab: the texts of the figure just drawn (its `axes`): the tick
# labels, the title, the axis labels and the legend
FIGURE_PROBE = """import json
print(json.dumps([text.get_text() for text in [*axes.get_xticklabels(), *axes.get_yticklabels(), axes.title,
                  axes.xaxis.label, axes.yaxis.label, *axes.get_legend().get_texts()]], ensure_ascii=False))"""
FILTERS = ("SIRParticleFilter", "AuxiliaryParticleFilter", "RegularizedParticleFilter")  # the lab's three
# a curve's pixels in a figure: its colour within 2/255 per channel (a PNG's rounding), at least 50 of them
# (a line of 1.2 points over a figure 8 inches wide, or a study's markers, draw thousands)
COLOUR_TOLERANCE, LEAST_PIXELS = 2.5 / 255, 50


def read_notebook(language: str = "en") -> nbformat.NotebookNode:
    return nbformat.read(NOTEBOOKS[language], as_version=nbformat.NO_CONVERT)


def code_cells(notebook: nbformat.NotebookNode) -> list[nbformat.NotebookNode]:
    return [cell for cell in notebook.cells if cell.cell_type == "code"]


@pytest.mark.parametrize("language", NOTEBOOKS)
def test_committed_notebook_has_no_outputs(language):
    notebook = read_notebook(language)
    nbformat.validate(notebook)
    for cell in code_cells(notebook):
        assert cell.outputs == [], f"cell {cell.id} has outputs: strip them before committing"
        assert cell.execution_count is None, f"cell {cell.id} has an execution count: strip it before committing"
    # executing in Jupyter adds e.g. "widgets" (the viewer's state, megabytes); only these two belong
    assert set(notebook.metadata) == {"kernelspec", "language_info"}
    assert all(not cell.metadata for cell in notebook.cells), "cell metadata (collapsed, scrolled, ...) is noise"


@pytest.mark.parametrize("language", NOTEBOOKS)
def test_notebook_metadata_matches_the_supported_python(language):
    metadata = read_notebook(language).metadata
    requires = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["requires-python"]
    assert requires.startswith(">=")
    minimum = tuple(int(part) for part in requires.removeprefix(">=").split("."))
    declared = tuple(int(part) for part in metadata.language_info.version.split("."))
    assert metadata.language_info.name == "python"
    assert declared[: len(minimum)] >= minimum
    assert metadata.kernelspec.language == "python"
    assert metadata.kernelspec.name == "python3"


@pytest.fixture
def kernel_spec(tmp_path, monkeypatch) -> str:
    """A kernel spec that starts ipykernel on sys.executable (this very environment) with the inline
    matplotlib backend (figures become image/png outputs, whatever MPLBACKEND the tests run with).
    JUPYTER_PATH comes first in Jupyter's search; the kernel's state stays in tmp_path."""
    spec_dir = tmp_path / "jupyter" / "kernels" / KERNEL_NAME
    spec_dir.mkdir(parents=True)
    spec = {
        "argv": [sys.executable, "-m", "ipykernel_launcher", "-f", "{connection_file}"],
        "display_name": "maze lab tests",
        "language": "python",
        "env": {"MPLBACKEND": "module://matplotlib_inline.backend_inline"},
    }
    (spec_dir / "kernel.json").write_text(json.dumps(spec))
    monkeypatch.setenv("JUPYTER_PATH", str(tmp_path / "jupyter"))
    monkeypatch.setenv("JUPYTER_RUNTIME_DIR", str(tmp_path / "runtime"))
    monkeypatch.setenv("JUPYTER_PLATFORM_DIRS", "1")  # jupyter_core's own future default; silences its warning
    monkeypatch.setenv("IPYTHONDIR", str(tmp_path / "ipython"))
    for name in ("DISPLAY", "WAYLAND_DISPLAY"):  # no native viewer window, whatever the notebook asks for
        monkeypatch.delenv(name, raising=False)
    return KERNEL_NAME


def stdout_of(cell: nbformat.NotebookNode) -> str:
    return "".join(output.text for output in cell.outputs if output.output_type == "stream" and output.name == "stdout")


def code_without_words(source: str) -> str:
    """A cell's code with its strings and comments blanked (what a translation may change)."""
    lines = [line for line in source.splitlines() if not line.startswith("%")]  # IPython magics
    tree = ast.parse("\n".join(lines))
    for node in ast.walk(tree):
        if isinstance(node, ast.Constant) and isinstance(node.value, str):
            node.value = ""
        elif isinstance(node, ast.JoinedStr):
            node.values = [value for value in node.values if not isinstance(value, ast.Constant)]
    return ast.dump(tree)


def test_the_ukrainian_notebook_is_the_english_one_in_the_papers_words():
    english, ukrainian = read_notebook("en"), read_notebook("uk")
    assert [(c.id, c.cell_type) for c in ukrainian.cells] == [(c.id, c.cell_type) for c in english.cells]
    for en, uk in zip(code_cells(english), code_cells(ukrainian), strict=True):
        assert code_without_words(uk.source) == code_without_words(en.source), f"cell {uk.id}: not the same code"
    text = " ".join(cell.source for cell in ukrainian.cells if cell.cell_type == "markdown").lower()
    for term in ("гранул", "гранулярн", "станці", "лабіринт"):  # the paper's own terms
        assert term in text
    headings = [cell.source.splitlines()[0] for cell in ukrainian.cells if cell.source.startswith("## Крок ")]
    assert [int(h.split()[2].rstrip(":")) for h in headings] == list(range(1, 16))  # steps 1-14 and 15, in order


@pytest.mark.slow  # about 15 s each: a kernel, then the whole lab (it still runs by default)
def execute_lab(language: str, kernel_spec: str, workdir: Path) -> nbformat.NotebookNode:
    """The notebook run top to bottom in a fresh kernel, in `workdir`, with a last cell that prints the
    kernel's interpreter; raises CellExecutionError, naming the cell, if any cell fails."""
    notebook = read_notebook(language)
    for index in reversed([i for i, cell in enumerate(notebook.cells) if "plt.show()" in cell.source]):
        probe = nbformat.v4.new_code_cell(FIGURE_PROBE, id=f"test-figure-{index}")
        notebook.cells.insert(index + 1, probe)  # what the figure just drawn says, in words
    notebook.cells.append(nbformat.v4.new_code_cell("import sys\nprint(sys.executable)", id="test-probe"))
    workdir.mkdir()
    client = NotebookClient(
        notebook, kernel_name=kernel_spec, timeout=CELL_TIMEOUT, resources={"metadata": {"path": str(workdir)}}
    )
    client.execute()
    return notebook


def figure_texts(notebook: nbformat.NotebookNode) -> list[list[str]]:
    """The words of each figure an executed lab drew (FIGURE_PROBE's output after it)."""
    probes = [cell for cell in notebook.cells if cell.id.startswith("test-figure-")]
    return [json.loads(stdout_of(cell)) for cell in probes]


def test_notebook_runs_top_to_bottom_in_a_fresh_kernel(kernel_spec, tmp_path):
    """The English lab; the Ukrainian one runs once, in tests/test_notebook_uk.py, with these checks."""
    workdir = tmp_path / "work"
    notebook = execute_lab("en", kernel_spec, workdir)
    check_the_executed_lab(notebook, workdir, "en")
    for texts in figure_texts(notebook):  # the filters by their short names, as the viewer's tables say them
        assert {"SIR", "APF", "RPF"} <= set(texts) and not set(FILTERS) & set(texts), texts


def check_the_executed_lab(notebook: nbformat.NotebookNode, workdir: Path, language: str) -> None:
    """What an executed lab shows: no error, this interpreter, the two figures, the viewers, the scenario."""
    cells = code_cells(notebook)
    assert all(output.output_type != "error" for cell in cells for output in cell.outputs)
    assert stdout_of(cells[-1]).strip() == sys.executable  # the kernel ran in this environment

    figure_cells = [cell for cell in cells if "plt.show()" in cell.source]
    assert len(figure_cells) == 3  # lab steps 13, 14 and 15
    for cell in figure_cells:
        pngs = [output.data["image/png"] for output in cell.outputs if "image/png" in output.get("data", {})]
        assert len(pngs) == 1, f"cell {cell.id} drew no inline figure"
        image = matplotlib.image.imread(io.BytesIO(base64.b64decode(pngs[0])), format="png")
        assert image.shape[0] > 100 and image.shape[1] > 100
        for name in FILTERS:  # each filter drawn in its registry colour, as the viewer and the CLI draw it
            distance = np.abs(image[..., :3] - np.array(rgb(described(name).colour))).max(axis=-1)
            assert (distance < COLOUR_TOLERANCE).sum() >= LEAST_PIXELS, f"cell {cell.id}: no {name} in its colour"

    viewer_cells = [cell for cell in cells if "visualize=VIEWER" in cell.source]
    assert len(viewer_cells) == 2  # lab steps 1 and 9
    for cell in viewer_cells:
        widgets = [output for output in cell.outputs if WIDGET in output.get("data", {})]
        assert bool(widgets) == notebook_viewer_installed(), f"cell {cell.id}: inline viewer expected iff installed"

    # step 9 saved the scenario in the kernel's working folder, where steps 10-12 read it back
    scenario = load_scenario(workdir / "model_parameters.json")
    assert len(scenario.init_particles_pos) == 1500
    assert len(scenario.robot_actual_angles) == len(scenario.robot_measurements) == 200
    assert SAME_PATH[language] in "".join(stdout_of(cell) for cell in cells)
    assert sorted(path.name for path in workdir.iterdir()) == ["model_parameters.json"]  # no recordings left behind


def test_mazelab_notebook_copies_a_notebook_into_ones_own_folder_and_says_how_to_open_it(tmp_path, monkeypatch, capsys):
    """The notebooks are run from a copy in the student's folder: the clone stays as shipped."""
    monkeypatch.chdir(tmp_path)
    assert main(["notebook", "lab_uk"]) == 0
    out = capsys.readouterr().out.splitlines()
    assert (tmp_path / "lab_uk.ipynb").read_bytes() == NOTEBOOKS["uk"].read_bytes()
    assert out[-1].startswith(("uv run", "jupyter lab")) and "jupyter lab lab_uk.ipynb" in out[-1]
    assert main(["notebook", "lab_uk"]) == 2  # a copy with the student's outputs is never replaced unasked
    assert "exists; use --force" in capsys.readouterr().err
    assert main(["notebook", "lab.ipynb"]) == 0 and (tmp_path / "lab.ipynb").is_file()
    assert main(["notebook", "nope"]) == 2
    assert "the lab's notebooks are exercise, exercise_uk, lab, lab_uk" in capsys.readouterr().err
    monkeypatch.chdir(ROOT / "notebooks")
    before = sorted(path.name for path in (ROOT / "notebooks").iterdir())
    assert main(["notebook", "lab"]) == 2  # never into the clone
    assert "a folder of your own" in capsys.readouterr().err
    assert sorted(path.name for path in (ROOT / "notebooks").iterdir()) == before


def test_in_the_clones_activated_environment_the_notebook_opens_with_uv_not_pip(tmp_path, monkeypatch, capsys):
    """The clone's environment is made by uv, which puts no pip in it: `pip install jupyterlab` there
    ran another Python's pip. Activated (the command on the PATH, not under `uv run`), `mazelab notebook`
    says uv's command with the project's jupyter group, which installs JupyterLab into this environment."""
    if Path(sys.prefix).resolve() != (PROJECT_DIR / ".venv").resolve():
        pytest.skip("runs in the clone's own environment (.venv, made by `uv run`), not this one")
    monkeypatch.chdir(tmp_path)
    monkeypatch.delenv("UV", raising=False)
    assert main(["notebook", "lab"]) == 0
    line = capsys.readouterr().out.splitlines()[-1]
    assert line == f"uv run --project {shlex.quote(str(PROJECT_DIR))} --group jupyter jupyter lab lab.ipynb"


MISSING = "jupyter lab lab.ipynb  (JupyterLab is not installed here; install it first: {install} jupyterlab)"


@pytest.mark.parametrize(
    ("installed", "expected"),
    [
        ({"jupyterlab", "pip"}, "jupyter lab lab.ipynb"),
        ({"pip"}, MISSING.format(install="{python} -m pip install")),
        (set(), MISSING.format(install="uv pip install --python {python}")),
    ],
)
def test_in_another_environment_jupyterlab_is_installed_into_this_very_python(
    tmp_path, monkeypatch, capsys, installed, expected
):
    """A pip-made environment, or one uv made without pip: the install line names this interpreter
    (not a `pip` on the PATH, which may be another Python's), and uses uv's pip where there is no pip."""
    find_spec = importlib.util.find_spec

    def found(name, *args):
        if name in ("jupyterlab", "pip"):
            return object() if name in installed else None
        return find_spec(name, *args)

    monkeypatch.setattr(importlib.util, "find_spec", found)
    monkeypatch.setattr(sys, "prefix", str(tmp_path / "venv"))
    monkeypatch.delenv("UV", raising=False)
    monkeypatch.setenv("PATH", "")  # no `python` on the PATH: the interpreter by its path
    monkeypatch.chdir(tmp_path)
    assert main(["notebook", "lab"]) == 0
    line = capsys.readouterr().out.splitlines()[-1]
    assert line == expected.format(python=shlex.quote(sys.executable))
