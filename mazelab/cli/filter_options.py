"""Filter options on the command line, read from each filter's declaration (mazelab.declaration).

The named flags of run, compare and study (`--threshold`, `--bandwidth`, `--kld`, ...) are generated from
the declarations' `Option.flag` (`with_option_flags`), so a declared flag is taken by every command that
runs filters and `mazelab filters` never lists one that a command refuses. They are spellings of the
options: `--bandwidth 0.05` and `--option bandwidth=0.05` give the same value, parsed and checked by the
same declaration. `--option NAME=VALUE` (repeatable) sets any declared option of any filter, a plug-in's
included, and `--option FILTER.NAME=VALUE` (e.g. `rpf.threshold`) sets it for that filter alone. An
option that no filter of the command declares is refused in one line naming what they take, before any
work; so is a value the declaration refuses. `mazelab filters [NAME]` lists the registry's filters and one
filter's options from the same declarations, so the list is never out of date, a plug-in's included.
"""

from __future__ import annotations

import inspect
import textwrap
from collections.abc import Callable, Mapping, Sequence
from typing import Annotated, Any

import typer

from mazelab.cli.options import UserError, with_parameters
from mazelab.declaration import Option, not_taken, parse_flag, scoped, show_value
from mazelab.experiments.study import declared_option
from mazelab.experiments.study import options_per_filter as reaching
from mazelab.registry import SHIPPED, FilterEntry, entries, filter_entry, is_plugin_spec, resolve_filter

# A declared flag "--a/--b" is a pair of switches on run and compare, each setting the option to a value
# (the study's flag takes a list of the values instead); the one place these values are written.
SWITCH_VALUES = {"--recovery": "augmented", "--sensor-resetting": "sensor"}


def declared_flags() -> dict[str, Option]:
    """The named flags of the lab's filters' options, by option name (the first declaration's)."""
    flags: dict[str, Option] = {}
    for entry in SHIPPED:
        for option in entry.options.settable():
            if option.flag:
                flags.setdefault(option.name, option)
    return flags


def _flag_parameters(lists: bool) -> dict[str, inspect.Parameter]:
    """A typer parameter per declared flag: a switch for a flag option (`--kld`) and for each half of
    a pair (`--recovery`, `--sensor-resetting`) on run and compare; a value (a list of them for a
    study, `lists`) otherwise. They are listed in the command's help in one paragraph (`flags_line`)."""
    parameters = {}
    for option in declared_flags().values():
        spellings = (option.flag or "").split("/")
        switches = [spellings[0]] if option.parse is parse_flag else spellings if len(spellings) > 1 else []
        for flag in [] if lists and option.parse is not parse_flag else switches:
            typer_option = typer.Option(flag, hidden=True, help=option.help)
            parameters[_parameter_name(flag)] = _parameter(flag, bool, False, typer_option)
        if (lists and option.parse is not parse_flag) or not switches:
            typer_option = typer.Option(spellings[0], hidden=True, help=option.help)
            parameters[_parameter_name(spellings[0])] = _parameter(spellings[0], str | None, None, typer_option)
    return parameters


def flags_line(lists: bool) -> str:
    """The help's paragraph naming the declared flags (each a spelling of --option NAME=VALUE)."""
    flags = ", ".join(f"--{name.replace('_', '-')}" for name in _flag_parameters(lists))
    values = "V1,V2" if lists else "VALUE"
    return f"Filter options, each also --option NAME={values} (mazelab filters NAME says what they do): {flags}."


def _parameter_name(flag: str) -> str:
    return flag.removeprefix("--").replace("-", "_")


def _parameter(flag: str, kind: Any, default: Any, typer_option: Any) -> inspect.Parameter:
    kind_ = inspect.Parameter.KEYWORD_ONLY
    return inspect.Parameter(_parameter_name(flag), kind_, default=default, annotation=Annotated[kind, typer_option])


def with_option_flags(lists: bool = False) -> Callable[[Callable[..., Any]], Callable[..., Any]]:
    """Add the declared flags (`_flag_parameters`) to a command's parameters, named in its help; the
    command receives the ones given as `named`: {option name: its text, a list's text, or True for a
    switch}."""
    flags = {name: (p.annotation, p.default) for name, p in _flag_parameters(lists).items()}

    def decorate(command: Callable[..., Any]) -> Callable[..., Any]:
        wrapper = with_parameters("named", flags, _named)(command)
        wrapper.__doc__ = f"{inspect.cleandoc(command.__doc__ or '')} {flags_line(lists)}"
        return wrapper

    return decorate


def _named(given: Mapping[str, Any]) -> dict[str, Any]:
    """The flags given, by option name; both halves of a pair is one line."""
    named: dict[str, Any] = {}
    for name, option in declared_flags().items():
        spellings = (option.flag or "").split("/")
        chosen = [f for f in spellings if given.get(_parameter_name(f)) not in (None, False)]
        if len(chosen) > 1:
            raise UserError(f"choose one of {' and '.join(spellings)}")
        if chosen:
            value = given[_parameter_name(chosen[0])]
            named[name] = SWITCH_VALUES.get(chosen[0], value) if value is True and len(spellings) > 1 else value
    return named


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
        raise UserError(f"{spelled}: {message}{_list_hint(option, text)}") from None


def _list_hint(option: Option, text: str) -> str:
    """'; ...' when `text` reads as a list of values of `option` (V1,V2), else nothing."""
    try:
        for part in text.split(","):
            option.validate(option.parse_text(part))
    except ValueError:
        return ""
    return f"; a list of values is for mazelab study (study --option {option.name}={text})" if "," in text else ""


OptionFlag = Annotated[
    list[str] | None,
    typer.Option(
        "--option",
        metavar="NAME=VALUE",
        show_default=False,
        help="a filter option, repeatable (FILTER.NAME=...: one filter's)",
    ),
]
StudyOptionFlag = Annotated[
    list[str] | None,
    typer.Option(
        "--option",
        metavar="NAME=V1,V2",
        show_default=False,
        help="filter option values (FILTER.NAME: one's)",
    ),
]


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
    for name, value in named.items():
        spellings = (declared_flags()[name].flag or f"--{name}").split("/")
        given.spelled[name] = next((f for f in spellings if SWITCH_VALUES.get(f) == value), spellings[0])
        given[name] = _parsed(filter_names, name, value, given.spelled[name], lists)
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
        raise UserError(refusal(filter_names, name, spelled.split("=")[0]))
    if value is True:  # a switch (--kld)
        return [True] if lists else True
    if not lists:
        return read_value(declared, value, spelled)
    parts = [part for part in value.split(",") if part.strip()]
    if not parts:
        raise UserError(f"{spelled}: no values (write NAME=V1,V2)")
    return list(dict.fromkeys(read_value(declared, part, spelled) for part in parts))


def refusal(filter_names: Sequence[str | type], key: str, spelled: str) -> str:
    """The line for an option none of the filters declares (or its FILTER.NAME's filter does not)."""
    scope, _ = scoped(key)
    chosen = [filter_entry(scope)] if scope is not None else [filter_entry(f) for f in filter_names]
    return not_taken([entry.filter_class for entry in chosen], spelled)


def options_per_filter(
    filter_names: Sequence[str | type], given: Mapping[str, Any], *, check: bool = True
) -> dict[str, dict[str, Any]]:
    """Per filter (by `name`), the given options that reach it (mazelab.experiments.study.options_per_filter:
    a FILTER.NAME one its filter alone); an option that none of them declares is refused in one line naming
    how the user spelled it and what they take. With `check`, each filter's options are checked by its
    declaration as its constructor will check them, in one line."""
    spelled = getattr(given, "spelled", {})
    try:
        per_filter = reaching(filter_names, given, {k: spelled.get(k, f"--option {k}=...") for k in given})
        if check:
            for entry in map(filter_entry, filter_names):
                entry.options.resolve(per_filter[entry.name], entry.name)
    except ValueError as error:
        raise UserError(str(error)) from None
    return per_filter


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


def filter_choices(many: bool = False) -> str:
    """The help's list of filters, from the registry: 'sir, apf, rpf, grid, ekf, or FILE.py:Class'."""
    names = ", ".join(e.short_name for e in entries())
    return f"{names}, FILE.py:Class, comma-separated" if many else f"{names}, or FILE.py:Class"


# -- `mazelab filters [NAME]` ----------------------------------------------------------------------------
WIDTH = 100  # columns of the listing


def filters(
    name: Annotated[
        str | None,
        typer.Argument(
            metavar="[NAME]", help="one filter: sir, apf, rpf, grid, ekf or FILE.py:Class", show_default=False
        ),
    ] = None,
) -> None:
    """The filters, or one filter's options: name, default, the flag that sets it, what it does.
    Every option is set with --option NAME=VALUE on run, compare and study."""
    if name is None:
        typer.echo(registry_listing())
    else:
        typer.echo(options_listing(filter_entry(check_filter_name(name, "filters"))))


def registry_listing() -> str:
    """One line per shipped filter: short name, label, help, what it can do."""
    lines = ["filter  label  what it is", *(_entry_line(entry) for entry in entries())]
    lines += [
        "",
        "Your own: --filter FILE.py:Class (see `mazelab exercise new`); its options: mazelab filters FILE.py:Class",
        "One filter's options: mazelab filters rpf",
    ]
    return "\n".join(lines)


def registry_help() -> str:
    """The filters for `mazelab --help`, one short line each (from the registry)."""
    names = ", ".join(entry.short_name for entry in entries())
    return f"Filters (--filter NAME): {names}, or FILE.py:Class; `mazelab filters` lists them and their options."


def _entry_line(entry: FilterEntry) -> str:
    can = ", ".join(
        [*(["particles"] if entry.takes_particles else ["no particles"]), *(["runs batched"] if entry.batched else [])]
    )
    return f"{entry.short_name:<6}  {entry.label:<5}  {entry.help} ({can})"


def options_listing(entry: FilterEntry) -> str:
    """A filter's declared options: name, default, flag, help (wrapped to WIDTH columns)."""
    options = entry.options.settable()
    head = f"{entry.label} ({entry.name}): {entry.help}" if entry.label != entry.name else f"{entry.name}: {entry.help}"
    if entry.plugin is not None:
        head += f"\n  from {entry.plugin.spec} (sha256 {entry.plugin.sha256[:12]}...)"
    if not options:
        return f"{head}\n  it declares no options"
    rows = [(o.name, show_value(o.default), o.help + (f" [{o.flag}]" if o.flag else "")) for o in options]
    widths = [max(len(row[i]) for row in [("option", "default", ""), *rows]) for i in range(2)]
    indent = 2 + widths[0] + 2 + widths[1] + 2
    lines = [head, f"  {'option'.ljust(widths[0])}  {'default'.ljust(widths[1])}  what it does [its named flag]"]
    for name, default, text in rows:
        wrapped = textwrap.wrap(text, max(30, WIDTH - indent)) or [""]
        lines.append(f"  {name.ljust(widths[0])}  {default.ljust(widths[1])}  {wrapped[0]}")
        lines += [" " * indent + more for more in wrapped[1:]]
    lines.append(
        f"  set any of them: --option NAME=VALUE (e.g. --option {options[0].name}={show_value(options[0].default)})"
    )
    return "\n".join(lines)
