"""The command line's studies: `study` (lab step 14, a Monte Carlo parameter study; its Python twin is
`mazelab.study`) and `accuracy` (mazelab.cli.accuracy). Plain functions; mazelab.cli.app registers them."""

from __future__ import annotations

import contextlib
import dataclasses
import signal
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any

import typer

from mazelab.atomic import WriteError, write_text_atomically
from mazelab.backend import backend_for_work, use_backend
from mazelab.cli.accuracy import accuracy
from mazelab.cli.backend_option import HiddenBackendOption
from mazelab.cli.filter_options import (
    KldFlag,
    StudyOptionFlag,
    declared_by,
    options_per_filter,
    parse_option_texts,
)
from mazelab.cli.hints import check_filter_names
from mazelab.cli.options import (
    DEFAULT_DELTA,
    DEFAULT_SIGMA,
    MaxDrawnOption,
    NoVizOption,
    RrdOption,
    UserError,
    ViewerOption,
    WebOption,
    parse_list,
    seed_option,
    visualization,
)
from mazelab.cli.provenance import command_line, repeat_command, resume_command
from mazelab.cli.study_outputs import StudyOutputs, check_plugin_code, resumed, rows_file, session_of
from mazelab.experiments.claims import OutputClaims
from mazelab.experiments.dask_runner import DASK_TIMEOUT, check_workers, close_client, connect
from mazelab.experiments.executor import STOP_SIGNALS, default_workers, run_study
from mazelab.experiments.plan import StudyPlan, all_default, plan_study
from mazelab.experiments.plan import study_mazes as plan_mazes
from mazelab.experiments.record import Recorder
from mazelab.experiments.rowlog import RowLog
from mazelab.experiments.runs import parse_filters
from mazelab.experiments.study import MazeChoice, RunRecord, RunTask, StudyOutcome, declared_option
from mazelab.experiments.summary import CSV_DTYPES, study_table, summarise_study, summary_csv
from mazelab.experiments.trace_log import TraceLog
from mazelab.experiments.traces import (
    kept_traces,
    study_traces,
    write_traces,
)
from mazelab.mazes import DEFAULT_MAZE
from mazelab.model import DEFAULT_PARTICLE_COUNT, DEFAULT_STEPS, RPF_THRESHOLD
from mazelab.registry import filter_entry, resolve_filter
from mazelab.viz.style import DEFAULT_MAX_DRAWN

# "Repeat this study" repeats the study (the same table, bit for bit), not its files: the CSV, figure and
# record it wrote would be found taken when the line is pasted back (add --csv NEW.csv to write them again)
REPEAT_DROPS = ("--resume", "--force")
REPEAT_DROPS_WITH_VALUE = ("--csv", "--plot", "--traces", "--record", "--summary-csv", "--rrd")


def study(
    maze: Annotated[str | None, typer.Option(help=f"mazes (files or names) [default: {DEFAULT_MAZE}]")] = None,
    maze_size: Annotated[str | None, typer.Option(help="generated mazes ROWSxCOLUMNS, a list")] = None,
    stations: Annotated[str | None, typer.Option(hidden=True, help="generated mazes' station blocks, a list")] = None,
    wall_share: Annotated[str | None, typer.Option(hidden=True, help="generated mazes' wall shares, a list")] = None,
    sigma: Annotated[str, typer.Option(help="noise std sigma, a list")] = str(DEFAULT_SIGMA),
    delta: Annotated[str, typer.Option(help="compass error, a list")] = str(DEFAULT_DELTA),
    particles: Annotated[str, typer.Option(help="particle counts, a list")] = str(DEFAULT_PARTICLE_COUNT),
    threshold: Annotated[str | None, typer.Option(help=f"RPF's N_T / N_S, a list [default: {RPF_THRESHOLD}]")] = None,
    filters: Annotated[
        str, typer.Option(metavar="NAMES", show_default=False, help="a list (mazelab filters) [default: sir,apf,rpf]")
    ] = "sir,apf,rpf",
    kidnap_at: Annotated[int | None, typer.Option(min=1, help="carry the robot elsewhere at this step")] = None,
    recovery: Annotated[
        str | None, typer.Option(metavar="NAMES", help="none (default), augmented or sensor, a list")
    ] = None,
    kld: KldFlag = False,
    bandwidth: Annotated[
        str | None, typer.Option(metavar="KERNELS", help="RPF kernel: optimal (default), multimodal, h")
    ] = None,
    estimate: Annotated[str | None, typer.Option(metavar="RULES", help="mean (default), mode, a list")] = None,
    option: StudyOptionFlag = None,
    runs: Annotated[int, typer.Option(min=1, help="seeded runs per setting")] = 30,
    steps: Annotated[int, typer.Option(min=1, help="steps per run")] = DEFAULT_STEPS,
    seed: Annotated[int | None, typer.Option(callback=seed_option, help="root seed (default: new, printed)")] = None,
    workers: Annotated[int | None, typer.Option(min=1, help="processes (default: all cores)")] = None,
    dask: Annotated[str | None, typer.Option(help="a Dask scheduler, tcp://HOST:PORT")] = None,
    dask_timeout: Annotated[
        float,
        typer.Option(metavar="<s>", callback=dask_timeout_option, hidden=True, help="give up after s idle seconds"),
    ] = DASK_TIMEOUT,
    csv_path: Annotated[Path | None, typer.Option("--csv", help="one row per run and filter")] = None,
    plot: Annotated[Path | None, typer.Option(help="the figure: .png, .pdf or .svg (the suffix chooses)")] = None,
    summary_csv: Annotated[
        Path | None, typer.Option("--summary-csv", hidden=True, help="the table as CSV [default: CSV.summary.csv]")
    ] = None,
    reference: Annotated[
        str | None, typer.Option(metavar="grid", help="the exact grid filter too: distance_to_exact")
    ] = None,
    paired: Annotated[
        str | None, typer.Option(metavar="FILTER", help="each filter's difference to FILTER, run by run")
    ] = None,
    plot_x: Annotated[
        str | None, typer.Option(metavar="PARAMETER", help="the figure's x axis, a varied parameter")
    ] = None,
    plot_y: Annotated[
        str, typer.Option(metavar="Y", show_default=False, help="mean (default), median, converged, exact, paired")
    ] = "mean",
    title: Annotated[str | None, typer.Option(help="the figure's title")] = None,
    traces: Annotated[Path | None, typer.Option(help="per-step rows of every run (.csv, .parquet)")] = None,
    record: Annotated[Path | None, typer.Option(help="JSON record [default: CSV.record.json]")] = None,
    resume: Annotated[bool, typer.Option("--resume", help="run only the rows missing from --csv")] = False,
    force: Annotated[bool, typer.Option("--force", help="replace existing output files")] = False,
    draw_run: Annotated[
        int, typer.Option(hidden=True, help="the run --viewer/--rrd/--web draw", show_default=False)
    ] = 1,
    viewer: ViewerOption = False,
    rrd: RrdOption = None,
    web: WebOption = False,
    no_viz: NoVizOption = False,
    max_drawn: MaxDrawnOption = DEFAULT_MAX_DRAWN,
    backend: HiddenBackendOption = None,
) -> None:
    """Lab step 14: a study of every combination of the values (docs/studies.md)."""
    visualize = visualization(viewer, rrd, web, no_viz, max_drawn, force) if viewer or web or rrd is not None else False
    outputs = StudyOutputs.parse(csv_path, plot, traces, record, rrd, force, resume, summary_csv)
    given = {"threshold": threshold, "recovery": recovery, "bandwidth": bandwidth, "estimate": estimate}
    plan = parse_plan(
        outputs, filters, given, option, maze=maze, maze_size=maze_size, stations=stations, wall_share=wall_share,
        sigma=sigma, delta=delta, particles=particles, runs=runs, steps=steps, seed=seed, kidnap_at=kidnap_at, kld=kld,
        reference=reference,
    )  # fmt: skip
    extras = StudyExtras.parse(plan, paired, plot_x, plot_y, title)
    workers = workers or default_workers()
    with study_backend(plan, workers, dask):
        session = open_session(plan, outputs, visualize, draw_run, dask, workers)
        try:
            outcome = run_session(session, visualize, dask_timeout)
            report_study(session, outcome, kld, extras)
        finally:
            session.claims.release()


def study_backend(plan: StudyPlan, workers: int, dask: str | None) -> contextlib.AbstractContextManager:
    """The backend of a study on this machine's worker processes (they inherit it): --backend's or
    MAZELAB_BACKEND's, else the compiled one where its start-up in each process pays for the study's work,
    else numpy (mazelab.backend.backend_for_work). A Dask cluster's workers run on their own."""
    if dask is not None:
        return contextlib.nullcontext()
    return use_backend(backend_for_work(*plan.work(), processes=min(workers, plan.runs * len(plan.settings))))


# -- the study in three steps: parse (outputs, plan), run (a session), report -------------------------
def parse_plan(
    outputs: StudyOutputs, filters: str, given: dict[str, str | None], option: list[str] | None, *,
    maze: str | None, maze_size: str | None, stations: str | None, wall_share: str | None, sigma: str, delta: str,
    particles: str, runs: int, steps: int, seed: int | None, kidnap_at: int | None, kld: bool,
    reference: str | None = None,
) -> StudyPlan:  # fmt: skip
    """The study's plan from the command line's lists: the paper's named flags (--threshold, --recovery,
    --bandwidth, --estimate, spellings of those options) and --option NAME=V1,V2 for any declared
    option, each value parsed and checked by its declaration; an option that none of the filters takes
    is refused first, in one line, unless it is given only its default. A resumed study keeps its
    recorded root seed unless --seed is given."""
    if outputs.recorded is not None and seed is None:
        seed = outputs.recorded["parameters"]["root_seed"]
    names = parse_filters(check_filter_names(filters))
    lists = {name: _list(text, str, f"--{name}") for name, text in given.items() if text is not None}
    named = {name: [_parsed(names, name, value) for value in values] for name, values in lists.items()}
    generic = parse_option_texts(option, names, lists=True)
    for name in named.keys() & generic.keys():
        raise UserError(f"{name} is given twice, as --{name} and as --option {name}; give it once")
    options = {**named, **generic}
    if "kld" in options and options["kld"] == [True]:
        kld, options = True, {k: v for k, v in options.items() if k != "kld"}
    options_per_filter(
        names,
        {**{k: None if all_default(k, v) else v for k, v in options.items()}, "kld": kld or None},
        flags={**{name: f"--{name}" for name in given}, "kld": "--kld"},
        check=False,  # each value is checked below, by plan_study, for every filter that takes it
    )
    return plan_study(
        plan_mazes(_list(maze, str, "--maze"), _list(maze_size, str, "--maze-size"),
                   _list(stations, int, "--stations"), _list(wall_share, float, "--wall-share")),
        names,
        sigma=parse_list(sigma, float, "--sigma"),
        delta=parse_list(delta, float, "--delta"),
        particles=parse_list(particles, int, "--particles"),
        options=options,
        runs=runs, steps=steps, seed=seed, kidnap_at=kidnap_at, kld=kld, traces=outputs.traces is not None,
        reference=reference,
    )  # fmt: skip


def _parsed(names: list[str], option: str, text: str) -> Any:
    """One value of a named list flag (--bandwidth optimal,0.05), read by the option's declaration."""
    declared = declared_by(names, option) or [declared_option(option)]
    if declared[0] is None:
        return text
    try:
        return declared[0].parse_text(text)
    except ValueError as error:
        raise UserError(f"--{option} {text}: {error}") from None


@dataclass
class StudyExtras:
    """What the report adds to the table and the figure: the filter of the paired differences (--paired)
    and the figure's x axis (--plot-x), checked before any run."""

    paired: str | None = None
    plot_x: str | None = None  # the figure's x axis (--plot-x), a varied parameter
    plot_y: str = "mean"  # what the figure draws (--plot-y): a key of study_plot.Y_QUANTITIES
    title: str | None = None  # the figure's first title line (--title), instead of the program's

    @classmethod
    def parse(
        cls, plan: StudyPlan, paired: str | None, plot_x: str | None = None, plot_y: str = "mean",
        title: str | None = None,
    ) -> StudyExtras:  # fmt: skip
        """--paired names one of the study's filters, --plot-x one of its varied parameters, --plot-y
        what the figure draws (exact needs --reference grid, paired needs --paired)."""
        from mazelab.experiments.study_plot import Y_QUANTITIES

        if plot_y not in Y_QUANTITIES:
            raise UserError(f"--plot-y {plot_y}: choose one of {', '.join(Y_QUANTITIES)}")
        if plot_y == "exact" and plan.reference is None:
            raise UserError("--plot-y exact: the distance to the exact posterior needs --reference grid")
        if plot_y == "paired" and paired is None:
            raise UserError("--plot-y paired: the paired difference needs --paired FILTER")
        if title is not None and ("\n" in title or not title.strip()):
            raise UserError("--title: give one line of text")
        if plot_x is not None and plot_x not in plan.varied:
            varied = ", ".join(plan.varied) or "none: give a parameter two values"
            raise UserError(f"--plot-x {plot_x}: the x axis is a varied parameter of the study ({varied})")
        if paired is not None:
            entries = [filter_entry(f) for f in plan.filters]
            chosen = resolve_filter(check_filter_names(paired, "--paired")).name
            if chosen not in [entry.name for entry in entries]:
                given = ", ".join(entry.reference for entry in entries)
                raise UserError(f"--paired {paired}: not one of the study's --filters ({given})")
            if len(entries) == 1:
                raise UserError(
                    f"--paired {paired}: the study's only filter, paired with itself (every difference 0); "
                    "add the filters to compare with it to --filters"
                )
            paired = chosen
        return cls(paired, plot_x, plot_y, title)


@dataclass
class StudySession:
    """One session of a study: its plan and outputs, the runs to go, the rows kept from an earlier
    session, the growing CSV (NAME.csv.partial), the Dask client and the record."""

    plan: StudyPlan
    outputs: StudyOutputs
    tasks: list[RunTask]
    kept: list[RunRecord]
    workers: int
    log: RowLog | None
    client: Any
    recorder: Recorder
    trace_log: TraceLog | None = None  # TRACES.partial, each finished run's traces appended (with --csv)
    claims: OutputClaims = dataclasses.field(default_factory=lambda: OutputClaims([]))  # the other outputs
    kept_traces: Any = None  # the traces of the kept runs (--resume), read before the trace log starts

    def append(self, records: list[RunRecord]) -> None:
        """One finished run's rows and traces, appended to the partial files."""
        if self.log is not None:
            self.log.append(records)
        if self.trace_log is not None:
            self.trace_log.append(records)


def open_session(
    plan: StudyPlan, outputs: StudyOutputs, visualize: Any, draw_run: int, dask: str | None, workers: int
) -> StudySession:
    """The runs to go, the row log, the cluster and the record; the study's header printed."""
    tasks, kept, recorded, csv_path = plan.tasks(), [], outputs.recorded, outputs.csv_path
    if recorded is not None and csv_path is not None:
        check_plugin_code(recorded, plan, outputs.record_file)
        tasks, kept = resumed(plan, recorded, csv_path, outputs.traces_kept_from)
    tasks = _drawn_first(tasks, draw_run) if visualize else tasks
    kept_from, rerun = outputs.traces_kept_from, {(t.setting_index, t.run) for t in tasks}
    kept_trace_rows = kept_traces(kept_from, rerun) if kept_from is not None else None
    claims = OutputClaims(  # a second study given one of these now is refused before its runs
        [("--summary-csv", outputs.summary_csv), ("--record", outputs.record_file), ("--plot", outputs.plot),
         ("--traces", outputs.traces)]
    )  # fmt: skip
    log = trace_log = None
    try:
        log = _row_log(plan, outputs, kept)
        if log is not None and outputs.traces is not None:  # claimed now: a second study with it is refused
            trace_log = TraceLog(outputs.traces, replace=outputs.force, adopt=outputs.resume, kept=kept_trace_rows)
        client = connect(dask) if dask is not None else None  # a bad address: one line and exit 2, before anything
        if client is not None:
            try:
                check_workers(client)  # workers that disagree on the backend or versions: one line, exit 2
            except ValueError:
                close_client(client)
                raise
    except BaseException:
        claims.release()
        if log is not None:
            log.close() if outputs.resume else log.discard()
        if trace_log is not None:
            trace_log.close() if outputs.resume else trace_log.discard()
        raise
    where = f"on the Dask cluster at {dask}" if dask is not None else f"{workers} worker(s)"
    typer.echo(plan.header(where))
    if visualize:
        typer.echo(f"drawing run {tasks[0].run} of setting {tasks[0].setting_index} (--draw-run chooses the run)")
    if recorded is not None:
        typer.echo(f"resuming: {len(kept)} rows kept from {rows_file(csv_path)}, {len(tasks)} run(s) to go")
    if log is not None and log.note:
        typer.echo(f"note: {log.note}", err=True)
    recorder = Recorder(
        "study", command_line(), plan.parameters(), outputs=_outputs(csv_path, outputs.plot, outputs.traces),
        sessions=[*(recorded or {}).get("sessions", []), *([] if recorded is None else [session_of(recorded)])],
        csv_dtypes=CSV_DTYPES,
    )  # fmt: skip
    if log is not None:  # now, beside the partial rows: an interrupted study keeps its parameters for --resume
        log.write_record(recorder)  # (the record beside the CSV stays the old CSV's until the new CSV replaces it)
    return StudySession(
        plan, outputs, tasks, kept, workers, log, client, recorder,
        trace_log=trace_log, kept_traces=kept_trace_rows, claims=claims,
    )  # fmt: skip


def _row_log(plan: StudyPlan, outputs: StudyOutputs, kept: list[RunRecord]) -> RowLog | None:
    """NAME.csv.partial with the study's columns (the kept rows in it at once), the record beside it."""
    if outputs.csv_path is None:
        return None
    replace = outputs.force or outputs.resume
    return RowLog(
        outputs.csv_path, replace=replace, adopt=outputs.resume, record=outputs.record_file, kept=kept,
        columns=plan.columns,
    )  # fmt: skip


def run_session(session: StudySession, visualize: Any, dask_timeout: float) -> StudyOutcome:
    """The session's runs, on the workers or the cluster, rows appended to the log as they come."""
    log = session.log
    try:
        return run_study(
            session.tasks,
            session.workers,
            visualize=visualize,
            progress=True,
            on_records=None if log is None else session.append,
            dask=session.client,
            dask_timeout=dask_timeout,
            ignore_signals_after_stop=True,  # a stopped study only saves and exits: a further Ctrl-C waits
        )
    finally:
        if session.client is not None:
            close_client(session.client)


def report_study(session: StudySession, outcome: StudyOutcome, kld: bool, extras: StudyExtras | None = None) -> None:
    """The failures, then the table (first: a write error cannot lose it), the CSV, the summary CSV,
    traces, figure and record; a stopped or lost study keeps its rows in the partial file and exits
    non-zero."""
    plan, outputs, log = session.plan, session.outputs, session.log
    extras = extras or StudyExtras()
    for failure in outcome.failures:
        typer.echo(f"error: {failure.describe()}", err=True)
    records = _in_order([*session.kept, *outcome.records], plan)
    finished, total = len({(r.setting, r.run) for r in records}), len(plan.tasks())
    summaries = summarise_study(records, plan.settings, paired=extras.paired)
    closing = {
        "runs_finished": finished,
        "runs_in_study": total,
        "failures": [f.describe() for f in outcome.failures],
        "summary": [s.as_dict() for s in summaries],
        "paired": extras.paired,
        "workers": [dataclasses.asdict(report) for report in outcome.workers.values()],
        "startup_seconds": round(outcome.startup_seconds, 3),
        **({"summary_csv": str(outputs.summary_csv)} if outputs.summary_csv is not None else {}),
    }
    if outcome.interrupted or outcome.lost is not None:
        report_stopped(session, outcome, closing)
    typer.echo(study_table(summaries, plan.varied, kld=kld))
    seconds = session.recorder.finish("finished" if not outcome.failures else "finished with failures", **closing)
    ran = len({(r.setting, r.run) for r in outcome.records})
    typer.echo(f"{ran} runs in {seconds['duration_seconds']:.1f} s wall time; {startup_line(outcome)}")
    typer.echo(f"Repeat this study: {repeat_command(plan.seed, REPEAT_DROPS, REPEAT_DROPS_WITH_VALUE)}")
    if outputs.csv_path is not None and log is not None:
        try:
            log.finish(records, session.recorder)  # the whole CSV, in order, its record; then the partial files go
        except OSError as error:
            log.close()
            typer.echo(f"error: {describe_write_error(error)}; {log.kept()}", err=True)
            raise typer.Exit(1) from None
        typer.echo(f"one row per run and filter written to {outputs.csv_path}")
    if outputs.summary_csv is not None and summaries:
        try:
            write_text_atomically(
                outputs.summary_csv,
                summary_csv(summaries, plan.option_columns),
                replace=outputs.force or outputs.resume,
            )
        except OSError as error:
            typer.echo(f"error: {describe_write_error(error)}", err=True)
            raise typer.Exit(1) from None
        typer.echo(f"one row per setting and filter (the table, with its intervals) written to {outputs.summary_csv}")
    if _write_traces(outputs.traces, _in_order(outcome.records, plan), session.kept_traces, session.trace_log):
        typer.echo(f"per-step traces written to {outputs.traces}")
    if outputs.plot is not None and summaries:
        _plot(plan, summaries, outputs.plot, outputs.force or outputs.resume, extras)  # --resume: its own figure
    if outputs.record_file is not None:
        session.recorder.write(outputs.record_file)
        typer.echo(f"the study's record (command, versions, seeds, mazes, summary) written to {outputs.record_file}")
    if outcome.failures:
        raise typer.Exit(1)


def report_stopped(session: StudySession, outcome: StudyOutcome, closing: dict[str, Any]) -> None:
    """A stopped study (Ctrl-C, SIGTERM, SIGHUP) or a lost cluster: the CSV stays the old file, the
    rows are in NAME.csv.partial (the line gives the command with --resume), the traces and the record
    are written; exits."""
    outputs, log = session.outputs, session.log
    if log is not None:
        log.close()
    if session.trace_log is not None:  # with a CSV: each finished run's traces are in TRACES.partial already
        session.trace_log.close()
    else:
        _write_traces(outputs.traces, _in_order(outcome.records, session.plan), session.kept_traces)
    if outputs.record_file is not None:  # with a CSV: beside the partial rows, the old CSV keeps its record
        session.recorder.finish("interrupted", **closing)
        if log is not None:
            log.write_record(session.recorder)
        else:
            session.recorder.write(outputs.record_file)
    saved = f"; {log.kept()}; go on with: {resume_command()}" if log is not None else ""
    finished, total = closing["runs_finished"], closing["runs_in_study"]
    if outcome.lost is not None:  # a lost cluster or pool: one line, exit 1
        typer.echo(f"error: {outcome.lost}; {finished} of {total} runs finished{saved}", err=True)
        raise typer.Exit(1)
    typer.echo(f"interrupted after {finished} of {total} runs{saved}", err=True)
    for sig in STOP_SIGNALS:  # stopping already: a further Ctrl-C, SIGTERM or SIGHUP changes nothing
        signal.signal(sig, signal.SIG_IGN)
    raise typer.Exit(128 + (outcome.stopped_by or signal.SIGINT))  # 130 Ctrl-C, 143 SIGTERM, 129 SIGHUP


def dask_timeout_option(value: float) -> float:
    """--dask-timeout: a positive number of seconds (typer names the option in its one-line error)."""
    if not 0 < value < float("inf"):
        raise typer.BadParameter(f"seconds must be a positive number, got {value}")
    return value


def _list(text: str | None, kind: type, option: str) -> list | None:
    return None if text is None else parse_list(text, kind, option)


def _outputs(csv_path: Path | None, plot: Path | None, traces: Path | None) -> dict[str, str | None]:
    return {"csv": _name(csv_path), "plot": _name(plot), "traces": _name(traces)}


def _name(path: Path | None) -> str | None:
    return None if path is None else str(path)


def startup_line(outcome: StudyOutcome) -> str:
    """The processes' start-up, reported apart from ms/step and run_seconds (mazelab.experiments.warmup)."""
    processes = len(outcome.workers)
    return (
        f"start-up {outcome.startup_seconds:.1f} s in {processes} process(es) (numba's kernels loaded, first "
        "calls; not in ms_per_step or run_seconds)"
    )


def describe_write_error(error: OSError) -> str:
    """One line naming the file and the cause of a write error."""
    return str(error) if isinstance(error, WriteError) else f"cannot write {error.filename}: {error.strerror or error}"


def _drawn_first(tasks: list[RunTask], run: int) -> list[RunTask]:
    """The tasks with the drawn one (run `run` of the first setting) first: the executor draws it."""
    chosen = next((i for i, t in enumerate(tasks) if t.run == run), None)
    if chosen is None:
        raise UserError(f"--draw-run {run}: the study has no such run to draw")
    return [tasks[chosen], *tasks[:chosen], *tasks[chosen + 1 :]]


def _in_order(records: list[RunRecord], plan: StudyPlan) -> list[RunRecord]:
    """Rows in (setting, run, filter) order, filters in the study's order."""
    names = [getattr(f, "name", f) for f in plan.filters]
    order = {name: i for i, name in enumerate(dict.fromkeys([*names, *(r.filter for r in records)]))}
    return sorted(records, key=lambda r: (r.setting, r.run, order[r.filter]))


def _write_traces(path: Path | None, records: list[RunRecord], kept: Any, trace_log: TraceLog | None = None) -> bool:
    """Write the whole traces: the kept ones of an earlier session (--resume), then this session's
    runs; then the partial traces (TraceLog) go."""
    if path is None:
        return False
    write_traces(path, study_traces(records), kept)
    if trace_log is not None:
        trace_log.discard()
    return True


def _plot(plan: StudyPlan, summaries: list, plot: Path, force: bool = True, extras: StudyExtras | None = None) -> None:
    """The study's figure (mazelab.experiments.study_plot), as `mazelab.study(...).figure(...)` draws it."""
    from mazelab.experiments.study_plot import plot_study, study_title

    extras = extras or StudyExtras()
    varied = plan.varied
    title = extras.title or study_title(
        varied, summaries, plan.runs, plan.settings[0].maze.label, extras.plot_x, extras.plot_y
    )
    plot_study(summaries, varied or ["maze"], plot, title, replace=force, x=extras.plot_x, y=extras.plot_y)
    typer.echo(f"figure written to {plot}")


def study_mazes(files: str | None, sizes: str | None, stations: str | None) -> list[MazeChoice]:
    """The study's mazes from the command line's text (mazelab.experiments.plan.study_mazes)."""
    return plan_mazes(_list(files, str, "--maze"), _list(sizes, str, "--maze-size"), _list(stations, int, "--stations"))


__all__ = ["accuracy", "study", "study_mazes"]
