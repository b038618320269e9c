"""The lab's example and its command-line interface.

python main.py                 the paper's example: a lost robot, SIR, 1500 particles, 200 steps
python main.py run --help      one run, with any maze, filter and parameters, or a saved scenario
python main.py bench [--quick] the filters' speed against a plain numpy reference step
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Annotated, Any

import numpy as np
import typer

from draw import Maze, MazeError
from particle_filter import (
    DEFAULT_PARTICLE_COUNT,
    DEFAULT_STEPS,
    Robot,
    RunResult,
    Scenario,
    ScenarioError,
    load_scenario,
    save_scenario,
    simulate,
)

MAZES_DIR = Path(__file__).resolve().parent / "mazes"
DEFAULT_MAZE = "maze_10x10"
DEFAULT_SIGMA, DEFAULT_DELTA = 0.3, 0.5

app = typer.Typer(
    add_completion=False,
    no_args_is_help=False,
    pretty_exceptions_enable=False,
    help="A robot lost in a maze, found by particle filters. Without a command: the paper's example.",
)


# Where a run is drawn: these four options sit on every command that runs filters.
ViewerOption = Annotated[bool, typer.Option("--viewer", help="open the native Rerun viewer (default with a display)")]
RrdOption = Annotated[Path | None, typer.Option("--rrd", help="save the Rerun recording to this file")]
WebOption = Annotated[bool, typer.Option("--web", help="serve the web viewer on 127.0.0.1")]
NoVizOption = Annotated[bool, typer.Option("--no-viz", help="draw nothing")]


def visualization(viewer: bool, rrd: Path | None, web: bool, no_viz: bool) -> Any:
    """The `visualize` argument of run_model for the command-line options (see draw.py)."""
    if sum([viewer, rrd is not None, web, no_viz]) > 1:
        raise UserError("choose one of --viewer, --rrd, --web and --no-viz")
    if no_viz:
        return False
    if rrd is not None:
        return rrd
    return "viewer" if viewer else "web" if web else True


class UserError(Exception):
    """An input problem reported as one line on stderr with exit code 2."""


def find_maze(name_or_path: str) -> Path:
    """A maze file path, or the name of a file in mazes/ (with or without .txt)."""
    path = Path(name_or_path)
    if path.exists():
        return path
    for candidate in (MAZES_DIR / name_or_path, MAZES_DIR / f"{name_or_path}.txt"):
        if candidate.exists():
            return candidate
    return path  # Maze.from_file reports it missing


def load_maze(name_or_path: str) -> Maze:
    return Maze.from_file(find_maze(name_or_path))


def summarise(result: RunResult) -> str:
    """A short report of a run: final error, convergence step, time per step."""
    errors = result.errors
    converged = result.converged_at
    when = f"converged at step {converged} (error < 0.5 from then on)" if converged else "not converged"
    return (
        f"{result.filter_name}: final error {errors[-1]:.3f}, mean error over the last 20% "
        f"{errors[-max(1, len(errors) // 5) :].mean():.3f}; {when}; "
        f"{1e3 * result.step_seconds.mean():.2f} ms per step; seed {result.scenario.seed}"
    )


def progress_printer(steps: int, every: int = 20) -> Any:
    """A per-step callback that prints the error every `every` steps."""

    def report(k: int, robot: Robot, filt: Any) -> None:
        if k % every == 0 or k == steps:
            error = float(np.hypot(*(filt.estimate - np.array(robot.position))))
            state = "confident" if filt.is_confident else "searching"
            typer.echo(f"  step {k:4d}/{steps}: error {error:6.3f}  ({state})")

    return report


def check_output_path(path: Path, force: bool) -> None:
    """Refuse to overwrite an existing file without --force, or to write into a missing folder."""
    if path.exists() and not force:
        raise UserError(f"{path} exists; use --force to replace it")
    if not path.parent.exists():
        raise UserError(f"{path.parent} does not exist: cannot write {path.name} there")


@app.callback(invoke_without_command=True)
def demo(
    ctx: typer.Context,
    viewer: ViewerOption = False,
    rrd: RrdOption = None,
    web: WebOption = False,
    no_viz: NoVizOption = False,
) -> None:
    """The paper's example: a lost robot, the SIR filter, 1500 particles, 200 steps."""
    if ctx.invoked_subcommand is not None:
        return
    visualize = visualization(viewer, rrd, web, no_viz)
    world = load_maze(DEFAULT_MAZE)
    seed = int(np.random.SeedSequence().entropy % 2**31)
    robot = Robot(DEFAULT_SIGMA, DEFAULT_DELTA, world.random_free_place(np.random.default_rng(seed)))
    typer.echo(
        f"A robot is lost in {find_maze(DEFAULT_MAZE).name} ({world.height}x{world.width}, "
        f"{len(world.stations)} stations); SIR with {DEFAULT_PARTICLE_COUNT} particles looks for it."
    )
    result = simulate(
        robot,
        world,
        DEFAULT_SIGMA,
        DEFAULT_DELTA,
        DEFAULT_PARTICLE_COUNT,
        DEFAULT_STEPS,
        seed=seed,
        visualize=visualize,
        on_step=progress_printer(DEFAULT_STEPS),
    )
    typer.echo(summarise(result))
    typer.echo(f"Repeat this run: python main.py run --seed {seed} --start-seed {seed}")


@app.command()
def run(
    maze: Annotated[str | None, typer.Option(help=f"maze file, or a name in mazes/ [default: {DEFAULT_MAZE}]")] = None,
    filter_name: Annotated[str, typer.Option("--filter", help="sir, apf, rpf or grid (or a class name)")] = "sir",
    particles: Annotated[int, typer.Option(min=1, help="particle count N_S")] = DEFAULT_PARTICLE_COUNT,
    steps: Annotated[int, typer.Option(min=1, help="number of steps")] = DEFAULT_STEPS,
    sigma: Annotated[float | None, typer.Option(help="measurement noise std [0.2, 0.8]")] = None,
    delta: Annotated[float | None, typer.Option(help="compass error width, radians [0.05, 0.6]")] = None,
    seed: Annotated[int | None, typer.Option(help="seed of the run (robot, particles, filter)")] = None,
    start_seed: Annotated[int | None, typer.Option(help="seed of the robot's start position")] = None,
    scenario: Annotated[Path | None, typer.Option(help="replay a saved scenario json")] = None,
    save_scenario_path: Annotated[Path | None, typer.Option("--save-scenario", help="save the run as json")] = None,
    force: Annotated[bool, typer.Option(help="replace an existing output file")] = False,
    quiet: Annotated[bool, typer.Option(help="no per-step progress")] = False,
    viewer: ViewerOption = False,
    rrd: RrdOption = None,
    web: WebOption = False,
    no_viz: NoVizOption = False,
) -> None:
    """Run one filter: on a fresh lost robot, or replaying a saved scenario (--scenario)."""
    visualize = visualization(viewer, rrd, web, no_viz)
    if save_scenario_path is not None:
        check_output_path(save_scenario_path, force)
    if scenario is not None:
        world, robot, sigma, delta, init_particles = from_scenario(load_scenario(scenario), maze, sigma, delta)
        particles_arg, steps_arg = None, None
    else:
        world = load_maze(maze or DEFAULT_MAZE)
        sigma = DEFAULT_SIGMA if sigma is None else sigma
        delta = DEFAULT_DELTA if delta is None else delta
        robot = Robot(sigma, delta, world.random_free_place(np.random.default_rng(start_seed)))
        init_particles, particles_arg, steps_arg = None, particles, steps
    total = steps_arg or robot.recorded_steps
    result = simulate(
        robot,
        world,
        sigma,
        delta,
        particles_arg,
        steps_arg,
        init_particles,
        filter_name,
        seed=seed,
        visualize=visualize,
        on_step=None if quiet else progress_printer(total),
    )
    typer.echo(summarise(result))
    if save_scenario_path is not None:
        typer.echo(f"scenario saved to {save_scenario(result.scenario, save_scenario_path)}")


@app.command()
def bench(
    quick: Annotated[bool, typer.Option(help="fewer sizes and steps: about half a minute")] = False,
) -> None:
    """Measure the filters' speed (particle-steps per second) against a plain numpy reference step."""
    from benchmark import run_benchmark  # only this command needs it

    run_benchmark(load_maze(DEFAULT_MAZE), quick=quick, echo=typer.echo)


def from_scenario(
    scenario: Scenario, maze: str | None, sigma: float | None, delta: float | None
) -> tuple[Maze, Robot, float, float, list]:
    """World, robot, sigma, delta and particles of a saved scenario; flags override stored values."""
    stored = scenario.world()
    world = stored if stored is not None else load_maze(maze or DEFAULT_MAZE)
    if stored is not None and maze is not None:
        given = load_maze(maze)
        if not np.array_equal(given.grid, stored.grid):
            raise UserError(f"the scenario's maze differs from {given.source}; leave out --maze to use the stored one")
    sigma = sigma if sigma is not None else scenario.sigma if scenario.sigma is not None else DEFAULT_SIGMA
    delta = delta if delta is not None else scenario.delta if scenario.delta is not None else DEFAULT_DELTA
    robot = scenario.robot(sigma, delta)
    return world, robot, sigma, delta, scenario.init_particles_pos


def main(argv: list[str] | None = None) -> int:
    """Run the CLI; problems with the input end as one line on stderr and exit code 2."""
    try:
        code = app(args=argv, standalone_mode=False)
    except typer.TyperException as error:  # typer's usage errors: bad option, bad value, missing argument
        typer.echo(f"error: {error.format_message()}", err=True)
        return 2
    except (UserError, MazeError, ScenarioError, ValueError) as error:
        typer.echo(f"error: {error}", err=True)
        return 2
    except (KeyboardInterrupt, typer.Abort):
        typer.echo("interrupted", err=True)
        return 130
    return code if isinstance(code, int) else 0


if __name__ == "__main__":
    sys.exit(main())
