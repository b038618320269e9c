"""What the commands share: the drawing and backend options, output-path checks (one file per output),
list parsing, the one-line errors and warnings of the command line and what turns a puzzling one into one a
student can act on (an option given to the wrong command, an option swallowed as another option's value,
the help's usage lines without typer's braces), a run's summary and progress lines. The filters' own
options are in mazelab.cli.filter_options, read from their declarations."""

from __future__ import annotations

import functools
import inspect
import os
import re
import shlex
import sys
import time
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Annotated, Any

import numpy as np
import typer
import typer.core

from mazelab.atomic import NameTakenError, NotRegularFileError, output_target
from mazelab.backend import ENVIRONMENT_VARIABLE, THREADS_VARIABLE, check_backend, check_threads
from mazelab.checks import check_seed
from mazelab.experiments.runs import FINAL_SHARE, final_error
from mazelab.experiments.tables import pyplot
from mazelab.invocation import command_prefix
from mazelab.maze import Maze
from mazelab.robot import Robot
from mazelab.simulation import RunResult
from mazelab.viz.style import DEFAULT_MAX_DRAWN
from mazelab.viz.targets import Visualization

DEFAULT_SIGMA, DEFAULT_DELTA = 0.3, 0.5


class UserError(Exception):
    """An input problem reported as one line on stderr with exit code 2."""


def opt(kind: Any, *flags: str, **typer_options: Any) -> Any:
    """A typer option's annotated type: `opt(int | None, "--runs", help=...)`."""
    return Annotated[kind, typer.Option(*flags, **typer_options)]


def with_parameters(
    into: str, parameters: Mapping[str, tuple[Any, Any]], convert: Callable[[dict[str, Any]], Any] = dict
) -> Callable[[Callable[..., Any]], Callable[..., Any]]:
    """Add a group of typer parameters (name -> (Annotated type with its typer.Option, default)) to a
    command; the command receives their values together as its parameter `into` (a dict, or what
    `convert` makes of it). The options several commands share are declared once this way."""

    def decorate(command: Callable[..., Any]) -> Callable[..., Any]:
        signature = inspect.signature(command, eval_str=True)
        own = [p for p in signature.parameters.values() if p.name != into]
        keyword = inspect.Parameter.KEYWORD_ONLY
        added = [
            inspect.Parameter(name, keyword, default=default, annotation=annotation)
            for name, (annotation, default) in parameters.items()
        ]

        @functools.wraps(command)
        def wrapper(*args: Any, **kwargs: Any) -> Any:
            given = {name: kwargs.pop(name) for name in parameters if name in kwargs}
            return command(*args, **kwargs, **{into: convert(given)})

        wrapper.__signature__ = signature.replace(parameters=[*own, *added])  # type: ignore[attr-defined]
        wrapper.__annotations__ = {p.name: p.annotation for p in [*own, *added]}
        return wrapper

    return decorate


# Where a run is drawn: these options sit on every command that runs filters (`with_drawing`).
DRAWING: dict[str, tuple[Any, Any]] = {
    "viewer": (Annotated[bool, typer.Option("--viewer", help="the native viewer (default with a display)")], False),
    "rrd": (Annotated[Path | None, typer.Option("--rrd", help="save the recording to this .rrd file")], None),
    "web": (Annotated[bool, typer.Option("--web", help="serve the web viewer on 127.0.0.1")], False),
    "no_viz": (Annotated[bool, typer.Option("--no-viz", help="draw nothing")], False),
    "max_drawn": (
        Annotated[int, typer.Option("--max-drawn", min=1, help="most particles drawn a step")],
        DEFAULT_MAX_DRAWN,
    ),
}
with_drawing = with_parameters("drawing", DRAWING)


def visualization(
    viewer: bool = False,
    rrd: Path | None = None,
    web: bool = False,
    no_viz: bool = False,
    max_drawn: int = DEFAULT_MAX_DRAWN,
    force: bool = True,
) -> Any:
    """The `visualize` argument of run_model for the drawing options (see draw.py); an --rrd file
    replaces an existing one only with `force`."""
    if sum([viewer, rrd is not None, web, no_viz]) > 1:
        raise UserError("choose one of --viewer, --rrd, --web and --no-viz")
    if no_viz:
        return False
    if rrd is not None and rrd.suffix.lower() != ".rrd":
        raise UserError(f"--rrd {rrd}: a recording is an .rrd file (e.g. --rrd {rrd.with_suffix('.rrd')})")
    target = rrd if rrd is not None else "viewer" if viewer else "web" if web else True
    return Visualization(target, max_drawn, replace=force)


# -- --backend and --threads: set MAZELAB_BACKEND / MAZELAB_THREADS for the command (its worker
# processes inherit them), and put back what was there when the command ends -------------------------
def environment_option(variable: str, check: Callable[[Any, str], Any], flag: str) -> Callable[..., Any]:
    """The callback of an option that sets `variable` for the command: the value checked by `check` (one
    line, exit 2: a wrong backend, compiled without numba, threads outside 1 to the machine's cores), the
    variable set until the command's context closes and then put back."""

    def callback(ctx: typer.Context, value: Any) -> Any:
        if value is None or ctx.resilient_parsing:
            return value
        try:
            value = check(value, flag)
        except ValueError as error:
            raise UserError(str(error)) from None
        before = os.environ.get(variable)
        os.environ[variable] = str(value)
        ctx.call_on_close(lambda: os.environ.pop(variable) if before is None else os.environ.update({variable: before}))
        return value

    return callback


BackendOption = opt(str | None, "--backend", metavar="NAME", show_default=False,
                    callback=environment_option(ENVIRONMENT_VARIABLE, check_backend, "--backend"),
                    help="numpy or compiled [default: by the work]")  # fmt: skip
ThreadsOption = opt(int | None, "--threads", metavar="N", show_default=False,
                    callback=environment_option(THREADS_VARIABLE, check_threads, "--threads"),
                    help="compiled: threads for a large run [default: the cores]")  # fmt: skip


# -- outputs --------------------------------------------------------------------------------------------
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


def file_identity(path: Path) -> tuple[str, tuple[int, int] | None]:
    """(the path with every link resolved, (device, inode) of the file if it exists)."""
    resolved = os.path.realpath(path)
    try:
        status = os.stat(resolved)
    except OSError:  # missing (the usual case for a new output), a loop, no permission
        return resolved, None
    return resolved, (status.st_dev, status.st_ino)


def check_one_file_each(outputs: Sequence[tuple[str, Path | None]]) -> None:
    """Refuse (one line) the first two of `outputs`, (what the user calls it, its path or None), that
    are one file: the same path once links are resolved (`./s.csv` and `s.csv`, a symlink to another
    output), or two names of one existing file (a hard link). Checked before any run."""
    given = [(name, Path(path), file_identity(Path(path))) for name, path in outputs if path is not None]
    for i, (name_a, path_a, (real_a, inode_a)) in enumerate(given):
        for name_b, path_b, (real_b, inode_b) in given[i + 1 :]:
            if real_a == real_b or (inode_a is not None and inode_a == inode_b):
                same = f"{path_a}" if str(path_a) == str(path_b) else f"{path_a} and {path_b}"
                raise UserError(f"{name_a} and {name_b} are one file ({same}): give each output a name of its own")


# -- values ---------------------------------------------------------------------------------------------
def seed_option(value: int | None) -> int | None:
    """A --seed: a whole number in [0, 2**128) (typer names the option in its one-line error)."""
    if value is not None:
        try:
            check_seed("a seed", value)
        except ValueError as error:
            raise typer.BadParameter(str(error)) from None
    return value


def parse_list(text: str | None, kind: type, option: str) -> list | None:
    """'0.2,0.4' -> [0.2, 0.4] (of `kind`; None stays None), or a one-line error naming the option;
    '0,3' for a number is refused with what to write (a list of 0 and 3 is no lab's value)."""
    if text is None:
        return None
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


_warned: set[str] = set()


def warn_in_one_line(message: Warning | str, category: type[Warning], *_args: Any, **_kwargs: Any) -> None:
    """Warnings (e.g. sigma outside the lab's range) as one line on stderr, each once, no source lines."""
    if str(message) not in _warned:
        _warned.add(str(message))
        typer.echo(f"warning: {message}", err=True)


# -- errors that name the fix ----------------------------------------------------------------------------
def plain_usage_names() -> None:
    """Usage lines name a required argument as `SCENARIO`, not typer's `{SCENARIO}` (which reads as
    a placeholder to type with its braces)."""
    argument = typer.core.TyperArgument
    if hasattr(argument, "_usage_display_name"):

        def usage_name(self: Any) -> str:
            name = self.display_name_raw if self.required else f"[{self.display_name_raw}]"
            return name + ("..." if self.nargs != 1 else "")

        argument._usage_display_name = usage_name


def commands_of(group: Any) -> dict[str, Any]:
    """The subcommands of a click group, by name (the group's own, one level down for groups)."""
    return dict(getattr(group, "commands", {}))


def option_elsewhere(error: Exception, group: Any, argv: Sequence[str] = ()) -> str:
    """For "No such option" at the top level: the commands that take that option, and the command to
    type instead (`uv run main.py --seed 1` means `run --seed 1`); '' when there is nothing to add."""
    name = getattr(error, "option_name", None)
    ctx = getattr(error, "ctx", None)
    if not name or ctx is None or ctx.command is not group:
        return ""
    takers = [
        command
        for command, cmd in commands_of(group).items()
        if any(name in param.opts for param in getattr(cmd, "params", []))
    ]
    if not takers:
        return ""
    first = "run" if "run" in takers else takers[0]
    given = shlex.join(argv) if argv else f"{name} ..."
    return f"; {name} is an option of {', '.join(takers)}: {command_prefix()} {first} {given}"


# what to type for a command's missing argument
ARGUMENT_EXAMPLES = {
    "compare": "compare paper_5x5 (a shipped scenario, or a .json saved by run --save-scenario FILE.json)",
    "view": "view recordings/FILE.rrd",
    "new": "exercise new my_exercise",
    "check": "exercise check my_exercise/my_filter.py",
    "show": "maze show paper_5x5",
}


def usage_hint(error: Exception, argv: Sequence[str] = ()) -> str:
    """What to add to typer's usage errors so that they name the fix: a decimal comma ("write 0.3"), a
    list given as several arguments ("--sigma 0.2,0.4"), a missing argument (an example); '' else."""
    format_message = getattr(error, "format_message", None)
    message = format_message() if callable(format_message) else str(error)
    args = list(argv)
    name = getattr(getattr(error, "param", None), "opts", None)
    if name and "valid number" in message:
        value = _value_of(args, name)
        if value is not None and re.fullmatch(r"-?\d+,\d+", value.strip()):
            return f"; write {value.strip().replace(',', '.')} (a decimal point, not a comma)"
    extra = re.search(r"unexpected extra argument(?:s|\(s\))? \((.+)\)", message)
    if extra:
        first = extra.group(1).split()[0]
        at = args.index(first) if first in args else -1
        if at >= 2 and args[at - 2].startswith("--"):
            return f"; a list is one argument, comma-separated: {args[at - 2]} {args[at - 1]},{first}"
    if "Missing argument" in message or "Missing parameter" in message:
        command = getattr(getattr(error, "ctx", None), "info_name", None)
        if command in ARGUMENT_EXAMPLES:
            return f"; e.g. {command_prefix()} {ARGUMENT_EXAMPLES[command]}"
    return ""


def _value_of(args: list[str], names: Sequence[str]) -> str | None:
    """The value given to an option in argv (`--sigma 0,3` or `--sigma=0,3`), or None."""
    for index, token in enumerate(args):
        for name in names:
            if token == name and index + 1 < len(args):
                return args[index + 1]
            if token.startswith(name + "="):
                return token[len(name) + 1 :]
    return None


def refuse_option_as_value(argv: Sequence[str], group: Any) -> None:
    """`run --filter --no-viz` would take `--no-viz` as the filter's name: refuse an option that takes a
    value when what follows it is another option of the same command."""
    argv = list(argv)
    command = group
    for index, token in enumerate(argv):
        sub = commands_of(command).get(token)
        if sub is not None:
            command = sub
            continue
        known = {opt for param in getattr(command, "params", []) for opt in param.opts}
        param = next((p for p in getattr(command, "params", []) if token in p.opts), None)
        if param is None or getattr(param, "is_flag", True) or index + 1 >= len(argv):
            continue
        following = argv[index + 1]
        if following in known or following.split("=", 1)[0] in known:
            raise UserError(f"{token} needs a value, got the option {following}")


# -- a run's summary and progress --------------------------------------------------------------------
def report_run(result: RunResult) -> None:
    """A short report of a run: the last step's error, the last-20% error (the mean error over the last
    20% of the steps, what compare and study report), the convergence step and the seed; the same text for
    the same seed (timings, which vary, are compare's and bench's)."""
    errors = result.errors
    converged = result.converged_at
    when = f"converged at step {converged} (error < 0.5 from then on)" if converged else "not converged"
    typer.echo(
        f"{result.filter_name}: last-step error {errors[-1]:.3f}, last-{FINAL_SHARE:.0%} error "
        f"{final_error(errors):.3f}; {when}; seed {result.seed}"
    )


def progress_printer(steps: int, every: int = 20) -> Any:
    """A per-step callback that prints the error every `every` steps."""

    def report(k: int, robot: Robot, filt: Any) -> None:
        if k % every == 0 or k == steps:
            error = float(np.hypot(*(filt.estimate - np.array(robot.position))))
            state = "confident" if filt.is_confident else "searching"
            typer.echo(f"  step {k:4d}/{steps}: error {error:6.3f}  ({state})")

    return report


LOOKUP_PROGRESS_CELLS = 2**18  # a nearest-station table this large takes seconds: say so while building it
GENERATE_PROGRESS_CELLS = 2**18  # generating a maze this large takes seconds (512 x 512)


def prepare_world(world: Maze, min_cells: int = LOOKUP_PROGRESS_CELLS) -> Maze:
    """Build a large maze's nearest-station table up front, with a progress line on stderr (a 1000 x
    1000 maze takes tens of seconds); a small maze's table is built on first use, silently."""
    if world.lookup_cells >= min_cells and not world.has_lookup:
        world.prepare(ProgressLine(f"building the nearest-station table of {world.source}"))
    return world


def generation_progress(rows: int, columns: int) -> ProgressLine | None:
    """A progress line for generating a large maze (None for a small one, made in a blink)."""
    return ProgressLine(f"generating a {rows}x{columns} maze") if rows * columns >= GENERATE_PROGRESS_CELLS else None


class ProgressLine:
    """progress(done, total) as one line on stderr: redrawn in place on a terminal, else a line at the
    start and one at the end (a log file gets no carriage returns)."""

    def __init__(self, what: str):
        self.what = what
        self.started = time.perf_counter()
        self.shown = -1  # the last percentage drawn
        self.terminal = sys.stderr.isatty()
        typer.echo(f"{what} ...", err=True, nl=not self.terminal)

    def __call__(self, done: int, total: int) -> None:
        percent = 100 * done // max(total, 1)
        if done == total:
            seconds = time.perf_counter() - self.started
            start = "\r" if self.terminal else ""
            typer.echo(f"{start}{self.what}: done in {seconds:.1f} s", err=True)
        elif self.terminal and percent != self.shown:
            typer.echo(f"\r{self.what}: {percent}%", err=True, nl=False)
        self.shown = percent
