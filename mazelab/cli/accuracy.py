"""`mazelab accuracy`: every filter against the exact grid posterior, with a progress bar, intervals,
a CSV of the runs and a JSON record beside it."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Annotated

import typer

from mazelab.atomic import write_text_atomically
from mazelab.checks import check_sigma_within
from mazelab.cli.backend_option import BackendOption
from mazelab.cli.filter_options import OptionFlag, options_per_filter, parse_option_texts
from mazelab.cli.options import DEFAULT_DELTA, DEFAULT_SIGMA, check_output_path, parse_list, seed_option
from mazelab.cli.outputs import check_one_file_each
from mazelab.cli.provenance import command_line
from mazelab.declaration import show_value
from mazelab.experiments.accuracy import (
    AccuracyStopped,
    accuracy_csv,
    accuracy_filters,
    accuracy_summary,
    accuracy_table,
    accuracy_tasks,
    run_accuracy,
)
from mazelab.experiments.executor import default_workers, progress_bar
from mazelab.experiments.plan import maze_description, study_mazes
from mazelab.experiments.record import Recorder, record_path
from mazelab.experiments.runs import parse_filters
from mazelab.experiments.study import MazeChoice
from mazelab.limits import check_particles, check_steps, check_study
from mazelab.mazes import LAB_MAZES
from mazelab.model import DEFAULT_PARTICLE_COUNT, DEFAULT_STEPS, check_model_parameters
from mazelab.registry import resolve_filter


def accuracy(
    maze: Annotated[
        str | None,
        typer.Option(help=f"maze files or names, comma-separated (default: the shipped {', '.join(LAB_MAZES)})"),
    ] = None,
    maze_size: Annotated[str | None, typer.Option(help="generated mazes ROWSxCOLUMNS, comma-separated")] = None,
    stations: Annotated[str | None, typer.Option(help="generated mazes' station blocks, comma-separated")] = None,
    filters: Annotated[
        str | None,
        typer.Option(
            metavar="NAMES", help="sir, apf, rpf, ekf or FILE.py:Class, comma-separated [default: SIR, APF, both RPFs]"
        ),
    ] = None,
    sigma: Annotated[float, typer.Option(help="measurement noise std")] = DEFAULT_SIGMA,
    delta: Annotated[float, typer.Option(help="compass error width, radians")] = DEFAULT_DELTA,
    particles: Annotated[int, typer.Option(min=1, help="particle count N_S")] = DEFAULT_PARTICLE_COUNT,
    runs: Annotated[int, typer.Option(min=1, help="seeded runs per maze")] = 10,
    steps: Annotated[int, typer.Option(min=2, help="steps per run (the distance is averaged over the second half)")] = (
        DEFAULT_STEPS
    ),
    seed: Annotated[
        int, typer.Option(callback=seed_option, help="root seed (run r has the same seed on every maze)")
    ] = 1,
    option: OptionFlag = None,
    workers: Annotated[int | None, typer.Option(min=1, help="processes (default: all cores)")] = None,
    csv_path: Annotated[Path | None, typer.Option("--csv", help="one row per maze, run and filter")] = None,
    record: Annotated[Path | None, typer.Option(help="the JSON record [default: beside --csv]")] = None,
    force: Annotated[bool, typer.Option("--force", help="replace existing output files")] = False,
    backend: BackendOption = None,
) -> None:
    """How close each filter comes to the exact posterior: per maze, the mean distance between its
    estimate and the exact grid filter's posterior mean over the second half of the steps (with a 95%
    bootstrap interval), and the share of runs that converged (error below 0.5 from some step on;
    Wilson interval)."""
    record_file = record if record is not None else record_path(csv_path) if csv_path is not None else None
    check_one_file_each([("--csv", csv_path), ("--record" if record is not None else "the record", record_file)])
    for path in (csv_path, record_file):
        if path is not None:
            check_output_path(path, force)
    mazes = accuracy_mazes(maze, maze_size, stations)
    chosen = with_options(accuracy_filters(None if filters is None else parse_filters(filters)), option)
    check_accuracy(mazes, chosen, sigma, delta, particles, runs, steps)
    tasks = accuracy_tasks([(m.label, m) for m in mazes], runs, sigma, delta, particles, steps, seed, chosen)
    labels = ", ".join(label for label, _, _ in chosen)
    typer.echo(
        f"Accuracy: {len(mazes)} maze(s) ({', '.join(m.label for m in mazes)}) x {runs} runs, sigma {sigma:g}, "
        f"delta {delta:g}, {particles} particles, {steps} steps, seed {seed}; filters: {labels}"
    )
    parameters = {
        "mazes": [maze_description(m) for m in mazes],
        "filters": [label for label, _, _ in chosen],
        "sigma": sigma, "delta": delta, "particles": particles, "runs": runs, "steps": steps, "root_seed": seed,
    }  # fmt: skip
    recorder = Recorder(
        "accuracy", command_line(), parameters, outputs={"csv": None if csv_path is None else str(csv_path)}
    )
    started = time.perf_counter()
    try:
        with progress_bar(len(tasks), True) as advance:
            records = run_accuracy(tasks, workers or default_workers(), advance)
    except AccuracyStopped as stop:  # the workers are ended; what finished is reported and saved
        done = len({(r.maze, r.run) for r in stop.records})
        if stop.records:
            report_accuracy(stop.records, time.perf_counter() - started, done, csv_path, record_file, recorder, force,
                            status="interrupted")  # fmt: skip
        typer.echo(f"interrupted after {done} of {len(tasks)} runs", err=True)
        raise typer.Exit(128 + stop.signum) from None
    report_accuracy(records, time.perf_counter() - started, len(tasks), csv_path, record_file, recorder, force)


def with_options(chosen: tuple, texts: list[str] | None) -> tuple:
    """The table's filters with the --option values each declares (its label then says so); an option
    none of them declares, or a bad value, is one line."""
    if not texts:
        return chosen
    names = list(dict.fromkeys(name for _, name, _ in chosen))
    given = parse_option_texts(texts, names)
    per_filter = options_per_filter(names, given)
    shown = ", ".join(f"{k} {show_value(v)}" for k, v in given.items())
    result = []
    for label, name, options in chosen:
        mine = per_filter[resolve_filter(name).name]
        result.append((f"{label} ({shown})" if mine else label, name, {**options, **mine}))
    return tuple(result)


def accuracy_mazes(maze: str | None, maze_size: str | None, stations: str | None) -> list[MazeChoice]:
    """The mazes of the table: the files named, the generated sizes, or the lab's shipped set (named,
    so that a maze a student adds to mazes/ does not join it)."""
    files = parse_list(maze, str, "--maze") if maze is not None else None
    if files is None and maze_size is None and stations is None:
        files = list(LAB_MAZES)
    sizes = parse_list(maze_size, str, "--maze-size") if maze_size is not None else None
    counts = parse_list(stations, int, "--stations") if stations is not None else None
    return study_mazes(files, sizes, counts) if files or sizes or counts else study_mazes(None)


def check_accuracy(
    mazes: list[MazeChoice], chosen: tuple, sigma: float, delta: float, particles: int, runs: int, steps: int
) -> None:
    """The table's size and numbers, refused before any work (--runs 10000000 included)."""
    check_model_parameters(sigma, delta)
    check_steps(steps)
    check_particles(particles)
    check_study(len(mazes) * runs, len(chosen))
    for choice in mazes:
        rows, columns = choice.size if choice.grid is None else (len(choice.grid), len(choice.grid[0]))
        check_sigma_within(sigma, columns, rows)


def report_accuracy(
    records: list, seconds: float, runs: int, csv_path: Path | None, record_file: Path | None,
    recorder: Recorder, force: bool, status: str = "finished",
) -> None:  # fmt: skip
    """The table, the time, the CSV and the record (its `status`: finished, or interrupted)."""
    typer.echo(accuracy_table(records))
    typer.echo(f"{runs} runs in {seconds:.1f} s wall time")
    if csv_path is not None:
        write_text_atomically(csv_path, accuracy_csv(records), replace=force)
        typer.echo(f"one row per maze, run and filter written to {csv_path}")
    if record_file is not None:
        recorder.finish(status, summary=accuracy_summary(records))
        recorder.write(record_file)
        typer.echo(f"the record (command, versions, seeds, mazes, summary) written to {record_file}")


__all__ = ["accuracy"]
