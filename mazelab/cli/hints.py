"""What turns a puzzling command-line error into one a student can act on: an option given to the
wrong command, an option swallowed as another option's value, a misspelt filter name; and the help's
usage lines without typer's braces."""

from __future__ import annotations

import re
import shlex
from collections.abc import Sequence
from typing import Any

import typer
import typer.core

from mazelab.cli.options import UserError
from mazelab.invocation import command_prefix
from mazelab.plugins import is_plugin_spec
from mazelab.registry import entries, resolve_filter


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
