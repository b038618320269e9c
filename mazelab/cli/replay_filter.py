"""The filter and options of a replay (`run --scenario`): those the scenario stores, so that the replay
repeats the run that made it bit for bit, unless the user names another filter or option on the
command line; then one line says what was overridden."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import typer

from mazelab.contract import takes
from mazelab.option_json import describe_option
from mazelab.registry import resolve_filter
from mazelab.scenario import Scenario

# the command-line parameters of `run` that set each filter option
OPTION_FLAGS: dict[str, tuple[str, ...]] = {
    "resampling": ("resampling",),
    "recovery": ("recovery", "sensor_resetting", "alpha_slow", "alpha_fast"),
    "kld": ("kld", "kld_epsilon", "kld_z"),
    "init": ("init",),
    "bandwidth": ("bandwidth",),
    "estimate": ("estimate",),
}


def given_on_command_line(ctx: typer.Context, parameter: str) -> bool:
    """Whether the user typed this parameter (rather than leaving its default). By the source's name:
    typer carries its own click, whose ParameterSource is not the click package's."""
    source = ctx.get_parameter_source(parameter)
    return source is not None and source.name == "COMMANDLINE"


def replay_filter_name(ctx: typer.Context, stored: Scenario | None, filter_name: str) -> str:
    """The filter of a run: --filter when given, else the scenario's own, else the default."""
    if stored is None or stored.filtering_algorithm is None or given_on_command_line(ctx, "filter_name"):
        return filter_name
    return stored.filtering_algorithm


def replay_options(
    ctx: typer.Context, stored: Scenario, filter_name: str, options: Mapping[str, Any]
) -> dict[str, Any]:
    """The options of a replay: the scenario's (those the chosen filter takes), then every option the
    user named on the command line; one line on stderr lists what differs from the stored run."""
    chosen = resolve_filter(filter_name)
    kept = {k: v for k, v in stored.filter_kwargs().items() if takes(chosen, k)}
    named = {k: v for k, v in options.items() if any(given_on_command_line(ctx, f) for f in OPTION_FLAGS.get(k, ()))}
    if stored.filter_options is None:  # an older file: the options given, as before
        return dict(options)
    final = {**kept, **named}
    changes = []
    if stored.filtering_algorithm is not None and resolve_filter(stored.filtering_algorithm) is not chosen:
        changes.append(f"filter {resolve_filter(stored.filtering_algorithm).name} -> {chosen.name}")
    for name, value in named.items():
        before = kept.get(name, chosen.options.get(name))
        if before != value:
            changes.append(f"{name} {describe_option(before)} -> {describe_option(value)}")
    if changes:
        typer.echo(f"note: replaying with {'; '.join(changes)} (the scenario's run used the former)", err=True)
    return final


__all__ = ["OPTION_FLAGS", "given_on_command_line", "replay_filter_name", "replay_options"]
