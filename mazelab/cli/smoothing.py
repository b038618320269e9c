"""`mazelab smooth` (mazelab.smoothing) and `mazelab learn` (mazelab.learning), each command's docstring saying
what it computes: each prints a table and writes, when asked, rows (--csv), a figure (--plot) and a JSON record
beside the rows like a study's (the command, versions, the scenario's sha256, a summary)."""

from __future__ import annotations

import functools
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import typer

from mazelab.atomic import write_atomically
from mazelab.cli.options import (
    Force,
    OptionFlag,
    UserError,
    arg,
    check_outputs,
    given_options,
    opt,
    parse_list,
    seed_option,
    with_option_flags,
    with_parameters,
)
from mazelab.cli.study import exit_stopped
from mazelab.experiments import executor
from mazelab.experiments.journal import Journal, Recorder, differences, journal_path, read_journal, record_path
from mazelab.experiments.runs import options_per_filter, parse_filters
from mazelab.experiments.tables import format_table, pyplot, records_csv, save_figure
from mazelab.invocation import command_line, resume_command
from mazelab.learning import ParameterGrid, ParameterPosterior, evidence_filter, exact_parameter_posterior
from mazelab.learning import pmmh as run_pmmh
from mazelab.model import LAB_DELTA_RANGE, LAB_SIGMA_RANGE
from mazelab.registry import file_sha256, filter_entry
from mazelab.smoothing import SCORE_COLUMNS, SMOOTHERS, SmootherScores, score_smoothers

if TYPE_CHECKING:
    from mazelab.scenario import Scenario

Scenario_ = arg(Path, "SCENARIO", "a saved scenario with measurements (.json) or a shipped name")
SIGMA_RANGE, DELTA_RANGE = (",".join(map(str, r)) for r in (LAB_SIGMA_RANGE, LAB_DELTA_RANGE))
CHAIN = {  # learn's PMMH options, named as its record names them
    "pmmh": (opt(int, "--pmmh", min=0, help="a PMMH chain of this many iterations (0: none)"), 0),
    "filter": (opt(str, "--filter", help="PMMH's filter (its evidence must estimate p(z_1:K))"), "sir"),
    "particles": (opt(int, "--particles", min=1, help="PMMH's particles"), 200),
    "seed": (opt(int, "--seed", callback=seed_option, help="PMMH's seed"), 1),
}
Workers = opt(int | None, "--workers", min=1, help="processes for the exact posterior's cells (default: all cores)")
Dask = opt(str | None, "--dask", help="a Dask scheduler for the exact posterior's cells, tcp://HOST:PORT")
CLUSTER = {"workers": (Workers, None), "dask": (Dask, None)}  # where learn's exact posterior runs (run_cells)
RESUME = (opt(bool, "--resume", help="compute only the cells missing from --csv's journal"), False)
Resolution = opt(float, help="the exact grid's cells, map units (memory grows as its inverse square)")


def output_options(rrd_help: str, **more: tuple[Any, Any]) -> dict[str, tuple[Any, Any]]:
    """The output options of smooth and learn (a `with_parameters` group; `more` before --force)."""
    return {
        "csv_path": (opt(Path | None, "--csv", help="the rows (.csv)"), None),
        "plot": (opt(Path | None, "--plot", help="the figure (.png; plot extra)"), None),
        "record": (opt(Path | None, "--record", help="the JSON record [default: beside --csv]"), None),
        "rrd": (opt(Path | None, "--rrd", help=f"a Rerun recording: {rrd_help}"), None),
        **more,
        "force": (Force, False),
    }


@with_option_flags()
@with_parameters("option", {"option": (OptionFlag, None)}, lambda given: given["option"])  # after the files
@with_parameters("files", output_options("each filter's cloud beside its path smoother's"))
def smooth(
    scenario: Scenario_,
    filters: opt(str, metavar="NAMES", help="particle filters, comma-separated") = "sir,apf,rpf",
    lag: opt(int, min=1, help="L, the fixed-lag smoother's lag (steps)") = 10,
    resolution: Resolution = 0.05,
    seed: opt(int | None, callback=seed_option, help="the filters' seed [default: the scenario's]") = None,
    *,
    files: dict[str, Any],
    option: list[str] | None,
    named: dict[str, Any],
) -> None:
    """Where the robot was at each step given every measurement: the exact smoother on the grid, and each
    filter's own estimate, fixed-lag and path smoothers scored against it step by step (the distance of
    their means to the exact smoothed mean, the total variation over the maze's cells, the distinct
    ancestors each rests on: the path degeneracy). Each filter takes the options it declares."""
    path, stored, files, (world, sigma, delta) = opened(scenario, files)
    options = filter_options(filters, named, option)
    seed = seed if seed is not None else stored.seed if stored.seed is not None else 0
    parameters = {
        "scenario": str(path),
        "filters": list(options),
        "lag": lag,
        "resolution": resolution,
        "seed": seed,
        "sigma": sigma,
        "delta": delta,
        "options": options,
    }
    recorder = Recorder("smooth", command_line(), parameters, scenario_sha256=file_sha256(path))
    typer.echo(
        f"{path.name}: {len(stored.robot_compass_angles)} steps, {len(stored.init_particles_pos)} particles, "
        f"sigma {sigma:g}, delta {delta:g}, lag {lag}, grid {resolution:g}, seed {seed}"
    )
    scores = score_smoothers(
        world,
        stored.robot(),
        sigma,
        delta,
        options,
        lag=lag,
        seed=seed,
        grid_options={"resolution": resolution},
        initial_particles=stored.init_particles_pos,
        clouds=files["rrd"] is not None,
    )
    summary = smoothing_summary(scores)
    rows = ("filter and step", lambda: records_csv(scores.rows, SCORE_COLUMNS))
    figure = functools.partial(smoothing_figure, scores, f"{path.name}: smoothers (lag {lag})")
    write_outputs(files, recorder, summary, rows, figure, functools.partial(smoothing_recording, scores, world))


def smoothing_recording(scores: SmootherScores, world: Any, path: Path, force: bool) -> None:
    """Each filter's weighted cloud (its own, lag 0) beside its path smoother's, step by step, with the
    exact smoothed mean in both views: a Rerun recording written whole to `path`."""
    import rerun as rr
    import rerun.blueprint as rrb

    from mazelab.viz.recording import Recording
    from mazelab.viz.style import CELL_DOT_RADIUS, MAP, ROBOT_COLOR, entity_name, lab_blueprint, map_view

    views = {
        (label, name): f"{label} {what}"
        for label in scores.recorded
        for name, what in (("filter", "filtered"), ("path", "smoothed"))
    }
    blueprint = lab_blueprint(rrb.Grid(*[map_view(world, title) for title in views.values()], grid_columns=2))
    recording = Recording.open(path, world, blueprint, label="smooth", replace=force)
    if recording is None:  # Rerun switched off: a line said so
        return
    for (label, name), title in views.items():
        colour = filter_entry(label).colour
        for k, (points, weights) in sorted(scores.recorded[label].clouds[name].items()):
            recording.stream.set_time("step", sequence=k)
            radii = CELL_DOT_RADIUS * np.sqrt(weights * len(weights))  # a dot's area grows with its weight
            cloud = rr.Points2D(points, colors=colour, radii=radii)
            recording.stream.log(f"{MAP}/{entity_name(title)}/particles", cloud)
            mean = rr.Points2D([scores.exact.means[k - 1]], colors=ROBOT_COLOR, radii=2 * CELL_DOT_RADIUS)
            recording.stream.log(f"{MAP}/{entity_name(title)}/exact_smoothed_mean", mean)
    recording.close()


def filter_options(filters: str, named: dict[str, Any], option: list[str] | None) -> dict[str, dict[str, Any]]:
    """Each of --filters (its short name) -> the options it declares among the named flags and --option (one
    that none of them takes: one line)."""
    names = [filter_entry(name).short_name for name in parse_filters(filters)]
    given = given_options(named, option, names)
    per_filter = options_per_filter(names, given, given.spelled)
    return {name: per_filter[filter_entry(name).name] for name in names}


def smoothing_summary(scores: SmootherScores) -> list[dict[str, Any]]:
    """Print, per filter, the means over the walk of each smoother's error and total variation, and the
    fewest distinct ancestors the path smoother rests on (at its first step), the exact smoother's error
    to the truth first; return them for the record."""
    exact = (("filter_error", "exact_filtered_to_truth"), ("path_error", "exact_smoothed_to_truth"))
    rows = [{"filter": "exact, to the truth", **{k: float(np.mean([r[c] for r in scores.rows])) for k, c in exact}}]
    for label in dict.fromkeys(r["filter"] for r in scores.rows):
        mine = [r for r in scores.rows if r["filter"] == label]
        means = {
            f"{name}_{k}": float(np.mean([r[f"{name}_{k}"] for r in mine]))
            for name in SMOOTHERS
            for k in ("error", "tv")
        }
        rows.append({"filter": label, **means, "path_ancestors_fewest": int(min(r["path_ancestors"] for r in mine))})
    columns = list(rows[-1])
    typer.echo(format_table(columns, [[shown(row.get(k)) for k in columns] for row in rows]))
    return rows


def shown(value: Any) -> str:
    """A table's cell: a float to 3 decimals, nothing for none."""
    return "" if value is None else f"{value:.3f}" if isinstance(value, float) else str(value)


def smoothing_figure(scores: SmootherScores, title: str) -> Any:
    """Per step: each smoother's distance to the exact smoothed mean (top), the path smoother's distinct
    ancestors (bottom, log scale)."""
    plt = pyplot()
    figure, (top, bottom) = plt.subplots(2, 1, figsize=(9, 7), sharex=True)
    for label in dict.fromkeys(r["filter"] for r in scores.rows):
        mine = [r for r in scores.rows if r["filter"] == label]
        steps = [r["step"] for r in mine]
        for name, style in zip(SMOOTHERS, (":", "--", "-"), strict=True):
            top.plot(steps, [r[f"{name}_error"] for r in mine], style, label=f"{label} {name}")
        bottom.semilogy(steps, [r["path_ancestors"] for r in mine], label=label)
    top.set(yscale="log", ylabel="distance to the exact smoothed mean", title=title)
    bottom.set(xlabel="step k", ylabel="path smoother's distinct ancestors")
    top.legend(fontsize=7, ncol=3)
    bottom.legend(fontsize=7)
    return figure


@with_parameters("files", output_options("the PMMH chain over the exact posterior", resume=RESUME))
@with_parameters("cluster", CLUSTER)
@with_parameters("chain", CHAIN)
def learn(
    scenario: Scenario_,
    sigma_range: opt(str, metavar="LOW,HIGH", help="the uniform prior's sigma range (map units)") = SIGMA_RANGE,
    delta_range: opt(str, metavar="LOW,HIGH", help="the uniform prior's delta range (radians)") = DELTA_RANGE,
    cells: opt(int, min=1, help="the parameter grid's cells along sigma and along delta") = 12,
    resolution: Resolution = 0.1,
    *,
    chain: dict[str, Any],
    cluster: dict[str, Any],
    files: dict[str, Any],
) -> None:
    """Which sigma and delta explain the scenario's measurements: the exact posterior on a grid of cells
    under the uniform prior on the ranges (the grid filter's exact evidence at each, spread over --workers
    processes or a --dask cluster, each finished cell kept in a journal beside --csv that --resume goes on
    from), and a PMMH chain (--pmmh) with a particle filter's evidence beside it."""
    path, stored, files, (world, _, _) = opened(scenario, files)
    ranges = []  # --sigma-range and --delta-range, LOW,HIGH each
    for text, option in ((sigma_range, "--sigma-range"), (delta_range, "--delta-range")):
        values = parse_list(text, float, option)
        if len(values) != 2:
            raise UserError(f"{option} takes LOW,HIGH (two numbers), got {text!r}")
        ranges.append(tuple(values))
    try:
        grid = ParameterGrid(*ranges, (cells, cells))
    except ValueError as error:
        raise UserError(f"{error} (--sigma-range, --delta-range)") from None
    if chain["pmmh"]:
        evidence_filter(chain["filter"])  # a filter PMMH cannot use: one line before the exact posterior's runs
    parameters = {
        "scenario": str(path),
        "sigma_range": grid.sigma_range,
        "delta_range": grid.delta_range,
        "cells": cells,
        "resolution": resolution,
        **chain,
    }
    recorder = Recorder("learn", command_line(), parameters, scenario_sha256=file_sha256(path))
    walk = stored.robot_compass_angles, stored.robot_measurements
    cells_map = functools.partial(run_cells, cells_journal(files, recorder), **cluster)
    posterior = exact_parameter_posterior(world, *walk, grid, mapper=cells_map, resolution=resolution)
    chained = None  # the PMMH chain (none for --pmmh 0), its first tenth the burn-in
    if chain["pmmh"]:
        settings = {"filter_name": chain["filter"], "particle_count": chain["particles"], "seed": chain["seed"]}
        chained = run_pmmh(world, *walk, chain["pmmh"], prior=grid, burn_in=chain["pmmh"] // 10, **settings)
    summary = learning_summary(posterior, chained, chain["filter"])
    rows = ("(sigma, delta) cell", functools.partial(posterior_csv, posterior))
    figure = functools.partial(posterior_figure, posterior, chained, path.name)
    write_outputs(files, recorder, summary, rows, figure, functools.partial(chain_recording, posterior, chained, world))


def cells_journal(files: dict[str, Any], recorder: Recorder) -> tuple[Journal, dict] | None:
    """The journal of the exact posterior's cells beside --csv (a study's Journal, refused as a study's is) and
    the cells an earlier session finished (--resume: what they depend on must be this command's, else one line)."""
    csv_path, file, resume = files["csv_path"], files["journal"], files["resume"]  # the journal `opened` named
    if resume and (file is None or not file.exists()):
        raise UserError(f"--resume: no journal of the cells beside {csv_path} to go on from; leave out --resume")
    if file is None:
        return None
    parameters = recorder.data["parameters"]  # what the cells depend on, which --resume compares
    compared = {
        "scenario_sha256": recorder.data["scenario_sha256"],
        **{k: parameters[k] for k in ("sigma_range", "delta_range", "cells", "resolution")},
    }
    done: dict[int, float] = {}
    if resume:
        lines = read_journal(file)
        sessions = [line["session"]["parameters"] for line in lines if "session" in line]
        changed = differences(sessions[-1], compared) if sessions else ["no session line"]
        if changed:
            raise UserError(
                f"--resume: the command differs from {file} ({changed[0]}); give the same parameters, "
                "or --force to start again"
            )
        try:
            done = {int(line["cell"]): float(line["log_evidence"]) for line in lines if "cell" in line}
        except (KeyError, TypeError, ValueError) as error:
            raise UserError(f"--resume: {file} holds a line that is not a cell's ({error!r})") from None
        typer.echo(f"resuming: {len(done)} cell(s) kept from {file}")
    journal = Journal(file, adopt=resume, replace=files["force"])
    started = {k: recorder.data[k] for k in ("command", "started")}  # as a study's session line
    journal.write({"session": {**started, "parameters": compared}})
    return journal, done


def run_cells(
    journal: tuple[Journal, dict] | None,
    cell: Any,
    sigmas: list[float],
    deltas: list[float],
    *,
    workers: int | None,
    dask: str | None,
) -> np.ndarray:
    """exact_parameter_posterior's map: `cell(sigma, delta)` of every cell (S D,) the journal lacks, on the
    study's executor (--workers processes or the --dask cluster), each finished one appended to the journal;
    a stop or a lost cluster ends as a study's (`exit_stopped`), a cell that failed in one line, exit 1."""
    (log, done), workers = journal or (None, {}), executor.worker_count(workers)
    units = [((i, sigmas[i], deltas[i]),) for i in range(len(sigmas)) if i not in done]

    def keep(cells: list[tuple[int, float]]) -> None:  # finished cells, as the study's collector hands a run's rows
        for index, value in cells:
            log.write({"cell": index, "log_evidence": value})

    client = executor.open_cluster(dask, "numpy")  # a bad address, workers of other versions: one line
    where = f"the Dask cluster at {dask}" if client is not None else f"{min(workers, max(len(units), 1))} process(es)"
    typer.echo(f"the exact posterior's cells: {len(units)} of {len(sigmas)} to go on {where}")
    outcome = executor.StudyOutcome()
    collect = outcome.collector(keep if log is not None else None)  # the cells in outcome.records, and the journal
    try:
        work = executor.Units(units, functools.partial(cell_unit, cell), workers, client, executor.DASK_TIMEOUT)
        executor.run_units(outcome, work, collect, len(units), True, "cells")
    finally:
        if client is not None:
            executor.close_client(client)
    done.update(outcome.records)  # the cells finished now, (index, log evidence) each
    failed = [f"the cell sigma {f.task[1]:g}, delta {f.task[2]:g}: {f.message}" for f in outcome.failures]
    stopped = "lost" if outcome.lost is not None else "interrupted" if outcome.interrupted else None
    if log is not None:
        log.end_session(stopped or ("finished" if not failed else "failed"))
    if stopped:
        kept = f"; {log.kept()}; go on with: {resume_command()}" if log is not None else ""
        exit_stopped(outcome, len(done), len(sigmas), kept, what="cells")
    if failed:
        typer.echo(f"error: {failed[0]} ({len(failed)} cell(s) failed)", err=True)
        raise typer.Exit(1)
    return np.array([done[i] for i in range(len(sigmas))])


def cell_unit(cell: Any, unit: tuple[tuple[int, float, float], ...]) -> list[list[tuple[int, float]]]:
    """A unit of the executor: [(index, log evidence)] of each of its cells (index, sigma, delta)."""
    return [[(index, cell(sigma, delta))] for index, sigma, delta in unit]


def learning_summary(posterior: ParameterPosterior, chain: Any, filter_name: str) -> dict[str, Any]:
    """Print the exact posterior's (and the chain's) mean and 90% interval of sigma and delta, the chain's
    acceptance rate, effective sample size and Monte Carlo error; return them for the record."""
    rows = [["exact", *posterior_cells(posterior.mean, posterior.interval())]]
    summary: dict[str, Any] = {"exact": {"mean": posterior.mean, "interval_90": posterior.interval()}}
    if chain is not None:
        rows.append([f"PMMH ({filter_entry(filter_name).label})", *posterior_cells(chain.mean, chain.interval())])
        summary["pmmh"] = {
            "mean": chain.mean,
            "mean_error": chain.mean_error,
            "interval_90": chain.interval(),
            "acceptance_rate": chain.acceptance_rate,
            "ess": chain.ess,
        }
    typer.echo(format_table(["posterior", "sigma mean", "sigma 90%", "delta mean", "delta 90%"], rows))
    if chain is not None:
        typer.echo(
            f"PMMH: acceptance rate {chain.acceptance_rate:.2f}, effective sample size "
            f"{chain.ess[0]:.0f} (sigma), {chain.ess[1]:.0f} (delta), mean's Monte Carlo error "
            f"{chain.mean_error[0]:.3f}, {chain.mean_error[1]:.3f}"
        )
    return summary


def chain_recording(posterior: ParameterPosterior, chain: Any, world: Any, path: Path, force: bool) -> None:
    """The exact posterior's cells (a dot at each cell's centre, its area the cell's mass, the largest one
    filling its cell) and the PMMH chain's state at every iteration over them: a Rerun recording written
    whole to `path`, the chain's states so far in sight at each iteration."""
    import rerun as rr
    import rerun.blueprint as rrb

    from mazelab.viz.recording import Recording
    from mazelab.viz.style import ROBOT_COLOR, lab_blueprint

    everything = rrb.VisibleTimeRange(
        "iteration", start=rrb.TimeRangeBoundary.infinite(), end=rrb.TimeRangeBoundary.cursor_relative()
    )
    view = rrb.Spatial2DView(name="p(sigma, delta | z_1:K)", origin="/posterior", time_ranges=everything)
    recording = Recording.open(path, world, lab_blueprint(view), label="learn", replace=force)
    if recording is None:  # Rerun switched off: a line said so
        return
    recording.stream.set_time("iteration", sequence=0)
    half_width = min(e[1] - e[0] for e in posterior.grid.edges) / 2
    radii = half_width * np.sqrt(posterior.mass.ravel() / posterior.mass.max())
    cells = rr.Points2D(np.column_stack(posterior.grid.values), radii=radii, colors=(120, 120, 120))
    recording.stream.log("/posterior/cells", cells)
    for i, state in enumerate(chain.samples if chain is not None else (), start=1):
        recording.stream.set_time("iteration", sequence=i)
        dot = rr.Points2D([state], radii=half_width / 8, colors=ROBOT_COLOR if i > chain.burn_in else (255, 160, 0))
        recording.stream.log("/posterior/chain", dot)
    recording.close()


def posterior_cells(mean: np.ndarray, interval: np.ndarray) -> list[str]:
    """A table row's cells: sigma's mean and 90% interval, then delta's."""
    return [cell for i in range(2) for cell in (f"{mean[i]:.3f}", f"{interval[i, 0]:.3f}-{interval[i, 1]:.3f}")]


def posterior_csv(posterior: Any) -> str:
    """One row per cell: its sigma and delta (centres), log p(z_1:K | sigma, delta) and posterior mass."""
    sigmas, deltas = posterior.grid.values
    rows = [
        {"sigma": s, "delta": d, "log_evidence": float(e), "mass": float(m)}
        for s, d, e, m in zip(sigmas, deltas, posterior.log_evidence.ravel(), posterior.mass.ravel(), strict=True)
    ]
    return records_csv(rows, ["sigma", "delta", "log_evidence", "mass"])


def posterior_figure(posterior: Any, chain: Any, title: str) -> Any:
    """The exact posterior's mass on the (sigma, delta) cells, the PMMH chain's states over it."""
    plt = pyplot()
    figure, axes = plt.subplots(figsize=(7, 5.5))
    sigma_edges, delta_edges = posterior.grid.edges
    mesh = axes.pcolormesh(sigma_edges, delta_edges, posterior.mass.T, cmap="Greys")
    figure.colorbar(mesh, ax=axes, label="exact posterior mass of the cell")
    if chain is not None:
        axes.plot(*chain.kept.T, ".", markersize=2, alpha=0.3, color="tab:orange", label="PMMH chain")
        axes.legend()
    axes.set(xlabel="sigma (map units)", ylabel="delta (radians)", title=f"{title}: p(sigma, delta | z_1:K)")
    return figure


def opened(scenario: Path, files: dict[str, Any]) -> tuple[Path, Scenario, dict[str, Any], tuple[Any, float, float]]:
    """The scenario (a file or a shipped name) with its measurements, the outputs (`output_options`, and --csv's
    journal) checked before any work (distinct files, none replaced without --force or learn's --resume, the
    record beside --csv by default) and returned so, and the scenario's maze (the shipped one it fits when it
    stores none), sigma and delta."""
    from mazelab.cli.replay import replay_setup
    from mazelab.scenario import find_scenario, load_scenario  # imported by the commands that read one (a study never)

    csv_path = files["csv_path"]
    replace = files["force"] or files.get("resume", False)  # what may replace an output, kept for write_outputs
    record = files["record"] or (record_path(csv_path) if csv_path is not None else None)
    journal = journal_path(csv_path) if csv_path else None  # learn's, checked by its owner; smooth's too
    named = [("--csv", csv_path), ("--csv's journal", journal), ("--plot", files["plot"]), ("the record", record)]
    check_outputs([*named, ("--rrd", files["rrd"])], replace, apart="--csv's journal")
    path = find_scenario(scenario)
    stored = load_scenario(path)
    if stored.robot_measurements is None:
        raise UserError(f"{path} stores no measurements (robot_measurements): save a run's scenario with them")
    setup = replay_setup(stored, None, None, None, 0)
    files = {**files, "journal": journal, "record": record, "replace": replace}
    return path, stored, files, (setup.world, setup.sigma, setup.delta)


def write_outputs(
    files: dict[str, Any], recorder: Recorder, summary: Any, rows: tuple[str, Any], figure: Any, recording: Any
) -> None:
    """Each output `opened` checked: the rows (`rows`: what one row is, and a callable giving the CSV's text),
    the figure (`figure()`), the recording (`recording(path, replace)`) and the record, finished with `summary`;
    --force (or learn's --resume) replaces them."""
    if files["csv_path"] is not None:
        write_atomically(files["csv_path"], rows[1](), replace=files["replace"])
        typer.echo(f"one row per {rows[0]} written to {files['csv_path']}")
    if files["plot"] is not None:
        save_figure(figure(), files["plot"], replace=files["replace"])
        typer.echo(f"the figure written to {files['plot']}")
    if files["rrd"] is not None:
        recording(files["rrd"], files["replace"])
    if files["record"] is not None:
        recorder.finish("finished", summary=summary)
        recorder.write(files["record"])
        typer.echo(f"the record (command, versions, the scenario's sha256, summary) written to {files['record']}")
