"""How this program was started, so that the commands it prints can be pasted back as they are:
`uv run mazelab ...` under uv, `python main.py ...` for the script, `mazelab ...` when installed on
the PATH, `python -m mazelab ...` otherwise; and the command as typed (`main` keeps it), for the records
and the "Repeat this ..." lines."""

from __future__ import annotations

import contextlib
import os
import shlex
import shutil
import sys
from collections.abc import Mapping
from contextvars import ContextVar
from pathlib import Path

PROJECT_DIR = Path(__file__).resolve().parent.parent  # the clone (an editable install), where pyproject.toml is


def command_prefix(argv0: str | None = None, environ: Mapping[str, str] | None = None, cwd: Path | None = None) -> str:
    """The words that start this program again from the current folder, e.g. `uv run mazelab`.

    `uv run` sets the variable UV; outside the project's folder uv needs `--project CLONE` to find it.
    The script `main.py` is named as it was typed; the installed command is `mazelab` when that is the
    one on the PATH, else `python -m mazelab` with this interpreter."""
    argv0 = sys.argv[0] if argv0 is None else argv0
    environ = os.environ if environ is None else environ
    project = _uv_project(environ, cwd)
    uv = project is not None
    if Path(argv0).name == "main.py":
        return f"uv run {project}{shlex.quote(argv0)}" if uv else f"python {shlex.quote(argv0)}"
    if uv:
        return f"uv run {project}mazelab"
    on_path = shutil.which("mazelab", path=environ.get("PATH"))
    with contextlib.suppress(OSError):  # a path missing: not the same file
        if on_path is not None and (Path(argv0).name != "mazelab" or os.path.samefile(on_path, argv0)):
            return "mazelab"
    return f"{shlex.quote(sys.executable)} -m mazelab"


def python_prefix(environ: Mapping[str, str] | None = None, cwd: Path | None = None) -> str:
    """The words that run a Python file with the lab importable: `uv run [--project CLONE] python`
    under uv, else `python` (an activated environment or a pip install)."""
    project = _uv_project(os.environ if environ is None else environ, cwd)
    return "python" if project is None else f"uv run {project}python"


def _uv_project(environ: Mapping[str, str], cwd: Path | None) -> str | None:
    """Under `uv run` (which sets UV): "" in the clone's folder, else "--project CLONE " (uv needs it to
    find the project); None when not under uv."""
    if "UV" not in environ:
        return None
    cwd = Path.cwd() if cwd is None else cwd
    outside = (PROJECT_DIR / "pyproject.toml").is_file() and not cwd.resolve().is_relative_to(PROJECT_DIR)
    return f"--project {shlex.quote(str(PROJECT_DIR))} " if outside else ""


_ARGUMENTS: ContextVar[list[str] | None] = ContextVar("mazelab_arguments", default=None)


def remember_arguments(argv: list[str] | None) -> None:
    """Keep the command's arguments (those handed to main, else the process's) for the records."""
    _ARGUMENTS.set(list(argv) if argv is not None else sys.argv[1:])


def _typed() -> list[str]:
    """The command's arguments as typed (kept by `remember_arguments`, else the process's)."""
    return list(_ARGUMENTS.get() or sys.argv[1:])


def command_line() -> list[str]:
    """The command as typed: the program's name, then every argument."""
    program = Path(sys.argv[0]).name if sys.argv and sys.argv[0] else "mazelab"
    return ["mazelab" if program in ("", "-c", "__main__.py") else program, *_typed()]


def resume_command() -> str:
    """The command as typed, with --resume, written to be pasted back (see mazelab.invocation)."""
    arguments = _typed()
    return f"{command_prefix()} {shlex.join(arguments if '--resume' in arguments else [*arguments, '--resume'])}"


def repeat_command(seed: int | None, files: tuple[str, ...] = (), backend: str | None = None) -> str:
    """The command as typed with its seed given (`--seed S` set, or replaced) and the backend it ran on
    (`--backend B`, unless typed), to be pasted back: the same run or study again, bit for bit. Left out:
    --resume and --force (a resumed study repeats whole; --force would replace files unasked), and the
    options in `files` with their values (a file the run wrote, which the pasted command would find taken)."""
    tokens, kept, valued = iter(_typed()), [], ("--seed", *files)
    for token in tokens:
        if token in valued:
            next(tokens, None)  # and its value
        elif not token.startswith(tuple(f"{option}=" for option in valued)) and token not in ("--resume", "--force"):
            kept.append(token)
    if seed is not None:
        kept += ["--seed", str(seed)]
    if backend is not None and not any(token == "--backend" or token.startswith("--backend=") for token in kept):
        kept += ["--backend", backend]
    return f"{command_prefix()} {shlex.join(kept)}"
