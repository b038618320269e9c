"""`mazelab notebook NAME`: a copy of one of the lab's notebooks (notebooks/NAME.ipynb) in the folder
you are in, and the command that opens it there.

A notebook is run from such a copy, never in the clone: running one writes its outputs into the file,
which would leave the clone changed (`git status`) and `git pull` refusing to update it. The copy's
outputs, and the scenario it saves beside itself, are yours.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from mazelab.atomic import write_bytes_atomically
from mazelab.cli.options import UserError, check_output_path
from mazelab.invocation import PROJECT_DIR, python_prefix

NOTEBOOKS_DIR = PROJECT_DIR / "notebooks"  # the lab's notebooks, in the clone (an editable install)


def shipped_notebooks() -> list[str]:
    """The names of the lab's notebooks (file names without .ipynb), sorted."""
    return sorted(path.stem for path in NOTEBOOKS_DIR.glob("*.ipynb"))


def jupyter_command(path: Path) -> str:
    """The command that opens the notebook `path` in JupyterLab from the folder it is in: the project's
    `jupyter` group under uv (JupyterLab in the project's own environment, where the inline viewer's
    front end is), else the environment's own `jupyter`."""
    prefix = python_prefix()
    if prefix.startswith("uv run"):
        return f"{prefix.removesuffix(' python')} --group jupyter jupyter lab {path.name}"
    return f"jupyter lab {path.name}  (pip install jupyterlab, if it is missing)"


def notebook(
    name: Annotated[
        str,
        typer.Argument(metavar="NAME", help="lab, lab_uk (in Ukrainian), exercise or exercise_uk", show_default=False),
    ],
    force: Annotated[bool, typer.Option("--force", help="replace a copy made before (and its outputs)")] = False,
) -> None:
    """Copy the lab's notebook NAME (notebooks/NAME.ipynb) into the folder you are in, and say how to open
    it: run the notebooks from a copy in a folder of your own, never in the clone."""
    names = shipped_notebooks()
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
    check_output_path(target, force)
    write_bytes_atomically(target, (NOTEBOOKS_DIR / f"{stem}.ipynb").read_bytes(), replace=force)
    typer.echo(f"{target.name} copied here from the lab's notebooks; open it with:")
    typer.echo(jupyter_command(target))


__all__ = ["NOTEBOOKS_DIR", "jupyter_command", "notebook", "shipped_notebooks"]
