"""--backend numpy|compiled: which implementation of the filters' hot parts a command runs on
(mazelab.backend). The option sets MAZELAB_BACKEND for the command (a study's worker processes inherit
it) and puts back what was there when the command ends. --threads N does the same with
MAZELAB_THREADS: the compiled backend's threads for one large run."""

from __future__ import annotations

import os
from typing import Annotated, Any

import typer

from mazelab.backend import ENVIRONMENT_VARIABLE, THREADS_VARIABLE, check_backend, check_threads
from mazelab.cli.options import UserError


def set_backend(ctx: typer.Context, value: str | None) -> str | None:
    """The option's callback: check the name (one line, exit 2, for a wrong one or for compiled without
    numba) and set MAZELAB_BACKEND until the command's context closes.

    Parameters
    ----------
    ctx : typer.Context
    value : str or None
        The name given, None without the option.

    Returns
    -------
    str or None
        The checked name.
    """
    if value is None or ctx.resilient_parsing:
        return value
    try:
        name = check_backend(value, "--backend")
    except ValueError as error:
        raise UserError(str(error)) from None
    _set_for_the_command(ctx, ENVIRONMENT_VARIABLE, name)
    return name


def set_threads(ctx: typer.Context, value: int | None) -> int | None:
    """--threads' callback: check the count (one line, exit 2, outside 1 to the machine's cores) and set
    MAZELAB_THREADS until the command's context closes.

    Parameters
    ----------
    ctx : typer.Context
    value : int or None
        The count given, None without the option.

    Returns
    -------
    int or None
        The checked count.
    """
    if value is None or ctx.resilient_parsing:
        return value
    try:
        count = check_threads(value, "--threads")
    except ValueError as error:
        raise UserError(str(error)) from None
    _set_for_the_command(ctx, THREADS_VARIABLE, str(count))
    return count


def _set_for_the_command(ctx: typer.Context, variable: str, value: str) -> None:
    """Set an environment variable, and put back what was there when the command's context closes."""
    before = os.environ.get(variable)
    os.environ[variable] = value

    def restore() -> None:
        if before is None:
            os.environ.pop(variable, None)
        else:
            os.environ[variable] = before

    ctx.call_on_close(restore)


def backend_option(hidden: bool = False) -> Any:
    """The --backend option's type (hidden where the command's help has no line to spare: it fills one
    screen, and MAZELAB_BACKEND does the same).

    Parameters
    ----------
    hidden : bool

    Returns
    -------
    typing.Annotated type for a typer parameter
    """
    return Annotated[
        str | None,
        typer.Option(
            "--backend",
            metavar="numpy|compiled",
            callback=set_backend,
            help="numpy or compiled (default: by the work)",
            show_default=False,
            hidden=hidden,
        ),
    ]


BackendOption = backend_option()
HiddenBackendOption = backend_option(hidden=True)
ThreadsOption = Annotated[
    int | None,
    typer.Option(
        "--threads",
        metavar="N",
        callback=set_threads,
        help="compiled: threads for one large run [default: 1]",
        show_default=False,
        hidden=True,  # an expert's option, documented in docs/speed.md: run --help stays one screen
    ),
]


__all__ = ["BackendOption", "HiddenBackendOption", "ThreadsOption", "backend_option", "set_backend", "set_threads"]
