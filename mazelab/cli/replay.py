"""Runs from a seed or a saved scenario: the start a seed gives, the seed of a replay, and the maze,
sigma and delta of a scenario (flags override the stored values; a file with only the paper's four
keys runs on the one shipped maze it fits)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import typer

from mazelab.cli.filter_options import GivenOptions
from mazelab.cli.options import DEFAULT_DELTA, DEFAULT_SIGMA, UserError
from mazelab.declaration import show_value
from mazelab.maze import Maze
from mazelab.mazes import load_maze, mazes_fitting
from mazelab.registry import filter_entry
from mazelab.robot import Robot
from mazelab.scenario import Scenario, check_measurements_within
from mazelab.seeding import new_seed
from mazelab.simulation import check_start, check_walk_in_maze


def replay_seed(stored: Scenario, seed: int | None) -> int:
    """The seed of a replay: --seed, else the scenario's own (as compare uses), else a new one."""
    return seed if seed is not None else stored.seed if stored.seed is not None else new_seed()


def refuse_counts_for_replay(
    stored: Scenario, particles: int | None, steps: int | None, start_seed: int | None
) -> None:
    """A replay takes its particles, steps and start from the scenario: refuse flags that would be ignored."""
    given = [flag for flag, value in (("--particles", particles), ("--steps", steps), ("--start-seed", start_seed))
             if value is not None]  # fmt: skip
    if given:
        raise UserError(
            f"{' and '.join(given)} cannot change a replayed scenario (it has {len(stored.init_particles_pos)} "
            f"particles and {len(stored.robot_actual_angles)} steps); leave {'them' if len(given) > 1 else 'it'} out"
        )


def from_scenario(
    scenario: Scenario, maze: str | None, sigma: float | None, delta: float | None
) -> tuple[Maze, Robot, float, float, list]:
    """World, robot, sigma, delta and particles of a saved scenario; flags override stored values.
    A scenario without a maze (the paper's four keys) runs on --maze, or on the one shipped maze
    its start and particles fit; missing sigma and delta take the defaults, and a line says so."""
    stored = scenario.world()
    world = stored if stored is not None else load_maze(maze) if maze is not None else fitting_maze(scenario)
    if stored is not None and maze is not None:
        given = load_maze(maze)
        if not np.array_equal(given.grid, stored.grid):
            raise UserError(f"the scenario's maze differs from {given.source}; leave out --maze to use the stored one")
    defaults = [f"{name} {value:g}" for name, value, flag, kept in (
        ("sigma", DEFAULT_SIGMA, sigma, scenario.sigma), ("delta", DEFAULT_DELTA, delta, scenario.delta)
    ) if flag is None and kept is None]  # fmt: skip
    if defaults:
        typer.echo(f"warning: the scenario stores no {' or '.join(d.split()[0] for d in defaults)}: using the "
                   f"default {', '.join(defaults)} (--sigma/--delta choose)", err=True)  # fmt: skip
    warn_overrides(scenario, sigma, delta)
    sigma = sigma if sigma is not None else scenario.sigma if scenario.sigma is not None else DEFAULT_SIGMA
    delta = delta if delta is not None else scenario.delta if scenario.delta is not None else DEFAULT_DELTA
    robot = scenario.robot(sigma, delta)
    if stored is None:  # a maze given or fitted: the scenario's start and walk must lie in its free area
        try:
            check_start(world, robot.initial_position, None, robot.kidnap_position)
            check_walk_in_maze(world, robot)
            check_measurements_within(scenario.robot_measurements, world, sigma)
        except ValueError as error:
            raise UserError(f"{error}; pass the maze the scenario was made on (--maze)") from None
    return world, robot, sigma, delta, scenario.init_particles_pos


def warn_overrides(scenario: Scenario, sigma: float | None, delta: float | None) -> None:
    """Say when --sigma or --delta differs from what the scenario's walk and measurements were made
    with: the filters then assume a model that the replayed data does not follow (a legitimate
    experiment, but never a silent one)."""
    made_with = {"sigma": "measurements", "delta": "compass angles"}
    for name, given, stored in (("sigma", sigma, scenario.sigma), ("delta", delta, scenario.delta)):
        replayed = name == "delta" or scenario.robot_measurements is not None  # else z is drawn with --sigma
        if given is not None and stored is not None and given != stored and replayed:
            typer.echo(
                f"warning: --{name} {given:g} overrides the scenario's {name} {stored:g}: the filters assume "
                f"{given:g}, the replayed {made_with[name]} were made with {stored:g}",
                err=True,
            )


def check_plugin_name(stored: Scenario, filter_name: str, path: Path | None) -> None:
    """Refuse, in one line, a replay whose plug-in is the file the scenario names but whose stored
    filtering_algorithm is not that plug-in's name (see Scenario.plugin_name_problem)."""
    reference = filter_entry(filter_name).plugin
    if reference is None:
        return
    problem = stored.plugin_name_problem(filter_entry(filter_name).name, reference.sha256, reference.class_name)
    if problem is not None:
        raise UserError(f"{path or 'the scenario'}: {problem}")


def stored_options(stored: Scenario, filter_names: Sequence[str], path: Path) -> dict[str, Any]:
    """The options the scenario's run set away from their defaults, as the compared filters that
    declare them read them (a filter's default is not an option set: every filter keeps its own)."""
    found: dict[str, Any] = {}
    for name in filter_names:
        entry = filter_entry(name)
        try:
            kept = stored.filter_kwargs(entry.filter_class)
        except ValueError as error:
            raise UserError(f"{path}: the scenario's filter_options for {entry.name}: {error}") from None
        for option, value in kept.items():
            if value != entry.options[option].default:
                found.setdefault(option, value)
    return found


def with_stored_options(given: GivenOptions, stored: Mapping[str, Any], path: Path) -> GivenOptions:
    """The options of a comparison on a saved scenario: those its run set (`stored_options`), each
    filter that declares one taking it, then those given on the command line over them; one line on
    stderr names the stored ones used, so that the scenario's own filter scores as its replay does."""
    used = {name: value for name, value in stored.items() if name not in given}
    if used:
        shown = ", ".join(f"{name} {show_value(value)}" for name, value in used.items())
        typer.echo(
            f"note: {path.name} was saved by a run with {shown}: each filter that takes "
            f"{'them' if len(used) > 1 else 'it'} does so here (--option NAME=VALUE to change)",
            err=True,
        )
    merged = GivenOptions({**used, **given})
    merged.spelled = {**{name: f"--option {name}" for name in used}, **getattr(given, "spelled", {})}
    return merged


def fitting_maze(scenario: Scenario) -> Maze:
    """The shipped maze of a scenario that stores none: the only one whose free area holds its start
    and every particle; with none or several, a one-line refusal asking for --maze."""
    fitting = mazes_fitting(scenario.init_robot_pos, np.asarray(scenario.init_particles_pos))
    if len(fitting) != 1:
        which = "no shipped maze fits" if not fitting else f"several shipped mazes fit ({', '.join(fitting)})"
        raise UserError(
            f"the scenario stores no maze and {which} its start and particles: "
            "pass --maze (and --sigma/--delta if they differ from the defaults)"
        )
    typer.echo(f"warning: the scenario stores no maze: using {fitting[0]}, the one shipped maze it fits", err=True)
    return load_maze(fitting[0])


__all__ = [
    "check_plugin_name",
    "fitting_maze",
    "from_scenario",
    "refuse_counts_for_replay",
    "replay_seed",
    "stored_options",
    "warn_overrides",
    "with_stored_options",
]
