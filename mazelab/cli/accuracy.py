"""`mazelab accuracy`: every filter against the exact grid posterior (mazelab.experiments.accuracy, a study
with the grid as its reference), with a progress bar, intervals, a CSV of the runs and a JSON record beside
it. Each finished run is appended to the study's journal beside the outputs (mazelab.experiments.journal):
the same command after an interrupted one goes on from it (the runs it finished are kept), and one of other
parameters replaces what it left; a line says which."""

from __future__ import annotations

import signal
import time
from pathlib import Path
from typing import Any

import typer

from mazelab.atomic import write_text_atomically
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
from mazelab.declaration import show_value
from mazelab.experiments.accuracy import (
    AccuracyFilter,
    AccuracyRecord,
    accuracy_csv,
    accuracy_filters,
    accuracy_plan,
    accuracy_records,
    accuracy_summary,
    accuracy_table,
)
from mazelab.experiments.executor import default_workers, run_study, study_backend
from mazelab.experiments.journal import (
    Journal,
    JournalError,
    journal_parameters,
    journal_path,
    journal_state,
    read_journal,
    resume_study,
)
from mazelab.experiments.plan import StudyPlan, maze_description, study_mazes
from mazelab.experiments.record import Recorder, differences, record_path
from mazelab.experiments.runs import parse_filters
from mazelab.experiments.study import MazeChoice, RunRecord, RunTask
from mazelab.invocation import command_line
from mazelab.mazes import LAB_MAZES
from mazelab.model import DEFAULT_PARTICLE_COUNT, DEFAULT_STEPS
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
    rows = with_options(accuracy_filters(None if filters is None else parse_filters(filters)), option)
    plan = accuracy_plan(mazes, rows, sigma=sigma, delta=delta, particles=particles, runs=runs, steps=steps,
                         seed=seed)  # fmt: skip
    labels = [label for label, _, _ in rows]
    parameters = {"mazes": [maze_description(m) for m in mazes], "filters": labels, "sigma": sigma, "delta": delta,
                  "particles": particles, "runs": runs, "steps": steps, "root_seed": seed}  # fmt: skip
    workers = workers or default_workers()
    journal, tasks, kept, replace = open_journal(csv_path, record_file, plan, rows, force, workers)
    typer.echo(f"Accuracy: {len(mazes)} maze(s) ({', '.join(m.label for m in mazes)}) x {runs} runs, sigma "
               f"{sigma:g}, delta {delta:g}, {particles} particles, {steps} steps, seed {seed}; filters: "
               f"{', '.join(labels)}")  # fmt: skip
    recorder = Recorder("accuracy", command_line(), parameters, outputs={"csv": csv_path and str(csv_path)})
    outputs = {"csv_path": csv_path, "record_file": record_file, "recorder": recorder, "replace": replace}
    run_and_report(plan, rows, tasks, kept, workers, journal, outputs)


def open_journal(
    csv_path: Path | None, record_file: Path | None, plan: StudyPlan, rows: tuple[AccuracyFilter, ...], force: bool,
    workers: int,
) -> tuple[Journal | None, list[RunTask], list[RunRecord], bool]:  # fmt: skip
    """The journal beside the outputs, the runs to go and those kept from an interrupted run of the same
    command, and whether the outputs may be replaced: an earlier run's files are refused without --force,
    unless it was interrupted (no finished session in its journal): then it is resumed (the same
    parameters, mazelab.experiments.journal.resume_study) or replaced, and a line says which."""
    journal = journal_path(csv_path or record_file) if csv_path or record_file else None
    lines = [] if journal is None or journal_state(journal) != "left" else read_journal(journal)
    finished = any(line.get("closed", {}).get("status") == "finished" for line in lines)
    interrupted = any("session" in line for line in lines) and not finished
    tasks, kept = plan.tasks(), []
    if interrupted and not force:
        try:
            changed = differences(journal_parameters(journal, lines), plan.parameters(), ignore=("runs",))
            if changed:
                raise JournalError(f"its parameters differ ({changed[0]})")
            tasks, kept, _ = resume_study(journal, lines, plan, study_backend(tasks, workers))
        except JournalError as error:
            why = str(error).removeprefix("--resume: ")
            typer.echo(f"replacing what an interrupted run left ({journal} and its outputs): {why}")
        else:
            done = {(r.maze, r.run) for r in accuracy_records(kept, rows)}
            typer.echo(f"resuming the interrupted run of {journal}: {len(done)} runs kept")
    for path in (csv_path, record_file):
        if path is not None:
            check_output_path(path, force or interrupted)
    if journal is None:
        return None, tasks, [], force
    try:
        opened = Journal(journal, adopt=bool(kept), replace=True)
    except JournalError as error:
        raise UserError(str(error)) from None
    opened.write({"session": {"command": command_line(), "parameters": plan.parameters()}})
    return opened, tasks, kept, force or interrupted


def run_and_report(
    plan: StudyPlan, rows: tuple[AccuracyFilter, ...], tasks: list[RunTask], kept: list[RunRecord], workers: int,
    journal: Journal | None, outputs: dict[str, Any],
) -> None:  # fmt: skip
    """The runs not kept, each appended to the journal; then the table, the CSV and the record (an
    interrupted run's too, its status "interrupted")."""
    started = time.perf_counter()

    def append(records: list[RunRecord]) -> None:
        if journal is not None:
            journal.write({"run": [records[0].setting, records[0].run], "records": [r.to_json() for r in records]})

    outcome = run_study(tasks, workers, progress=True, on_records=append, ignore_signals_after_stop=True)
    stopped = outcome.interrupted or outcome.lost is not None
    if journal is not None:
        journal.write({"closed": {"status": "interrupted" if stopped else "finished"}})
        journal.close()
    for failure in outcome.failures:
        typer.echo(f"error: {failure.describe()}", err=True)
    records = accuracy_records(sorted([*kept, *outcome.records], key=lambda r: (r.setting, r.run)), rows)
    runs = len({(r.maze, r.run) for r in records})
    if records:
        seconds = time.perf_counter() - started
        report_accuracy(records, seconds, runs, status="interrupted" if stopped else "finished", **outputs)
    total = len({s.maze for s in plan.settings}) * plan.runs
    if outcome.lost is not None:
        typer.echo(f"error: {outcome.lost}; {runs} of {total} runs finished", err=True)
    elif stopped:
        typer.echo(f"interrupted after {runs} of {total} runs", err=True)
        raise typer.Exit(128 + (outcome.stopped_by or signal.SIGINT))
    if outcome.failures or outcome.lost is not None:
        raise typer.Exit(1)


def with_options(chosen: tuple[AccuracyFilter, ...], texts: list[str] | None) -> tuple[AccuracyFilter, ...]:
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


def report_accuracy(
    records: list[AccuracyRecord],
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
