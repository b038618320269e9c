"""What the commands share: the drawing and recovery options, output-path checks, list parsing, and
the one-line errors and warnings of the command line."""

from __future__ import annotations

import os
import re
from pathlib import Path
from typing import Annotated, Any

import typer

from mazelab.atomic import NameTakenError, NotRegularFileError, output_target
from mazelab.checks import check_seed
from mazelab.experiments.tables import pyplot
from mazelab.viz.style import DEFAULT_MAX_DRAWN
from mazelab.viz.targets import Visualization

DEFAULT_SIGMA, DEFAULT_DELTA = 0.3, 0.5


# Where a run is drawn: these options sit on every command that runs filters (the filters' own options
# are in mazelab.cli.filter_options, read from their declarations).
ViewerOption = Annotated[bool, typer.Option("--viewer", help="the native viewer (default with a display)")]
RrdOption = Annotated[Path | None, typer.Option("--rrd", help="save the recording to this .rrd file")]
WebOption = Annotated[bool, typer.Option("--web", help="serve the web viewer on 127.0.0.1")]
NoVizOption = Annotated[bool, typer.Option("--no-viz", help="draw nothing")]
MaxDrawnOption = Annotated[int, typer.Option("--max-drawn", min=1, help="most particles drawn a step")]


def visualization(
    viewer: bool, rrd: Path | None, web: bool, no_viz: bool, max_drawn: int = DEFAULT_MAX_DRAWN, force: bool = True
) -> Any:
    """The `visualize` argument of run_model for the command-line options (see draw.py); an --rrd file
    replaces an existing one only with `force`."""
    if sum([viewer, rrd is not None, web, no_viz]) > 1:
        raise UserError("choose one of --viewer, --rrd, --web and --no-viz")
    if no_viz:
        return False
    if rrd is not None and rrd.suffix.lower() != ".rrd":
        raise UserError(f"--rrd {rrd}: a recording is an .rrd file (e.g. --rrd {rrd.with_suffix('.rrd')})")
    target = rrd if rrd is not None else "viewer" if viewer else "web" if web else True
    return Visualization(target, max_drawn, replace=force)


class UserError(Exception):
    """An input problem reported as one line on stderr with exit code 2."""


def check_output_path(path: Path, force: bool) -> None:
    """Refuse to overwrite an existing file (or a symlink, dangling or not) without --force, anything
    but a regular file with or without it, or to write into a missing folder. (The write itself checks
    again: without --force it creates the name exclusively, see mazelab.atomic.)"""
    if path.is_dir() and not path.is_symlink():
        raise UserError(f"{path} is a folder: name a file in it (e.g. {path}/NAME)")
    try:
        output_target(path, force)
    except NameTakenError as error:
        raise UserError(f"{path} exists; use --force to replace it" if path.exists() else str(error)) from None
    except NotRegularFileError as error:
        raise UserError(str(error).removeprefix("cannot write ")) from None
    if not path.parent.exists():
        raise UserError(f"{path.parent} does not exist: cannot write {path.name} there")
    if not os.access(path.parent, os.W_OK):
        raise UserError(f"{path.parent} is not writable: cannot write {path.name} there")
    if path.is_dir():
        raise UserError(f"{path} is a folder, not a file")


def seed_option(value: int | None) -> int | None:
    """A --seed: a whole number in [0, 2**128) (typer names the option in its one-line error)."""
    if value is not None:
        try:
            check_seed("a seed", value)
        except ValueError as error:
            raise typer.BadParameter(str(error)) from None
    return value


def parse_list(text: str, kind: type, option: str) -> list:
    """'0.2,0.4' -> [0.2, 0.4] (of `kind`), or a one-line error naming the option; '0,3' for a number
    is refused with what to write (a decimal comma: a list of 0 and 3 is no lab's value)."""
    if kind is float and re.fullmatch(r"\s*0,\d+\s*", text):
        decimal = text.strip().replace(",", ".")
        raise UserError(
            f"{option} {text.strip()}: the comma separates values (0 and {text.strip()[2:]}); "
            f"for one value write {decimal}, for a list {decimal},0.4"
        )
    try:
        values = [kind(part) for part in text.split(",") if part.strip()]
    except ValueError:
        raise UserError(f"{option} takes comma-separated {kind.__name__} values, got {text!r}") from None
    if not values:
        raise UserError(f"{option} is empty")
    return list(dict.fromkeys(values))


def check_outputs(csv_path: Path | None, plot: Path | None, force: bool, rrd: Path | None = None) -> None:
    """Check the output paths, and that matplotlib is there for --plot and writes its format, before
    any run starts."""
    for path in (csv_path, plot, rrd):
        if path is not None:
            check_output_path(path, force)
    if plot is not None:
        pyplot()
        from matplotlib.backend_bases import FigureCanvasBase

        formats = FigureCanvasBase.get_supported_filetypes()
        suffix = plot.suffix.lstrip(".").lower() or "png"
        if suffix not in formats:
            raise UserError(f"--plot {plot}: cannot draw .{suffix} files; use one of .{', .'.join(sorted(formats))}")


_warned: set[str] = set()


def warn_in_one_line(message: Warning | str, category: type[Warning], *_args: Any, **_kwargs: Any) -> None:
    """Warnings (e.g. sigma outside the lab's range) as one line on stderr, each once, no source lines."""
    if str(message) not in _warned:
        _warned.add(str(message))
        typer.echo(f"warning: {message}", err=True)


__all__ = [
    "DEFAULT_DELTA",
    "DEFAULT_SIGMA",
    "MaxDrawnOption",
    "NoVizOption",
    "RrdOption",
    "UserError",
    "ViewerOption",
    "WebOption",
    "check_output_path",
    "check_outputs",
    "parse_list",
    "seed_option",
    "visualization",
    "warn_in_one_line",
]
