"""--backend numpy|compiled: which implementation of the filters' hot parts a command runs on
(mazelab.backend). The option sets MAZELAB_BACKEND for the command (a study's worker processes inherit
it) and puts back what was there when the command ends."""

from __future__ import annotations

import os
from typing import Annotated, Any

import typer

from mazelab.backend import ENVIRONMENT_VARIABLE, check_backend
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
    before = os.environ.get(ENVIRONMENT_VARIABLE)
    os.environ[ENVIRONMENT_VARIABLE] = name

    def restore() -> None:
        if before is None:
            os.environ.pop(ENVIRONMENT_VARIABLE, None)
        else:
            os.environ[ENVIRONMENT_VARIABLE] = before

    ctx.call_on_close(restore)
    return name


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
            help="numpy or compiled (default: compiled with numba)",
            show_default=False,
            hidden=hidden,
        ),
    ]


BackendOption = backend_option()
HiddenBackendOption = backend_option(hidden=True)


__all__ = ["BackendOption", "HiddenBackendOption", "backend_option", "set_backend"]
