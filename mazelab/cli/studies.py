"""The command line's studies: `study` (lab step 14, a Monte Carlo parameter study) and `accuracy`
(every filter against the exact grid posterior). Plain functions; mazelab.cli.app registers them."""

from __future__ import annotations

import signal
import time
from pathlib import Path
from typing import Annotated

import typer

from mazelab import maze_generator
from mazelab.atomic import WriteError
from mazelab.checks import check_bandwidth_within, check_sigma_within
from mazelab.cli.options import (
    DEFAULT_DELTA,
    DEFAULT_SIGMA,
    EstimateOption,
    MaxDrawnOption,
    NoVizOption,
    RrdOption,
    UserError,
    ViewerOption,
    WebOption,
    check_outputs,
    parse_list,
    visualization,
)
from mazelab.experiments.dask_runner import DASK_TIMEOUT, close_client, connect
from mazelab.experiments.executor import STOP_SIGNALS, default_workers, run_study
from mazelab.experiments.rowlog import RowLog
from mazelab.experiments.runs import parse_filters
from mazelab.experiments.stats import CONFIDENCE_LEVEL
from mazelab.experiments.study import MazeChoice, StudySetting, study_settings, study_tasks, varied_parameters
from mazelab.experiments.summary import describe_setting, plot_study, study_table, summarise_study
from mazelab.filters import RegularizedParticleFilter
from mazelab.limits import check_particles, check_steps, check_study
from mazelab.mazes import DEFAULT_MAZE, MAZES_DIR, find_maze, load_maze
from mazelab.model import DEFAULT_PARTICLE_COUNT, DEFAULT_STEPS, RPF_THRESHOLD, check_model_parameters
from mazelab.registry import resolve_filter
from mazelab.regularisation import check_bandwidth
from mazelab.simulation import new_seed
from mazelab.viz.style import DEFAULT_MAX_DRAWN


def study(
    maze: Annotated[
        str | None, typer.Option(help=f"maze files or names, comma-separated [default: {DEFAULT_MAZE}]")
    ] = None,
    maze_size: Annotated[str | None, typer.Option(help="generated mazes ROWSxCOLUMNS, comma-separated")] = None,
    stations: Annotated[str | None, typer.Option(help="station blocks, comma-separated")] = None,
    sigma: Annotated[str, typer.Option(help="noise std sigma, comma-separated")] = str(DEFAULT_SIGMA),
    delta: Annotated[str, typer.Option(help="compass error width, comma-separated")] = str(DEFAULT_DELTA),
    particles: Annotated[str, typer.Option(help="particle counts, comma-separated")] = str(DEFAULT_PARTICLE_COUNT),
    threshold: Annotated[str, typer.Option(help="RPF's N_T / N_S, comma-separated")] = str(RPF_THRESHOLD),
    filters: Annotated[str, typer.Option(help="sir, apf, rpf, grid, ekf, comma-separated")] = "sir,apf,rpf",
    kidnap_at: Annotated[int | None, typer.Option(min=1, help="carry the robot elsewhere at this step")] = None,
    recovery: Annotated[str, typer.Option(help="none, augmented, sensor, comma-separated")] = "none",
    kld: Annotated[bool, typer.Option("--kld", help="KLD-sampling (--particles is the most)")] = False,
    bandwidth: Annotated[str, typer.Option(help="RPF kernels: optimal, multimodal, h", show_default=False)] = "optimal",
    estimate: EstimateOption = "mean",
    runs: Annotated[int, typer.Option(min=1, help="seeded runs per setting")] = 30,
    steps: Annotated[int, typer.Option(min=1, help="steps per run")] = DEFAULT_STEPS,
    seed: Annotated[int | None, typer.Option(min=0, help="the study's root seed (default: new, printed)")] = None,
    workers: Annotated[int | None, typer.Option(min=1, help="processes (default: all cores)")] = None,
    dask: Annotated[str | None, typer.Option(help="the Dask scheduler to run on, tcp://HOST:PORT")] = None,
    dask_timeout: Annotated[
        float, typer.Option(min=0.1, help="seconds without a finished run before a Dask study gives up")
    ] = DASK_TIMEOUT,
    csv_path: Annotated[Path | None, typer.Option("--csv", help="one row per run and filter")] = None,
    plot: Annotated[Path | None, typer.Option(help="error against the varied parameter (.png)")] = None,
    force: Annotated[bool, typer.Option("--force", help="replace existing output files")] = False,
    viewer: ViewerOption = False,
    rrd: RrdOption = None,
    web: WebOption = False,
    no_viz: NoVizOption = False,
    max_drawn: MaxDrawnOption = DEFAULT_MAX_DRAWN,
) -> None:
    """Lab step 14: a Monte Carlo study over every combination of the values given.

    Each setting gets R seeded runs, every filter seeing the same scenario in a run. The table gives
    per setting and filter the mean final error (last 20% of the steps) with its 95% t-interval, the
    share converged and the median convergence step (README: "Parameter studies")."""
    visualize = visualization(viewer, rrd, web, no_viz, max_drawn) if viewer or web or rrd is not None else False
    check_outputs(csv_path, plot, force, rrd)
    names = parse_filters(filters)
    check_steps(steps)  # each run's limits, up front rather than in every worker
    check_particles(max(parse_list(particles, int, "--particles")))
    settings = study_settings(
        study_mazes(maze, maze_size, stations),
        parse_list(sigma, float, "--sigma"),
        parse_list(delta, float, "--delta"),
        parse_list(particles, int, "--particles"),
        parse_list(threshold, float, "--threshold"),
        parse_list(recovery, str, "--recovery"),
        parse_list(bandwidth, str, "--bandwidth"),
    )
    check_study(len(settings) * runs, len(names))
    check_study_numbers(settings, names)
    seed = new_seed() if seed is None else seed
    tasks = study_tasks(settings, names, runs, steps, seed, kidnap_at=kidnap_at, kld=kld, estimate=estimate)
    workers = workers or default_workers()
    varied = varied_parameters(settings)
    log = RowLog(csv_path, replace=force) if csv_path is not None else None  # rows go to NAME.csv.partial
    try:
        client = connect(dask) if dask is not None else None  # a bad address: one line and exit 2, before anything
    except BaseException:
        if log is not None:
            log.discard()
        raise
    where = f"on the Dask cluster at {dask}" if dask is not None else f"{workers} worker(s)"
    typer.echo(
        f"Study: {len(settings)} setting(s) x {runs} runs x {len(names)} filters, seed {seed}, {where}\n"
        f"{describe_setting(settings[0], steps, runs, kidnap_at)}"
        + (f"; varied: {', '.join(varied)}" if varied else "")
    )
    if log is not None and log.note:
        typer.echo(f"note: {log.note}", err=True)
    started = time.perf_counter()
    try:
        outcome = run_study(
            tasks,
            workers,
            visualize=visualize,
            progress=True,
            on_records=None if log is None else log.append,
            dask=client,
            dask_timeout=dask_timeout,
            ignore_signals_after_stop=True,  # a stopped study only saves and exits: a further Ctrl-C waits
        )
    finally:
        if client is not None:
            close_client(client)
    seconds = time.perf_counter() - started
    for failure in outcome.failures:
        typer.echo(f"error: {failure.describe()}", err=True)
    finished = len({(r.setting, r.run) for r in outcome.records})
    if outcome.lost is not None:  # the cluster or the pool is gone: the CSV stays the old file
        if log is not None:
            log.close()
        kept = f"; {log.kept()}" if log is not None else ""
        typer.echo(f"error: {outcome.lost}; {finished} of {len(tasks)} runs finished{kept}", err=True)
        raise typer.Exit(1)
    if outcome.interrupted:
        saved = f"; {log.kept()}" if log is not None else ""  # the CSV stays the old file (or none)
        if log is not None:
            log.close()
        typer.echo(f"interrupted after {finished} of {len(tasks)} runs{saved}", err=True)
        for sig in STOP_SIGNALS:  # stopping already: a further Ctrl-C, SIGTERM or SIGHUP changes nothing
            signal.signal(sig, signal.SIG_IGN)
        raise typer.Exit(128 + (outcome.stopped_by or signal.SIGINT))  # 130 Ctrl-C, 143 SIGTERM, 129 SIGHUP
    summaries = summarise_study(outcome.records, settings)
    typer.echo(study_table(summaries, varied, kld=kld))  # the table first: a write error cannot lose it
    typer.echo(f"{finished} runs in {seconds:.1f} s wall time")
    if csv_path is not None and log is not None:
        try:
            log.finish(outcome.records)  # the whole CSV, in order; then the partial file goes
        except OSError as error:
            log.close()
            typer.echo(f"error: {describe_write_error(error)}; {log.kept()}", err=True)
            raise typer.Exit(1) from None
        typer.echo(f"one row per run and filter written to {csv_path}")
    if plot is not None and summaries:
        what = ", ".join(varied) or "the setting"
        where = "" if "maze" in varied else f" on {settings[0].maze.label}"
        title = (
            f"Final error against {what}{where}\n({runs} runs per point, "
            f"{CONFIDENCE_LEVEL:.0%} t-intervals for the mean)"
        )
        plot_study(summaries, varied or ["maze"], plot, title, replace=force)
        typer.echo(f"figure written to {plot}")
    if outcome.failures:
        raise typer.Exit(1)


def accuracy(
    maze: Annotated[
        str | None, typer.Option(help="maze files or names, comma-separated (default: every maze in mazes/)")
    ] = None,
    sigma: Annotated[float, typer.Option(help="measurement noise std")] = DEFAULT_SIGMA,
    delta: Annotated[float, typer.Option(help="compass error width, radians")] = DEFAULT_DELTA,
    particles: Annotated[int, typer.Option(min=1, help="particle count N_S")] = DEFAULT_PARTICLE_COUNT,
    runs: Annotated[int, typer.Option(min=1, help="seeded runs per maze")] = 10,
    steps: Annotated[int, typer.Option(min=2, help="steps per run (the distance is averaged over the second half)")] = (
        DEFAULT_STEPS
    ),
    seed: Annotated[int, typer.Option(min=0, help="root seed (run r has the same seed on every maze)")] = 1,
    workers: Annotated[int | None, typer.Option(min=1, help="processes (default: all cores)")] = None,
) -> None:
    """How close each filter comes to the exact posterior: per maze, the mean distance between its
    estimate and the exact grid filter's posterior mean over the second half of the steps, and the
    share of runs that converged (error below 0.5 from some step on)."""
    from mazelab.experiments.accuracy import ACCURACY_FILTERS, accuracy_table, accuracy_tasks, run_accuracy

    names = parse_list(maze, str, "--maze") if maze is not None else sorted(p.stem for p in MAZES_DIR.glob("*.txt"))
    check_model_parameters(sigma, delta)
    check_steps(steps)
    check_particles(particles)
    check_study(len(names) * runs, len(ACCURACY_FILTERS))  # --runs 10000000: refused before any work
    mazes = [(n, load_maze(n)) for n in names]
    for _, world in mazes:
        check_sigma_within(sigma, world.width, world.height)
    tasks = accuracy_tasks(mazes, runs, sigma, delta, particles, steps, seed)
    typer.echo(
        f"Accuracy: {len(names)} maze(s) x {runs} runs, sigma {sigma:g}, delta {delta:g}, {particles} particles, "
        f"{steps} steps, seed {seed}; filters: {', '.join(label for label, _, _ in ACCURACY_FILTERS)}"
    )
    started = time.perf_counter()
    records = run_accuracy(tasks, workers or default_workers())
    typer.echo(accuracy_table(records))
    typer.echo(f"{len(tasks)} runs in {time.perf_counter() - started:.1f} s wall time")


def check_study_numbers(settings: list[StudySetting], names: list[str]) -> None:
    """Each setting's sigma and RPF bandwidth within the ranges of its maze, and a bandwidth other than
    optimal only with the rpf among the filters (as `run` refuses it), before any run starts."""
    rpf = any(resolve_filter(name) is RegularizedParticleFilter for name in names)
    for setting in settings:
        rows, columns = setting.maze.size or (len(setting.maze.grid or ()), len((setting.maze.grid or ((),))[0]))
        check_sigma_within(setting.sigma, columns, rows)
        check_bandwidth_within(check_bandwidth(setting.bandwidth), columns, rows)
        if setting.bandwidth != "optimal" and not rpf:
            raise UserError("--bandwidth applies to the rpf only: add rpf to --filters")


def describe_write_error(error: OSError) -> str:
    """One line naming the file and the cause of a write error."""
    return str(error) if isinstance(error, WriteError) else f"cannot write {error.filename}: {error.strerror or error}"


def study_mazes(files: str | None, sizes: str | None, stations: str | None) -> list[MazeChoice]:
    """The study's mazes: the files, then every generated size x station count."""
    mazes = (
        [MazeChoice.from_maze(find_maze(name).stem, load_maze(name)) for name in parse_list(files, str, "--maze")]
        if files is not None
        else []
    )
    if sizes is not None or stations is not None:
        for rows, columns in (maze_generator.parse_size(s) for s in parse_list(sizes or "10x10", str, "--maze-size")):
            counts = (
                parse_list(stations, int, "--stations")
                if stations
                else [maze_generator.default_station_count(rows, columns)]
            )
            for count in counts:
                maze_generator.check_generation(rows, columns, count)  # --stations 0: refused up front
            mazes += [MazeChoice.generated(rows, columns, count) for count in counts]
    return mazes or [MazeChoice.from_maze(DEFAULT_MAZE, load_maze(DEFAULT_MAZE))]
