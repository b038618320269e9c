"""Comparing the filters on one scenario (lab steps 12-13) and Monte Carlo parameter studies (step 14).

compare: every filter replays the same saved scenario (start, initial particles, angles, measurements);
    `compare_filters` returns their RunResults, `comparison_table`, `errors_csv` and `plot_errors` report them.
study: settings (the product of the varied parameters) x R seeded runs; in each run every filter sees
    the same scenario. `run_study` runs them on all cores, `summarise_study` gives per setting and
    filter the mean final error with its 95% t-interval, the converged share and the median
    convergence step; `study_csv` and `plot_study` write them out.
Both can kidnap the robot (`kidnap_at`) and turn on recovery and KLD-sampling in the particle filters;
their tables then add the share of runs that re-localise, the median steps to recover (kidnapping.py's
`relocalised` and `recovery_steps`) and the mean particle count.

Figures of one run (used by both):
    final error       the mean error over the last FINAL_SHARE (20%) of the steps: robust to one unlucky step;
    convergence step  `convergence_step`: the step from which the error stays below CONVERGENCE_RADIUS.
"""

from __future__ import annotations

import csv
import functools
import io
import itertools
import math
import os
import signal
import statistics
import warnings
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from contextlib import contextmanager
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path
from typing import Any

import numpy as np

import draw
from draw import STATION_WALL, Maze
from kidnapping import RECOVERY_VARIANTS, recovery_steps, relocalised, walk_until
from maze_generator import generate_maze
from particle_filter import (
    CONVERGENCE_RADIUS,
    KLDSampling,
    ParticleFilter,
    Recovery,
    RegularizedParticleFilter,
    Robot,
    RunResult,
    check_model_parameters,
    convergence_step,
    resolve_filter,
    simulate,
    write_bytes_atomically,
)

FINAL_SHARE = 0.2  # the final error is the mean error over this share of the last steps
CONFIDENCE_LEVEL = 0.95  # of the t-interval for the mean final error
PLOT_INSTALL_HINT = 'plotting needs matplotlib: pip install -e ".[plot]"'


# -- figures of one run ----------------------------------------------------------------------------
def final_error(errors: np.ndarray, share: float = FINAL_SHARE) -> float:
    """Mean error over the last `share` of the steps (at least one step), map units."""
    errors = np.asarray(errors, dtype=float)
    return float(errors[-max(1, int(len(errors) * share)) :].mean())


def mean_ess(result: RunResult) -> float:
    """Mean effective sample size over the steps; NaN for the grid filter, which has none."""
    return math.nan if np.isnan(result.ess).all() else float(np.nanmean(result.ess))


def parse_filters(text: str) -> list[str]:
    """'sir,apf,rpf' -> the filters' class names, in order, without repeats."""
    names = [resolve_filter(part.strip()).name for part in text.split(",") if part.strip()]
    if not names:
        raise ValueError("--filters is empty; give e.g. sir,apf,rpf")
    return list(dict.fromkeys(names))


# -- several filters on one scenario ---------------------------------------------------------------
def filter_options(
    filter_name: str,
    threshold: float | None,
    recovery: bool | str | Recovery | None = None,
    kld: bool | KLDSampling | None = None,
) -> dict[str, Any]:
    """Constructor options of one filter: the RPF threshold N_T / N_S goes to the RPF only, recovery
    and KLD-sampling to the particle filters only (the exact grid filter needs neither)."""
    filter_class = resolve_filter(filter_name)
    options: dict[str, Any] = {}
    if threshold is not None and filter_class is RegularizedParticleFilter:
        options["threshold"] = threshold
    if issubclass(filter_class, ParticleFilter):
        options.update(recovery=recovery, kld=kld)
    return options


def is_particle_filter(filter_name: str) -> bool:
    return issubclass(resolve_filter(filter_name), ParticleFilter)


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
    threshold: float | None = None,
    comparison: Any = None,
    kidnap_at: int | None = None,
    recovery: bool | str | Recovery | None = None,
    kld: bool | KLDSampling | None = None,
) -> dict[str, RunResult]:
    """Run every filter on the same scenario: the robot's walk, measurements and initial particles.

    The first run records the walk and measurements (if the robot has none) and draws the particles
    (if none are given); every later filter replays exactly those, the kidnapping (`kidnap_at`, its
    place drawn from `seed`) included. Each filter's random draws come from `seed`, and with
    `comparison` (draw.open_comparison) each run draws into its own view.
    """
    results: dict[str, RunResult] = {}
    for name in filter_names:
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
            visualize=False if comparison is None else comparison.view_for(name),
            kidnap_at=kidnap_at,
            **filter_options(name, threshold, recovery, kld),
        )
        if particles is None:
            particles = np.array(result.scenario.init_particles_pos)
        steps = len(result.errors)
        results[result.filter_name] = result
    return results


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
    recovery: bool | str | Recovery | None = None,
    kld: bool | KLDSampling | None = None,
) -> dict[str, RunResult]:
    """Lab steps 12-13: every filter on one saved scenario, drawn side by side in one recording.

    `kidnap_at=K` on a scenario recorded without a kidnapping replays its walk up to step K - 1; then
    the robot is carried to a free place drawn from `seed` and walks on, every filter seeing the same."""
    steps = robot.recorded_steps
    if kidnap_at is not None and robot.kidnap_at is None:
        robot = walk_until(robot, kidnap_at)
    comparison = draw.open_comparison(visualize, world, list(filter_names))
    try:
        return run_filters(
            world,
            robot,
            sigma,
            delta,
            filter_names,
            seed=seed,
            particles=particles,
            steps=steps,
            comparison=comparison,
            kidnap_at=kidnap_at,
            recovery=recovery,
            kld=kld,
        )
    finally:
        comparison.close()


def comparison_table(results: dict[str, RunResult], kld: bool = False) -> str:
    """Per filter: mean error, final error, convergence step, mean ESS and milliseconds per step; with a
    kidnapping, whether the filter re-localised and in how many steps; with `kld`, the mean particle count."""
    kidnapped = any(result.scenario.kidnap_at is not None for result in results.values())
    headers = ["filter", "mean error", f"last {FINAL_SHARE:.0%} error", "converged at", "mean ESS", "ms/step"]
    headers += ["re-localised", "steps to recover"] * kidnapped + ["mean N"] * kld
    rows = []
    for name, result in results.items():
        converged = result.converged_at
        row = [
            name,
            f"{result.errors.mean():.3f}",
            f"{final_error(result.errors):.3f}",
            "never" if converged is None else f"step {converged}",
            _number(mean_ess(result), "{:.0f}"),
            f"{1e3 * result.step_seconds.mean():.2f}",
        ]
        if kidnapped:
            steps = recovery_steps(result)
            row += ["yes" if relocalised(result) else "no", "never" if steps is None else str(steps)]
        if kld:
            row.append(f"{mean_particle_count(result):.0f}" if is_particle_filter(name) else "-")
        rows.append(row)
    return format_table(headers, rows)


def mean_particle_count(result: RunResult) -> float:
    """The particle count averaged over the steps (it varies with KLD-sampling)."""
    return float(np.mean(result.extras["particle_count"]))


def errors_csv(results: dict[str, RunResult]) -> str:
    """Per-step errors as CSV: a `step` column (1..steps), then one column per filter."""
    names = list(results)
    buffer = io.StringIO()
    writer = csv.writer(buffer, lineterminator="\n")
    writer.writerow(["step", *names])
    columns = [results[name].errors for name in names]
    for k, row in enumerate(zip(*columns, strict=True), start=1):
        writer.writerow([k, *(repr(float(e)) for e in row)])
    return buffer.getvalue()


def plot_errors(results: dict[str, RunResult], path: Path, title: str) -> None:
    """The lab's figure: error against step, one line per filter, saved to `path` (png, pdf or svg)."""
    plt = pyplot()
    figure, axes = plt.subplots(figsize=(8, 4.5), layout="constrained")
    for name, result in results.items():
        axes.plot(np.arange(1, len(result.errors) + 1), result.errors, label=name, linewidth=1.2)
    axes.axhline(CONVERGENCE_RADIUS, color="grey", linestyle="--", linewidth=0.8, label="convergence radius")
    axes.set(title=title, xlabel="step k", ylabel="error |estimate - true position| (map units)")
    axes.set_ylim(bottom=0)
    axes.grid(alpha=0.3)
    axes.legend()
    save_figure(figure, path)


# -- a study: settings, runs and seeds -------------------------------------------------------------
@dataclass(frozen=True)
class MazeChoice:
    """A study's maze: a file's grid, or a size and station count generated anew in every run."""

    label: str
    grid: tuple[tuple[int, ...], ...] | None = None
    size: tuple[int, int] | None = None  # (rows, columns) of a generated maze
    stations: int | None = None  # station blocks of a generated maze

    @classmethod
    def from_maze(cls, label: str, world: Maze) -> MazeChoice:
        return cls(label, grid=tuple(map(tuple, world.as_lists())))

    @classmethod
    def generated(cls, rows: int, columns: int, stations: int) -> MazeChoice:
        return cls(f"random {rows}x{columns}, {stations} stations", size=(rows, columns), stations=stations)

    def world(self, maze_seed: int | None) -> Maze:
        """The maze of one run: the file's grid, or the generated maze of `maze_seed`."""
        if self.grid is not None:
            return _maze_of(self.grid, self.label)
        assert self.size is not None and self.stations is not None
        return generate_maze(*self.size, self.stations, np.random.default_rng(maze_seed))


@functools.lru_cache(maxsize=8)
def _maze_of(grid: tuple[tuple[int, ...], ...], label: str) -> Maze:
    """The Maze of a file's grid, built once per process: its nearest-station table then serves every
    run of the study that uses it (a Maze does not change once built)."""
    return Maze(grid, source=label)


@dataclass(frozen=True)
class StudySetting:
    """One combination of the studied parameters."""

    maze: MazeChoice
    sigma: float
    delta: float
    particles: int
    threshold: float  # the RPF's N_T / N_S
    recovery: str = "none"  # a kidnapping.RECOVERY_VARIANTS name, for the particle filters

    def value(self, parameter: str) -> Any:
        return self.maze.label if parameter == "maze" else getattr(self, parameter)


STUDY_PARAMETERS = ("maze", "sigma", "delta", "particles", "threshold", "recovery")


def study_settings(
    mazes: Sequence[MazeChoice],
    sigmas: Sequence[float],
    deltas: Sequence[float],
    particle_counts: Sequence[int],
    thresholds: Sequence[float],
    recoveries: Sequence[str] = ("none",),
) -> list[StudySetting]:
    """Every combination of the given values (the first parameter varies slowest), each checked."""
    for recovery in recoveries:
        if recovery not in RECOVERY_VARIANTS:
            raise ValueError(f"unknown recovery {recovery!r}; choose from {', '.join(RECOVERY_VARIANTS)}")
    for count in particle_counts:
        if count < 1:
            raise ValueError(f"particle counts must be >= 1, got {count}")
    for threshold in thresholds:
        if not 0 < threshold <= 1:
            raise ValueError(f"the RPF threshold must be in (0, 1] (N_T = threshold * N_S), got {threshold}")
    for sigma, delta in itertools.product(dict.fromkeys(sigmas), dict.fromkeys(deltas)):
        check_model_parameters(sigma, delta)  # refuses impossible values, warns once outside the lab's ranges
    combinations = itertools.product(mazes, sigmas, deltas, particle_counts, thresholds, recoveries)
    return [StudySetting(*values) for values in combinations]


def varied_parameters(settings: Sequence[StudySetting]) -> list[str]:
    """The parameters that take more than one value across the settings."""
    return [p for p in STUDY_PARAMETERS if len({s.value(p) for s in settings}) > 1]


@dataclass(frozen=True)
class RunTask:
    """Run `run` of setting `setting_index`: the seeds that fix its scenario, and what to run."""

    setting_index: int  # 1-based
    setting: StudySetting
    run: int  # 1-based
    seed: int  # seeds the start (default_rng(seed)) and simulate(seed=seed), as `run --seed S --start-seed S`
    maze_seed: int | None  # seeds a generated maze (as `maze generate --seed`); None for a maze file
    filters: tuple[str, ...]
    steps: int
    kidnap_at: int | None = None  # kidnap the robot at this step (its place drawn from `seed`)
    kld: bool = False  # KLD-sampling in the particle filters


def run_seeds(root_seed: int, runs: int) -> list[tuple[int, int]]:
    """(seed, maze seed) of runs 1..R, children of one root SeedSequence.

    Run r has the same seeds in every setting (common random numbers: settings differ by their
    parameters, not by their luck), and no seed depends on the number of workers.
    """
    children = np.random.SeedSequence(root_seed).spawn(runs)
    return [tuple(int(v >> np.uint64(1)) for v in child.generate_state(2, np.uint64)) for child in children]


def study_tasks(
    settings: Sequence[StudySetting],
    filters: Sequence[str],
    runs: int,
    steps: int,
    root_seed: int,
    *,
    kidnap_at: int | None = None,
    kld: bool = False,
) -> list[RunTask]:
    """One task per setting and run, in order."""
    if runs < 1 or steps < 1:
        raise ValueError(f"runs and steps must be >= 1, got {runs} runs and {steps} steps")
    if kidnap_at is not None and not 1 <= kidnap_at <= steps:
        raise ValueError(f"kidnap_at must be a step from 1 to {steps}, got {kidnap_at}")
    seeds = run_seeds(root_seed, runs)
    return [
        RunTask(
            i, setting, r, seed, maze_seed if setting.maze.grid is None else None, tuple(filters), steps, kidnap_at, kld
        )
        for i, setting in enumerate(settings, start=1)
        for r, (seed, maze_seed) in enumerate(seeds, start=1)
    ]


@dataclass
class RunRecord:
    """One filter in one run of a study: a row of the study's CSV."""

    setting: int
    run: int
    seed: int
    maze: str
    maze_seed: int | None
    stations: int  # station blocks (cells of type 2) of the run's maze
    sigma: float
    delta: float
    particles: int
    threshold: float
    steps: int
    filter: str
    final_error: float  # mean error over the last FINAL_SHARE of the steps
    mean_error: float
    converged_at: int | None  # convergence_step of the errors; None: never
    mean_ess: float  # NaN for the grid filter
    ms_per_step: float
    recovery: str = "none"
    kidnap_at: int | None = None
    relocalised: bool | None = None  # kidnapping.relocalised; None without a kidnapping
    steps_to_recover: int | None = None  # kidnapping.recovery_steps; None: never, or no kidnapping
    mean_particle_count: float = math.nan  # over the steps (KLD-sampling varies it)


@dataclass
class RunFailure:
    """A run that raised: which one, its seeds, and the error on one line."""

    task: RunTask
    message: str

    def describe(self) -> str:
        t = self.task
        maze_seed = "" if t.maze_seed is None else f", maze seed {t.maze_seed}"
        return f"run {t.run} of setting {t.setting_index} (seed {t.seed}{maze_seed}) failed: {self.message}"


def run_task(task: RunTask, visualize: Any = False) -> list[RunRecord]:
    """One run of a study: one scenario, every filter on it; a record per filter."""
    s = task.setting
    world = s.maze.world(task.maze_seed)
    robot = Robot(s.sigma, s.delta, world.random_free_place(np.random.default_rng(task.seed)))
    comparison = draw.open_comparison(visualize, world, list(task.filters)) if visualize else None
    try:
        with warnings.catch_warnings():  # the range warnings were shown once, by study_settings
            warnings.simplefilter("ignore", UserWarning)
            results = run_filters(
                world,
                robot,
                s.sigma,
                s.delta,
                task.filters,
                seed=task.seed,
                particle_count=s.particles,
                steps=task.steps,
                threshold=s.threshold,
                comparison=comparison,
                kidnap_at=task.kidnap_at,
                recovery=RECOVERY_VARIANTS[s.recovery],
                kld=task.kld,
            )
    finally:
        if comparison is not None:
            comparison.close()
    stations = int((world.grid == STATION_WALL).sum())
    return [
        RunRecord(
            task.setting_index,
            task.run,
            task.seed,
            s.maze.label,
            task.maze_seed,
            stations,
            s.sigma,
            s.delta,
            s.particles,
            s.threshold,
            task.steps,
            name,
            final_error(result.errors),
            float(result.errors.mean()),
            convergence_step(result.errors),
            mean_ess(result),
            1e3 * float(result.step_seconds.mean()),
            s.recovery,
            task.kidnap_at,
            *kidnap_figures(result),
            mean_particle_count(result),
        )
        for name, result in results.items()
    ]


def kidnap_figures(result: RunResult) -> tuple[bool | None, int | None]:
    """(re-localised, steps to recover) of a run with a kidnapping; (None, None) without one."""
    if result.scenario.kidnap_at is None:
        return None, None
    return relocalised(result), recovery_steps(result)


def run_task_safely(task: RunTask) -> list[RunRecord] | RunFailure:
    """`run_task`, with an exception turned into a RunFailure so that the other runs go on."""
    try:
        return run_task(task)
    except Exception as error:
        return RunFailure(task, f"{type(error).__name__}: {error}")


@dataclass
class StudyOutcome:
    """What a study produced: a record per finished run and filter, the failed runs, and whether
    the user interrupted it (then the records are the runs that finished before)."""

    records: list[RunRecord] = field(default_factory=list)
    failures: list[RunFailure] = field(default_factory=list)
    interrupted: bool = False
    tasks: int = 0

    def add(self, outcome: list[RunRecord] | RunFailure) -> None:
        if isinstance(outcome, RunFailure):
            self.failures.append(outcome)
        else:
            self.records.extend(outcome)

    def sort(self) -> None:
        """Records in (setting, run, filter order) order, whatever order the workers finished in."""
        order = {name: i for i, name in enumerate(dict.fromkeys(r.filter for r in self.records))}
        self.records.sort(key=lambda r: (r.setting, r.run, order[r.filter]))
        self.failures.sort(key=lambda f: (f.task.setting_index, f.task.run))


def default_workers() -> int:
    """All the cores this process may use."""
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1


def run_study(
    tasks: Sequence[RunTask], workers: int | None = None, *, visualize: Any = False, progress: bool = False
) -> StudyOutcome:
    """Run every task, on `workers` processes (default: all cores); Ctrl-C keeps the finished runs.

    With `visualize`, the first run is drawn (all its filters, as compare draws them) in this process.
    A run that raises becomes a RunFailure; the others go on.
    """
    workers = default_workers() if workers is None else workers
    if workers < 1:
        raise ValueError(f"--workers must be >= 1, got {workers}")
    outcome = StudyOutcome(tasks=len(tasks))
    with _progress_bar(len(tasks), progress) as advance:
        try:
            drawn, rest = (list(tasks[:1]), list(tasks[1:])) if visualize else ([], list(tasks))
            if workers == 1 or len(rest) <= 1:
                for task in drawn:
                    outcome.add(_draw_task(task, visualize))
                    advance()
                for task in rest:
                    outcome.add(run_task_safely(task))
                    advance()
            else:
                _run_in_pool(rest, drawn, workers, visualize, outcome, advance)
        except KeyboardInterrupt:
            outcome.interrupted = True
    outcome.sort()
    return outcome


def _draw_task(task: RunTask, visualize: Any) -> list[RunRecord] | RunFailure:
    try:
        return run_task(task, visualize)
    except Exception as error:
        return RunFailure(task, f"{type(error).__name__}: {error}")


def _run_in_pool(
    tasks: list[RunTask],
    drawn: list[RunTask],
    workers: int,
    visualize: Any,
    outcome: StudyOutcome,
    advance: Callable[[], None],
) -> None:
    """Tasks on a process pool (the drawn ones here meanwhile); on Ctrl-C, cancel what has not
    started, let the running tasks finish, and keep every finished result."""
    pool = ProcessPoolExecutor(max_workers=min(workers, len(tasks)), initializer=_ignore_sigint)
    pending: dict[Future, RunTask] = {}
    try:
        pending = {pool.submit(run_task_safely, task): task for task in tasks}
        for task in drawn:
            outcome.add(_draw_task(task, visualize))
            advance()
        while pending:
            done, _ = wait(pending, return_when=FIRST_COMPLETED)
            for future in done:
                outcome.add(_result_of(future, pending.pop(future)))
                advance()
    finally:  # also on Ctrl-C: the workers ignore it and finish their current run
        pool.shutdown(wait=True, cancel_futures=True)
        for future, task in pending.items():
            if future.done() and not future.cancelled():
                outcome.add(_result_of(future, task))
                advance()


def _result_of(future: Future, task: RunTask) -> list[RunRecord] | RunFailure:
    try:
        return future.result()
    except BrokenProcessPool:
        return RunFailure(task, "its worker process died (out of memory?)")


def _ignore_sigint() -> None:
    """Workers leave Ctrl-C to the main process, which stops the study and saves what finished."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)


@contextmanager
def _progress_bar(total: int, show: bool) -> Iterator[Callable[[], None]]:
    """A rich progress bar on stderr (typer brings rich); yields the function that advances it."""
    if not show:
        yield lambda: None
        return
    from rich.console import Console
    from rich.progress import (
        BarColumn,
        MofNCompleteColumn,
        Progress,
        TextColumn,
        TimeElapsedColumn,
        TimeRemainingColumn,
    )

    columns = (
        TextColumn("runs"),
        BarColumn(),
        MofNCompleteColumn(),
        TimeElapsedColumn(),
        TextColumn("left"),
        TimeRemainingColumn(),
    )
    with Progress(*columns, console=Console(stderr=True), transient=False) as bar:
        task = bar.add_task("runs", total=total)
        yield lambda: bar.advance(task)


# -- a study's statistics ---------------------------------------------------------------------------
@dataclass
class StudySummary:
    """One setting and filter over its runs."""

    setting_index: int
    setting: StudySetting
    filter: str
    runs: int
    mean_final_error: float
    interval: tuple[float, float]  # the 95% t-interval for the mean final error; NaN with one run
    converged_share: float  # share of the runs with a convergence step
    median_convergence_step: float | None  # median over the converged runs; None if none converged
    ms_per_step: float
    relocalised_share: float | None = None  # share of the runs re-localised; None without a kidnapping
    median_steps_to_recover: float | None = None  # median over the runs that recovered; None if none did
    mean_particle_count: float = math.nan


def student_t_two_sided(t: float, df: int) -> float:
    """P(|T| <= t) for Student's t with `df` degrees of freedom (Abramowitz & Stegun 26.7.3-4, exact)."""
    theta = math.atan(t / math.sqrt(df))
    c2, s = math.cos(theta) ** 2, math.sin(theta)
    if df % 2 == 0:  # sin th [1 + 1/2 cos^2 th + (1*3)/(2*4) cos^4 th + ... up to cos^(df-2) th]
        term = total = 1.0
        for j in range(0, df - 2, 2):
            term *= c2 * (j + 1) / (j + 2)
            total += term
        return s * total
    if df == 1:
        return 2 * theta / math.pi
    term = total = math.cos(theta)  # 2/pi [th + sin th (cos th + 2/3 cos^3 th + ... up to cos^(df-2) th)]
    for j in range(1, df - 2, 2):
        term *= c2 * (j + 1) / (j + 2)
        total += term
    return 2 / math.pi * (theta + s * total)


def student_t_quantile(level: float, df: int) -> float:
    """The t with P(|T| <= t) = level, e.g. level 0.95 gives the 97.5% quantile (bisection to 1e-12)."""
    if not 0 < level < 1 or df < 1:
        raise ValueError(f"need 0 < level < 1 and df >= 1, got {level} and {df}")
    low, high = 0.0, 1.0
    while student_t_two_sided(high, df) < level:
        low, high = high, 2 * high
    while high - low > 1e-12 * high:
        middle = (low + high) / 2
        low, high = (middle, high) if student_t_two_sided(middle, df) < level else (low, middle)
    return (low + high) / 2


def t_interval(values: Sequence[float], level: float = CONFIDENCE_LEVEL) -> tuple[float, float]:
    """Confidence interval for the mean: mean -/+ t_{(1+level)/2, n-1} s / sqrt(n), s the sample
    standard deviation; (NaN, NaN) for fewer than two values."""
    n = len(values)
    if n < 2:
        return math.nan, math.nan
    mean = statistics.fmean(values)
    half = student_t_quantile(level, n - 1) * statistics.stdev(values) / math.sqrt(n)
    return mean - half, mean + half


def summarise_study(records: Sequence[RunRecord], settings: Sequence[StudySetting]) -> list[StudySummary]:
    """Per setting and filter (in the records' order): the statistics of the study's table."""
    groups: dict[tuple[int, str], list[RunRecord]] = {}
    for record in records:
        groups.setdefault((record.setting, record.filter), []).append(record)
    summaries = []
    for (index, name), group in groups.items():
        finals = [r.final_error for r in group]
        converged = [r.converged_at for r in group if r.converged_at is not None]
        summaries.append(
            StudySummary(
                index,
                settings[index - 1],
                name,
                len(group),
                statistics.fmean(finals),
                t_interval(finals),
                len(converged) / len(group),
                statistics.median(converged) if converged else None,
                statistics.fmean(r.ms_per_step for r in group),
                *recovery_summary(group),
                statistics.fmean(r.mean_particle_count for r in group),
            )
        )
    return summaries


def recovery_summary(group: Sequence[RunRecord]) -> tuple[float | None, float | None]:
    """(share of the runs that re-localised, median steps to recover over the runs that recovered);
    None for both without a kidnapping, None for the median when no run recovered."""
    if any(r.relocalised is None for r in group):
        return None, None
    recovered = [r.steps_to_recover for r in group if r.steps_to_recover is not None]
    return sum(r.relocalised for r in group) / len(group), statistics.median(recovered) if recovered else None


def describe_setting(setting: StudySetting, steps: int, runs: int, kidnap_at: int | None = None) -> str:
    """The fixed parameters of a study in one line."""
    kidnapping = "" if kidnap_at is None else f", kidnapped at step {kidnap_at}, recovery {setting.recovery}"
    return (
        f"maze {setting.maze.label}, sigma {setting.sigma:g}, delta {setting.delta:g}, {setting.particles} particles, "
        f"RPF N_T = {setting.threshold:g} N_S, {steps} steps{kidnapping}, {runs} runs per setting"
    )


def study_table(summaries: Sequence[StudySummary], varied: Sequence[str], kld: bool = False) -> str:
    """A row per setting and filter: the varied parameters, then the statistics; with a kidnapping the
    re-localised share and median steps to recover, with `kld` the mean particle count."""
    kidnapped = any(s.relocalised_share is not None for s in summaries)
    headers = [
        *varied,
        "filter",
        "runs",
        "final error",
        f"{CONFIDENCE_LEVEL:.0%} CI of mean",
        "converged",
        "median conv. step",
        "ms/step",
        *(["re-localised", "median steps to recover"] if kidnapped else []),
        *(["mean N"] if kld else []),
    ]
    rows = []
    for s in summaries:
        low, high = s.interval
        row = [
            *(_format_value(s.setting.value(p)) for p in varied),
            s.filter,
            str(s.runs),
            f"{s.mean_final_error:.3f}",
            "-" if math.isnan(low) else f"[{low:.3f}, {high:.3f}]",
            f"{s.converged_share:.0%}",
            _optional(s.median_convergence_step, "{:g}"),
            f"{s.ms_per_step:.2f}",
        ]
        if kidnapped:
            row += [_optional(s.relocalised_share, "{:.0%}"), _optional(s.median_steps_to_recover, "{:g}")]
        if kld:
            row.append(f"{s.mean_particle_count:.0f}" if is_particle_filter(s.filter) else "-")
        rows.append(row)
    return format_table(headers, rows)


CSV_COLUMNS = [f.name for f in fields(RunRecord)]


def study_csv(records: Sequence[RunRecord]) -> str:
    """One row per run and filter, columns CSV_COLUMNS; an empty cell for None and NaN."""
    buffer = io.StringIO()
    writer = csv.DictWriter(buffer, fieldnames=CSV_COLUMNS, lineterminator="\n")
    writer.writeheader()
    for record in records:
        writer.writerow({k: _csv_cell(v) for k, v in asdict(record).items()})
    return buffer.getvalue()


def plot_study(summaries: Sequence[StudySummary], varied: Sequence[str], path: Path, title: str) -> None:
    """Mean final error with its t-interval against the varied parameter, a line per filter."""
    plt = pyplot()
    numeric = len(varied) == 1 and varied[0] in _PARAMETER_LABELS
    names = list(dict.fromkeys(s.filter for s in summaries))
    positions = {i: (s.setting.value(varied[0]) if numeric else n) for n, (i, s) in enumerate(_first_of(summaries))}
    spread = (max(positions.values()) - min(positions.values()) or 1) if numeric else 4
    figure, axes = plt.subplots(figsize=(8, 4.5), layout="constrained")
    for f, name in enumerate(names):
        mine = [s for s in summaries if s.filter == name]
        dodge = 0.012 * spread * (f - (len(names) - 1) / 2)  # side by side, so the error bars do not hide each other
        x = [positions[s.setting_index] + dodge for s in mine]
        mean = np.array([s.mean_final_error for s in mine])
        low, high = np.array([s.interval for s in mine]).T
        bars = np.nan_to_num([mean - low, high - mean])
        axes.errorbar(x, mean, yerr=bars, marker="o", capsize=4, label=name)
    if numeric:
        axes.set_xlabel(_PARAMETER_LABELS[varied[0]])
    else:
        labels = {s.setting_index: ", ".join(_setting_label(s.setting, p) for p in varied) for s in summaries}
        axes.set_xticks(
            list(positions.values()), [labels[i] or f"setting {i}" for i in positions], rotation=20, ha="right"
        )
        axes.set_xlabel("setting")
    axes.set(title=title, ylabel=f"final error (mean of the last {FINAL_SHARE:.0%} of steps)")
    axes.set_ylim(bottom=0)
    axes.grid(alpha=0.3)
    axes.legend()
    save_figure(figure, path)


def _setting_label(setting: StudySetting, parameter: str) -> str:
    value = _format_value(setting.value(parameter))
    return value if parameter == "maze" else f"{parameter} {value}"


def _first_of(summaries: Sequence[StudySummary]) -> list[tuple[int, StudySummary]]:
    """(setting index, its first summary) per setting, in order."""
    first: dict[int, StudySummary] = {}
    for s in summaries:
        first.setdefault(s.setting_index, s)
    return list(first.items())


_PARAMETER_LABELS = {
    "sigma": "sigma, measurement noise std (map units)",
    "delta": "Delta, compass error width (radians)",
    "particles": "particle count N_S",
    "threshold": "RPF threshold N_T / N_S",
}


# -- output helpers --------------------------------------------------------------------------------
def pyplot() -> Any:
    """matplotlib.pyplot on the Agg backend (no display needed), or a one-line install hint."""
    try:
        import matplotlib
    except ImportError:
        raise ValueError(PLOT_INSTALL_HINT) from None
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def save_figure(figure: Any, path: Path) -> None:
    """Save a matplotlib figure atomically in the format of the path's suffix, then close it."""
    buffer = io.BytesIO()
    try:
        figure.savefig(buffer, format=path.suffix.lstrip(".").lower() or "png", dpi=150)
    finally:
        pyplot().close(figure)
    write_bytes_atomically(path, buffer.getvalue())


def format_table(headers: Sequence[str], rows: Sequence[Sequence[str]]) -> str:
    """A plain-text table: the first column left-aligned, the others right-aligned."""
    widths = [max(len(str(cell)) for cell in column) for column in zip(headers, *rows, strict=True)]

    def line(cells: Sequence[str]) -> str:
        return "  ".join(
            str(c).ljust(w) if i == 0 else str(c).rjust(w) for i, (c, w) in enumerate(zip(cells, widths, strict=True))
        ).rstrip()

    return "\n".join([line(headers), line(["-" * w for w in widths]), *map(line, rows)])


def _number(value: float, spec: str) -> str:
    return "-" if math.isnan(value) else spec.format(value)


def _optional(value: float | None, spec: str) -> str:
    return "-" if value is None else spec.format(value)


def _format_value(value: Any) -> str:
    return f"{value:g}" if isinstance(value, float) else str(value)


def _csv_cell(value: Any) -> Any:
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return ""
    return repr(value) if isinstance(value, float) else value
