"""`mazelab filters [NAME]`: the registry's filters and, for one filter, every option it declares, read
from the declarations (so the list is never out of date, a plug-in's included)."""

from __future__ import annotations

import textwrap
from typing import Annotated

import typer

from mazelab.cli.hints import check_filter_name
from mazelab.declaration import show_value
from mazelab.registry import FilterEntry, entries, filter_entry

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


__all__ = ["filters", "options_listing", "registry_help", "registry_listing"]
