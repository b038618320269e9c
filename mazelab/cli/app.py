"""The command-line interface (typer): `python main.py ...` or `mazelab ...` from any folder. Without a
command, `demo`: the paper's example (a lost robot, SIR, 1500 particles, 200 steps); the commands are
registered below, each with the one line `mazelab --help` shows, and `main` turns errors into one line."""

from __future__ import annotations

import signal
import sys
from pathlib import Path
from typing import Any

import typer

from mazelab.atomic import WriteError
from mazelab.cli.exercise import exercise_app
from mazelab.cli.maze import maze_app
from mazelab.cli.notebook import notebook
from mazelab.cli.options import (
    BackendOption,
    Force,
    KidnapAt,
    OptionFlag,
    ThreadsOption,
    UserError,
    arg,
    filter_choices,
    filters,
    one_line_warnings,
    opt,
    option_elsewhere,
    plain_usage_names,
    refuse_option_as_value,
    seed_option,
    usage_hint,
    with_drawing,
    with_option_flags,
)
from mazelab.cli.recordings import recordings, view
from mazelab.cli.smoothing import learn, smooth
from mazelab.cli.study import accuracy, study
from mazelab.constants import DEFAULT_DELTA, DEFAULT_PARTICLE_COUNT, DEFAULT_SIGMA, DEFAULT_STEPS
from mazelab.experiments.journal import package_version, program_versions
from mazelab.invocation import remember_arguments
from mazelab.maze import DEFAULT_MAZE, MazeError, load_maze
from mazelab.stops import STOP_SIGNALS, StudentCodeError, exit_without_strays, mark_interrupts
from mazelab.viz.recording import deferred_to_the_end

app = typer.Typer(
    add_completion=False,
    rich_markup_mode=None,  # plain click help: text flows, defaults show, option names are never cut
    no_args_is_help=False,
    pretty_exceptions_enable=False,
    help="A robot lost in a maze, found by particle filters. Without a command: the paper's example.\n\n"
    f"Filters (--filter NAME): {filter_choices()}; `mazelab filters` lists them and their options.",
)


def show_version(value: bool) -> None:
    """--version: the program's, its git commit (if any), numpy's and Python's; then exit."""
    if value:
        versions = program_versions()
        commit = f" (git {versions['git_commit']})" if versions["git_commit"] else ""
        typer.echo(f"mazelab {package_version()}{commit}, numpy {versions['numpy']}, Python {versions['python']}")
        raise typer.Exit()


@app.callback(invoke_without_command=True)
@with_drawing
def demo(
    ctx: typer.Context,
    force: opt(bool, "--force", help="replace an existing --rrd file") = False,
    version: opt(bool, "--version", is_eager=True, callback=show_version, help="the versions, then exit") = False,
    drawing: dict[str, Any] | None = None,
) -> None:
    """The paper's example: a lost robot, the SIR filter, 1500 particles, 200 steps."""
    if ctx.invoked_subcommand is not None:
        return
    from mazelab.cli.replay import run_demo  # scenarios and drawing: imported by the commands that use them

    run_demo(drawing or {}, force)


Maze_ = opt(str | None, "--maze", metavar="MAZE", help=f"a maze file or a name in mazes/ [default: {DEFAULT_MAZE}]")
Filter = opt(str | None, "--filter", metavar="NAME", help=f"{filter_choices()} [default: sir]")
Particles = opt(int | None, help=f"particle count N_S [default: {DEFAULT_PARTICLE_COUNT}]")
Steps = opt(int | None, min=1, help=f"number of steps [default: {DEFAULT_STEPS}]")
Sigma = opt(float | None, help=f"noise std, lab 0.2-0.8 [default: {DEFAULT_SIGMA}]")
Delta = opt(float | None, help=f"compass error, rad, lab 0.05-0.6 [default: {DEFAULT_DELTA}]")
Seed = opt(int | None, callback=seed_option, help="seed of the whole run (default: new, printed)")
StartSeed = opt(int | None, callback=seed_option, hidden=True, help="seed of the start only")
ScenarioFile = opt(Path | None, help="replay a saved scenario (.json), or a shipped one by name")
SaveScenario = opt(Path | None, "--save-scenario", help="save the run (.json)")
Quiet = opt(bool, "--quiet", help="no per-step progress")
SavedScenario = arg(Path, "SCENARIO", "a saved scenario (.json) or a shipped name")
Filters = opt(str, metavar="NAMES", help=filter_choices(many=True))
StoredMaze = opt(str | None, metavar="MAZE", help="the maze, if the scenario stores none")
NewSigma = opt(float | None, "--sigma", help="override the scenario's sigma")
NewDelta = opt(float | None, "--delta", help="override the scenario's delta")
ReplaySeed = opt(int | None, "--seed", callback=seed_option, help="the filters' seed (default: the scenario's)")
ErrorsCsv = opt(Path | None, "--csv", help="per-step errors, a column per filter")
Plot = opt(Path | None, help="the lab's error figure (.png; plot extra)")
Traces = opt(Path | None, help="per-step rows of every filter (.csv, or .parquet)")


@app.command(short_help="One filter on a lost robot, or on a saved scenario.")
@with_drawing
@with_option_flags()
def run(maze: Maze_ = None, filter_name: Filter = None, particles: Particles = None, steps: Steps = None,
        sigma: Sigma = None, delta: Delta = None, seed: Seed = None, start_seed: StartSeed = None,
        scenario: ScenarioFile = None, save_scenario_path: SaveScenario = None, force: Force = False,
        quiet: Quiet = False, kidnap_at: KidnapAt = None, option: OptionFlag = None, backend: BackendOption = None,
        threads: ThreadsOption = None, *, named: dict, drawing: dict) -> None:  # fmt: skip
    """Run one filter on a lost robot, or replay a saved scenario (--scenario) with its filter and
    options. Every filter option: --option NAME=VALUE (`mazelab filters` lists them)."""
    from mazelab.cli.replay import run_one  # scenarios and drawing: imported by the commands that use them

    run_one(**locals())


@app.command(short_help="Lab steps 12-13: every filter on one saved scenario.")
@with_drawing
@with_option_flags()
def compare(scenario: SavedScenario, filters: Filters = "sir,apf,rpf", maze: StoredMaze = None, sigma: NewSigma = None,
            delta: NewDelta = None, seed: ReplaySeed = None, csv_path: ErrorsCsv = None, plot: Plot = None,
            traces: Traces = None, force: Force = False, kidnap_at: KidnapAt = None, option: OptionFlag = None,
            backend: BackendOption = None, *, named: dict, drawing: dict) -> None:  # fmt: skip
    """Lab steps 12-13: every filter on one saved scenario (the same start, particles, walk). Each
    filter takes the options it declares (--option NAME=VALUE; `mazelab filters` lists them), and
    those the scenario's run set away from their defaults unless given here (a line names them).

    A kidnapping (stored, or --kidnap-at) adds whether each filter re-localised (mean error below 0.5
    over the last 30 steps) and the steps it took."""
    from mazelab.cli.replay import compare_scenario  # scenarios and drawing: imported by the commands that use them

    compare_scenario(**locals())


app.command(short_help="Lab step 14: a Monte Carlo parameter study.")(study)
app.command(short_help="The filters, and every option each declares.")(filters)
app.command(short_help="Every filter against the exact grid posterior.")(accuracy)
app.command(short_help="Lab step 15: where the robot was, the smoothers vs the exact.")(smooth)
app.command(short_help="Lab step 15: which sigma and delta explain a scenario.")(learn)
# each short help fits on its line of `mazelab --help` in 80 columns (click cuts a longer one with "...")
app.add_typer(maze_app, name="maze", short_help="Random connected mazes (generate); a look at one (show).")
app.add_typer(exercise_app, name="exercise", short_help="Your own filter: write it (new), grade it (check).")
app.command(short_help="A saved recording in the web viewer on 127.0.0.1.")(view)
app.command(short_help="A copy of a lab notebook here, to run in Jupyter.")(notebook)
app.command(short_help="The saved recordings, with sizes; --clean removes old ones.")(recordings)


@app.command(short_help="The filters' speed against a plain numpy step.")
def bench(
    quick: opt(bool, "--quick", help="fewer sizes and steps (41 s on a 2-core machine)") = False,
    backend: BackendOption = None,
) -> None:
    """Measure the filters' speed (particle-steps per second) against a plain numpy reference step, on
    both backends side by side (numpy, and compiled where numba is installed), or on --backend's."""
    from mazelab.bench import run_benchmark  # only this command needs it

    run_benchmark(
        load_maze(DEFAULT_MAZE), quick=quick, echo=typer.echo, backends=None if backend is None else (backend,)
    )


def main(argv: list[str] | None = None) -> int:
    """Run the CLI; problems with the input end as one line on stderr and exit code 2, a file that
    cannot be written as one line and exit code 1 (after the results are printed).

    A stopped study leaves Ctrl-C, SIGTERM and SIGHUP ignored until the process exits (a further one
    can neither hang nor interrupt the exit); called with `argv` (in-process), main puts the signal
    handlers back as it found them."""
    one_line_warnings()
    remember_arguments(argv)
    handlers = {sig: signal.getsignal(sig) for sig in STOP_SIGNALS}
    unmark = mark_interrupts()  # Ctrl-C raises a marked KeyboardInterrupt: a filter's own is told apart
    try:
        code = _main(argv)
    finally:
        unmark()
        if argv is not None:
            for sig, handler in handlers.items():
                signal.signal(sig, handler)
    if argv is None:  # a process of its own: a plug-in's forgotten thread must not keep it alive
        exit_without_strays(code, lambda line: typer.echo(line, err=True))
    return code


def _main(argv: list[str] | None) -> int:
    plain_usage_names()
    group, args = typer.main.get_command(app), sys.argv[1:] if argv is None else argv
    try:
        refuse_option_as_value(args, group)
        with deferred_to_the_end():
            code = group.main(args=argv, standalone_mode=False)
    except typer.TyperException as error:  # typer's usage errors: bad option, bad value, missing argument
        hint = option_elsewhere(error, group, args) or usage_hint(error, args)
        message = error.format_message()
        typer.echo(f"error: {message.rstrip('.') if hint else message}{hint}", err=True)
        return 2
    except (UserError, MazeError, ValueError) as error:  # a ScenarioError is a ValueError
        typer.echo(f"error: {error}", err=True)
        return 2
    except StudentCodeError as error:  # the student's filter raised: their frames and the step, not ours
        typer.echo(f"error: {error}", err=True)
        return 1
    except OSError as error:  # a full disk, a file size limit, a read-only folder, a name too long: its file, why
        plain = isinstance(error, WriteError) or error.filename is None
        typer.echo(f"error: {error if plain else f'{error.filename}: {error.strerror or error}'}", err=True)
        return 1
    except (KeyboardInterrupt, typer.Abort):
        typer.echo("interrupted", err=True)
        return 130
    return code if isinstance(code, int) else 0


if __name__ == "__main__":
    sys.exit(main())
