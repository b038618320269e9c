"""`mazelab exercise autograder OUT.zip`: Gradescope's bundle. Its setup.sh is checked for what it
installs (nothing is downloaded here); its run_autograder runs in a simulated /autograder tree (a root
given in the environment) against this checkout, for an honest submission, a missing one and one
that does not import: each gets a results.json Gradescope can read."""

from __future__ import annotations

import io
import json
import os
import stat
import subprocess
import sys
import zipfile

import numpy
import pytest
from exercise_answers import write_submission

from mazelab import __version__
from mazelab.cli.app import main
from mazelab.exercise.template import ROOT, lab_files

KEY = "0123456789abcdef0123456789abcdef"


@pytest.fixture(scope="module")
def bundle(tmp_path_factory):
    folder = tmp_path_factory.mktemp("bundle")
    (folder / "grading.key").write_text(KEY + "\n")
    zipped = str(folder / "autograder.zip")
    assert main(["exercise", "autograder", zipped, "--key", str(folder / "grading.key"), "--timeout", "30"]) == 0
    with zipfile.ZipFile(folder / "autograder.zip") as archive:
        archive.extractall(folder / "source")
        modes = {info.filename: info.external_attr >> 16 for info in archive.infolist()}
    for name in ("setup.sh", "run_autograder"):
        (folder / "source" / name).chmod(modes[name] & 0o777)
    return folder, modes


def test_the_bundle_carries_this_lab_and_a_setup_that_installs_it_with_the_sandbox(bundle):
    folder, modes = bundle
    source = folder / "source"
    assert stat.S_IMODE(modes["setup.sh"]) == 0o755 and stat.S_IMODE(modes["run_autograder"]) == 0o755
    setup = (source / "setup.sh").read_text()
    assert "apt-get install" in setup and "bubblewrap" in setup
    assert "cd /autograder/source/lab" in setup and "uv sync --frozen --no-dev" in setup and __version__ in setup
    assert (source / "grading.key").read_text().strip() == KEY and stat.S_IMODE(modes["grading.key"]) == 0o600
    for name in lab_files():
        assert (source / "lab" / name).read_bytes() == (ROOT / name).read_bytes(), name
    assert f'version = "{__version__}"' in (source / "lab" / "pyproject.toml").read_text()
    assert (source / "lab" / "mazelab" / "exercise" / "locale" / "uk.po").is_file()
    assert not (source / "lab" / "tests").exists()  # the test answers stay in the repository
    assert "/autograder/submission/my_filter.py" in (source / "run_autograder").read_text().replace(
        "$root", "/autograder"
    )


@pytest.mark.parametrize("submission", ["honest", "missing", "does not import"])
def test_run_autograder_writes_results_json_in_a_simulated_tree(bundle, tmp_path, submission):
    folder, _ = bundle
    root = tmp_path / "autograder"
    (root / "submission").mkdir(parents=True)
    if submission == "honest":
        write_submission(root / "submission" / "my_filter.py")
    elif submission == "does not import":
        (root / "submission" / "my_filter.py").write_text("import mazelab.filters\n")
    environment = {
        **os.environ,
        "MAZELAB_AUTOGRADER_ROOT": str(root),
        "MAZELAB_COMMAND": f"{sys.executable} -m mazelab",
    }
    done = subprocess.run(
        ["bash", str(folder / "source" / "run_autograder")],
        env=environment,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert done.returncode == 0, done.stderr
    results = json.loads((root / "results" / "results.json").read_text())
    assert KEY not in json.dumps(results) and "seed" not in json.dumps(results.get("extra_data", {}))
    if submission == "honest":
        assert results["score"] == 5.0 and "inputs from the grader's secret key" in results["output"], results["output"]
    else:
        reason = "no such file" if submission == "missing" else "No module named 'mazelab.filters'"
        assert results["score"] == 0.0 and reason in results["output"] and len(results["tests"]) == 5


def test_the_bundle_is_made_from_an_install_without_uv_lock(tmp_path, monkeypatch):
    """Installed with pip from a clone (no uv.lock): the bundle pins the dependencies installed here in
    requirements.txt, and setup.sh installs them with the lab."""
    from mazelab.exercise import template as autograder

    for name in lab_files():
        if name.name != "uv.lock":
            (tmp_path / name).parent.mkdir(parents=True, exist_ok=True)
            (tmp_path / name).write_bytes((ROOT / name).read_bytes())
    monkeypatch.setattr(autograder, "ROOT", tmp_path)
    with zipfile.ZipFile(io.BytesIO(autograder.bundle_bytes(bytes(16)))) as archive:
        names = set(archive.namelist())
        pinned = archive.read("lab/requirements.txt").decode().splitlines()
        setup = archive.read("setup.sh").decode()
    assert "lab/uv.lock" not in names and "lab/pyproject.toml" in names
    assert f"numpy=={numpy.__version__}" in pinned and all("==" in line for line in pinned)
    assert "uv pip install --python .venv/bin/python -r requirements.txt ." in setup
    (tmp_path / "pyproject.toml").unlink()
    with pytest.raises(autograder.BundleError, match=r"pyproject\.toml missing"):
        autograder.bundle_bytes(bytes(16))
