"""What the records of the command line need: the command as typed (`main` keeps it) and
`mazelab --version`."""

from __future__ import annotations

import shlex
import sys
from contextvars import ContextVar
from pathlib import Path

import typer

from mazelab.experiments.record import package_version, program_versions
from mazelab.invocation import command_prefix

_ARGUMENTS: ContextVar[list[str] | None] = ContextVar("mazelab_arguments", default=None)


def remember_arguments(argv: list[str] | None) -> None:
    """Keep the command's arguments (those handed to main, else the process's) for the records."""
    _ARGUMENTS.set(list(argv) if argv is not None else sys.argv[1:])


def command_line() -> list[str]:
    """The command as typed: the program's name, then every argument."""
    arguments = _ARGUMENTS.get()
    program = Path(sys.argv[0]).name if sys.argv and sys.argv[0] else "mazelab"
    return ["mazelab" if program in ("", "-c", "__main__.py") else program, *(arguments or sys.argv[1:])]


def resume_command() -> str:
    """The command as typed, with --resume, written to be pasted back (see mazelab.invocation)."""
    arguments = list(_ARGUMENTS.get() or sys.argv[1:])
    if "--resume" not in arguments:
        arguments.append("--resume")
    return f"{command_prefix()} {shlex.join(arguments)}"


def repeat_command(
    seed: int | None, drop: tuple[str, ...] = ("--resume",), drop_with_value: tuple[str, ...] = (),
    backend: str | None = None,
) -> str:  # fmt: skip
    """The command as typed with its seed given (`--seed S` set, or replaced) and the backend it ran on
    (`--backend B`, unless typed), to be pasted back: the same run or study again, bit for bit. Flags in
    `drop` are left out (a resumed study repeats whole), and so are the options in `drop_with_value` with
    their values (a file the run wrote, which the pasted command would find taken)."""
    arguments, kept, skip = list(_ARGUMENTS.get() or sys.argv[1:]), [], False
    valued = ("--seed", *drop_with_value)
    for token in arguments:
        if skip:
            skip = False
            continue
        if token in valued:
            skip = True
            continue
        if token.startswith(tuple(f"{option}=" for option in valued)) or token in drop:
            continue
        kept.append(token)
    if seed is not None:
        kept += ["--seed", str(seed)]
    if backend is not None and not any(token == "--backend" or token.startswith("--backend=") for token in kept):
        kept += ["--backend", backend]
    return f"{command_prefix()} {shlex.join(kept)}"


def show_version(value: bool) -> None:
    """--version: the program's, its git commit (if any), numpy's and Python's; then exit."""
    if value:
        versions = program_versions()
        commit = f" (git {versions['git_commit']})" if versions["git_commit"] else ""
        typer.echo(f"mazelab {package_version()}{commit}, numpy {versions['numpy']}, Python {versions['python']}")
        raise typer.Exit()


__all__ = [
    "command_line",
    "remember_arguments",
    "repeat_command",
    "resume_command",
    "show_version",
]
