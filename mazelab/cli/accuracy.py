"""`mazelab accuracy`: every filter against the exact grid posterior, with a progress bar, intervals, a CSV
of the runs and a JSON record beside it. Each finished run is appended to a journal beside the outputs
(mazelab.experiments.journal): the same command after an interrupted one goes on from it (the runs it
finished are kept), and one of other parameters replaces what it left; a line says which."""

from __future__ import annotations

import dataclasses
import time
from pathlib import Path
from typing import Any

import typer

from mazelab.atomic import write_text_atomically
from mazelab.checks import check_sigma_within
from mazelab.cli.filter_options import OptionFlag, given_options, options_per_filter
from mazelab.cli.options import (
    DEFAULT_DELTA,
    DEFAULT_SIGMA,
    BackendOption,
    UserError,
    check_one_file_each,
    check_output_path,
    opt,
    parse_list,
    seed_option,
)
from mazelab.cli.provenance import command_line
from mazelab.declaration import show_value
from mazelab.experiments.accuracy import (
    AccuracyRecord,
    AccuracyStopped,
    accuracy_csv,
    accuracy_filters,
    accuracy_summary,
    accuracy_table,
    accuracy_tasks,
    run_accuracy,
)
from mazelab.experiments.executor import default_workers, progress_bar
from mazelab.experiments.journal import Journal, JournalError, journal_path, journal_state, read_journal
from mazelab.experiments.plan import maze_description, study_mazes
from mazelab.experiments.record import Recorder, differences, record_path
from mazelab.experiments.runs import parse_filters
from mazelab.experiments.study import MazeChoice
from mazelab.limits import check_particles, check_steps, check_study
from mazelab.mazes import LAB_MAZES
from mazelab.model import DEFAULT_PARTICLE_COUNT, DEFAULT_STEPS, check_model_parameters
from mazelab.registry import resolve_filter

Mazes = opt(str | None, help=f"maze files or names, comma-separated (default: the shipped {', '.join(LAB_MAZES)})")
Sizes = opt(str | None, help="generated mazes ROWSxCOLUMNS, comma-separated")
Stations = opt(str | None, help="generated mazes' station blocks, comma-separated")
Filters = opt(str | None, metavar="NAMES",
              help="sir, apf, rpf, ekf or FILE.py:Class, comma-separated [default: SIR, APF, both RPFs]")  # fmt: skip
Sigma, Delta = opt(float, help="measurement noise std"), opt(float, help="compass error width, radians")
Particles, Runs = opt(int, help="particle count N_S"), opt(int, min=1, help="seeded runs per maze")
Steps = opt(int, min=2, help="steps per run (the distance is averaged over the second half)")
Seed = opt(int, callback=seed_option, help="root seed (run r has the same seed on every maze)")
Workers = opt(int | None, min=1, help="processes (default: all cores)")
Csv = opt(Path | None, "--csv", help="one row per maze, run and filter")
Record = opt(Path | None, help="the JSON record [default: beside --csv]")
Force = opt(bool, "--force", help="replace existing output files")


def accuracy(
    maze: Mazes = None,
    maze_size: Sizes = None,
    stations: Stations = None,
    filters: Filters = None,
    sigma: Sigma = DEFAULT_SIGMA,
    delta: Delta = DEFAULT_DELTA,
    particles: Particles = DEFAULT_PARTICLE_COUNT,
    runs: Runs = 10,
    steps: Steps = DEFAULT_STEPS,
    seed: Seed = 1,
    option: OptionFlag = None,
    workers: Workers = None,
    csv_path: Csv = None,
    record: Record = None,
    force: Force = False,
    backend: BackendOption = None,
) -> None:
    """How close each filter comes to the exact posterior: per maze, the mean distance between its
    estimate and the exact grid filter's posterior mean over the second half of the steps (with a 95%
    bootstrap interval), and the share of runs that converged (error below 0.5 from some step on;
    Wilson interval)."""
    record_file = record if record is not None else record_path(csv_path) if csv_path is not None else None
    check_one_file_each([("--csv", csv_path), ("--record" if record is not None else "the record", record_file)])
    mazes = accuracy_mazes(maze, maze_size, stations)
    chosen = with_options(accuracy_filters(None if filters is None else parse_filters(filters)), option)
    check_accuracy(mazes, chosen, sigma, delta, particles, runs, steps)
    labels = [label for label, _, _ in chosen]
    parameters = {"mazes": [maze_description(m) for m in mazes], "filters": labels, "sigma": sigma, "delta": delta,
                  "particles": particles, "runs": runs, "steps": steps, "root_seed": seed}  # fmt: skip
    journal, kept, replace = open_journal(csv_path, record_file, parameters, force)
    tasks = accuracy_tasks([(m.label, m) for m in mazes], runs, sigma, delta, particles, steps, seed, chosen)
    typer.echo(f"Accuracy: {len(mazes)} maze(s) ({', '.join(m.label for m in mazes)}) x {runs} runs, sigma "
               f"{sigma:g}, delta {delta:g}, {particles} particles, {steps} steps, seed {seed}; filters: "
               f"{', '.join(labels)}")  # fmt: skip
    recorder = Recorder("accuracy", command_line(), parameters, outputs={"csv": csv_path and str(csv_path)})
    outputs = {"csv_path": csv_path, "record_file": record_file, "recorder": recorder, "replace": replace}
    run_and_report(tasks, kept, workers or default_workers(), journal, outputs)


def open_journal(
    csv_path: Path | None, record_file: Path | None, parameters: dict[str, Any], force: bool
) -> tuple[Journal | None, list[AccuracyRecord], bool]:
    """The journal beside the outputs, the runs kept from an interrupted run of the same command, and
    whether the outputs may be replaced: an earlier run's files are refused without --force, unless it
    was interrupted (no finished session in its journal): then it is resumed (the same parameters) or
    replaced, and a line says which."""
    journal = journal_path(csv_path or record_file) if csv_path or record_file else None
    lines = [] if journal is None or journal_state(journal) != "left" else read_journal(journal)
    sessions = [line["session"] for line in lines if "session" in line]
    interrupted = bool(sessions) and not any(line.get("closed", {}).get("status") == "finished" for line in lines)
    kept: list[AccuracyRecord] = []
    if interrupted and not force:
        changed = differences(sessions[-1].get("parameters", {}), parameters)
        if changed:
            typer.echo(
                f"replacing what an interrupted run left ({journal} and its outputs): its parameters differ "
                f"({changed[0]})"
            )
        else:
            kept = [AccuracyRecord(**row) for line in lines if "run" in line for row in line["records"]]
            typer.echo(f"resuming the interrupted run of {journal}: {len({(r.maze, r.run) for r in kept})} runs kept")
    for path in (csv_path, record_file):
        if path is not None:
            check_output_path(path, force or interrupted)
    if journal is None:
        return None, [], force
    try:
        opened = Journal(journal, adopt=bool(kept), replace=True)
    except JournalError as error:
        raise UserError(str(error)) from None
    opened.write({"session": {"command": command_line(), "parameters": parameters}})
    return opened, kept, force or interrupted


def run_and_report(
    tasks: list, kept: list[AccuracyRecord], workers: int, journal: Journal | None, outputs: dict[str, Any]
) -> None:
    """The runs not kept, each appended to the journal; then the table, the CSV and the record (an
    interrupted run's too, its status "interrupted")."""
    done = {(r.maze, r.run) for r in kept}
    todo = [task for task in tasks if (task.maze, task.run) not in done]
    order = {(task.maze, task.run): i for i, task in enumerate(tasks)}
    finished, started = list(kept), time.perf_counter()

    def append(records: list[AccuracyRecord]) -> None:
        finished.extend(records)
        if journal is not None:
            rows = [dataclasses.asdict(r) for r in records]
            journal.write({"run": [records[0].maze, records[0].run], "records": rows})

    stopped = None
    try:
        with progress_bar(len(todo), True) as advance:
            run_accuracy(todo, workers, advance, on_records=append)
    except AccuracyStopped as stop:  # the workers are ended; what finished is reported and saved
        stopped = stop
    if journal is not None:
        journal.write({"closed": {"status": "interrupted" if stopped else "finished"}})
        journal.close()
    runs = len({(r.maze, r.run) for r in finished})
    if finished:
        ordered = sorted(finished, key=lambda r: order[r.maze, r.run])
        report_accuracy(
            ordered, time.perf_counter() - started, runs, status="interrupted" if stopped else "finished", **outputs
        )
    if stopped is not None:
        typer.echo(f"interrupted after {runs} of {len(tasks)} runs", err=True)
        raise typer.Exit(128 + stopped.signum)


def with_options(chosen: tuple, texts: list[str] | None) -> tuple:
    """The table's filters with the --option values each declares (its label then says so); an option
    none of them declares, or a bad value, is one line."""
    if not texts:
        return chosen
    names = list(dict.fromkeys(name for _, name, _ in chosen))
    given = given_options({}, texts, names)
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
    files, sizes, counts = (
        parse_list(maze, str, "--maze"),
        parse_list(maze_size, str, "--maze-size"),
        parse_list(stations, int, "--stations"),
    )
    if files is None and sizes is None and counts is None:
        files = list(LAB_MAZES)
    return study_mazes(files, sizes, counts)


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
    records: list,
    seconds: float,
    runs: int,
    csv_path: Path | None,
    record_file: Path | None,
    recorder: Recorder,
    replace: bool,
    status: str = "finished",
) -> None:
    """The table, the time, the CSV and the record (its `status`: finished, or interrupted)."""
    typer.echo(accuracy_table(records))
    typer.echo(f"{runs} runs in {seconds:.1f} s wall time")
    if csv_path is not None:
        write_text_atomically(csv_path, accuracy_csv(records), replace=replace)
        typer.echo(f"one row per maze, run and filter written to {csv_path}")
    if record_file is not None:
        recorder.finish(status, summary=accuracy_summary(records))
        recorder.write(record_file)
        typer.echo(f"the record (command, versions, seeds, mazes, summary) written to {record_file}")


__all__ = ["accuracy"]
