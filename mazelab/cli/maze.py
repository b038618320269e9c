"""`mazelab maze generate` and `mazelab maze show`: random connected mazes, and a look at any maze."""

from __future__ import annotations

import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import typer

from mazelab import maze_generator
from mazelab.atomic import write_atomically
from mazelab.cli.options import arg, check_outputs, opt, seed_option, visualization, with_drawing
from mazelab.invocation import command_prefix
from mazelab.maze import Maze, load_maze
from mazelab.seeding import new_seed
from mazelab.viz.views import open_view

maze_app = typer.Typer(
    no_args_is_help=True, rich_markup_mode=None, help="Random connected mazes (generate) and a look at any maze (show)."
)


@maze_app.command("generate", short_help="A random maze with a connected free area.")
def maze_generate(
    size: opt(str, help="ROWSxCOLUMNS") = "10x10",
    stations: opt(int | None, min=1, help="station blocks (default: one per 25 cells)", show_default=False) = None,
    walls: opt(float, "--wall-share", help="share of the cells that are walls") = maze_generator.DEFAULT_WALL_SHARE,
    old_walls: opt(float | None, "--walls", hidden=True, help="the former --wall-share") = None,
    seed: opt(int | None, callback=seed_option, help="the same seed gives the same maze") = None,
    out: opt(Path | None, help="write the maze file here (default: print it)") = None,
    force: opt(bool, "--force", help="replace an existing file") = False,
) -> None:
    """A random maze whose free area is connected, in the mazes/ file format."""
    walls = walls if old_walls is None else old_walls  # --walls: its earlier spelling
    check_outputs([("--out", out)], force)
    rows, columns = maze_generator.parse_size(size)
    stations = maze_generator.default_station_count(rows, columns) if stations is None else stations
    seed = new_seed() if seed is None else seed
    big = rows * columns >= PROGRESS_CELLS  # a small maze is made in a blink
    progress = ProgressLine(f"generating a {rows}x{columns} maze") if big else None
    world = maze_generator.generate_maze(rows, columns, stations, np.random.default_rng(seed), walls, progress)
    command = f"{command_prefix()} maze generate --size {rows}x{columns} --stations {stations} --seed {seed}"
    if walls != maze_generator.DEFAULT_WALL_SHARE:
        command += f" --wall-share {walls:g}"
    text = maze_generator.maze_file_text(world, command)
    if out is None:
        typer.echo(text, nl=False)
    else:
        write_atomically(out, text, replace=force)
        typer.echo(f"{maze_generator.describe_maze(world)}; written to {out}")


@maze_app.command("show", short_help="Print a maze; --viewer, --rrd or --web draw it.")
@with_drawing
def maze_show(path: arg(str, "MAZE", "a maze file, or a name in mazes/"), *, drawing: dict[str, Any]) -> None:
    """Print a maze as text ('##' wall, '[]' station block, '. ' free); --viewer/--rrd/--web also log it to Rerun."""
    visualize = visualization(**drawing, unasked=False)
    world = load_maze(path)
    typer.echo(maze_generator.maze_picture(world), nl=False)
    typer.echo(f"{world.source}: {maze_generator.describe_maze(world)}")
    if visualize:
        open_view(visualize, world, "maze").close()  # opening a view logs the maze


# -- progress lines for a large maze ---------------------------------------------------------------------
PROGRESS_CELLS = 2**18  # generating a maze this large (512 x 512), or its nearest-station table, takes seconds


def prepare_world(world: Maze, min_cells: int = PROGRESS_CELLS) -> Maze:
    """Build a large maze's nearest-station table up front, with a progress line on stderr (a 1000 x
    1000 maze takes tens of seconds); a small maze's table is built on first use, silently."""
    if world.lookup_cells >= min_cells and not world.has_lookup:
        world.prepare(ProgressLine(f"building the nearest-station table of {world.source}"))
    return world


class ProgressLine:
    """progress(done, total) as one line on stderr: redrawn in place on a terminal, else a line at the
    start and one at the end (a log file gets no carriage returns)."""

    def __init__(self, what: str):
        self.what = what
        self.started = time.perf_counter()
        self.shown = -1  # the last percentage drawn
        self.terminal = sys.stderr.isatty()
        typer.echo(f"{what} ...", err=True, nl=not self.terminal)

    def __call__(self, done: int, total: int) -> None:
        percent = 100 * done // max(total, 1)
        if done == total:
            seconds = time.perf_counter() - self.started
            start = "\r" if self.terminal else ""
            typer.echo(f"{start}{self.what}: done in {seconds:.1f} s", err=True)
        elif self.terminal and percent != self.shown:
            typer.echo(f"\r{self.what}: {percent}%", err=True, nl=False)
        self.shown = percent
