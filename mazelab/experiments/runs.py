"""Several filters on one robot walk, the figures of one run (`FIGURES`: the last-20% error `final_error`,
robust to one unlucky step, the convergence step, `relocalised` and `recovery_steps` after a kidnapping, ...),
and comparing the filters on one saved scenario (lab steps 12-13: every filter replays the same start, initial
particles, angles and measurements; `compare_filters` returns their RunResults, `comparison_table`,
`errors_csv` and `plot_errors` report them).
"""

from __future__ import annotations

import contextlib
import dataclasses
import math
import time
import warnings
from collections.abc import Callable, Hashable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from mazelab.backend import backend_by_work, chosen_backend
from mazelab.declaration import not_taken, options_of, scoped
from mazelab.experiments.tables import column_table, format_number, pyplot, records_csv, save_figure
from mazelab.maze import Maze
from mazelab.model import CONVERGENCE_RADIUS, DEFAULT_PARTICLE_COUNT, DEFAULT_STEPS
from mazelab.registry import described, filter_entry, resolve_filter, rgb
from mazelab.robot import Robot
from mazelab.simulation import RunResult, convergence_step, simulate
from mazelab.viz.views import open_comparison

FINAL_SHARE = 0.2  # the last-20% error (`final_error`) is the mean error over this share of the last steps
DEFAULT_WINDOW = 30  # re-localised: mean error over this many final steps below CONVERGENCE_RADIUS


def walk_until(robot: Robot, kidnap_at: int) -> Robot:
    """A copy of `robot` replaying only the steps before `kidnap_at` (angles and measurements), so that it
    can be kidnapped there: a recorded walk after the jump would retrace the old place's path."""
    if isinstance(kidnap_at, bool) or not isinstance(kidnap_at, int) or kidnap_at < 1:
        raise ValueError(f"kidnap_at must be a step number >= 1, got {kidnap_at!r}")
    keep = kidnap_at - 1
    return Robot(
        robot.sigma,
        robot.delta,
        robot.initial_position,
        actual_angles=robot.actual_angles[:keep],
        compass_angles=robot.compass_angles[:keep],
        measurements=robot.measurements[:keep] if robot.measurements else None,
        rng=robot.rng if robot.rng_given else None,
        max_straight_steps=robot.max_straight_steps,
        speed=robot.speed,
    )


def recovery_steps(result: RunResult) -> int | None:
    """R - K: R the first step from which the error stays below CONVERGENCE_RADIUS, K the kidnap step."""
    kidnap_at = result.inputs.kidnap_at
    if kidnap_at is None:
        raise ValueError("the run has no kidnapping")
    since = convergence_step(result.errors[kidnap_at - 1 :])  # 1-based within the errors of steps K..end
    return None if since is None else since - 1


def relocalised(result: RunResult, window: int = DEFAULT_WINDOW) -> bool:
    """The mean error over the last `window` steps is below CONVERGENCE_RADIUS."""
    return bool(result.errors[-window:].mean() < CONVERGENCE_RADIUS)


def final_error(errors: np.ndarray, share: float = FINAL_SHARE) -> float:
    """Mean error over the last `share` of the steps (at least one step), map units."""
    errors = np.asarray(errors, dtype=float)
    return float(errors[-max(1, int(len(errors) * share)) :].mean())


def parse_filters(text: str) -> list[str]:
    """'sir,apf,rpf' -> the filters' class names, in order, without repeats; a plug-in
    `file.py:Class` -> its spec with the file's absolute path (what worker processes import)."""
    names = [filter_key(part.strip()) for part in text.split(",") if part.strip()]
    if not names:
        raise ValueError("--filters is empty; give e.g. sir,apf,rpf")
    names = list(dict.fromkeys(names))
    labels = [resolve_filter(name).name for name in names]
    for label in labels:
        if labels.count(label) > 1:
            raise ValueError(f"--filters has two filters named {label}: rename one class (or its `name`)")
    return names


def filter_key(name: str) -> str:
    """A shipped filter's class name, or a plug-in's spec with its absolute path (what worker processes import)."""
    entry = filter_entry(name)
    return entry.reference if entry.plugin is not None else entry.name


# -- start-up apart from the time per step --------------------------------------------------------
# The one-off costs of a process (importing numba and loading the compiled kernels, numpy's and the
# filters' first calls, lazily imported modules) are paid before any timed step, so that a filter's ms/step
# is the same whichever order the filters run in and whether or not it is the first run of a worker. Each
# filter is warmed once per process, backend and set of options (a different option can reach different
# kernels), by a few untimed steps on a walk of its own (its numbers are thrown away; no seed of the study
# is drawn from). The time spent is kept as the process's start-up (`take_startup_seconds`), which the
# study and compare report apart, once. A maze's nearest-station table is built before the timed steps too
# (`Maze.prepare`): a run on a new maze (a generated one) would otherwise charge it to the first step.
WARM_UP_STEPS = 3  # untimed steps per filter: the first loads the kernels, the next ones reach the resampling
# (a filter that resamples when N_eff < threshold N is warmed again with threshold 1, which resamples at once)
WARM_UP_SEED = 0  # the warm-up walk's seed (its numbers are discarded)

_warmed: set[Hashable] = set()  # what this process has warmed: (filter, backend, options, shape)
_startup_seconds = [0.0]  # start-up spent in this process and not yet reported


def warm_once(key: Hashable, filter_class: type, options: Mapping[str, Any], warm: Callable[[dict], Any]) -> None:
    """Run `warm(options)` the first time this process sees `key`, the filter, the options that differ from
    their declared default (a filter given its defaults runs the same code as one given nothing) and the
    chosen backend; its time kept as start-up, the warnings it raises dropped (the study or compare shows its
    own). A filter that resamples only when N_eff falls below threshold N (the RPF's 0.2 N: a few steps may
    not reach it) is warmed with threshold 1 too, so that its resampling's code (the RPF's covariance and
    jitter) is loaded before the timed steps too."""
    declared = options_of(filter_class)
    changed = repr(sorted((k, v) for k, v in options.items() if k not in declared or declared[k].default != v))
    key = (key, filter_class, changed, chosen_backend())
    if key in _warmed:
        return
    threshold = declared.get("threshold")
    late = threshold is not None and options.get("threshold", threshold.default) < 1
    started = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for warmed in [{**options}, {**options, "threshold": 1.0}] if late else [{**options}]:
            warm(warmed)
    _warmed.add(key)
    _startup_seconds[0] += time.perf_counter() - started


def warm_up_filters(
    world: Maze,
    sigma: float,
    delta: float,
    filter_names: Sequence[str],
    particle_count: int | None,
    options: Mapping[str, Mapping[str, Any]],
) -> None:
    """Before a run's timed steps: the maze's table built, and each filter (with its options) warmed
    once per process by WARM_UP_STEPS steps on a walk of its own (mazelab.simulation.simulate)."""
    world.prepare()
    for name in filter_names:

        def warm(warmed: dict[str, Any], name: str = name) -> None:
            robot = Robot.of_seed(world, sigma, delta, WARM_UP_SEED)
            simulate(robot, world, sigma, delta, particle_count, WARM_UP_STEPS, None, name, seed=WARM_UP_SEED, **warmed)

        warm_once("single", resolve_filter(name), dict(options.get(name, {})), warm)


def take_startup_seconds() -> float:
    """The start-up this process spent since it was last taken (then 0 until more is spent)."""
    seconds, _startup_seconds[0] = _startup_seconds[0], 0.0
    return seconds


# -- several filters on one scenario ---------------------------------------------------------------
def run_filters(
    world: Maze,
    robot: Robot,
    sigma: float,
    delta: float,
    filter_names: Sequence[str],
    *,
    seed: int,
    particles: Sequence[Sequence[float]] | np.ndarray | None = None,
    particle_count: int | None = None,
    steps: int | None = None,
    visualize: Any = False,
    kidnap_at: int | None = None,
    options: Mapping[str, Mapping[str, Any]] | None = None,
) -> dict[str, RunResult]:
    """Run every filter on the same scenario: the robot's walk, measurements and initial particles.

    The first run records the walk and measurements (if the robot has none) and draws the particles
    (if none are given); every later filter replays exactly those, the kidnapping (`kidnap_at`, its
    place drawn from `seed`) included. Each filter's random draws come from `seed`, and with
    `visualize` the runs are drawn side by side in one recording (open_comparison). `options` maps a
    filter's name (as in `filter_names`) to its own options. Before the first timed step, each filter is
    warmed once per process (`warm_up_filters`): a filter's time per step is the same in any order.
    """
    count = particle_count if particles is None else len(particles)
    calls = (steps or robot.recorded_steps or DEFAULT_STEPS) * len(filter_names)  # the filters' steps
    results: dict[str, RunResult] = {}
    labels = [resolve_filter(name).name for name in filter_names]  # a plug-in's: its class name
    comparison = open_comparison(visualize, world, labels)  # without drawing: no recording
    with backend_by_work((count or DEFAULT_PARTICLE_COUNT) * calls, calls), contextlib.closing(comparison):
        warm_up_filters(world, sigma, delta, filter_names, count, options or {})  # on the runs' backend
        for name, label in zip(filter_names, labels, strict=True):
            result = simulate(
                robot,
                world,
                sigma,
                delta,
                particle_count,
                steps,
                particles,
                name,
                seed=seed,
                view=comparison.view_for(label),
                kidnap_at=kidnap_at,
                **(options or {}).get(name, {}),
            )
            particles = result.inputs.init_particles_pos if particles is None else particles
            steps = len(result.errors)
            results[result.inputs.filtering_algorithm] = result
    return results


@dataclass(frozen=True)
class Figure:
    """A column of a study's rows after its filter (a RunRecord field, a CSV column): a figure of one
    filter's run, computed by `of(result, entry)` from its RunResult and its filter's registry entry (None:
    a cell the study sets, of the run's scenario or its timing; `default` its value until then, REQUIRED:
    none, every RunRecord is made with it), and how a study summarises it: with `summary` "mean", the mean
    over the runs that have one, a summary CSV column of its name and a table column `header` (each value
    in `spec`, shown where a run has one); "interval" adds its BCa bootstrap interval (NAME_low, NAME_high).
    The figures summarised by statistics of their own (the final error, convergence, re-localisation, log
    evidence) leave `summary` None (mazelab.experiments.summary)."""

    name: str
    of: Callable[[RunResult, Any], Any] | None = None
    default: Any = None
    summary: str | None = None
    header: str = ""
    spec: str = "{:.3f}"


REQUIRED = dataclasses.MISSING  # a Figure's `default`: none (every RunRecord is made with the figure)


FIGURES = (  # in the CSV's order; a new figure of a run is one more line here (and its words in docs/studies.md)
    Figure("final_error", lambda r, e: final_error(r.errors), REQUIRED),  # the last-20% error, map units
    Figure("mean_error", lambda r, e: float(r.errors.mean()), REQUIRED),
    Figure("converged_at", lambda r, e: r.converged_at, REQUIRED),  # convergence_step of the errors; None: never
    # the mean effective sample size over the steps; NaN for the grid filter, which has none
    Figure("mean_ess", lambda r, e: math.nan if np.isnan(r.ess).all() else float(np.nanmean(r.ess)), REQUIRED),
    Figure("ms_per_step", lambda r, e: 1e3 * float(r.step_seconds.mean()), REQUIRED),
    Figure("kidnap_at"),  # the step the robot is kidnapped at (steps_to_recover None: never re-localised)
    Figure("relocalised", lambda r, e: None if r.inputs.kidnap_at is None else relocalised(r), None),
    Figure("steps_to_recover", lambda r, e: None if r.inputs.kidnap_at is None else recovery_steps(r), None),
    Figure("mean_particle_count", lambda r, e: float(np.mean(r.extras["particle_count"])), math.nan),  # KLD varies it
    Figure("maze_sha256"),  # of the maze file's bytes; a generated maze's: of its grid as maze text
    Figure("maze_rows", default=0),  # the run's maze size
    Figure("maze_columns", default=0),
    Figure("wall_share"),  # a generated maze's requested share of walls; None for a file
    Figure("run_seconds", default=math.nan),  # wall time of the run: its share of the unit of runs it ran in
    # with `study --reference grid`: the distance of the filter's estimates to the exact posterior means
    Figure("distance_to_exact", default=math.nan, summary="interval", header="dist. to exact"),
    Figure("log_evidence", lambda r, e: float(r.log_evidence[-1]), math.nan),
    Figure("log_evidence_caveat", lambda r, e: e.evidence, ""),  # why it is not of p(z_1:K) (the registry's)
    Figure("label", lambda r, e: e.label, ""),  # the filter's label in the registry (SIR, APF, ...)
    Figure("backend", lambda r, e: r.extras["backend"], ""),  # as the process that ran it says
)


def run_figures(name: str, result: RunResult) -> dict[str, Any]:
    """The figures of filter `name`'s run (FIGURES), by the study CSV's names: every table and record of a
    run reads them here."""
    entry = described(name)
    return {figure.name: figure.of(result, entry) for figure in FIGURES if figure.of is not None}


# -- comparing the filters on one saved scenario (lab steps 12-13) ---------------------------------
def options_per_filter(
    filters: Sequence[str | type],
    given: Mapping[str, Any],
    spelled: Mapping[str, str] | None = None,
    *,
    check: bool = False,
) -> dict[str, dict[str, Any]]:
    """Per filter (by `name`), the given options (None: not given) that reach it: a plain
    name every filter that declares it, FILTER.NAME its filter alone. With `check`, each filter's
    options are checked by its declaration as its constructor will check them.

    Raises
    ------
    ValueError
        One line, the option as `spelled`: an option none of the filters takes (naming what they take),
        FILTER.NAME of a filter not among them, one option given both for every filter and for one,
        or (with `check`) a value or combination the filter refuses.
    """
    entries_ = [filter_entry(f) for f in filters]
    spelled = spelled or {}
    every = {k: v for k, v in given.items() if scoped(k)[0] is None and v is not None}
    for option in every:  # a plain name: every filter that declares it
        if not any(option in e.options for e in entries_):
            raise ValueError(not_taken([e.filter_class for e in entries_], spelled.get(option, option)))
    per_filter = {e.name: {o: v for o, v in every.items() if o in e.options} for e in entries_}
    for key, value in given.items():
        scope, name = scoped(key)
        if scope is None or value is None:
            continue
        target = filter_entry(scope)
        if target.name not in per_filter:
            shown = ", ".join(e.short_name for e in entries_)
            raise ValueError(f"{spelled.get(key, key)}: {scope} is not one of the filters ({shown})")
        if name not in target.options:
            raise ValueError(not_taken([target.filter_class], spelled.get(key, key)))
        if given.get(name) is not None:
            raise ValueError(f"{name} is given for every filter and for {scope}: give one of them")
        per_filter[target.name][name] = value
    for entry in entries_ if check else ():
        entry.options.resolve(per_filter[entry.name], entry.name)
    return per_filter


def compare_filters(
    world: Maze,
    robot: Robot,
    sigma: float,
    delta: float,
    particles: Sequence[Sequence[float]],
    filter_names: Sequence[str],
    *,
    seed: int,
    visualize: Any = False,
    kidnap_at: int | None = None,
    **options: Any,
) -> dict[str, RunResult]:
    """Lab steps 12-13: every filter on one saved scenario, drawn side by side in one recording.

    `kidnap_at=K` on a scenario recorded without a kidnapping replays its walk up to step K - 1; then
    the robot is carried to a free place drawn from `seed` and walks on, every filter seeing the same.
    `options` (e.g. recovery="sensor", bandwidth="multimodal") reach each filter that declares them; one
    that none of the filters declares is refused in one line."""
    per_filter = options_per_filter(filter_names, options)
    steps = robot.recorded_steps
    if kidnap_at is not None and robot.kidnap_at is None:
        robot = walk_until(robot, kidnap_at)
    options = {name: per_filter[resolve_filter(name).name] for name in filter_names}
    return run_filters(
        world,
        robot,
        sigma,
        delta,
        filter_names,
        seed=seed,
        particles=particles,
        steps=steps,
        visualize=visualize,
        kidnap_at=kidnap_at,
        options=options,
    )


def comparison_table(results: dict[str, RunResult], kld: bool = False, startup_seconds: float | None = None) -> str:
    """Per filter: mean error, last-20% error (the mean error over the last 20% of the steps), convergence
    step, mean ESS, the log evidence log p(z_1:K) of the whole walk (its estimate; exact for the grid
    filter; '-' for a filter that keeps none; marked '*' where it is not an estimate of p(z_1:K) under the
    model, a line under the table says why) and milliseconds per step with the backend it ran on; with a
    kidnapping, whether the filter re-localised and in how many steps; with `kld`, the mean particle
    count. With `startup_seconds` (the process's one-off costs), a line saying what ms/step is."""
    figures = [{**run_figures(name, result), "name": name} for name, result in results.items()]
    backends = {f["backend"] for f in figures}
    one = len(backends) == 1
    columns = [
        ("filter", lambda f: f["label"]),
        ("mean error", lambda f: f"{f['mean_error']:.3f}"),
        (f"last-{FINAL_SHARE:.0%} error", lambda f: f"{f['final_error']:.3f}"),
        ("converged at", lambda f: "never" if f["converged_at"] is None else f"step {f['converged_at']}"),
        ("mean ESS", lambda f: format_number(f["mean_ess"], "{:.0f}")),
        ("log p(z_1:K)", lambda f: format_number(f["log_evidence"], "{:.1f}") + "*" * bool(f["log_evidence_caveat"])),
        (
            f"ms/step, {next(iter(backends))}" if one else "ms/step, backend",
            lambda f: f"{f['ms_per_step']:.2f}" + ("" if one else f" {f['backend']}"),
        ),
    ]
    if any(result.inputs.kidnap_at is not None for result in results.values()):
        columns += [
            ("re-localised", lambda f: "yes" if f["relocalised"] else "no"),
            ("steps to recover", lambda f: "never" if f["steps_to_recover"] is None else str(f["steps_to_recover"])),
        ]
    if kld:
        columns.append(
            ("mean N", lambda f: f"{f['mean_particle_count']:.0f}" if filter_entry(f["name"]).takes_particles else "-")
        )
    caveats = {f["label"]: f["log_evidence_caveat"] for f in figures if f["log_evidence_caveat"]}
    notes = [f"[* {label}: the log evidence is {why}]" for label, why in caveats.items()]
    if startup_seconds is not None:
        notes.append(
            f"[ms/step: one run's steps of each filter, on the backend named, after untimed warm-up steps; start-up "
            f"(first calls, and numba's kernels loaded on the compiled backend) {startup_seconds:.2f} s, not in "
            "ms/step]"
        )
    return "\n".join([column_table(columns, figures), *notes])


def errors_csv(results: dict[str, RunResult]) -> str:
    """Per-step errors as CSV: a `step` column (1..steps), then one column per filter."""
    columns = {name: result.errors for name, result in results.items()}
    steps = range(len(next(iter(columns.values()))))
    rows = [{"step": k + 1, **{name: float(errors[k]) for name, errors in columns.items()}} for k in steps]
    return records_csv(rows, ["step", *columns])


def plot_errors(results: dict[str, RunResult], path: Path, title: str, *, replace: bool = True) -> None:
    """The lab's figure: error against step, one line per filter in its registry colour, each with a line
    style and markers of its own (the lines stay apart in grey print), saved to `path` (png, pdf or svg)."""
    plt = pyplot()
    figure, axes = plt.subplots(figsize=(8, 4.5), layout="constrained")
    for i, (name, result) in enumerate(results.items()):
        steps = np.arange(1, len(result.errors) + 1)
        entry = described(name)  # the registry's label and colour, as in the viewer
        axes.plot(
            steps,
            result.errors,
            label=entry.label,
            color=rgb(entry.colour),
            linewidth=1.2,
            linestyle=LINE_STYLES[i % len(LINE_STYLES)],
            marker=MARKERS[i % len(MARKERS)],
            markevery=(i, max(1, len(steps) // 12)),
            markersize=4,
        )
    axes.axhline(CONVERGENCE_RADIUS, color="grey", linestyle="--", linewidth=0.8, label="convergence radius")
    axes.set(title=title, xlabel="step k", ylabel="error |estimate - true position| (map units)")
    axes.set_ylim(bottom=0)
    axes.grid(alpha=0.3)
    axes.legend()
    save_figure(figure, path, replace=replace)


MARKERS = ("o", "s", "^", "D", "v", "P", "X")  # each line of a figure a marker and a line style of its own
LINE_STYLES = ("-", "--", ":", "-.")
