"""The demo, `run` and `compare` (lab steps 9-13): one filter on a fresh lost robot or a saved scenario
replayed (`RunSetup`: `replay_setup` says what flags override), and every filter on one saved scenario; a replay
takes the scenario's filter and options (`replay_filter_name`, `replay_options`: a plug-in's run replays
only when the user names the plug-in, a scenario never imports code); their reports and files."""

from __future__ import annotations

import shlex
import warnings
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
import typer

from mazelab.atomic import write_atomically
from mazelab.cli.maze import prepare_world
from mazelab.cli.options import (
    GivenOptions,
    UserError,
    check_filter_name,
    check_filter_names,
    check_outputs,
    given_options,
    repeat_line,
    visualization,
)
from mazelab.constants import DEFAULT_DELTA, DEFAULT_PARTICLE_COUNT, DEFAULT_SIGMA, DEFAULT_STEPS
from mazelab.declaration import show_value, to_plain_json
from mazelab.experiments.journal import Recorder, record_path
from mazelab.experiments.runs import (
    FINAL_SHARE,
    compare_filters,
    comparison_table,
    errors_csv,
    final_error,
    options_per_filter,
    parse_filters,
    plot_errors,
    recovery_steps,
    run_figures,
    take_startup_seconds,
)
from mazelab.experiments.tables import compare_traces, write_traces
from mazelab.invocation import command_line, command_prefix
from mazelab.maze import DEFAULT_MAZE, Maze, find_maze, load_maze, mazes_fitting
from mazelab.registry import file_sha256, filter_entry, resolve_filter
from mazelab.robot import Robot
from mazelab.scenario import Scenario, check_measurements_within, find_scenario, load_scenario, save_scenario
from mazelab.seeding import new_seed
from mazelab.simulation import RunResult, check_walk, simulate


def run_one(flags: Mapping[str, Any], named: Mapping[str, Any], drawing: dict, demo: bool = False) -> None:
    """`run`'s work (mazelab.cli.app; `flags`: its parameters by name, those left out at their defaults):
    one filter on a fresh lost robot or a replayed scenario, its report; the `demo` is `run` with every
    default (the paper's example), said in a line first."""
    visualize = visualization(**drawing, force=flags.get("force", False))
    setup, filter_name, options = run_plan(flags, named, drawing)
    prepare_world(setup.world)
    if demo:
        world, lab = setup.world, find_maze(DEFAULT_MAZE).name
        typer.echo(
            f"A robot is lost in {lab} ({world.height}x{world.width}, {len(world.stations)} stations); SIR "
            f"with {DEFAULT_PARTICLE_COUNT} particles looks for it."
        )
    steps = flags.get("steps")
    progress = None if flags.get("quiet") else progress_printer(steps or setup.robot.recorded_steps or DEFAULT_STEPS)
    try:
        result = simulate(
            setup.robot,
            setup.world,
            setup.sigma,
            setup.delta,
            flags.get("particles"),
            steps,
            setup.initial_particles,
            filter_name,
            seed=setup.seed,
            visualize=visualize,
            on_step=progress,
            kidnap_at=flags.get("kidnap_at"),
            **options,
        )
    except (KeyboardInterrupt, SystemExit):  # Ctrl-C; SIGTERM or SIGHUP with a recording exit through SystemExit
        if flags.get("save_scenario_path") is not None:
            typer.echo(f"the run did not finish: no scenario saved to {flags['save_scenario_path']}", err=True)
        raise
    report_run(result, flags, demo)


def run_plan(flags: Mapping[str, Any], named: Mapping[str, Any], drawing: dict) -> tuple[RunSetup, str, dict[str, Any]]:
    """What `run` reads from its flags, checked once before the run: its setup (a fresh lost robot, its
    start drawn from the seed, or a scenario replayed: `replay_setup`), its filter's name and that
    filter's options (a replay's: the scenario's, then those given, `replay_options`)."""
    scenario, start_seed = flags.get("scenario"), flags.get("start_seed")
    stored = load_scenario(scenario) if scenario is not None else None
    filter_name = check_filter_name(replay_filter_name(stored, flags.get("filter_name"), scenario))
    given = given_options(named, flags.get("option"), [filter_name])
    options = options_per_filter([filter_name], given, given.spelled)[resolve_filter(filter_name).name]
    if stored is not None:  # a replay takes its particles, steps and start from the scenario
        counts = {"--particles": flags.get("particles"), "--steps": flags.get("steps"), "--start-seed": start_seed}
        refused = [flag for flag, value in counts.items() if value is not None]
        if refused:
            raise UserError(
                f"{' and '.join(refused)} cannot change a replayed scenario (it has {len(stored.init_particles_pos)} "
                f"particles and {len(stored.robot_actual_angles)} steps); leave {'them' if refused[1:] else 'it'} out"
            )
        options = replay_options(stored, filter_name, options, scenario)
    options_per_filter([filter_name], options, given.spelled, check=True)  # checked as the filter will check them
    outputs = [("--save-scenario", flags.get("save_scenario_path")), ("--rrd", drawing.get("rrd"))]
    check_outputs(outputs, flags.get("force", False))
    maze, sigma, delta, seed = (flags.get(name) for name in ("maze", "sigma", "delta", "seed"))
    if stored is not None:
        return replay_setup(stored, maze, sigma, delta, seed), filter_name, options
    world = load_maze(maze or DEFAULT_MAZE)  # a fresh lost robot: its start drawn from the seed (new if none)
    sigma = DEFAULT_SIGMA if sigma is None else sigma
    delta = DEFAULT_DELTA if delta is None else delta
    seed = new_seed() if seed is None else seed
    if start_seed is not None and start_seed != seed:
        warnings.warn(f"--start-seed {start_seed} differs from --seed {seed}: repeat with both", stacklevel=1)
    robot = Robot.of_seed(world, sigma, delta, seed if start_seed is None else start_seed)
    return RunSetup(world, robot, sigma, delta, None, seed), filter_name, options


def compare_scenario(flags: Mapping[str, Any], named: Mapping[str, Any], drawing: dict) -> None:
    """`compare`'s work (mazelab.cli.app; `flags`: its parameters by name): every filter on the saved
    scenario, the table, files and record."""
    visualize = visualization(**drawing, force=flags["force"])
    check_filter_names(flags["filters"])
    files = {"csv_path": flags["csv_path"], "plot": flags["plot"], "traces": flags["traces"]}
    files["record_file"] = next((record_path(p) for p in files.values() if p is not None), None)  # beside them
    outputs = [*zip(("--csv", "--plot", "--traces"), files.values(), strict=False), ("--rrd", drawing.get("rrd"))]
    check_outputs([*outputs, ("the record", files["record_file"])], flags["force"])
    scenario = find_scenario(flags["scenario"])  # a shipped one by its name: its file's name in the table's title
    stored = load_scenario(scenario)
    setup = replay_setup(stored, flags["maze"], flags["sigma"], flags["delta"], flags["seed"])
    names = parse_filters(flags["filters"])
    given = with_stored_options(stored, names, given_options(named, flags["option"], names), scenario)
    # an option that none of the filters takes, or a bad value: one line, first
    options_per_filter(names, given, given.spelled, check=True)
    parameters = {  # the record, begun before the runs: the command, its parameters and the scenario's hash
        "filters": [resolve_filter(n).name for n in names],
        "sigma": setup.sigma,
        "delta": setup.delta,
        "seed": setup.seed,
        "kidnap_at": flags["kidnap_at"],
        "options": {k: to_plain_json(v) for k, v in given.items()},
        "scenario": str(scenario),
    }
    recorder = Recorder("compare", command_line(), parameters, scenario_sha256=file_sha256(scenario))
    prepare_world(setup.world)
    shown = f"sigma {setup.sigma:g}, delta {setup.delta:g}"
    count = len(setup.initial_particles)
    typer.echo(f"{scenario.name}: {count} particles, {setup.robot.recorded_steps} steps, {shown}, seed {setup.seed}")
    results = compare_filters(  # the scenario's maze, robot, sigma, delta and particles (RunSetup), the filters
        *setup[:5], names, seed=setup.seed, visualize=visualize, kidnap_at=flags["kidnap_at"], **given
    )
    title = f"Localisation error: {scenario.name} ({shown}, {count} particles)"
    report_compare(results, recorder, title, bool(given.get("kld")), flags["force"], files)
    backend = next(iter(results.values())).extras["backend"]
    repeat_line("comparison", setup.seed, ("--csv", "--plot", "--traces", "--rrd"), backend)


# -- a run's inputs, summary and progress ---------------------------------------------------------------
def report_run(result: RunResult, flags: Mapping[str, Any], demo: bool = False) -> None:
    """A run's report: the last step's error, the last-20% error (the mean error over the last 20% of the
    steps, what compare and study report), the convergence step and the seed, the same text for the same
    seed (timings, which vary, are compare's and bench's); then where a kidnapped robot went, a KLD run's
    particle counts, the saved scenario (--save-scenario) and the command that repeats the run."""
    errors = result.errors
    converged = result.converged_at
    when = f"converged at step {converged} (error < 0.5 from then on)" if converged else "not converged"
    typer.echo(
        f"{result.inputs.filtering_algorithm}: last-step error {errors[-1]:.3f}, last-{FINAL_SHARE:.0%} error "
        f"{final_error(errors):.3f}; {when}; seed {result.inputs.seed}"
    )
    if (kidnapping := kidnap_report(result)) is not None:
        typer.echo(kidnapping)
    if (result.inputs.filter_options or {}).get("kld"):  # KLD-sampling: the particle count per step
        counts = result.extras["particle_count"]
        typer.echo(f"particle count: mean {counts.mean():.0f}, least {counts.min()}, most {counts.max()}")
    if flags.get("save_scenario_path") is not None:
        saved = save_scenario(result.scenario, flags["save_scenario_path"], replace=flags.get("force", False))
        typer.echo(f"scenario saved to {saved}")
    if demo:  # typed without a command: the command that repeats it is `run`
        words = ["run", "--seed", str(result.inputs.seed), "--backend", result.extras["backend"]]
        typer.echo(f"Repeat this run: {command_prefix()} {shlex.join(words)}")
    else:
        repeat_line("run", result.inputs.seed, ("--save-scenario", "--rrd"), result.extras["backend"])


def progress_printer(steps: int, every: int = 20) -> Any:
    """A per-step callback that prints the error every `every` steps."""

    def report(k: int, robot: Robot, filt: Any) -> None:
        if k % every == 0 or k == steps:
            error = float(np.hypot(*(filt.estimate - np.array(robot.position))))
            state = "confident" if filt.is_confident else "searching"
            typer.echo(f"  step {k:4d}/{steps}: error {error:6.3f}  ({state})")

    return report


class RunSetup(NamedTuple):
    """A run's inputs: the maze, the robot, sigma and delta, the initial particles (a replay's; None: drawn
    from the seed) and the seed."""

    world: Maze
    robot: Robot
    sigma: float
    delta: float
    initial_particles: Any
    seed: int


def replay_setup(
    stored: Scenario, maze: str | None, sigma: float | None, delta: float | None, seed: int | None
) -> RunSetup:
    """A saved scenario replayed: its maze (or --maze), walk, measurements, particles and seed (--seed,
    else the scenario's own, else a new one); --sigma and --delta override the stored values, and a
    scenario without a maze (the paper's four keys) runs on --maze, or on the one shipped maze its start
    and particles fit; missing sigma and delta take the defaults, and a line says so."""
    kept = stored.world()
    if kept is not None and maze is not None and not np.array_equal(load_maze(maze).grid, kept.grid):
        raise UserError(
            f"the scenario's maze differs from {load_maze(maze).source}; leave out --maze to use the stored one"
        )
    world = kept or (load_maze(maze) if maze is not None else None)
    if world is None:  # neither stored nor given: the only shipped maze whose free area holds the start and particles
        fitting = mazes_fitting(stored.init_robot_pos, np.asarray(stored.init_particles_pos))
        if len(fitting) != 1:
            which = "no shipped maze fits" if not fitting else f"several shipped mazes fit ({', '.join(fitting)})"
            raise UserError(
                f"the scenario stores no maze and {which} its start and particles: pass --maze (and "
                "--sigma/--delta if they differ from the defaults)"
            )
        typer.echo(f"warning: the scenario stores no maze: using {fitting[0]}, the one shipped maze it fits", err=True)
        world = load_maze(fitting[0])
    sigma, delta = replayed_model(stored, sigma, delta)
    robot = stored.robot(sigma, delta)
    if kept is None:  # a maze given or fitted: the scenario's start and walk must lie in its free area
        try:
            check_walk(world, robot)
            check_measurements_within(stored.robot_measurements, world, sigma)
        except ValueError as error:
            raise UserError(f"{error}; pass the maze the scenario was made on (--maze)") from None
    seed = seed if seed is not None else stored.seed if stored.seed is not None else new_seed()
    return RunSetup(world, robot, sigma, delta, stored.init_particles_pos, seed)


def replayed_model(stored: Scenario, sigma: float | None, delta: float | None) -> tuple[float, float]:
    """A replay's sigma and delta: --sigma and --delta, else the scenario's, else the defaults (a line says
    which it lacks); a line also says when a flag differs from what the scenario's walk and measurements
    were made with: the filters then assume a model that the replayed data does not follow (a legitimate
    experiment, but never a silent one)."""
    given = {"sigma": (sigma, stored.sigma, DEFAULT_SIGMA), "delta": (delta, stored.delta, DEFAULT_DELTA)}
    missing = [(name, default) for name, (flag, had, default) in given.items() if flag is None and had is None]
    if missing:
        typer.echo(
            f"warning: the scenario stores no {' or '.join(n for n, _ in missing)}: using the default "
            f"{', '.join(f'{n} {v:g}' for n, v in missing)} (--sigma/--delta choose)",
            err=True,
        )
    made_with = {"sigma": "measurements", "delta": "compass angles"}
    for name, (flag, had, _) in given.items():
        replayed = name == "delta" or stored.robot_measurements is not None  # else z is drawn with --sigma
        if flag is not None and had is not None and flag != had and replayed:
            typer.echo(
                f"warning: --{name} {flag:g} overrides the scenario's {name} {had:g}: the filters assume "
                f"{flag:g}, the replayed {made_with[name]} were made with {had:g}",
                err=True,
            )
    sigma, delta = (next(value for value in values if value is not None) for values in given.values())
    return sigma, delta


# -- the filter and options of a replay ------------------------------------------------------------------
def replay_filter_name(stored: Scenario | None, filter_name: str | None, path: Path | None = None) -> str:
    """The filter of a run: --filter when given (`filter_name`), else the scenario's own when it is the
    lab's, else SIR. A scenario made by a plug-in (or a filter this program does not have) names the
    command that replays it: its code is never imported from the file."""
    if filter_name is not None:
        return filter_name
    if stored is None or stored.filtering_algorithm is None:
        return "sir"
    if stored.shipped_filter is not None:
        return stored.shipped_filter.short_name
    where = f"{path}" if path is not None else "the scenario"
    if stored.filter_plugin is not None:
        plugin = stored.filter_plugin
        raise UserError(
            f"{where} was made by the plug-in {plugin.describe()}; a scenario never runs code: name it "
            f"to replay it, --filter {plugin.spec} (or replay it with another filter, e.g. --filter sir)"
        )
    raise UserError(
        f"{where} was made by {stored.filtering_algorithm!r}, which is not one of the lab's filters; "
        f"name the filter to replay it with, --filter FILE.py:Class (or e.g. --filter sir)"
    )


def replay_options(stored: Scenario, filter_name: str, given: Mapping[str, Any], path: Path | None) -> dict[str, Any]:
    """The options of a replay: the scenario's (those the chosen filter declares), then every option
    the user gave on the command line (`given`, named flags and --option alike); one line on stderr
    lists what differs from the stored run. The plug-in named to replay a plug-in's run (the same class
    name: the same filter) is refused in one line when it is the file the scenario names (the same
    sha256) but carries another name than its filtering_algorithm (one of the two was edited by hand);
    a line says when its file changed since."""
    chosen, plugin = filter_entry(filter_name), stored.filter_plugin
    if plugin is None:
        same = stored.shipped_filter is not None and stored.shipped_filter.filter_class is chosen.filter_class
    else:
        same = chosen.plugin is not None and chosen.plugin.class_name == plugin.class_name
    if same and plugin is not None:  # a plug-in's run replayed by that plug-in: its file's sha256 compared
        if chosen.plugin.sha256 == plugin.sha256 and chosen.name != stored.filtering_algorithm:
            raise UserError(
                f"{path or 'the scenario'}: filtering_algorithm {stored.filtering_algorithm!r} is not the name of "
                f"the plug-in {plugin.spec} that filter_plugin names ({chosen.name!r}): one of the two was edited"
            )
        if chosen.plugin.sha256 != plugin.sha256:
            typer.echo(
                f"warning: {chosen.plugin.spec} has changed since the scenario was saved (sha256 "
                f"{chosen.plugin.sha256[:12]}..., saved {plugin.sha256[:12]}...): the replay may differ from the "
                "saved run",
                err=True,
            )
    if stored.filter_options is None:  # an older file: the options given, as before
        return dict(given)
    try:
        kept = stored.filter_kwargs(chosen.filter_class)
    except ValueError as error:
        raise UserError(f"the scenario's filter_options for {chosen.name}: {error}") from None
    changes = (
        [] if stored.filtering_algorithm is None or same else [f"filter {stored.filtering_algorithm} -> {chosen.name}"]
    )
    for name, value in given.items():
        before = kept.get(name, chosen.options[name].default if name in chosen.options else None)
        if before != value:
            changes.append(f"{name} {show_value(before)} -> {show_value(value)}")
    if changes:
        typer.echo(f"note: replaying with {'; '.join(changes)} (the scenario's run used the former)", err=True)
    return {**kept, **given}


def with_stored_options(stored: Scenario, filter_names: Sequence[str], given: GivenOptions, path: Path) -> GivenOptions:
    """The options of a comparison on a saved scenario: those its run set away from their defaults, each
    compared filter that declares one taking it (a filter's default is not an option set: every filter
    keeps its own), then those given on the command line over them; one line on stderr names the stored
    ones used, so that the scenario's own filter scores as its replay does."""
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
    used = {name: value for name, value in found.items() if name not in given}
    if used:
        shown = ", ".join(f"{name} {show_value(value)}" for name, value in used.items())
        them = "them" if len(used) > 1 else "it"
        typer.echo(
            f"note: {path.name} was saved by a run with {shown}: each filter that takes {them} does so here "
            "(--option NAME=VALUE to change)",
            err=True,
        )
    merged = GivenOptions({**used, **given})
    merged.spelled = {**{name: f"--option {name}" for name in used}, **getattr(given, "spelled", {})}
    return merged


# -- what run and compare print and write -----------------------------------------------------------
def kidnap_report(result: RunResult, found: bool = True) -> str | None:
    """Where the robot was carried, and (`found`) when, if ever, the filter found it again."""
    inputs = result.inputs  # kidnap_at and kidnap_position: both set, or both None (RunInputs.of_run)
    if inputs.kidnap_at is None:
        return None
    x, y = inputs.kidnap_position
    line = f"kidnapped at step {inputs.kidnap_at} to ({x:.2f}, {y:.2f})"
    if not found:
        return line
    steps = recovery_steps(result)
    return line + (f": re-localised {steps} steps later" if steps is not None else ": not re-localised by the end")


# -- compare's outputs ------------------------------------------------------------------------------------
def report_compare(
    results: dict[str, RunResult], recorder: Recorder, title: str, kld: bool, force: bool, files: dict
) -> None:
    """The kidnapping (if any), the table, then the `files` asked for (by compare's parameter names, and
    `record_file`): the per-step errors, the figure, the traces (with the scenario's maze, sigma, delta and
    particle count) and the record (with each filter's figures)."""
    csv_path, plot, traces, record_file = (files[name] for name in ("csv_path", "plot", "traces", "record_file"))
    if (kidnapping := kidnap_report(next(iter(results.values())), found=False)) is not None:
        typer.echo(kidnapping)  # where each filter found the robot again is in the table
    typer.echo(comparison_table(results, kld=kld, startup_seconds=take_startup_seconds()))
    if csv_path is not None:
        write_atomically(csv_path, errors_csv(results), replace=force)
        typer.echo(f"per-step errors written to {csv_path}")
    if plot is not None:
        plot_errors(results, plot, title, replace=force)
        typer.echo(f"figure written to {plot}")
    if traces is not None:
        write_traces(traces, compare_traces(results))
        typer.echo(f"per-step traces written to {traces}")
    if record_file is not None:
        kept = (
            "mean_error",
            "final_error",
            "converged_at",
            "mean_ess",
            "log_evidence",
            "log_evidence_caveat",
            "ms_per_step",
            "backend",
        )
        summary = [
            {"filter": name, **{k: run_figures(name, result)[k] for k in kept}} for name, result in results.items()
        ]
        recorder.finish("finished", summary=summary)
        recorder.write(record_file)
        typer.echo(f"the record (command, versions, scenario hash, summary) written to {record_file}")
