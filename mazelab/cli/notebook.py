"""`mazelab notebook NAME`: a copy of one of the lab's notebooks (notebooks/NAME.ipynb) in the folder
you are in, and the command that opens it there.

A notebook is run from such a copy, never in the clone: running one writes its outputs into the file,
which would leave the clone changed (`git status`) and `git pull` refusing to update it. The copy's
outputs, and the scenario it saves beside itself, are yours.
"""

from __future__ import annotations

import importlib.util
import os
import shlex
import shutil
import sys
from pathlib import Path

import typer

from mazelab.atomic import write_atomically
from mazelab.cli.options import UserError, arg, check_outputs, opt
from mazelab.invocation import PROJECT_DIR, python_prefix

NOTEBOOKS_DIR = PROJECT_DIR / "notebooks"  # the lab's notebooks, in the clone (an editable install)


def jupyter_command(path: Path) -> str:
    """The command that opens the notebook `path` in JupyterLab from the folder it is in, in the lab's
    own environment (JupyterLab finds the inline viewer's front end only among its own packages).
    Under uv, or in the clone's environment that uv made (activated), the project's `jupyter` group;
    else `jupyter lab`, saying how to install JupyterLab into this very Python where it is missing:
    a bare `pip` may be another Python's, and an environment uv made has no pip of its own."""
    prefix = python_prefix()
    if not prefix.startswith("uv run") and Path(sys.prefix).resolve() == (PROJECT_DIR / ".venv").resolve():
        prefix = f"uv run --project {shlex.quote(str(PROJECT_DIR))} python"
    if prefix.startswith("uv run"):
        return f"{prefix.removesuffix(' python')} --group jupyter jupyter lab {path.name}"
    if importlib.util.find_spec("jupyterlab") is not None:
        return f"jupyter lab {path.name}"
    on_path = shutil.which("python")
    python = "python" if on_path and os.path.samefile(on_path, sys.executable) else shlex.quote(sys.executable)
    pip = f"{python} -m pip install" if importlib.util.find_spec("pip") else f"uv pip install --python {python}"
    return f"jupyter lab {path.name}  (JupyterLab is not installed here; install it first: {pip} jupyterlab)"


def notebook(
    name: arg(str, "NAME", "lab, lab_uk (in Ukrainian), exercise or exercise_uk"),
    force: opt(bool, "--force", help="replace a copy made before (and its outputs)") = False,
) -> None:
    """Copy the lab's notebook NAME (notebooks/NAME.ipynb) into the folder you are in, and say how to open
    it: run the notebooks from a copy in a folder of your own, never in the clone."""
    names = sorted(path.stem for path in NOTEBOOKS_DIR.glob("*.ipynb"))  # the lab's notebooks
    stem = name.removesuffix(".ipynb")
    if stem not in names:
        raise UserError(f"{name}: no such notebook; the lab's notebooks are {', '.join(names)}")
    here = Path.cwd()
    if here.resolve().is_relative_to(PROJECT_DIR):
        raise UserError(
            f"{here} is in the lab's clone, which git pull updates: copy the notebook into a folder of your "
            f"own (e.g. mkdir ~/maze-work && cd ~/maze-work, then the same command)"
        )
    target = here / f"{stem}.ipynb"
    check_outputs([("NAME", target)], force)
    write_atomically(target, (NOTEBOOKS_DIR / f"{stem}.ipynb").read_bytes(), replace=force)
    typer.echo(f"{target.name} copied here from the lab's notebooks; open it with:")
    typer.echo(jupyter_command(target))
