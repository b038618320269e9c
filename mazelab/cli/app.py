"""The command-line interface (typer): `python main.py ...` or `mazelab ...` from any folder. Without a
command, `demo`: the paper's example (a lost robot, SIR, 1500 particles, 200 steps); the commands are
registered below, each with the one line `mazelab --help` shows, with `mazelab filters [NAME]` (the
registry's filters, and the options each declares); `main` turns errors into one line that names the fix
(`usage_hint`)."""

from __future__ import annotations

import itertools
import re
import shlex
import signal
import sys
import textwrap
import warnings
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import typer
import typer.core

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
    check_filter_name,
    opt,
    seed_option,
    with_drawing,
    with_option_flags,
    with_parameters,
)
from mazelab.cli.recordings import recordings, view
from mazelab.cli.smoothing import learn, smooth
from mazelab.cli.study import accuracy, study
from mazelab.constants import DEFAULT_DELTA, DEFAULT_PARTICLE_COUNT, DEFAULT_SIGMA, DEFAULT_STEPS
from mazelab.declaration import decimal_comma, show_value
from mazelab.experiments.journal import package_version, program_versions
from mazelab.invocation import command_prefix, remember_arguments
from mazelab.maze import DEFAULT_MAZE, MazeError, load_maze
from mazelab.registry import FilterEntry, entries, filter_entry
from mazelab.stops import STOP_SIGNALS, StudentCodeError, exit_without_strays, mark_interrupts
from mazelab.viz.recording import deferred_to_the_end


def filter_choices(many: bool = False) -> str:
    """The help's list of filters, from the registry: 'sir, apf, rpf, grid, ekf, or FILE.py:Class'."""
    names = ", ".join(e.short_name for e in entries())
    return f"{names}, FILE.py:Class, comma-separated" if many else f"{names}, or FILE.py:Class"


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
    from mazelab.cli.replay import run_one  # scenarios and drawing: imported by the commands that use them

    run_one({"force": force}, {}, drawing or {}, demo=True)


# run's parameters (`run_one` reads them as one value, `flags`), then compare's (`compare_scenario`)
RUN: dict[str, tuple[Any, Any]] = {
    "maze": (
        opt(str | None, "--maze", metavar="MAZE", help=f"a maze file or a name in mazes/ [default: {DEFAULT_MAZE}]"),
        None,
    ),
    "filter_name": (opt(str | None, "--filter", metavar="NAME", help=f"{filter_choices()} [default: sir]"), None),
    "particles": (opt(int | None, help=f"particle count N_S [default: {DEFAULT_PARTICLE_COUNT}]"), None),
    "steps": (opt(int | None, min=1, help=f"number of steps [default: {DEFAULT_STEPS}]"), None),
    "sigma": (opt(float | None, help=f"noise std, lab 0.2-0.8 [default: {DEFAULT_SIGMA}]"), None),
    "delta": (opt(float | None, help=f"compass error, rad, lab 0.05-0.6 [default: {DEFAULT_DELTA}]"), None),
    "seed": (opt(int | None, callback=seed_option, help="seed of the whole run (default: new, printed)"), None),
    "start_seed": (opt(int | None, callback=seed_option, hidden=True, help="seed of the start only"), None),
    "scenario": (opt(Path | None, help="replay a saved scenario (.json), or a shipped one by name"), None),
    "save_scenario_path": (opt(Path | None, "--save-scenario", help="save the run (.json)"), None),
    "force": (Force, False),
    "quiet": (opt(bool, "--quiet", help="no per-step progress"), False),
    "kidnap_at": (KidnapAt, None),
    "option": (OptionFlag, None),
    "backend": (BackendOption, None),
    "threads": (ThreadsOption, None),
}
COMPARE: dict[str, tuple[Any, Any]] = {
    "scenario": (arg(Path, "SCENARIO", "a saved scenario (.json) or a shipped name"), ...),
    "filters": (opt(str, metavar="NAMES", help=filter_choices(many=True)), "sir,apf,rpf"),
    "maze": (opt(str | None, metavar="MAZE", help="the maze, if the scenario stores none"), None),
    "sigma": (opt(float | None, "--sigma", help="override the scenario's sigma"), None),
    "delta": (opt(float | None, "--delta", help="override the scenario's delta"), None),
    "seed": (opt(int | None, "--seed", callback=seed_option, help="the filters' seed (default: the scenario's)"), None),
    "csv_path": (opt(Path | None, "--csv", help="per-step errors, a column per filter"), None),
    "plot": (opt(Path | None, help="the lab's error figure (.png; plot extra)"), None),
    "traces": (opt(Path | None, help="per-step rows of every filter (.csv, or .parquet)"), None),
    "force": (Force, False),
    "kidnap_at": (KidnapAt, None),
    "option": (OptionFlag, None),
    "backend": (BackendOption, None),
}


@app.command(short_help="One filter on a lost robot, or on a saved scenario.")
@with_drawing
@with_option_flags()
@with_parameters("flags", RUN)
def run(*, flags: dict, named: dict, drawing: dict) -> None:
    """Run one filter on a lost robot, or replay a saved scenario (--scenario) with its filter and
    options. Every filter option: --option NAME=VALUE (`mazelab filters` lists them)."""
    from mazelab.cli.replay import run_one  # scenarios and drawing: imported by the commands that use them

    run_one(flags, named, drawing)


@app.command(short_help="Lab steps 12-13: every filter on one saved scenario.")
@with_drawing
@with_option_flags()
@with_parameters("flags", COMPARE)
def compare(*, flags: dict, named: dict, drawing: dict) -> None:
    """Lab steps 12-13: every filter on one saved scenario (the same start, particles, walk). Each
    filter takes the options it declares (--option NAME=VALUE; `mazelab filters` lists them), and
    those the scenario's run set away from their defaults unless given here (a line names them).

    A kidnapping (stored, or --kidnap-at) adds whether each filter re-localised (mean error below 0.5
    over the last 30 steps) and the steps it took."""
    from mazelab.cli.replay import compare_scenario  # scenarios and drawing: imported by the commands that use them

    compare_scenario(flags, named, drawing)


# -- `mazelab filters [NAME]` ----------------------------------------------------------------------------
WIDTH = 100  # columns of the listing


def filters(name: arg(str | None, "[NAME]", "one filter: sir, apf, rpf, grid, ekf or FILE.py:Class") = None) -> None:
    """The filters, or one filter's options: name, default, the flag that sets it, what it does.
    Every option is set with --option NAME=VALUE on run, compare and study."""
    if name is not None:
        typer.echo(options_listing(filter_entry(check_filter_name(name, "filters"))))
        return
    lines = ["filter  label  what it is"]  # one line per shipped filter: short name, label, help, what it can do
    for entry in entries():
        can = ["particles" if entry.takes_particles else "no particles", *(["runs batched"] if entry.batched else [])]
        lines.append(f"{entry.short_name:<6}  {entry.label:<5}  {entry.help} ({', '.join(can)})")
    lines += [
        "",
        "Your own: --filter FILE.py:Class (see `mazelab exercise new`); its options: mazelab filters FILE.py:Class",
        "One filter's options: mazelab filters rpf",
    ]
    typer.echo("\n".join(lines))


def options_listing(entry: FilterEntry) -> str:
    """A filter's declared options: name, default, flag, help (wrapped to WIDTH columns)."""
    options = entry.options.settable()
    head = f"{entry.label} ({entry.name}): {entry.help}" if entry.label != entry.name else f"{entry.name}: {entry.help}"
    if entry.plugin is not None:
        head += f"\n  from {entry.plugin.describe()}"
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


# -- errors that name the fix ----------------------------------------------------------------------------
def usage_name(self: Any) -> str:
    """Usage lines name a required argument as `SCENARIO`, not typer's `{SCENARIO}` (which reads as
    a placeholder to type with its braces)."""
    name = self.display_name_raw if self.required else f"[{self.display_name_raw}]"
    return name + ("..." if self.nargs != 1 else "")


typer.core.TyperArgument._usage_display_name = usage_name

# what to type for a command's missing argument
ARGUMENT_EXAMPLES = {
    "compare": "compare paper_5x5 (a shipped scenario, or a .json saved by run --save-scenario FILE.json)",
    "view": "view recordings/FILE.rrd",
    "new": "exercise new my_exercise",
    "check": "exercise check my_exercise/my_filter.py",
    "show": "maze show paper_5x5",
}


def usage_hint(error: typer.TyperException, group: Any, argv: Sequence[str] = ()) -> str:
    """What to add to typer's usage errors so that they name the fix: for "No such option" at the top
    level, the commands that take that option and the command to type instead (`uv run main.py --seed 1`
    means `run --seed 1`); a decimal comma ("write 0.3"), a list given as several arguments ("--sigma
    0.2,0.4"), a missing argument (an example); '' when there is nothing to add."""
    message, args = error.format_message(), list(argv)
    name, ctx = getattr(error, "option_name", None), getattr(error, "ctx", None)
    if name and ctx is not None and ctx.command is group:
        commands = getattr(group, "commands", {}).items()
        takers = [command for command, cmd in commands if any(name in p.opts for p in getattr(cmd, "params", []))]
        if takers:
            first = "run" if "run" in takers else takers[0]
            given = shlex.join(args) if args else f"{name} ..."
            return f"; {name} is an option of {', '.join(takers)}: {command_prefix()} {first} {given}"
    name = getattr(getattr(error, "param", None), "opts", None)
    if name and "valid number" in message:  # the option's value as typed: --sigma 0,3 or --sigma=0,3
        values = [after for before, after in itertools.pairwise(args) if before in name]
        values += [token.split("=", 1)[1] for token in args if token.split("=", 1)[0] in name and "=" in token]
        decimal = next((decimal for decimal in map(decimal_comma, values) if decimal is not None), None)
        if decimal is not None:
            return f"; write {decimal} (a decimal point, not a comma)"
    extra = re.search(r"unexpected extra argument(?:s|\(s\))? \((.+)\)", message)
    if extra:
        first = extra.group(1).split()[0]
        at = args.index(first) if first in args else -1
        if at >= 2 and args[at - 2].startswith("--"):
            return f"; a list is one argument, comma-separated: {args[at - 2]} {args[at - 1]},{first}"
    if "Missing argument" in message or "Missing parameter" in message:
        command = getattr(ctx, "info_name", None)
        if command in ARGUMENT_EXAMPLES:
            return f"; e.g. {command_prefix()} {ARGUMENT_EXAMPLES[command]}"
    return ""


def refuse_option_as_value(argv: Sequence[str], group: Any) -> None:
    """`run --filter --no-viz` would take `--no-viz` as the filter's name: refuse an option that takes a
    value when what follows it is another option of the same command."""
    argv = list(argv)
    command = group
    for index, token in enumerate(argv):
        sub = getattr(command, "commands", {}).get(token)  # a subcommand (one level down for groups)
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


def main(argv: list[str] | None = None) -> int:
    """Run the CLI; problems with the input end as one line on stderr and exit code 2, a file that
    cannot be written as one line and exit code 1 (after the results are printed), each warning as
    one line (once in the command).

    A stopped study leaves Ctrl-C, SIGTERM and SIGHUP ignored until the process exits (a further one
    can neither hang nor interrupt the exit); called with `argv` (in-process), main puts the signal
    handlers back as it found them."""
    warned: set[str] = set()  # each warning once in the command; an earlier main(argv) in this process silences none

    def warn_in_one_line(message: Warning | str, category: type[Warning], *_args: Any, **_kwargs: Any) -> None:
        if str(message) not in warned:  # one line on stderr (e.g. sigma outside the lab's range), no source lines
            warned.add(str(message))
            typer.echo(f"warning: {message}", err=True)

    warnings.showwarning = warn_in_one_line
    remember_arguments(argv)
    handlers = {sig: signal.getsignal(sig) for sig in STOP_SIGNALS}
    unmark = mark_interrupts()  # Ctrl-C raises a marked KeyboardInterrupt: a filter's own is told apart
    group, args = typer.main.get_command(app), sys.argv[1:] if argv is None else argv
    try:
        refuse_option_as_value(args, group)
        with deferred_to_the_end():
            code = group.main(args=argv, standalone_mode=False)
        code = code if isinstance(code, int) else 0
    except typer.TyperException as error:  # typer's usage errors: bad option, bad value, missing argument
        hint = usage_hint(error, group, args)
        message = error.format_message()
        typer.echo(f"error: {message.rstrip('.') if hint else message}{hint}", err=True)
        code = 2
    except (UserError, MazeError, ValueError, StudentCodeError) as error:  # a ScenarioError is a ValueError
        typer.echo(f"error: {error}", err=True)
        code = 1 if isinstance(error, StudentCodeError) else 2  # the student's filter raised: not an input problem
    except OSError as error:  # a full disk, a file size limit, a read-only folder, a name too long: its file, why
        plain = isinstance(error, WriteError) or error.filename is None
        typer.echo(f"error: {error if plain else f'{error.filename}: {error.strerror or error}'}", err=True)
        code = 1
    except (KeyboardInterrupt, typer.Abort):
        typer.echo("interrupted", err=True)
        code = 130
    finally:
        unmark()
        if argv is not None:
            for sig, handler in handlers.items():
                signal.signal(sig, handler)
    if argv is None:  # a process of its own: a plug-in's forgotten thread must not keep it alive
        exit_without_strays(code, lambda line: typer.echo(line, err=True))
    return code
