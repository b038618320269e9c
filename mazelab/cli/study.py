"""`mazelab study` (lab step 14, docs/studies.md; its Python twin is `mazelab.study`) and `mazelab
accuracy` (every filter against the exact grid posterior, mazelab.experiments.accuracy): the flags make
the plan (mazelab.experiments.api), the files are checked before any work (`StudyFiles`), the runs go to
the executor, each finished run appended to the journal (mazelab.experiments.journal) from which an
interrupted study goes on (--resume; accuracy by itself), and the report writes the table and the files."""

from __future__ import annotations

import dataclasses
import functools
import signal
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import typer

from mazelab.atomic import WriteError, write_atomically
from mazelab.backend import cores
from mazelab.cli.options import (
    DRAWING,
    BackendOption,
    Force,
    KidnapAt,
    OptionFlag,
    StudyOptionFlag,
    UserError,
    check_filter_names,
    check_outputs,
    given_options,
    opt,
    parse_list,
    repeat_line,
    seed_option,
    visualization,
    with_option_flags,
    with_parameters,
)
from mazelab.constants import DEFAULT_DELTA, DEFAULT_SIGMA
from mazelab.declaration import show_value
from mazelab.experiments.accuracy import (
    AccuracyFilter,
    accuracy_csv,
    accuracy_filters,
    accuracy_plan,
    accuracy_records,
    accuracy_summary,
    accuracy_table,
)
from mazelab.experiments.api import StudyPlan, maze_description, plan_study, study_closing, study_mazes
from mazelab.experiments.executor import (
    DASK_TIMEOUT,
    StudyOutcome,
    close_client,
    open_cluster,
    run_study,
    study_backend,
)
from mazelab.experiments.journal import (
    Journal,
    JournalError,
    Recorder,
    claim_outputs,
    journal_parameters,
    journal_path,
    journal_state,
    jsonable,
    left_over,
    read_journal,
    record_path,
    resume_study,
)
from mazelab.experiments.runs import options_per_filter, parse_filters
from mazelab.experiments.study import MazeChoice, RunRecord, RunTask, study_order
from mazelab.experiments.summary import CSV_DTYPES, study_table, summarise_study, summary_csv, summary_path
from mazelab.experiments.tables import records_csv, study_traces, write_traces
from mazelab.invocation import command_line, resume_command
from mazelab.maze import DEFAULT_MAZE, LAB_MAZES
from mazelab.model import DEFAULT_PARTICLE_COUNT, DEFAULT_STEPS
from mazelab.registry import filter_entry, resolve_filter
from mazelab.viz.style import DEFAULT_MAX_DRAWN

FILES = {
    "csv_path": (opt(Path | None, "--csv", help="one row per run and filter"), None),
    "plot": (opt(Path | None, "--plot", help="the figure: .png, .pdf or .svg (the suffix chooses)"), None),
    "summary_csv": (opt(Path | None, "--summary-csv", help="the table as CSV [default: CSV.summary.csv]"), None),
    "traces": (opt(Path | None, "--traces", help="per-step rows of every run (.csv, .parquet)"), None),
    "record": (opt(Path | None, "--record", help="JSON record [default: CSV.record.json]"), None),
    "resume": (opt(bool, "--resume", help="run only the runs missing from --csv's journal"), False),
    "force": (Force, False),
}
FIGURE = {
    "paired": (
        opt(str | None, "--paired", metavar="FILTER", help="each filter's difference to FILTER, run by run"),
        None,
    ),
    "plot_x": (opt(str | None, "--plot-x", metavar="PARAMETER", help="the figure's x axis, a varied parameter"), None),
    "plot_y": (
        opt(str, "--plot-y", metavar="Y", show_default=False, help="mean, median, converged, exact, paired, evidence"),
        "mean",
    ),
    "title": (opt(str | None, "--title", help="the figure's title (no caption then)"), None),
}
# a study draws nothing unless asked (--no-viz is its default) and one run when asked (--max-drawn rarely matters)
DRAWN = {
    **DRAWING,
    "no_viz": (opt(bool, "--no-viz", hidden=True), False),
    "max_drawn": (opt(int, "--max-drawn", min=1, hidden=True), DEFAULT_MAX_DRAWN),
}


def positive_seconds(value: float) -> float:
    """--dask-timeout: a positive number of seconds (typer names the option in its one-line error)."""
    if not 0 < value < float("inf"):
        raise typer.BadParameter(f"seconds must be a positive number, got {value}")
    return value


Workers = opt(int | None, min=1, help="processes (default: all cores)")
StudyFilters = opt(str, metavar="NAMES", show_default=False, help="a list (mazelab filters) [default: sir,apf,rpf]")
DaskTimeout = opt(
    float,
    metavar="<s>",
    callback=positive_seconds,
    show_default=False,
    help="give up after s idle seconds [default: 300]",
)
AccuracyMazes = opt(
    str | None, help=f"maze files or names, comma-separated (default: the shipped {', '.join(LAB_MAZES)})"
)
AccuracyFilters = opt(
    str | None,
    metavar="NAMES",
    help="sir, apf, rpf, ekf or FILE.py:Class, comma-separated [default: SIR, APF, both RPFs]",
)


# what a study's plan takes as given (plan_study), and how it runs (in this order in --help, after the values)
PLAN = {
    "kidnap_at": (KidnapAt, None),
    "option": (StudyOptionFlag, None),
    "runs": (opt(int, min=1, help="seeded runs per setting"), 30),
    "steps": (opt(int, min=1, help="steps per run"), DEFAULT_STEPS),
    "seed": (opt(int | None, callback=seed_option, help="root seed (default: new, printed)"), None),
    "reference": (opt(str | None, metavar="grid", help="the exact grid filter too: distance_to_exact"), None),
}
EXECUTION = {
    "workers": (Workers, None),
    "dask": (opt(str | None, help="a Dask scheduler, tcp://HOST:PORT"), None),
    "dask_timeout": (DaskTimeout, DASK_TIMEOUT),
    "draw_run": (opt(int, help="the run --viewer/--rrd/--web draw", show_default=False), 1),
    "backend": (BackendOption, None),  # its callback sets the backend
}


@with_parameters("files", FILES)
@with_parameters("figure", FIGURE)
@with_parameters("drawing", DRAWN)
@with_parameters("execution", EXECUTION)
@with_parameters("planned", PLAN)
@with_option_flags(lists=True)
def study(
    maze: opt(str | None, help=f"mazes (files or names) [default: {DEFAULT_MAZE}]") = None,
    maze_size: opt(str | None, help="generated mazes ROWSxCOLUMNS, a list") = None,
    stations: opt(str | None, help="generated mazes' station blocks, a list") = None,
    wall_share: opt(str | None, help="generated mazes' wall shares, a list") = None,
    sigma: opt(str, help="noise std sigma, a list") = str(DEFAULT_SIGMA),
    delta: opt(str, help="compass error, a list") = str(DEFAULT_DELTA),
    particles: opt(str, help="particle counts, a list") = str(DEFAULT_PARTICLE_COUNT),
    filters: StudyFilters = "sir,apf,rpf",
    *,
    named: dict[str, Any],
    planned: dict[str, Any],
    execution: dict[str, Any],
    drawing: dict[str, Any],
    figure: dict[str, Any],
    files: dict[str, Any],
) -> None:
    """Lab step 14: a study of every combination of the values (docs/studies.md)."""
    chosen = StudyFiles.parse(**files, rrd=drawing.get("rrd"))
    visualize = visualization(**drawing, force=chosen.force, unasked=False)
    planned["seed"] = chosen.seed if planned["seed"] is None else planned["seed"]  # resumed: its journal's
    names = parse_filters(check_filter_names(filters))
    given = given_options(named, planned.pop("option"), names, lists=True)  # the named flags and --option NAME=V1,V2
    mazes = parse_mazes(maze, maze_size, stations, wall_share)
    model = {
        "sigma": parse_list(sigma, float, "--sigma"),
        "delta": parse_list(delta, float, "--delta"),
        "particles": parse_list(particles, int, "--particles"),
    }
    values = {**model, **given}  # the model's values and the options', each a list
    plan = plan_study(mazes, names, values, traces=chosen.traces is not None, spelled=given.spelled, **planned)
    figure = check_figure(plan, **figure)
    workers, dask = execution["workers"] or cores(), execution["dask"]
    backend = study_backend(plan.tasks, 1 if dask else workers)
    header = plan.header(f"on the Dask cluster at {dask}" if dask is not None else f"{workers} worker(s)", backend)
    session = open_session(
        plan, chosen, backend, header, visualize=visualize, draw_run=execution["draw_run"], dask=dask
    )
    if chosen.resume:
        typer.echo(f"resuming: {len(session.kept)} rows kept from {chosen.journal}, {len(session.tasks)} run(s) to go")
    report = functools.partial(report_study, session, figure=figure)
    session.run(workers, report, visualize, dask_timeout=execution["dask_timeout"])


def check_figure(
    plan: StudyPlan,
    paired: str | None = None,
    plot_x: str | None = None,
    plot_y: str = "mean",
    title: str | None = None,
) -> dict[str, Any]:
    """What the report adds to the table and the figure, checked before any run: --paired one of the
    study's filters (given by its name), --plot-x, --plot-y and --title as the figure takes them
    (study_plot.figure_axes), by draw_study's names (x, y, title)."""
    from mazelab.experiments.study_plot import figure_axes

    figure_axes(plan.varied, plot_x, plot_y, title, exact=plan.reference is not None, paired=paired is not None)
    if paired is not None:
        entries = [filter_entry(f) for f in plan.filters]
        chosen = resolve_filter(check_filter_names(paired, "--paired")).name
        if chosen not in [entry.name for entry in entries]:
            shown = ", ".join(entry.reference for entry in entries)
            raise UserError(f"--paired {paired}: not one of the study's --filters ({shown})")
        if len(entries) == 1:
            raise UserError(
                f"--paired {paired}: the study's only filter, paired with itself (every difference "
                "0); add the filters to compare with it to --filters"
            )
        paired = chosen
    return {"paired": paired, "x": plot_x, "y": plot_y, "title": title}


@dataclass
class StudyFiles:
    """The study's files, checked before any work: the CSV and its journal, the figure, the traces, the
    record and the summary CSV; with --resume, the journal's lines to go on with."""

    csv_path: Path | None
    plot: Path | None
    traces: Path | None
    record_file: Path | None
    summary_csv: Path | None
    journal: Path | None
    resume: bool
    force: bool
    lines: list[dict[str, Any]] = dataclasses.field(default_factory=list)
    seed: int | None = None  # a resumed study's root seed, its journal's
    replaces: bool = False  # an interrupted run's journal that does not match is replaced (accuracy's), not refused

    @classmethod
    def parse(
        cls,
        csv_path: Path | None = None,
        plot: Path | None = None,
        summary_csv: Path | None = None,
        traces: Path | None = None,
        record: Path | None = None,
        resume: bool = False,
        force: bool = False,
        rrd: Path | None = None,
    ) -> StudyFiles:
        """One line for two outputs that are one file, a name that exists without --force, a folder, a
        device, a journal another study writes or an earlier one left (without --resume or --force);
        --resume replaces its own outputs."""
        record_file = record or next((record_path(p) for p in (csv_path, plot, traces) if p), None)
        summary_named = "--summary-csv" if summary_csv is not None else "the summary CSV"
        summary_csv = summary_csv or (summary_path(csv_path) if csv_path is not None else None)
        journal = journal_path(csv_path) if csv_path is not None else None
        files = cls(csv_path, plot, traces, record_file, summary_csv, journal, resume, force)
        files.check_journal()
        outputs = [
            ("--csv", csv_path),
            ("--csv's journal", journal),
            ("--plot", plot),
            ("--traces", traces),
            ("--record" if record else "the record", record_file),
            ("--rrd", rrd),
            (summary_named, summary_csv),
        ]
        check_outputs(outputs, force or resume, apart="--csv's journal")
        return files

    @classmethod
    def left_by_accuracy(cls, csv_path: Path | None, record: Path | None, force: bool) -> StudyFiles:
        """accuracy's outputs (the record --record, else beside the CSV) and their journal (beside the CSV, else
        the record): an earlier run's files are refused without --force, unless it was interrupted (no finished
        session in its journal): then it is resumed, or replaced if it is not this run's (`open_session`)."""
        record_file = record if record is not None else record_path(csv_path) if csv_path is not None else None
        journal = journal_path(csv_path or record_file) if csv_path or record_file else None
        lines = [] if journal is None or journal_state(journal) != "left" else read_journal(journal)
        finished = any(line.get("closed", {}).get("status") == "finished" for line in lines)
        interrupted = any("session" in line for line in lines) and not finished
        check_outputs(
            [("--csv", csv_path), ("the record" if record is None else "--record", record_file)], force or interrupted
        )
        resume = interrupted and not force
        return cls(csv_path, None, None, record_file, None, journal, resume, force or bool(lines), lines, replaces=True)

    def check_journal(self) -> None:
        """The journal beside the CSV: being written by another study (refused), left by an earlier one
        (refused without --resume or --force), or read whole for --resume."""
        if self.journal is None:
            if self.resume:
                raise UserError("--resume needs the study's --csv (its journal lies beside it)")
            return
        state = journal_state(self.journal)
        if state == "busy":
            raise UserError(f"another study is writing {self.journal}: give this one another --csv")
        if state == "left" and not (self.resume or self.force):
            raise UserError(left_over(self.journal))
        if self.resume and state is None:
            raise UserError(
                f"--resume: no journal {self.journal} beside {self.csv_path} to go on from (an earlier "
                "version kept none): run the study again with --force"
                if self.csv_path.exists()
                else f"--resume: {self.csv_path} does not exist (nothing to resume; leave out --resume)"
            )
        if self.resume:
            try:
                self.lines = read_journal(self.journal)
                self.seed = journal_parameters(self.journal, self.lines)["root_seed"]
            except JournalError as error:
                raise UserError(f"--resume: {error}") from None


@dataclass
class StudySession:
    """One session of a study: its plan and files, the runs to go, the runs kept from earlier sessions
    (--resume), the backend, the journal, the Dask client, the record and the claimed outputs."""

    plan: StudyPlan
    files: StudyFiles
    tasks: list[RunTask]
    kept: list[RunRecord]
    backend: str
    journal: Journal | None
    client: Any
    recorder: Recorder
    release: Callable[[], None]

    def run(self, workers: int, report: Callable[[StudyOutcome], None], visualize: Any = False, **extra: Any) -> None:
        """Run the tasks on `workers` processes or the session's cluster (run_study: a progress bar, each finished
        run appended to the journal, the stop signals ignored after a stop), the failures printed, then
        `report` the outcome (exit 1 after it when a run failed); the session closed however it ends."""
        try:
            outcome = run_study(
                self.tasks,
                workers,
                visualize=visualize,
                progress=True,
                on_records=None if self.journal is None else self.journal.append_run,  # each finished run's rows
                dask=self.client,
                ignore_signals_after_stop=True,
                backend=self.backend,
                **extra,
            )
            for failure in outcome.failures:  # first: a report that fails to write cannot lose them
                typer.echo(f"error: {failure.describe()}", err=True)
            report(outcome)
            if outcome.failures:
                raise typer.Exit(1)
        finally:
            self.close()

    def close(self, status: str | None = None, **closing: Any) -> None:
        """The session's last line in the journal (with `status`), the journal, the cluster and the claims
        released."""
        if self.journal is not None and status is not None:
            self.journal.end_session(status, ended=self.recorder.data.get("ended"), **closing)  # and closes it
        elif self.journal is not None:
            self.journal.close()
        if self.client is not None:
            close_client(self.client)
        self.release()


def resumed_tasks(plan: StudyPlan, files: StudyFiles, backend: str) -> tuple[list, list, list]:
    """The runs to go, the rows kept and the earlier sessions: the plan's own, or with `--resume` what its
    journal leaves to do (checked against the plan). A journal an interrupted run left unreadable is
    replaced where `files.replaces` says so (`files.resume` is then off), and refused in one line otherwise."""
    if not files.resume:
        return plan.tasks, [], []
    try:
        return resume_study(files.journal, files.lines, plan, backend)
    except JournalError as error:
        if not files.replaces:
            raise UserError(str(error) if str(error).startswith("--resume") else f"--resume: {error}") from None
        why = str(error).removeprefix("--resume: ").removesuffix("; give the same parameters")
        typer.echo(f"replacing what an interrupted run left ({files.journal} and its outputs): {why}")
        files.resume = False
        return plan.tasks, [], []
    finally:
        files.lines = []  # now the kept rows: the journal's text is not held twice


def open_session(
    plan: StudyPlan,
    files: StudyFiles,
    backend: str,
    header: str,
    *,
    kind: str = "study",
    parameters: dict[str, Any] | None = None,
    visualize: Any = False,
    draw_run: int = 1,
    dask: str | None = None,
) -> StudySession:
    """The runs to go (a resumed study's checked against its journal), the claims, the journal, the
    cluster and the record (of `kind`, its `parameters` the plan's unless given); the `header` printed."""
    tasks, kept, earlier = resumed_tasks(plan, files, backend)
    if visualize:  # the drawn run (run `draw_run` of the first setting) first: the executor draws it
        chosen = next((i for i, t in enumerate(tasks) if t.run == draw_run), None)
        if chosen is None:
            raise UserError(f"--draw-run {draw_run}: the study has no such run to draw")
        tasks = [tasks[chosen], *tasks[:chosen], *tasks[chosen + 1 :]]
    recorder = Recorder(
        kind,
        command_line(),
        parameters or plan.parameters(),
        outputs={"csv": files.csv_path, "plot": files.plot, "traces": files.traces},  # as text (jsonable)
        sessions=earlier,
        csv_dtypes=CSV_DTYPES,
        backend=backend,
    )
    claimed = [
        ("--summary-csv", files.summary_csv),
        ("--record", files.record_file),
        ("--plot", files.plot),
        ("--traces", files.traces),
    ]
    session = StudySession(plan, files, tasks, kept, backend, None, None, recorder, claim_outputs(claimed))
    try:
        session.journal = Journal(files.journal, adopt=files.resume, replace=files.force) if files.journal else None
        session.client = open_cluster(dask, backend)  # a bad address, or workers that cannot run it: one line
    except BaseException:
        session.close()
        raise
    typer.echo(header)
    if visualize:
        typer.echo(f"drawing run {tasks[0].run} of setting {tasks[0].setting_index} (--draw-run chooses the run)")
    if session.journal is not None:  # the parameters --resume compares, before any run
        started = {k: recorder.data[k] for k in ("command", "started")}
        session.journal.write({"session": {**started, "parameters": jsonable(plan.parameters()), "backend": backend}})
    return session


def report_study(session: StudySession, outcome: StudyOutcome, figure: dict[str, Any]) -> None:
    """The table (first: a write error cannot lose it), the CSV, the summary CSV, the traces, the figure
    and the record. A stopped study (Ctrl-C, SIGTERM, SIGHUP) or a lost cluster leaves the CSV the old
    file and its runs in the journal (the line gives the command with --resume; without a journal the
    traces and the record are written), and exits non-zero (`exit_stopped`)."""
    plan, files = session.plan, session.files
    records = study_order([*session.kept, *outcome.records], plan.tasks)
    summaries = summarise_study(records, plan.settings, paired=figure["paired"])
    closing = study_closing(plan, outcome, records, summaries, figure["paired"])
    if files.summary_csv is not None:
        closing["summary_csv"] = str(files.summary_csv)
    if outcome.interrupted or outcome.lost is not None:
        session.recorder.finish("interrupted", **closing)
        if session.journal is None and files.traces is not None:
            write_traces(files.traces, study_traces(records))
        if session.journal is None and files.record_file is not None:
            session.recorder.write(files.record_file)
        session.close("interrupted", runs_finished=closing["runs_finished"])
        saved = f"; {session.journal.kept()}; go on with: {resume_command()}" if session.journal is not None else ""
        exit_stopped(outcome, closing["runs_finished"], closing["runs_in_study"], saved)
    typer.echo(study_table(summaries, plan.varied, kld=plan.kld))
    status = outcome.status
    seconds = session.recorder.finish(status, **closing)["duration_seconds"]
    ran = len({(r.setting, r.run) for r in outcome.records})
    loaded = "numba's kernels loaded, first calls" if session.backend == "compiled" else "first calls"
    typer.echo(
        f"{ran} runs in {seconds:.1f} s wall time on the {session.backend} backend; start-up "
        f"{outcome.startup_seconds:.1f} s in {len(outcome.workers)} process(es) ({loaded}; not in "
        "ms_per_step or run_seconds)"
    )
    repeat_line(
        "study", plan.seed, ("--csv", "--plot", "--traces", "--record", "--summary-csv", "--rrd"), session.backend
    )
    write_outputs(session, records, summaries, figure)
    session.close(status, runs_finished=closing["runs_finished"])


def write_outputs(session: StudySession, records: list[RunRecord], summaries: list, figure: dict[str, Any]) -> None:
    """The whole CSV (its record right after it, so the record beside a CSV always describes it), the
    summary CSV, the traces, the figure and the record; a file that cannot be written is one line (and
    the journal named, from which --resume writes them again), exit 1."""
    plan, files = session.plan, session.files
    replace = files.force or files.resume
    try:
        if files.csv_path is not None:
            write_atomically(files.csv_path, records_csv(records, plan.columns), replace=replace)
            typer.echo(f"one row per run and filter written to {files.csv_path}")
        if files.summary_csv is not None and summaries:
            write_atomically(files.summary_csv, summary_csv(summaries, plan.option_columns), replace=replace)
            typer.echo(f"one row per setting and filter (the table, with its intervals) written to {files.summary_csv}")
        if files.traces is not None:
            write_traces(files.traces, study_traces(records))
            typer.echo(f"per-step traces written to {files.traces}")
        if files.plot is not None and summaries:  # as `mazelab.study(...).figure(...)` draws it
            from mazelab.experiments.study_plot import draw_study

            drawing = {k: v for k, v in figure.items() if k != "paired"}
            draw_study(
                summaries, plan.varied, files.plot, plan.runs, plan.settings[0].maze.label, **drawing, replace=replace
            )
            typer.echo(f"figure written to {files.plot}")
        if files.record_file is not None:
            session.recorder.write(files.record_file)
            typer.echo(f"the study's record (command, versions, seeds, mazes, summary) written to {files.record_file}")
    except OSError as error:
        kept = f"; {session.journal.kept()}" if session.journal is not None else ""
        session.close("finished, its files not written")
        cause = str(error) if isinstance(error, WriteError) else f"cannot write {error.filename}: {error.strerror}"
        typer.echo(f"error: {cause}{kept}", err=True)
        raise typer.Exit(1) from None


def exit_stopped(outcome: StudyOutcome, finished: int, total: int, saved: str = "", what: str = "runs") -> None:
    """The line and the exit of a study, an accuracy or learn's cells (`what`) that did not run to its end: a
    lost cluster or pool, exit 1; a stop, exit 128 + its signal (130 Ctrl-C, 143 SIGTERM, 129 SIGHUP; further
    stops are ignored, run_study)."""
    if outcome.lost is not None:
        typer.echo(f"error: {outcome.lost}; {finished} of {total} {what} finished{saved}", err=True)
        raise typer.Exit(1)
    typer.echo(f"interrupted after {finished} of {total} {what}{saved}", err=True)
    raise typer.Exit(128 + (outcome.stopped_by or signal.SIGINT))


# -- `mazelab accuracy` ---------------------------------------------------------------------------------
def accuracy(
    maze: AccuracyMazes = None,
    maze_size: opt(str | None, help="generated mazes ROWSxCOLUMNS, comma-separated") = None,
    stations: opt(str | None, help="generated mazes' station blocks, comma-separated") = None,
    filters: AccuracyFilters = None,
    sigma: opt(float, help="measurement noise std") = DEFAULT_SIGMA,
    delta: opt(float, help="compass error width, radians") = DEFAULT_DELTA,
    particles: opt(int, help="particle count N_S") = DEFAULT_PARTICLE_COUNT,
    runs: opt(int, min=1, help="seeded runs per maze") = 10,
    steps: opt(int, min=2, help="steps per run (the distance is averaged over the second half)") = DEFAULT_STEPS,
    seed: opt(int, callback=seed_option, help="root seed (run r has the same seed on every maze)") = 1,
    option: OptionFlag = None,
    workers: Workers = None,
    csv_path: opt(Path | None, "--csv", help="one row per maze, run and filter") = None,
    record: opt(Path | None, help="the JSON record [default: beside --csv]") = None,
    force: Force = False,
    backend: BackendOption = None,
) -> None:
    """How close each filter comes to the exact posterior: per maze, the mean distance between its
    estimate and the exact grid filter's posterior mean over the second half of the steps (with a 95%
    bootstrap interval), and the share of runs that converged (error below 0.5 from some step on;
    Wilson interval)."""
    mazes = parse_mazes(maze, maze_size, stations, default=list(LAB_MAZES))
    rows = accuracy_filters(None if filters is None else parse_filters(filters))
    names = list(dict.fromkeys(name for _, name, _ in rows))
    given = given_options({}, option, names)  # --option: each filter takes those it declares (its label says so)
    per_filter = options_per_filter(names, given, given.spelled, check=True)
    shown = ", ".join(f"{k} {show_value(v)}" for k, v in given.items())
    mine = [per_filter[resolve_filter(name).name] for _, name, _ in rows]
    rows = tuple(
        (f"{label} ({shown})" if own else label, name, {**options, **own})
        for (label, name, options), own in zip(rows, mine, strict=True)
    )
    values = {"sigma": sigma, "delta": delta, "particles": particles, "runs": runs, "steps": steps}
    plan = accuracy_plan(mazes, rows, **values, seed=seed)
    labels = [label for label, _, _ in rows]
    parameters = {"mazes": [maze_description(m) for m in mazes], "filters": labels, **values, "root_seed": seed}
    workers = workers or cores()
    backend = study_backend(plan.tasks, workers)
    files = StudyFiles.left_by_accuracy(csv_path, record, force)
    header = (
        f"Accuracy: {len(mazes)} maze(s) ({', '.join(m.label for m in mazes)}) x {runs} runs, sigma "
        f"{sigma:g}, delta {delta:g}, {particles} particles, {steps} steps, seed {seed}; filters: "
        f"{', '.join(labels)}"
    )
    session = open_session(plan, files, backend, header, kind="accuracy", parameters=parameters)
    if files.resume:
        done = {(r["maze"], r["run"]) for r in accuracy_records(session.kept, rows)}
        typer.echo(f"resuming the interrupted run of {files.journal}: {len(done)} runs kept")
    session.run(workers, lambda outcome: report_accuracy(session, rows, outcome))


def report_accuracy(session: StudySession, rows: tuple[AccuracyFilter, ...], outcome: StudyOutcome) -> None:
    """The table, the time, the CSV and the record (an interrupted run's too, its status "interrupted"),
    the journal closed; a stopped or lost run exits non-zero."""
    files, recorder = session.files, session.recorder
    stopped = outcome.interrupted or outcome.lost is not None
    status = "interrupted" if stopped else "finished"
    records = accuracy_records(study_order([*session.kept, *outcome.records], session.plan.tasks), rows)
    runs = len({(r["maze"], r["run"]) for r in records})
    if records:
        summary = accuracy_summary(records)
        typer.echo(accuracy_table(summary))
        typer.echo(f"{runs} runs in {time.perf_counter() - recorder.started_clock:.1f} s wall time")
        if files.csv_path is not None:
            write_atomically(files.csv_path, accuracy_csv(records), replace=files.force or files.resume)
            typer.echo(f"one row per maze, run and filter written to {files.csv_path}")
        if files.record_file is not None:
            recorder.finish(status, summary=summary)
            recorder.write(files.record_file)
            typer.echo(f"the record (command, versions, seeds, mazes, summary) written to {files.record_file}")
    session.close(status, runs_finished=runs)
    if stopped:
        exit_stopped(outcome, runs, len({s.maze for s in session.plan.settings}) * session.plan.runs)


def parse_mazes(
    maze: str | None,
    maze_size: str | None,
    stations: str | None,
    wall_share: str | None = None,
    default: list[str] | None = None,
) -> list[MazeChoice]:
    """The mazes of --maze, --maze-size, --stations and --wall-share (lists; plan.study_mazes), or the
    `default` names when none is given (accuracy's: the lab's shipped set, named, so that a maze a
    student adds to mazes/ does not join it; the study's: the default maze)."""
    files, sizes = parse_list(maze, str, "--maze"), parse_list(maze_size, str, "--maze-size")
    counts = parse_list(stations, int, "--stations")
    if files is None and sizes is None and counts is None and wall_share is None:
        files = default
    return study_mazes(files, sizes, counts, parse_list(wall_share, float, "--wall-share"))
