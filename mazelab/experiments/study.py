"""A Monte Carlo study (lab step 14): settings (the product of the varied parameters) x R seeded runs;
in each run every filter sees the same scenario. A RunTask is one run; run_task gives a RunRecord per
filter (a row of the study's CSV), and a setting's runs go together in units of work (`study_units`,
`run_batch`)."""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import itertools
import math
import traceback
import warnings
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from itertools import groupby
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from mazelab.backend import backend_of
from mazelab.checks import particle_count
from mazelab.contract import check_filter
from mazelab.declaration import Option, options_of, scoped, show_value
from mazelab.experiments.runs import (
    FIGURES,
    WARM_UP_SEED,
    WARM_UP_STEPS,
    run_figures,
    run_filters,
    warm_once,
)
from mazelab.experiments.tables import trace_of
from mazelab.maze import STATION_WALL, Maze, find_maze, load_maze
from mazelab.maze_generator import DEFAULT_WALL_SHARE, generate_maze
from mazelab.model import check_model_parameters
from mazelab.registry import PluginReference, entries, file_sha256, filter_entry, filters_here, resolve_filter
from mazelab.robot import Robot
from mazelab.seeding import run_streams, study_seeds
from mazelab.simulation import RunInputs, RunResult, checked_walk, maze_for, record_steps


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
        digest = file_sha256(path) if path is not None else None
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


def file_mazes(names: Sequence[str | Path]) -> list[MazeChoice]:
    """The MazeChoices of maze files (paths or shipped names, mazelab.maze.find_maze): labelled by file name
    without .txt, or, where two files share a name, by as many of their last folders as tell them apart
    (a/m, b/m). The same file twice counts once."""
    paths = list(dict.fromkeys(str(find_maze(name)) for name in names))
    parts = [Path(p).with_suffix("").parts for p in paths]
    labels = [p[-1] for p in parts]
    for depth in range(2, max(map(len, parts), default=1) + 1):
        clashing = {label for label in labels if labels.count(label) > 1}
        if not clashing:
            break
        labels = ["/".join(p[-depth:]) if label in clashing else label for p, label in zip(parts, labels, strict=True)]
    return [MazeChoice.from_maze(label, load_maze(p), p) for label, p in zip(labels, paths, strict=True)]


@functools.lru_cache(maxsize=8)
def _maze_of(grid: tuple[tuple[int, ...], ...], label: str) -> Maze:
    """The Maze of a file's grid, built once per process: its nearest-station table then serves every
    run of the study that uses it (a Maze does not change once built)."""
    return Maze(grid, source=label)


@dataclass(frozen=True)
class StudySetting:
    """One combination of the studied parameters: the model's (maze, sigma, delta, particle count) and
    the filter options the study sets (`options`, by name, each checked by its declaration); a filter
    runs with those it declares and its declared defaults for the rest (`option_cells`)."""

    maze: MazeChoice
    sigma: float
    delta: float
    particles: int
    options: tuple[tuple[str, Any], ...] = ()  # the filter options the study sets, (name, value)

    def value(self, parameter: str) -> Any:
        """The value of a studied parameter: the maze's label, a model parameter, or an option the
        study sets (None for an option it leaves to the filters' defaults)."""
        if parameter == "maze":
            return self.maze.label
        if parameter in MODEL_PARAMETERS:
            return getattr(self, parameter)
        return dict(self.options).get(parameter)

    def filter_options(self, filter_name: str | type) -> dict[str, Any]:
        """The options of this setting that the filter takes: those it declares, set for every filter or
        for it alone (FILTER.NAME; its declaration checks them)."""
        entry = filter_entry(filter_name)
        return {name: value for key, value in self.options if (name := reaches(key, entry)) is not None}


MODEL_PARAMETERS = ("sigma", "delta", "particles")
BASE_PARAMETERS = ("maze", *MODEL_PARAMETERS)


def study_parameters(settings: Sequence[StudySetting]) -> tuple[str, ...]:
    """The parameters a study's settings give: the maze, the model's, then each option the study sets."""
    options = dict.fromkeys(name for s in settings for name, _ in s.options)
    return (*BASE_PARAMETERS, *options)


def option_columns(filters: Sequence[str | type]) -> tuple[str, ...]:
    """A study's option columns: the union of the options its filters declare (the derived ones left
    out), in the filters' order, each filter's in its declaration order. A study of SIR alone has no
    column for an option only the RPF declares."""
    names: dict[str, None] = {}
    for name in filters:
        names.update(dict.fromkeys(o.name for o in options_of(resolve_filter(name)).settable()))
    return tuple(names)


def takes_parameter(filter_name: str | type, parameter: str) -> bool:
    """Whether a study parameter can change a filter's results: the model's (maze, sigma, delta) always,
    the particle count unless the filter's entry says it takes none, an option only if it reaches it."""
    try:
        entry = filter_entry(filter_name)
    except ValueError:  # a filter known only by its name in a record (a student's own): assume it does
        return True
    if parameter == "particles":
        return entry.takes_particles
    if parameter in ("maze", "sigma", "delta"):
        return True
    return reaches(parameter, entry) is not None


def reaches(key: str, entry: Any) -> str | None:
    """The option a study's `key` sets for a filter's entry (its name), or None: `threshold` reaches every
    filter that declares it, `rpf.threshold` the RPF alone (mazelab.declaration.scoped)."""
    scope, name = scoped(key)
    if name not in entry.options or (scope is not None and filter_entry(scope).name != entry.name):
        return None
    return name


def study_settings(
    mazes: Sequence[MazeChoice],
    sigmas: Sequence[float],
    deltas: Sequence[float],
    particle_counts: Sequence[int],
    options: Mapping[str, Sequence[Any]] | None = None,
) -> list[StudySetting]:
    """Every combination of the given values (the first parameter varies slowest); `options` holds the
    filter options the study sets, each a list of values, each checked by the option's declaration
    (mazelab.declaration) as the filters' constructors check it."""
    for count in particle_counts:
        particle_count(count, "particles")  # a whole number >= 1 whose arrays fit in memory
    for sigma, delta in itertools.product(dict.fromkeys(sigmas), dict.fromkeys(deltas)):
        check_model_parameters(sigma, delta)  # refuses impossible values, warns once outside the lab's ranges
    checked = {name: _checked(name, values) for name, values in (options or {}).items()}
    combinations = itertools.product(mazes, sigmas, deltas, particle_counts, *checked.values())
    return [StudySetting(*values[:4], options=tuple(zip(checked, values[4:], strict=True))) for values in combinations]


def _checked(key: str, values: Sequence[Any]) -> list[Any]:
    """The values of a studied option, each checked by the option's declaration (the first filter of
    the lab's that declares it, or its own filter's for FILTER.NAME; a plug-in's own options are checked
    by its declaration in plan_study)."""
    option = declared_option(key)
    checked = [value if option is None else option.validate(value) for value in values]
    return list(dict.fromkeys(checked))


def declared_option(key: str, filters: Sequence[str | type] | None = None) -> Option | None:
    """The declaration of an option a study or a command sets: its filter's for FILTER.NAME, else the first
    of `filters` (default: the lab's) that declares it (None: none of them does)."""
    scope, name = scoped(key)
    chosen = [filter_entry(scope)] if scope else entries() if filters is None else map(filter_entry, filters)
    return next((entry.options[name] for entry in chosen if name in entry.options), None)


def varied_parameters(settings: Sequence[StudySetting]) -> list[str]:
    """The parameters that take more than one value across the settings."""
    return [p for p in study_parameters(settings) if len({hashable(s.value(p)) for s in settings}) > 1]


def hashable(value: Any) -> Any:
    """A value as a set member: a list or a dict (an object option's fields) as its repr."""
    return value if not isinstance(value, (list, dict)) else repr(value)


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
    traces: bool = False  # keep each filter's per-step trace on its record (`RunRecord.trace`)
    reference: str | None = None  # "grid": the exact grid filter runs too, each record gets distance_to_exact
    plugins: tuple[PluginReference, ...] = ()  # the code of the plug-ins among `filters`, sent with the run

    def here(self) -> RunTask:
        """This run with each plug-in's spec the one that imports its shipped code in this process
        (mazelab.registry.PluginReference): a worker runs the code the study was planned with."""
        if not self.plugins:
            return self
        return dataclasses.replace(self, filters=filters_here(self.filters, self.plugins))

    def cells(self) -> dict[str, Any]:
        """The cells of this run's rows that its seeds and setting fix, seed and maze first (what a journal's
        kept row is checked by, mazelab.experiments.journal.foreign_row); a generated maze's sha256 is left
        out (its run's own maze's, which maze_seed fixes)."""
        s = self.setting
        cells = {
            "seed": self.seed,
            "maze_sha256": s.maze.sha256,
            "maze_seed": self.maze_seed,
            "maze": s.maze.label,
            "wall_share": s.maze.wall_share,
            "sigma": s.sigma,
            "delta": s.delta,
            "particles": s.particles,
            "steps": self.steps,
            "kidnap_at": self.kidnap_at,
        }
        if s.maze.grid is None:
            del cells["maze_sha256"]
        return cells

    def row_filters(self) -> dict[str, str]:
        """The `filter` cells of this run's rows (each filter's name: a plug-in's is its class's), to
        the filters as this task names them (a plug-in by its spec, `file.py:Class`)."""
        return {resolve_filter(name).name: name for name in self.filters}


def filters_per_setting(settings: Sequence[StudySetting], filters: Sequence[str]) -> list[tuple[str, ...]]:
    """The filters each setting runs: a filter runs in the first setting of each combination of the
    parameters it takes (`takes_parameter`), so SIR is not run again for each RPF bandwidth. Run r
    has the same seeds in every setting, so the skipped runs would repeat the kept ones bit for bit."""
    parameters = study_parameters(settings)
    seen: set[tuple[Any, ...]] = set()
    chosen = []
    for setting in settings:
        mine = []
        for name in filters:
            key = (name, *(hashable(setting.value(p)) if takes_parameter(name, p) else None for p in parameters))
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
    traces: bool = False,
    reference: str | None = None,
    plugins: tuple[PluginReference, ...] = (),
) -> list[RunTask]:
    """One task per setting and run, in order, each with the filters that setting runs
    (`filters_per_setting`; a setting that runs none has no tasks). `traces` keeps each run's per-step
    trace (mazelab.experiments.tables); `reference` ("grid") measures each filter against the exact
    posterior (`with_reference`); `plugins` the code of the plug-ins among the filters
    (mazelab.registry.PluginReference), sent with every run."""
    if runs < 1 or steps < 1:
        raise ValueError(f"runs and steps must be >= 1, got {runs} runs and {steps} steps")
    if kidnap_at is not None and not 1 <= kidnap_at <= steps:
        raise ValueError(f"kidnap_at must be a step from 1 to {steps}, got {kidnap_at}")
    seeds = study_seeds(root_seed, runs)
    chosen = zip(settings, filters_per_setting(settings, filters), strict=True)
    return [
        RunTask(
            i,
            setting,
            r,
            seed,
            None if setting.maze.grid else maze_seed,
            mine,
            steps,
            kidnap_at,
            traces,
            reference,
            tuple(code for code in plugins if code.spec in mine),
        )
        for i, (setting, mine) in enumerate(chosen, start=1)
        if mine
        for r, (seed, maze_seed) in enumerate(seeds, start=1)
    ]


@dataclass
class RunCells:
    """The cells that say which run a study's row is of: its setting, run and seeds, its scenario and its filter;
    RunRecord adds the run's figures (mazelab.experiments.runs.FIGURES) and options."""

    setting: int
    run: int
    seed: int
    maze: str
    maze_seed: int | None
    station_blocks: int  # station blocks (cells of type 2) of the run's maze; each has 4 corner stations
    sigma: float
    delta: float
    particles: int
    steps: int
    filter: str
    # Not a column: with RunTask.traces, the filter's per-step arrays (mazelab.experiments.tables)
    trace: ClassVar[dict[str, Any] | None] = None

    def to_json(self) -> dict[str, Any]:
        """The row as a journal keeps it (mazelab.experiments.journal): its fields, its trace's arrays
        as lists (numbers in full: the CSV and traces written from it are the same bit for bit)."""
        data = {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}
        if self.trace is not None:
            data["trace"] = {
                k: {n: np.asarray(a).tolist() for n, a in v.items()} if k == "diagnostics" else np.asarray(v).tolist()
                for k, v in self.trace.items()
            }
        return data

    @classmethod
    def from_json(cls, data: dict[str, Any]) -> RunRecord:
        """A row from its journal form (`to_json`); a TypeError for one that is not."""
        data = dict(data)
        trace = data.pop("trace", None)
        record = cls(**data)
        if trace is not None:
            record.trace = {
                k: {n: np.asarray(a) for n, a in v.items()} if k == "diagnostics" else np.asarray(v)
                for k, v in trace.items()
            }
        return record


# One filter in one run of a study, a row of its CSV: RunCells, then a field per figure (FIGURES, in order), then
# every option the filter ran with as cells (`option_cells`), by name: a column each, after the figures; an
# option the filter does not declare has no key (an empty cell).
RunRecord = dataclasses.make_dataclass(
    "RunRecord",
    [*((f.name, Any, field(default=f.default)) for f in FIGURES), ("options", dict, field(default_factory=dict))],
    bases=(RunCells,),
    namespace={"__module__": __name__, "__doc__": "One filter in one run of a study: a row of the study's CSV."},
)


def study_order(records: Sequence[RunRecord], tasks: Sequence[RunTask]) -> list[RunRecord]:
    """The records in (setting, run, filter) order, the filters in the study's order (its tasks'): the
    order of the CSV, `mazelab.study`'s rows, the summary and the table, however the runs finished."""
    order = {name: i for i, name in enumerate(dict.fromkeys(n for task in tasks for n in task.row_filters()))}
    return sorted(records, key=lambda r: (r.setting, r.run, order.get(r.filter, len(order))))


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
    with warnings.catch_warnings():  # the range warnings were shown once, by study_settings
        warnings.simplefilter("ignore", UserWarning)
        robot = Robot.of_seed(world, s.sigma, s.delta, task.seed)
        options = {name: task.setting.filter_options(name) for name in task.filters}
        results = run_filters(
            world,
            robot,
            s.sigma,
            s.delta,
            task.filters,
            seed=task.seed,
            visualize=visualize,
            particle_count=s.particles,
            steps=task.steps,
            kidnap_at=task.kidnap_at,
            options=options,
        )
    records = run_records(task, world, results)
    return with_reference(task, world, robot, results, records) if task.reference else records


# -- the distance to the exact posterior (`study --reference grid`) ------------------------------------
REFERENCE = "grid"  # what --reference takes: the exact grid filter (mazelab.grid_filter), default options


def with_reference(
    task: RunTask, world: Maze, robot: Robot, results: dict[str, RunResult], records: list[RunRecord]
) -> list[RunRecord]:
    """Each record's distance_to_exact: the mean distance between its filter's estimates and the exact
    posterior means over the second half of the steps (mazelab.experiments.accuracy.distance_to_exact).
    The exact means are the grid filter's with its default options, on the robot's recorded walk;
    they are the same in every setting that shares this run's scenario, so a process computes them
    once per scenario (`exact_means`) and a grid row of the study with default options is reused."""
    grid = resolve_filter(REFERENCE).name
    s = task.setting
    key = (s.maze, task.maze_seed, s.sigma, s.delta, task.seed, task.steps, task.kidnap_at)
    declared = filter_entry(REFERENCE).options
    defaults = all(value == declared[name].default for name, value in task.setting.filter_options(grid).items())
    if grid in results and defaults:  # the study's own grid row, with the default options, is the reference
        _EXACT_MEANS[key] = results[grid].estimates
    exact = exact_means(key, world, robot)
    for record in records:
        record.distance_to_exact = distance_to_exact(results[record.filter].estimates, exact)
        if record.trace is not None:
            record.trace = {**record.trace, "exact": exact}  # the traces' exact_x, exact_y
    return records


def distance_to_exact(estimates: np.ndarray, exact: np.ndarray) -> float:
    """The mean distance between a filter's estimates and the exact posterior means (steps, 2) over the
    second half of the steps (after the first localisation), map units."""
    window = slice(len(exact) // 2, len(exact))
    return float(np.hypot(*(estimates - exact)[window].T).mean())


_EXACT_MEANS: dict[tuple[Any, ...], np.ndarray] = {}  # the exact posterior means of the scenarios seen here
_EXACT_KEPT = 256  # at most this many (steps x 2 floats each): a worker's memory stays small


def exact_means(key: tuple[Any, ...], world: Maze, robot: Robot) -> np.ndarray:
    """The exact grid filter's posterior means (steps, 2) on the robot's recorded walk (its scenario is
    `key`), computed once per scenario in this process."""
    if key not in _EXACT_MEANS:
        _, _, sigma, delta, seed, steps, kidnap_at = key
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", UserWarning)
            exact = run_filters(world, robot, sigma, delta, [REFERENCE], seed=seed, steps=steps, kidnap_at=kidnap_at)
        if len(_EXACT_MEANS) >= _EXACT_KEPT:
            _EXACT_MEANS.pop(next(iter(_EXACT_MEANS)))
        _EXACT_MEANS[key] = next(iter(exact.values())).estimates
    return _EXACT_MEANS[key]


def run_records(task: RunTask, world: Maze, results: dict[str, RunResult]) -> list[RunRecord]:
    """The study's rows of one run: a record per filter's result (its figures, `run_figures`), with its
    per-step trace if the task asks for it."""
    s = task.setting
    shared = {  # the run's cells, the same for every filter
        **task.cells(),
        "maze_sha256": s.maze.sha256 or hashlib.sha256(world.to_text().encode()).hexdigest(),  # generated: of to_text()
        "station_blocks": int((world.grid == STATION_WALL).sum()),
        "maze_rows": int(world.grid.shape[0]),
        "maze_columns": int(world.grid.shape[1]),
    }
    records = []
    for name, result in results.items():
        cells = {"filter": name, **shared, **run_figures(name, result), "options": option_cells(s, name)}
        record = RunRecord(task.setting_index, task.run, **cells)
        if task.traces:
            record.trace = trace_of(result)
        records.append(record)
    return records


def option_cells(setting: StudySetting, filter_name: str | type) -> dict[str, Any]:
    """Every option a filter runs with in a setting, by name in declaration order, as a row's cells
    (`option_cell`): the setting's value where it sets one, the declared default otherwise (the derived
    ones left out)."""
    given = setting.filter_options(filter_name)
    return {o.name: option_cell(given.get(o.name, o.default)) for o in filter_entry(filter_name).options.settable()}


def option_cell(value: Any) -> Any:
    """An option's value as a row's cell: a number, word or flag as it is, anything else (None, an
    object's fields) in the declaration's words ("none", "Recovery(...)")."""
    plain = isinstance(value, (bool, int, float, str))
    return value if plain else show_value(value)


def run_task_safely(task: RunTask, visualize: Any = False) -> list[RunRecord] | RunFailure:
    """`run_task`, with an exception turned into a RunFailure so that the other runs go on."""
    try:
        return run_task(task, visualize)
    except Exception as error:
        return RunFailure(task, f"{type(error).__name__}: {error}")


# -- a study's runs in units of work: the runs of one setting advanced together by one filter object of R runs
# (mazelab.smc: the same steps as a single run, bit for bit), or one run at a time where the declared rule says
# they cannot be (`batchable`) ------------------------------------------------------------------------------
MAX_BATCH = 32  # runs advanced together: beyond this the fixed cost per step is already small
MAX_BATCH_PARTICLES = 1_000_000  # R x N at most: a batch needs no more memory than a run of 10^6 particles


def batchable(task: RunTask) -> bool:
    """The declared rule: a setting's runs advance together when they share one maze (a maze file, not
    a maze generated per run) and every filter's registry entry declares it `batched` (the lab's
    particle filters; a new class only when it says so) with options that let runs go together
    (`runs_together`: not recovery or KLD-sampling), and no `--reference`; otherwise one run at a time."""
    if task.setting.maze.grid is None or task.reference is not None:  # a reference runs the grid per run
        return False
    for name in task.filters:
        entry = filter_entry(name)
        runs_together = getattr(entry.filter_class, "runs_together", None)
        if not entry.batched or (runs_together is not None and not runs_together(task.setting.filter_options(name))):
            return False
    return True


def study_units(tasks: Sequence[RunTask], workers: int) -> list[tuple[RunTask, ...]]:
    """The tasks cut into units of work: the runs of a setting together (at most MAX_BATCH runs and
    MAX_BATCH_PARTICLES particles, and small enough that every worker gets two units), or one run
    each where the batch does not apply."""
    units: list[tuple[RunTask, ...]] = []
    batches = [list(group) for _, group in groupby(tasks, key=lambda t: t.setting_index)]
    size = max(1, min(MAX_BATCH, math.ceil(len(tasks) / (2 * workers))))
    for batch in batches:
        fits = max(1, MAX_BATCH_PARTICLES // batch[0].setting.particles)
        if len(batch) > 1 and batchable(batch[0]) and min(size, fits) > 1:
            parts = math.ceil(len(batch) / min(size, fits))
            step = math.ceil(len(batch) / parts)
            units += [tuple(batch[i : i + step]) for i in range(0, len(batch), step)]
        else:
            units += [(task,) for task in batch]
    return units


def run_unit_safely(unit: Sequence[RunTask]) -> list[list[RunRecord] | RunFailure]:
    """Every run of a unit, in order: together when `batchable` says so, else one by one; a run that
    raises becomes a RunFailure, and so does every run of a batched unit that raises (a bug in the
    batched path is reported, never hidden by a quiet second try)."""
    if len(unit) > 1 and all(batchable(task) for task in unit):
        try:
            return list(run_batch(unit))
        except Exception as error:
            where = traceback.extract_tb(error.__traceback__)[-1]
            message = f"{type(error).__name__}: {error} (runs advanced together; at {where.name}, line {where.lineno})"
            return [RunFailure(task, message) for task in unit]
    return [run_task_safely(task) for task in unit]


def walk_of(task: RunTask, world: Maze) -> tuple[RunInputs, np.ndarray]:
    """The run's walk and particles from its seed, the draws simulate makes (robot, particles, kidnapping):
    the run's inputs, as run_task makes them, and the true positions (steps, 2)."""
    s = task.setting
    robot = Robot.of_seed(world, s.sigma, s.delta, task.seed)
    streams = run_streams(task.seed)  # as simulate draws them: particles, kidnapping, walk
    particles, _ = checked_walk(robot, world, s.particles, task.steps, None, False, streams, task.kidnap_at)
    positions = []
    for _ in range(task.steps):
        robot.step(world)
        positions.append(robot.position)
    inputs = RunInputs.of_run(robot, particles, world, s.sigma, s.delta, task.seed, task.steps, task.filters[0])
    return inputs, np.array(positions).reshape(task.steps, 2)


def run_batch(tasks: Sequence[RunTask]) -> list[list[RunRecord]]:
    """The runs of one setting (same filters and steps), each filter advancing all of them together."""
    s, steps = tasks[0].setting, tasks[0].steps
    world = s.maze.world(None)
    with warnings.catch_warnings():  # the range warnings were shown once, by study_settings
        warnings.simplefilter("ignore", UserWarning)
        walks = [walk_of(task, world) for task in tasks]
    particles = np.stack([inputs.init_particles_pos for inputs, _ in walks])  # (R, N, 2)
    compass = np.array([inputs.robot_compass_angles for inputs, _ in walks])  # (R, steps)
    z = np.array([inputs.robot_measurements for inputs, _ in walks])
    results: list[dict[str, RunResult]] = [{} for _ in tasks]
    world.prepare()
    pair = min(2, len(tasks))  # the warm-up advances one or two runs together, as the batch will

    def warm(filter_class: type, warmed: dict) -> None:  # a few untimed steps; their draws a stream of their own
        rngs = [run_streams(WARM_UP_SEED).filter for _ in range(pair)]
        filt = filter_class(maze_for(filter_class, world), s.sigma, s.delta, particles[:pair].copy(), rngs, **warmed)
        record_steps(
            filt,
            min(WARM_UP_STEPS, steps),
            lambda k: (compass[:pair, k], z[:pair, k]),
            runs=None if pair == 1 else pair,
        )

    for name in tasks[0].filters:
        filter_class = filter_entry(name).filter_class
        options = tasks[0].setting.filter_options(name)
        warm_once(("batch", pair), filter_class, options, functools.partial(warm, filter_class))  # once per process
        rngs = [run_streams(task.seed).filter for task in tasks]  # each run's filter stream, as simulate's
        filt = filter_class(maze_for(filter_class, world), s.sigma, s.delta, particles, rngs, **options)
        runs = None if len(tasks) == 1 else len(tasks)  # one run: the paper's shapes
        if runs is None:
            check_filter(filt)
        steps_of = record_steps(filt, steps, lambda k: (compass[:, k], z[:, k]), runs=runs)
        restarts = filt.reinitialised_at if len(tasks) > 1 else [filt.reinitialised_at]  # one run: one list
        for r, (walk, true_positions) in enumerate(walks):
            inputs = dataclasses.replace(walk, filtering_algorithm=filter_class.name)  # each filter: its own name
            results[r][filter_class.name] = RunResult.of_recorded(
                steps_of, r, true_positions, restarts[r], inputs, backend_of(filt)
            )
    return [run_records(task, world, result) for task, result in zip(tasks, results, strict=True)]
