"""The filter and options of a replay (`run --scenario`): those the scenario stores, so that the replay
repeats the run that made it bit for bit, unless the user names another filter or option on the
command line; then one line says what was overridden.

A scenario never imports code: a plug-in's saved run replays only when the user names the plug-in
(`--filter file.py:Class`); its file's sha256 is checked against the stored one (a changed file is said
in one line), and `--filter sir` replays the same scenario with SIR."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

import typer

from mazelab.cli.options import UserError
from mazelab.declaration import show_value
from mazelab.registry import FilterEntry, filter_entry
from mazelab.scenario import Scenario


def given_on_command_line(ctx: typer.Context, parameter: str) -> bool:
    """Whether the user typed this parameter (rather than leaving its default). By the source's name:
    typer carries its own click, whose ParameterSource is not the click package's."""
    source = ctx.get_parameter_source(parameter)
    return source is not None and source.name == "COMMANDLINE"


def replay_filter_name(ctx: typer.Context, stored: Scenario | None, filter_name: str, path: Path | None = None) -> str:
    """The filter of a run: --filter when given, else the scenario's own when it is the lab's, else
    the default. A scenario made by a plug-in (or a filter this program does not have) names the
    command that replays it: its code is never imported from the file."""
    if stored is None or stored.filtering_algorithm is None or given_on_command_line(ctx, "filter_name"):
        return filter_name
    shipped = stored.shipped_filter
    if shipped is not None:
        return shipped.short_name
    where = f"{path}" if path is not None else "the scenario"
    if stored.filter_plugin is not None:
        plugin = stored.filter_plugin
        raise UserError(
            f"{where} was made by the plug-in {plugin.describe()}; a scenario never runs code: name it to replay "
            f"it, --filter {plugin.spec} (or replay it with another filter, e.g. --filter sir)"
        )
    raise UserError(
        f"{where} was made by {stored.filtering_algorithm!r}, which is not one of the lab's filters; name the filter "
        f"to replay it with, --filter FILE.py:Class (or e.g. --filter sir)"
    )


def same_filter(stored: Scenario, chosen: FilterEntry) -> bool:
    """Whether the chosen filter is the one that made the scenario (a plug-in: the same class name)."""
    if stored.filtering_algorithm is None:
        return False
    if stored.filter_plugin is not None:
        return chosen.plugin is not None and chosen.plugin.class_name == stored.filter_plugin.class_name
    shipped = stored.shipped_filter
    return shipped is not None and shipped.filter_class is chosen.filter_class


def check_plugin_file(stored: Scenario, chosen: FilterEntry) -> None:
    """Say, in one line, when the plug-in named to replay a scenario is not the file that made it."""
    plugin = stored.filter_plugin
    if plugin is None or chosen.plugin is None or not same_filter(stored, chosen):
        return
    if chosen.plugin.sha256 != plugin.sha256:
        typer.echo(
            f"warning: {chosen.plugin.spec} has changed since the scenario was saved (sha256 "
            f"{chosen.plugin.sha256[:12]}..., saved {plugin.sha256[:12]}...): the replay may differ from the saved run",
            err=True,
        )


def replay_options(stored: Scenario, filter_name: str, given: Mapping[str, Any]) -> dict[str, Any]:
    """The options of a replay: the scenario's (those the chosen filter declares), then every option
    the user gave on the command line (`given`, named flags and --option alike); one line on stderr
    lists what differs from the stored run."""
    chosen = filter_entry(filter_name)
    check_plugin_file(stored, chosen)
    if stored.filter_options is None:  # an older file: the options given, as before
        return dict(given)
    try:
        kept = stored.filter_kwargs(chosen.filter_class)
    except ValueError as error:
        raise UserError(f"the scenario's filter_options for {chosen.name}: {error}") from None
    final = {**kept, **given}
    changes = []
    if stored.filtering_algorithm is not None and not same_filter(stored, chosen):
        changes.append(f"filter {stored.filtering_algorithm} -> {chosen.name}")
    for name, value in given.items():
        before = kept.get(name, chosen.options[name].default if name in chosen.options else None)
        if before != value:
            changes.append(f"{name} {show_value(before)} -> {show_value(value)}")
    if changes:
        typer.echo(f"note: replaying with {'; '.join(changes)} (the scenario's run used the former)", err=True)
    return final


__all__ = ["check_plugin_file", "given_on_command_line", "replay_filter_name", "replay_options", "same_filter"]
