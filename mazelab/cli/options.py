"""What the commands share: the drawing, backend and output options and their checks, list parsing,
filter names, the line that repeats a command, and the filters' options on the command line, read from
each filter's declaration (mazelab.declaration): the named flags generated from `Option.flag`
(`with_option_flags`) and `--option NAME=VALUE` (`given_options`), so that a declared option is taken by
every command that runs filters."""

from __future__ import annotations

import contextlib
import functools
import inspect
import os
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Annotated, Any

import typer

from mazelab.atomic import NameTakenError, NotRegularFileError, output_target
from mazelab.backend import ENVIRONMENT_VARIABLE, THREADS_VARIABLE, check_backend, check_threads
from mazelab.checks import check_seed
from mazelab.declaration import Option, decimal_comma, not_taken, parse_flag, scoped
from mazelab.experiments.study import declared_option
from mazelab.experiments.tables import check_trace_path, pyplot
from mazelab.invocation import repeat_command
from mazelab.registry import SHIPPED, filter_entry, is_plugin_spec, resolve_filter
from mazelab.viz.recording import Visualization
from mazelab.viz.style import DEFAULT_MAX_DRAWN


class UserError(Exception):
    """An input problem reported as one line on stderr with exit code 2."""


def opt(kind: Any, *flags: str, **typer_options: Any) -> Any:
    """A typer option's annotated type: `opt(int | None, "--runs", help=...)`."""
    return Annotated[kind, typer.Option(*flags, **typer_options)]


def arg(kind: Any, metavar: str, help: str) -> Any:
    """A typer argument's annotated type, shown as `metavar` without a default: `arg(Path, "FILE", help=...)`."""
    return Annotated[kind, typer.Argument(metavar=metavar, help=help, show_default=False)]


# options that several commands take, with the same meaning
Force = opt(bool, "--force", help="replace existing output files")
KidnapAt = opt(int | None, min=1, help="carry the robot elsewhere at this step")


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
    "viewer": (opt(bool, "--viewer", help="the native viewer (default with a display)"), False),
    "rrd": (opt(Path | None, "--rrd", help="save the recording to this .rrd file"), None),
    "web": (opt(bool, "--web", help="serve the web viewer on 127.0.0.1"), False),
    "no_viz": (opt(bool, "--no-viz", help="draw nothing"), False),
    "max_drawn": (opt(int, "--max-drawn", min=1, help="most particles drawn a step"), DEFAULT_MAX_DRAWN),
}
with_drawing = with_parameters("drawing", DRAWING)


def visualization(
    viewer: bool = False,
    rrd: Path | None = None,
    web: bool = False,
    no_viz: bool = False,
    max_drawn: int = DEFAULT_MAX_DRAWN,
    force: bool = True,
    unasked: Any = True,
) -> Any:
    """The `visualize` argument of run_model for the drawing options (see draw.py); an --rrd file
    replaces an existing one only with `force`. Given none of them: `unasked` (True: the viewer, or a
    file without a display; False for what draws only when asked, a study or a maze)."""
    if sum([viewer, rrd is not None, web, no_viz]) > 1:
        raise UserError("choose one of --viewer, --rrd, --web and --no-viz")
    if no_viz:
        return False
    if rrd is not None and rrd.suffix.lower() != ".rrd":
        raise UserError(f"--rrd {rrd}: a recording is an .rrd file (e.g. --rrd {rrd.with_suffix('.rrd')})")
    target = rrd if rrd is not None else "viewer" if viewer else "web" if web else unasked
    return Visualization(target, max_drawn, replace=force) if target else False


# -- --backend and --threads: set MAZELAB_BACKEND / MAZELAB_THREADS for the command (its worker
# processes inherit them), and put back what was there when the command ends -------------------------
def environment_option(variable: str, check: Callable[[Any, str], Any], flag: str) -> Callable[..., Any]:
    """The callback of an option that sets `variable` for the command: the value checked by `check` (one
    line, exit 2: a wrong backend, compiled without numba, threads outside 1 to the machine's cores), the
    variable set until the command's context closes and then put back."""

    def callback(ctx: typer.Context, value: Any) -> Any:
        if value is None or ctx.resilient_parsing:
            return value
        value = check(value, flag)  # a ValueError: one line and exit 2 (mazelab.cli.app.main)
        before = os.environ.get(variable)
        os.environ[variable] = str(value)
        ctx.call_on_close(lambda: os.environ.pop(variable) if before is None else os.environ.update({variable: before}))
        return value

    return callback


BackendOption = opt(
    str | None,
    "--backend",
    metavar="NAME",
    show_default=False,
    callback=environment_option(ENVIRONMENT_VARIABLE, check_backend, "--backend"),
    help="numpy or compiled [default: by the work]",
)
ThreadsOption = opt(
    int | None,
    "--threads",
    metavar="N",
    show_default=False,
    callback=environment_option(THREADS_VARIABLE, check_threads, "--threads"),
    help="compiled: threads for a large run [default: the cores]",
)


# -- outputs --------------------------------------------------------------------------------------------
def check_outputs(outputs: Sequence[tuple[str, Path | None]], force: bool, apart: str = "") -> None:
    """Check a command's outputs, (what the user calls each, its path or None), before any run: first that
    no two are one file (the same path once links are resolved, `./s.csv` and `s.csv` or a symlink to
    another output, or two names of one existing file, a hard link); then each (but the one named `apart`,
    a journal, checked by its owner) refused when it exists (or is a symlink, dangling or not) without
    --force, when it is anything but a regular file with or without it, or when its folder is missing (the
    write itself checks again: without --force it creates the name exclusively, see mazelab.atomic); a
    --plot in a format matplotlib draws (matplotlib there) and --traces in one this program writes."""
    seen: list[tuple[str, Path, str, tuple[int, int] | None]] = []
    for name, path in ((name, Path(path)) for name, path in outputs if path is not None):
        real, inode = os.path.realpath(path), None
        with contextlib.suppress(OSError):  # missing (the usual case for a new output), a loop, no permission
            status = os.stat(real)
            inode = (status.st_dev, status.st_ino)
        for name_a, path_a, real_a, inode_a in seen:
            if real == real_a or (inode is not None and inode == inode_a):
                same = f"{path_a}" if str(path_a) == str(path) else f"{path_a} and {path}"
                raise UserError(f"{name_a} and {name} are one file ({same}): give each output a name of its own")
        seen.append((name, path, real, inode))
    for path in (Path(path) for name, path in outputs if path is not None and name != apart):
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
    plot = dict(outputs).get("--plot")
    if plot is not None:
        pyplot()
        from matplotlib.backend_bases import FigureCanvasBase

        formats = FigureCanvasBase.get_supported_filetypes()
        suffix = plot.suffix.lstrip(".").lower() or "png"
        if suffix not in formats:
            raise UserError(f"--plot {plot}: cannot draw .{suffix} files; use one of .{', .'.join(sorted(formats))}")
    if dict(outputs).get("--traces") is not None:
        check_trace_path(dict(outputs)["--traces"])


# -- values ---------------------------------------------------------------------------------------------
def seed_option(value: int | None) -> int | None:
    """A --seed: a whole number in [0, 2**128) (typer names the option in its one-line error)."""
    if value is not None:
        try:
            check_seed("a seed", value)
        except ValueError as error:
            raise typer.BadParameter(str(error)) from None
    return value


def parse_list(text: str | None, kind: Callable[[str], Any], option: str) -> list | None:
    """'0.2,0.4' -> [0.2, 0.4] (each part read by `kind`, a type or an option's reader; None stays None),
    or a one-line error naming the option; '0,3' for a number is refused with what to write (a list of 0
    and 3 is no lab's value)."""
    if text is None:
        return None
    decimal = decimal_comma(text) if kind is float and text.strip().startswith("0,") else None
    if decimal is not None:
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


def repeat_line(what: str, seed: int | None, files: tuple[str, ...], backend: str) -> None:
    """ "Repeat this run" (comparison, study): the command that repeats it bit for bit, but not its files
    (mazelab.invocation.repeat_command)."""
    typer.echo(f"Repeat this {what}: {repeat_command(seed, files, backend)}")


# -- the filters' options, from their declarations ----------------------------------------------------
# A declared flag "--a/--b" is a pair of switches on run and compare, each setting the option to a value
# (the study's flag takes a list of the values instead); the one place these values are written.
SWITCH_VALUES = {"--recovery": "augmented", "--sensor-resetting": "sensor"}


def flag_spellings(lists: bool) -> list[tuple[str, Option, bool]]:
    """Each command-line spelling of the named flags of the lab's filters' options (`Option.flag`, the first
    declaration of each option): (flag, its option, whether it is a switch). A flag option (`--kld`) is a
    switch, and so is each half of a pair (`--recovery/--sensor-resetting`) on run and compare; any other
    flag, and a pair's first half in a study (`lists`), takes a value (a list)."""
    declared: dict[str, Option] = {}
    for option in (option for entry in SHIPPED for option in entry.options.settable() if option.flag):
        declared.setdefault(option.name, option)
    spellings = []
    for option in declared.values():
        flags = (option.flag or "").split("/")
        if option.parse is parse_flag:
            spellings.append((flags[0], option, True))
        elif len(flags) > 1 and not lists:
            spellings += [(flag, option, True) for flag in flags]
        else:
            spellings.append((flags[0], option, False))
    return spellings


def with_option_flags(lists: bool = False) -> Callable[[Callable[..., Any]], Callable[..., Any]]:
    """Add a hidden typer option per declared flag (`flag_spellings`) to a command, named together in one
    paragraph of its help; the command receives the ones given as `named`: {option name: (the flag as
    typed, its text, a list's text, or True for a switch; a pair's half: the value it sets)}, and both
    halves of a pair given is one line."""
    spellings = flag_spellings(lists)
    parameters = {
        flag.removeprefix("--").replace("-", "_"): (
            opt(bool if switch else str | None, flag, hidden=True, help=option.help),
            False if switch else None,
        )
        for flag, option, switch in spellings
    }

    def named(given: Mapping[str, Any]) -> dict[str, tuple[str, Any]]:
        chosen: dict[str, tuple[str, Any]] = {}
        for (flag, option, _), parameter in zip(spellings, parameters, strict=True):
            if given.get(parameter) in (None, False):
                continue
            if option.name in chosen:
                raise UserError(f"choose one of {' and '.join((option.flag or '').split('/'))}")
            value = given[parameter]
            chosen[option.name] = (flag, SWITCH_VALUES.get(flag, value) if value is True else value)
        return chosen

    def decorate(command: Callable[..., Any]) -> Callable[..., Any]:
        wrapper = with_parameters("named", parameters, named)(command)
        flags, values = ", ".join(flag for flag, _, _ in spellings), "V1,V2" if lists else "VALUE"
        wrapper.__doc__ = (
            f"{inspect.cleandoc(command.__doc__ or '')} Filter options, each also --option "
            f"NAME={values} (mazelab filters NAME says what they do): {flags}."
        )
        return wrapper

    return decorate


def read_value(option: Option, text: str, spelled: str) -> Any:
    """One value of `option` from command-line text, read by its declaration; a value with a comma
    that it refuses, when each part alone is one it takes, says that lists are the study's."""
    try:
        value = option.parse_text(text)
        if "," in text:
            option.validate(value)  # refused here, where the hint can say where lists go
        return value
    except ValueError as error:
        message = str(error).removeprefix(f"option {option.name}: ")
    try:
        for part in text.split(","):
            option.validate(option.parse_text(part))
        hint = f"; a list of values is for mazelab study (study --option {option.name}={text})" if "," in text else ""
    except ValueError:
        hint = ""
    raise UserError(f"{spelled}: {message}{hint}")


def option_flag(values: str, help: str) -> Any:
    """The --option flag's annotated type: NAME=`values` of a filter's option, repeatable."""
    return opt(list[str] | None, "--option", metavar=f"NAME={values}", show_default=False, help=help)


OptionFlag = option_flag("VALUE", "a filter option, repeatable (FILTER.NAME=...: one filter's)")
StudyOptionFlag = option_flag("V1,V2", "filter option values (FILTER.NAME: one's)")


class GivenOptions(dict):
    """Options given on the command line, by name (or FILTER.NAME), with how the user spelled each
    (`spelled`: the named flag, or --option NAME), for the messages."""

    spelled: dict[str, str]


def given_options(
    named: Mapping[str, Any], texts: Sequence[str] | None, filter_names: Sequence[str | type], *, lists: bool = False
) -> GivenOptions:
    """The named flags' values and the `--option NAME=VALUE` texts (NAME=V1,V2 with `lists`), each parsed
    by the declaration of the first filter that declares it; one given both ways is refused in one line.

    Raises
    ------
    UserError
        One line: a text without '=', an option none of the filters declares (naming what they take),
        an option given twice, or a value its declaration cannot read.
    """
    given = GivenOptions()
    given.spelled = {}
    for name, (spelled, value) in named.items():
        given.spelled[name] = spelled
        given[name] = _parsed(filter_names, name, value, spelled, lists)
    for text in texts or ():
        if not text.isprintable():  # a newline would print as a line of its own in the messages
            raise UserError(f"--option {text!r}: an option cannot hold a control character (a newline, a tab)")
        name, equals, value = text.partition("=")
        name = name.strip()
        if not equals or not name:
            raise UserError(f"--option {text!r}: write NAME=VALUE, e.g. --option bandwidth=multimodal")
        if name in given:
            raise UserError(f"{name} is given twice, as {given.spelled[name]} and as --option {name}; give it once")
        given.spelled[name] = f"--option {name}"
        given[name] = _parsed(filter_names, name, value, f"--option {name}={value}", lists)
    return given


def _parsed(filter_names: Sequence[str | type], name: str, value: Any, spelled: str, lists: bool) -> Any:
    """A value (or, with `lists`, the comma-separated values) of option `name`, read by its declaration."""
    try:
        declared = declared_option(name, filter_names)
    except ValueError as error:  # FILTER.NAME of an unknown filter
        raise UserError(f"{spelled.split('=')[0]}: {error}") from None
    if declared is None or declared.derived:
        scope, _ = scoped(name)  # FILTER.NAME: that filter's options, else every filter's
        chosen = [filter_entry(scope)] if scope is not None else [filter_entry(f) for f in filter_names]
        raise UserError(not_taken([entry.filter_class for entry in chosen], spelled.split("=")[0]))
    if value is True:  # a switch (--kld)
        return [True] if lists else True
    if not lists:
        return read_value(declared, value, spelled)
    return parse_list(value, lambda part: read_value(declared, part, spelled), spelled.split("=")[0])


# -- filter names ------------------------------------------------------------------------------------------
def check_filter_name(name: str, option: str = "--filter") -> str:
    """A filter name the registry knows, else one line naming the option and the registry's words (the
    nearest short name, `sri`: did you mean sir?, and the choices)."""
    if not is_plugin_spec(name):  # FILE.py:Class: the registry's own errors say what is wrong with it
        try:
            resolve_filter(name)
        except ValueError as error:
            raise UserError(f"{option}: {error}") from None
    return name


def check_filter_names(names: str, option: str = "--filters") -> str:
    """Every name of a comma-separated --filters list, checked as check_filter_name does."""
    for name in names.split(","):
        if name.strip():
            check_filter_name(name.strip(), option)
    return names
