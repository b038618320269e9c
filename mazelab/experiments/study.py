"""A Monte Carlo study (lab step 14): settings (the product of the varied parameters) x R seeded runs;
in each run every filter sees the same scenario. A RunTask is one run; run_task gives a RunRecord per
filter (a row of the study's CSV)."""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import itertools
import math
import warnings
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from mazelab.experiments.kidnapping import RECOVERY_VARIANTS, recovery_steps, relocalised
from mazelab.experiments.runs import filter_labels, final_error, mean_ess, mean_particle_count, run_filters
from mazelab.maze import STATION_WALL, Maze
from mazelab.maze_generator import DEFAULT_WALL_SHARE, generate_maze
from mazelab.model import check_model_parameters
from mazelab.modes import check_estimate
from mazelab.registry import resolve_filter
from mazelab.regularisation import check_bandwidth
from mazelab.robot import Robot
from mazelab.seeding import start_place, study_seeds
from mazelab.simulation import RunResult, convergence_step
from mazelab.viz.views import open_comparison


# -- a study: settings, runs and seeds -------------------------------------------------------------
@dataclass(frozen=True)
class MazeChoice:
    """A study's maze: a file's grid (its path and the sha256 of its bytes identify it), or a size,
    station-block count and wall share generated anew in every run (from the run's maze seed)."""

    label: str
    grid: tuple[tuple[int, ...], ...] | None = None
    size: tuple[int, int] | None = None  # (rows, columns) of a generated maze
    stations: int | None = None  # station blocks of a generated maze
    path: str | None = None  # the maze file, as given
    sha256: str | None = None  # of the maze file's bytes
    wall_share: float | None = None  # the share of cells a generated maze makes walls

    @classmethod
    def from_maze(cls, label: str, world: Maze, path: str | Path | None = None) -> MazeChoice:
        """A maze file's grid; with `path`, the file's path and content hash are kept too."""
        digest = hashlib.sha256(Path(path).read_bytes()).hexdigest() if path is not None else None
        return cls(
            label, grid=tuple(map(tuple, world.as_lists())), path=None if path is None else str(path), sha256=digest
        )

    @classmethod
    def generated(cls, rows: int, columns: int, stations: int, wall_share: float = DEFAULT_WALL_SHARE) -> MazeChoice:
        walls = "" if wall_share == DEFAULT_WALL_SHARE else f", wall share {wall_share:g}"
        label = f"random {rows}x{columns}, {stations} station blocks{walls}"
        return cls(label, size=(rows, columns), stations=stations, wall_share=wall_share)

    def world(self, maze_seed: int | None) -> Maze:
        """The maze of one run: the file's grid, or the generated maze of `maze_seed`."""
        if self.grid is not None:
            return _maze_of(self.grid, self.label)
        assert self.size is not None and self.stations is not None
        share = DEFAULT_WALL_SHARE if self.wall_share is None else self.wall_share
        return generate_maze(*self.size, self.stations, np.random.default_rng(maze_seed), share)


def file_mazes(paths: Sequence[str | Path], load: Any) -> list[MazeChoice]:
    """The MazeChoices of maze files: labelled by file name without .txt, or, where two files share a
    name, by as many of their last folders as tell them apart (a/m, b/m); `load(path)` reads a Maze.
    The same file twice counts once."""
    paths = list(dict.fromkeys(str(p) for p in paths))
    parts = [Path(p).with_suffix("").parts for p in paths]
    labels = [p[-1] for p in parts]
    for depth in range(2, max(map(len, parts), default=1) + 1):
        clashing = {label for label in labels if labels.count(label) > 1}
        if not clashing:
            break
        labels = ["/".join(p[-depth:]) if label in clashing else label for p, label in zip(parts, labels, strict=True)]
    return [MazeChoice.from_maze(label, load(p), p) for label, p in zip(labels, paths, strict=True)]


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
    bandwidth: str | float = "optimal"  # the RPF's kernel bandwidth (mazelab.regularisation)
    estimate: str = "mean"  # every filter's point estimate: "mean" or "mode" (mazelab.modes)

    def value(self, parameter: str) -> Any:
        return self.maze.label if parameter == "maze" else getattr(self, parameter)


STUDY_PARAMETERS = ("maze", "sigma", "delta", "particles", "threshold", "recovery", "bandwidth", "estimate")
# the study parameters that are filter options (mazelab.contract): a filter that does not declare one
# runs once for all its values
OPTION_PARAMETERS = {"threshold": "threshold", "recovery": "recovery", "bandwidth": "bandwidth", "estimate": "estimate"}
# filters that take no particle count (the constructor's particles are ignored): once for all counts.
# The contract has no declaration for this yet; these are the shipped ones that ignore it.
PARTICLE_FREE_FILTERS = ("GridBayesFilter", "ExtendedKalmanFilter")


def takes_parameter(filter_name: str | type, parameter: str) -> bool:
    """Whether a study parameter can change a filter's results: the model's (maze, sigma, delta) always,
    the particle count unless the filter ignores it, an option only if the filter declares it."""
    try:
        filter_class = resolve_filter(filter_name)
    except ValueError:  # a filter known only by its name in a record (a student's own): assume it does
        return True
    if parameter in OPTION_PARAMETERS:
        return OPTION_PARAMETERS[parameter] in filter_class.options
    if parameter == "particles":
        return filter_class.name not in PARTICLE_FREE_FILTERS
    return True


def study_settings(
    mazes: Sequence[MazeChoice],
    sigmas: Sequence[float],
    deltas: Sequence[float],
    particle_counts: Sequence[int],
    thresholds: Sequence[float],
    recoveries: Sequence[str] = ("none",),
    bandwidths: Sequence[str | float] = ("optimal",),
    estimates: Sequence[str] = ("mean",),
) -> list[StudySetting]:
    """Every combination of the given values (the first parameter varies slowest), each checked."""
    estimates = list(dict.fromkeys(check_estimate(e) for e in estimates))
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
    bandwidths = list(dict.fromkeys(check_bandwidth(b) for b in bandwidths))
    combinations = itertools.product(
        mazes, sigmas, deltas, particle_counts, thresholds, recoveries, bandwidths, estimates
    )
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
    seed: int  # seeds the start (default_rng(seed)) and simulate(seed=seed), as `run --seed S`
    maze_seed: int | None  # seeds a generated maze (as `maze generate --seed`); None for a maze file
    filters: tuple[str, ...]
    steps: int
    kidnap_at: int | None = None  # kidnap the robot at this step (its place drawn from `seed`)
    kld: bool = False  # KLD-sampling in the particle filters
    estimate: str = "mean"  # every filter's point estimate: "mean" or "mode" (mazelab.modes)
    traces: bool = False  # keep each filter's per-step trace on its record (`RunRecord.trace`)


def filters_per_setting(settings: Sequence[StudySetting], filters: Sequence[str]) -> list[tuple[str, ...]]:
    """The filters each setting runs: a filter runs in the first setting of each combination of the
    parameters it takes (`takes_parameter`), so SIR is not run again for each RPF bandwidth. Run r
    has the same seeds in every setting, so the skipped runs would repeat the kept ones bit for bit."""
    seen: set[tuple[Any, ...]] = set()
    chosen = []
    for setting in settings:
        mine = []
        for name in filters:
            key = (name, *(setting.value(p) if takes_parameter(name, p) else None for p in STUDY_PARAMETERS))
            if key not in seen:
                seen.add(key)
                mine.append(name)
        chosen.append(tuple(mine))
    return chosen


def study_tasks(
    settings: Sequence[StudySetting],
    filters: Sequence[str],
    runs: int,
    steps: int,
    root_seed: int,
    *,
    kidnap_at: int | None = None,
    kld: bool = False,
    estimate: str | None = None,
    traces: bool = False,
) -> list[RunTask]:
    """One task per setting and run, in order, each with the filters that setting runs
    (`filters_per_setting`; a setting that runs none has no tasks). `estimate`, if given, replaces the
    settings' own; `traces` keeps each run's per-step trace (mazelab.experiments.traces)."""
    if estimate is not None:
        settings = [dataclasses.replace(s, estimate=check_estimate(estimate)) for s in settings]
    if runs < 1 or steps < 1:
        raise ValueError(f"runs and steps must be >= 1, got {runs} runs and {steps} steps")
    if kidnap_at is not None and not 1 <= kidnap_at <= steps:
        raise ValueError(f"kidnap_at must be a step from 1 to {steps}, got {kidnap_at}")
    seeds = study_seeds(root_seed, runs)
    return [
        RunTask(
            i,
            setting,
            r,
            seed,
            maze_seed if setting.maze.grid is None else None,
            mine,
            steps,
            kidnap_at,
            kld,
            setting.estimate,
            traces,
        )
        for i, (setting, mine) in enumerate(zip(settings, filters_per_setting(settings, filters), strict=True), start=1)
        if mine
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
    station_blocks: int  # station blocks (cells of type 2) of the run's maze; each has 4 corner stations
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
    bandwidth: str | float = "optimal"  # the RPF's kernel bandwidth (the other filters ignore it)
    estimate: str = "mean"  # the point estimate the errors are measured from
    maze_sha256: str | None = None  # sha256 of the maze file's bytes; None for a generated maze
    maze_rows: int = 0  # the run's maze size
    maze_columns: int = 0
    wall_share: float | None = None  # a generated maze's requested share of walls; None for a file
    run_seconds: float = math.nan  # wall time of the run: its share of the unit of runs it ran in
    # Not a column: with RunTask.traces, the filter's per-step arrays (mazelab.experiments.traces)
    trace: ClassVar[dict[str, Any] | None] = None


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
    robot = Robot(s.sigma, s.delta, start_place(world, task.seed))
    comparison = open_comparison(visualize, world, filter_labels(task.filters)) if visualize else None
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
                bandwidth=s.bandwidth,
                estimate=task.estimate,
            )
    finally:
        if comparison is not None:
            comparison.close()
    return run_records(task, world, results)


def run_records(task: RunTask, world: Maze, results: dict[str, RunResult]) -> list[RunRecord]:
    """The study's rows of one run: a record per filter's result (with its per-step trace if the task
    asks for it)."""
    s = task.setting
    stations = int((world.grid == STATION_WALL).sum())
    records = [
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
            s.bandwidth,
            task.estimate,
            s.maze.sha256,
            int(world.grid.shape[0]),
            int(world.grid.shape[1]),
            s.maze.wall_share,
        )
        for name, result in results.items()
    ]
    if task.traces:
        for record, result in zip(records, results.values(), strict=True):
            record.trace = trace_of(result)
    return records


def trace_of(result: RunResult) -> dict[str, np.ndarray]:
    """A run's per-step arrays: true position, estimate, ESS, confidence, step time, particle count."""
    return {
        "true": result.true_positions,
        "estimate": result.estimates,
        "ess": result.ess,
        "confident": result.confident,
        "step_seconds": result.step_seconds,
        "particle_count": result.extras.get("particle_count", np.full(len(result.ess), -1)),
    }


def kidnap_figures(result: RunResult) -> tuple[bool | None, int | None]:
    """(re-localised, steps to recover) of a run with a kidnapping; (None, None) without one."""
    if result.kidnap_at is None:
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
    stopped_by: int | None = None  # the signal that stopped it (2: Ctrl-C), None if it ran to the end
    tasks: int = 0
    lost: str | None = None  # why the study stopped early without a signal (a lost cluster or pool), one line

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


__all__ = [
    "OPTION_PARAMETERS",
    "PARTICLE_FREE_FILTERS",
    "STUDY_PARAMETERS",
    "MazeChoice",
    "RunFailure",
    "RunRecord",
    "RunTask",
    "StudyOutcome",
    "StudySetting",
    "file_mazes",
    "filters_per_setting",
    "kidnap_figures",
    "run_records",
    "run_task",
    "run_task_safely",
    "study_settings",
    "study_tasks",
    "takes_parameter",
    "trace_of",
    "varied_parameters",
]
