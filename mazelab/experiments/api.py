"""The Python entry point of studies, `mazelab.study(...)`: the same study as `mazelab study`, its rows as
a list of dicts (`pandas.DataFrame(result.rows)`), its summary and its record. A study is a plan value
(`StudyPlan`), checked once whether it comes from the command line (`plan_study`) or from Python values
(`study_plan`, which says what each argument takes), and run by `study`.
"""

from __future__ import annotations

import inspect
import itertools
import numbers
import os
import sys
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from mazelab import maze_generator
from mazelab.checks import check_seed, check_sigma_within, check_steps, check_study
from mazelab.constants import DEFAULT_DELTA, DEFAULT_SIGMA
from mazelab.contract import missing_parts
from mazelab.declaration import scoped, show_value, to_plain_json
from mazelab.experiments.executor import StudyOutcome, open_cluster, run_study, study_backend
from mazelab.experiments.journal import Recorder
from mazelab.experiments.runs import filter_key, options_per_filter, parse_filters
from mazelab.experiments.study import (
    BASE_PARAMETERS,
    MODEL_PARAMETERS,
    REFERENCE,
    MazeChoice,
    RunRecord,
    RunTask,
    StudySetting,
    declared_option,
    file_mazes,
    option_columns,
    study_parameters,
    study_settings,
    study_tasks,
    varied_parameters,
)
from mazelab.experiments.summary import CSV_COLUMNS, CSV_DTYPES, StudySummary, summarise_study, summary_rows
from mazelab.experiments.tables import flat_row, study_traces, trace_table_columns
from mazelab.grid_filter import check_grid_memory
from mazelab.maze import DEFAULT_MAZE, MAZES_DIR
from mazelab.maze_generator import DEFAULT_WALL_SHARE
from mazelab.model import DEFAULT_PARTICLE_COUNT, DEFAULT_STEPS
from mazelab.registry import PluginReference, filter_entry, is_lab_class, plugin_codes, resolve_filter
from mazelab.seeding import new_seed


# -- the plan ----------------------------------------------------------------------------------------
def study_mazes(
    files: Sequence[str] | None,
    sizes: Sequence[str] | None = None,
    stations: Sequence[int] | None = None,
    wall_shares: Sequence[float] | None = None,
) -> list[MazeChoice]:
    """The study's mazes: the files (or shipped names), then every generated size x station-block
    count x wall share; the default maze if none is given."""
    mazes = file_mazes(files) if files else []
    if sizes or stations or wall_shares:
        for rows, columns in (maze_generator.parse_size(s) for s in (sizes or ["10x10"])):
            counts = list(stations) if stations else [maze_generator.default_station_count(rows, columns)]
            for count, share in itertools.product(counts, wall_shares or [DEFAULT_WALL_SHARE]):
                maze_generator.check_generation(rows, columns, count, share)  # --stations 0: refused up front
                mazes.append(MazeChoice.generated(rows, columns, count, share))
    return mazes or file_mazes([DEFAULT_MAZE])


def maze_description(choice: MazeChoice) -> dict[str, Any]:
    """A maze as the record lists it: a file's path (a shipped maze's, one of the project's own in mazes/,
    as mazes/NAME.txt: no machine's folder in it; another file's as given, relative to the record's
    working folder) and sha256, or what generates it."""
    if choice.grid is not None:
        shipped = choice.path is not None and Path(choice.path).resolve().parent == MAZES_DIR.resolve()
        return {
            "label": choice.label,
            "file": f"mazes/{Path(choice.path).name}" if shipped else choice.path,
            "shipped": shipped,
            "sha256": choice.sha256,
            "rows": len(choice.grid),
            "columns": len(choice.grid[0]),
            "station_blocks": sum(row.count(2) for row in choice.grid),
        }
    assert choice.size is not None
    return {
        "label": choice.label,
        "generated": f"{choice.size[0]}x{choice.size[1]}",
        "station_blocks": choice.stations,
        "wall_share": choice.wall_share,
        "note": "a new maze per run, from the run's maze_seed (mazelab maze generate --seed); each run's "
        "maze_sha256 in the CSV is the sha256 of its grid as maze text (Maze.to_text())",
    }


@dataclass
class StudyPlan:
    """Everything that fixes a study's rows."""

    settings: list[StudySetting]
    filters: list[Any]  # filter names (or classes, from Python)
    runs: int
    steps: int
    seed: int
    kidnap_at: int | None = None
    kld: bool = False
    traces: bool = False
    reference: str | None = None  # "grid": every row gets distance_to_exact (`study --reference grid`)
    plugins: tuple[PluginReference, ...] = ()  # the plug-ins' code, read once: every run carries it
    call: dict[str, Any] | None = None  # the Python values that made it (mazelab.study_plan), as data
    # every run of the study, each with the filters its setting runs (study.study_tasks), made once by plan_study
    tasks: list[RunTask] = field(default_factory=list, repr=False)

    @property
    def option_columns(self) -> list[str]:
        """The options the study's filters declare (`study.option_columns`): a CSV column each."""
        return list(option_columns(self.filters))

    @property
    def columns(self) -> list[str]:
        """The study CSV's columns: CSV_COLUMNS, then one per option its filters declare."""
        return [*CSV_COLUMNS, *self.option_columns]

    @property
    def varied(self) -> list[str]:
        return varied_parameters(self.settings)

    def parameters(self) -> dict[str, Any]:
        """The study's parameters as parsed (what the record keeps and --resume compares)."""

        def values(parameter: str) -> list[Any]:
            return list(dict.fromkeys(s.value(parameter) for s in self.settings))

        others = study_parameters(self.settings)[len(BASE_PARAMETERS) :]
        return {
            "filters": [resolve_filter(f).name for f in self.filters],
            "mazes": [maze_description(m) for m in dict.fromkeys(s.maze for s in self.settings)],
            **{p: values(p) for p in MODEL_PARAMETERS},
            "options": {p: [to_plain_json(v) for v in values(p)] for p in others},
            "runs": self.runs,
            "steps": self.steps,
            "root_seed": self.seed,
            "kidnap_at": self.kidnap_at,
            "kld": self.kld,
            "reference": self.reference,  # "grid", or None: no distance to the exact posterior
            **({"plugins": [plugin_description(code) for code in self.plugins]} if self.plugins else {}),
        }

    def header(self, where: str, backend: str | None = None) -> str:
        """The study's first lines: its size, seed, workers and backend; the fixed parameters (the maze, the
        model's, each option the study sets: an option not set runs at its default); the varied ones with all
        their values."""
        skipped = len(self.settings) - len(self.tasks) // max(1, self.runs)
        note = f" ({skipped} setting(s) run no filter)" if skipped else ""
        on = f", {backend} backend" if backend else ""
        first, varied = self.settings[0], self.varied
        parts = {
            "maze": f"maze {first.maze.label}",
            "sigma": f"sigma {first.sigma:g}",
            "delta": f"delta {first.delta:g}",
            "particles": f"{first.particles} particles",
            **{name: f"{name} {show_value(value)}" for name, value in first.options},
        }
        kidnapping = "" if self.kidnap_at is None else f", kidnapped at step {self.kidnap_at}"
        fixed = [text for parameter, text in parts.items() if parameter not in varied]
        lines = [
            f"Study: {len(self.settings)} setting(s){note} x {self.runs} runs x {len(self.filters)} filters, "
            f"seed {self.seed}, {where}{on}",
            "fixed: " + ", ".join([*fixed, f"{self.steps} steps{kidnapping}", f"{self.runs} runs per setting"]),
        ]
        if varied:
            values = {p: ", ".join(dict.fromkeys(show_value(s.value(p)) for s in self.settings)) for p in varied}
            shown = "; ".join(f"{p} {v}" for p, v in values.items())
            lines.append(f"varied: {shown} (each filter once per value it takes)")
        if self.reference:
            lines.append("reference: the exact grid filter, once per run's scenario (distance_to_exact)")
        return "\n".join(lines)


def plugin_description(code: PluginReference) -> dict[str, str]:
    """A plug-in as the record lists it: its filter's name, its file (relative to the working folder
    when inside it), its class and the sha256 of the file's bytes the rows were made with."""
    try:
        shown = str(code.path.relative_to(Path.cwd()))
    except ValueError:
        shown = str(code.path)
    return {"filter": resolve_filter(code.spec).name, "file": shown, "class": code.class_name, "sha256": code.sha256}


def plan_study(
    mazes: Sequence[MazeChoice],
    filters: str | Sequence[Any],
    values: Mapping[str, Sequence[Any]],
    *,
    runs: int = 30,
    steps: int = 200,
    seed: int | None = None,
    kidnap_at: int | None = None,
    kld: bool = False,
    traces: bool = False,
    reference: str | None = None,
    spelled: Mapping[str, str] | None = None,
) -> StudyPlan:
    """Check and combine a study's values into its plan (a new root seed if none is given).

    `values` holds every value the study takes, a list for each: the model's (MODEL_PARAMETERS: sigma,
    delta, particles), then the filter options it sets, by name (a plug-in's included; `kld` is a spelling
    of {"kld": [True]}). An option that no filter of the study takes, given a value other than its
    default, is refused in one line (naming it as `spelled` says: the command line's flag), and one given
    only its default is left out (no filter runs it); every value, for every filter that takes it, is
    checked by its declaration up front."""
    names = parse_filters(filters) if isinstance(filters, str) else _filter_list(filters)
    given = {name: list(listed) for name, listed in values.items() if name not in MODEL_PARAMETERS}
    if kld:
        given["kld"] = [True]
    for name, listed in given.items():
        if not listed:
            raise ValueError(f"option {name} has no values")
    checked = {name: None if all_default(name, listed) else listed for name, listed in given.items()}
    options_per_filter(names, checked, spelled)
    declared = set(option_columns(names))
    given = {name: listed for name, listed in given.items() if scoped(name)[1] in declared}
    check_steps(steps)  # each run's limits, up front rather than in every worker
    settings = study_settings(mazes, *(values[p] for p in MODEL_PARAMETERS), given)
    check_study(len(settings) * runs, len(names))
    check_settings(settings, names, reference)
    seed = new_seed() if seed is None else seed
    kld = given.get("kld") == [True]  # the table's mean N column
    plugins = plugin_codes(names)
    tasks = study_tasks(
        settings, names, runs, steps, seed, kidnap_at=kidnap_at, traces=traces, reference=reference, plugins=plugins
    )
    return StudyPlan(settings, names, runs, steps, seed, kidnap_at, kld, traces, reference, plugins, tasks=tasks)


def all_default(name: str, values: Sequence[Any]) -> bool:
    """Whether every value given to an option is its declared default (then no filter needs to take it)."""
    option = declared_option(name)
    try:
        return option is not None and all(option.validate(v) == option.default for v in values)
    except ValueError:  # a bad value: refused below, by the declaration of a filter that takes it
        return False


def check_settings(settings: Sequence[StudySetting], names: Sequence[Any], reference: str | None = None) -> None:
    """Before any run starts: each setting's sigma within the ranges of its maze (mazelab.checks), and every
    filter's options in it, checked by its declaration as its constructor will check them (values and
    combinations); with --reference, only "grid", whose cells must fit in memory on every maze (its
    constructor's own check, for each maze's size)."""
    if reference is not None and reference != REFERENCE:
        raise ValueError(f"--reference {reference}: the reference is the exact grid filter, --reference {REFERENCE}")
    seen: set[tuple[Any, ...]] = set()
    for setting in settings:
        maze = setting.maze
        rows, columns = maze.size if maze.grid is None else (len(maze.grid), len(maze.grid[0]))
        check_sigma_within(setting.sigma, columns, rows)
        if reference is not None:
            check_grid_memory(columns, rows)
        for name in names:
            given, entry = setting.filter_options(name), filter_entry(name)
            key = (entry.name, repr(sorted(given.items())))
            if key not in seen:
                seen.add(key)
                entry.options.resolve(given, entry.name)


def _filter_list(filters: Any) -> list[Any]:
    """Names resolved to the registry's, classes kept (a student's own filter, meeting mazelab.contract),
    without repeats; anything else (not a name or a class, a class without a filter's parts) a TypeError
    naming it."""
    chosen = _listed("filters", filters, (str, type), "filter names or filter classes")
    if not chosen:
        raise ValueError("filters is empty; give e.g. ['sir', 'apf', 'rpf']")
    for item in chosen:
        if isinstance(item, type) and missing_parts(item):
            raise TypeError(
                f"filters: {item.__name__} is not a filter class: it has no {', '.join(missing_parts(item))} "
                "(mazelab.contract)"
            )
    return list(dict.fromkeys(f if isinstance(f, type) else filter_key(f) for f in chosen))


# -- from Python ------------------------------------------------------------------------------------
@dataclass
class StudyResult:
    """What `study` returns: one dict per run and filter (the CSV's columns), one per setting and
    filter (the table's statistics and intervals), the record, the failed runs and, with
    traces=True, the per-step traces as columns (`pandas.DataFrame(result.traces)`)."""

    rows: list[dict[str, Any]]
    summary: list[dict[str, Any]]
    record: dict[str, Any]
    failures: list[str] = field(default_factory=list)
    traces: dict[str, np.ndarray] | None = None
    summaries: list[StudySummary] = field(default_factory=list, repr=False)  # the summary, as objects
    varied: list[str] = field(default_factory=list)  # the varied parameters

    def figure(self, path: str | Path, x: str | None = None, title: str | None = None, y: str = "mean") -> Path:
        """The study's figure, as `mazelab study --plot PATH` draws it (.png, .pdf or .svg by the
        suffix; `x` a varied parameter for the x axis, as --plot-x; `y` what it draws, as --plot-y;
        `title` instead of the program's title and caption, as --title); an existing file is replaced."""
        from mazelab.experiments.study_plot import draw_study

        runs, mazes = self.record["parameters"]["runs"], self.record["parameters"]["mazes"]
        draw_study(self.summaries, self.varied, Path(path), runs, mazes[0]["label"], x=x, y=y, title=title)
        return Path(path)


NUMBER = (numbers.Real,)  # int, float, numpy's numbers; bool is refused apart
WHOLE = (numbers.Integral,)
MODEL_DEFAULTS = {"sigma": DEFAULT_SIGMA, "delta": DEFAULT_DELTA, "particles": DEFAULT_PARTICLE_COUNT}  # as the CLI's
PLAN_ARGUMENTS = {  # the plan's arguments that are not filter options: (kinds, what one value is); None: one value
    "maze": ((str, os.PathLike), "a maze file or shipped name"),
    "maze_size": ((str,), "a size like '20x20'"),
    "stations": (WHOLE, "a whole number of station blocks"),
    "wall_share": (NUMBER, "a share of walls"),
    "sigma": (NUMBER, "a number"),
    "delta": (NUMBER, "a number"),
    "particles": (WHOLE, "a whole number"),
}


def _listed(name: str, value: Any, kinds: tuple[type, ...], what: str) -> list[Any] | None:
    """A value or a list (tuple, range, 1-d array) of values of `kinds` as a list; None stays None.
    A value of another type (True for a count, text for a number, a dict) is a TypeError, an empty
    list a ValueError: one line naming the argument."""
    if value is None:
        return None
    if isinstance(value, np.ndarray):
        value = value.tolist() if value.ndim == 1 else value.item() if value.ndim == 0 else value
    values = list(value) if isinstance(value, (list, tuple, range)) else [value]
    if not values:
        raise ValueError(f"{name} is empty; give {what} or a list of them")
    for item in values:
        if isinstance(item, bool) or not isinstance(item, kinds):
            raise TypeError(f"{name} takes {what} or a list of them, got {item!r} ({type(item).__name__})")
    return values


def _whole(name: str, value: Any, *, optional: bool = False) -> int | None:
    """A whole number (not a bool: runs=True is no run count), or None when `optional`."""
    if value is None and optional:
        return None
    if isinstance(value, bool) or not isinstance(value, numbers.Integral):
        raise TypeError(f"{name} must be a whole number, got {value!r} ({type(value).__name__})")
    return int(value)


def _flag(name: str, value: Any) -> bool:
    if not isinstance(value, (bool, np.bool_)):
        raise TypeError(f"{name} must be True or False, got {value!r} ({type(value).__name__})")
    return bool(value)


def _options(options: Any, named: Mapping[str, Any]) -> dict[str, list[Any]]:
    """The filter options: `options` (a mapping of names to a value or a list of values) and those given
    as keywords of their own (`bandwidth=...`), each a list; one given both ways is refused in one line
    (plan_study refuses an empty list, and the filters' declarations check the values)."""
    if options is not None and not isinstance(options, Mapping):
        raise TypeError(f"options takes a mapping of option names to values, got {type(options).__name__}")
    listed = {}
    for name, value in [*(options or {}).items(), *named.items()]:
        if str(name) in listed:
            raise ValueError(f"{name} is given twice, as {name}= and in options; give it once")
        listed[str(name)] = list(value) if isinstance(value, (list, tuple, range, np.ndarray)) else [value]
    return listed


def study_plan(
    maze: Any = None,
    *,
    filters: Any = ("sir", "apf", "rpf"),
    options: Mapping[str, Any] | None = None,
    runs: Any = 30,
    steps: Any = DEFAULT_STEPS,
    seed: Any = None,
    kidnap_at: Any = None,
    kld: Any = False,
    traces: Any = False,
    reference: str | None = None,
    **values: Any,
) -> StudyPlan:
    """A study's plan from Python values (a value or a list each): `maze`, `maze_size`, `stations`,
    `wall_share` (maze files or shipped names; generated mazes, their station blocks and wall share),
    `sigma` (default 0.3), `delta` (0.5), `particles` (1500), `filters` (names or filter classes of your
    own), any declared filter option by name (or in `options`), `runs`, `steps`, `seed` (None: a new one,
    in the record), `kidnap_at`, `kld`, `traces` (keep every run's per-step trace), `reference` ("grid":
    the distance to the exact posterior). TypeError for an argument of the wrong type (runs=True,
    sigma="0.3"), ValueError for a value out of its range or an empty list, each one line naming it."""
    call = {**{k: v for k, v in locals().items() if k != "values"}, **values}  # the values as given, for the record
    given = {name: _listed(name, values.pop(name, None), *PLAN_ARGUMENTS[name]) for name in PLAN_ARGUMENTS}
    given["maze"] = _listed("maze", maze, *PLAN_ARGUMENTS["maze"])
    seed = None if seed is None else check_seed("seed", _whole("seed", seed))
    plan = plan_study(
        study_mazes(*(given[name] for name in ("maze", "maze_size", "stations", "wall_share"))),
        filters,
        {**{p: given[p] or [MODEL_DEFAULTS[p]] for p in MODEL_PARAMETERS}, **_options(options, values)},
        runs=_whole("runs", runs),
        steps=_whole("steps", steps),
        seed=seed,
        kidnap_at=_whole("kidnap_at", kidnap_at, optional=True),
        kld=_flag("kld", kld),
        traces=_flag("traces", traces),
        reference=reference,
    )
    plan.call = call_arguments(call, plan.seed)
    return plan


def study(
    maze: Any = None,
    *,
    plan: StudyPlan | None = None,
    paired: str | None = None,
    workers: int | None = 1,
    dask: Any = None,
    **values: Any,
) -> StudyResult:
    """A Monte Carlo study, as `mazelab study` runs it: the plan (`plan`, or `study_plan(maze, **values)`'s)
    run on `workers` processes (None: all cores) or a Dask cluster (`dask`: a scheduler address or a
    distributed.Client); `paired` a filter of the study, each other filter's summary then gets its paired
    difference to it. Returns the rows, the summary, the record (the one `mazelab study` writes), the
    failures and the traces (StudyResult); a wrong argument is one line, as in `study_plan` (dask=42: a TypeError)."""
    if plan is not None and (maze is not None or values):
        raise TypeError("give the study's plan or its values, not both")
    workers = _whole("workers", workers, optional=True)  # >= 1, checked by run_study
    plan = plan or study_plan(maze, **values)
    if paired is not None and resolve_filter(paired).name not in [resolve_filter(f).name for f in plan.filters]:
        raise ValueError(f"paired={paired!r} is not one of the study's filters")
    recorder = Recorder(
        "study", [sys.argv[0] or "python", "mazelab.study(...)"], plan.parameters(), csv_dtypes=CSV_DTYPES
    )
    if dask is not None and not isinstance(dask, str):  # the caller's Client: run_study opens only an address
        open_cluster(dask, study_backend(plan.tasks, 1))  # its workers asked once, before any run
    outcome = run_study(plan.tasks, workers, dask=dask)
    summaries = summarise_study(outcome.records, plan.settings, paired=paired)
    closing = study_closing(plan, outcome, outcome.records, summaries, paired)
    call = {
        **(plan.call or {}),
        "paired": paired,
        "workers": workers,
        **({"dask": dask} if isinstance(dask, str) else {}),
    }
    record = recorder.finish(outcome.status, **closing, call={"function": "mazelab.study", "arguments": call})
    columns = trace_table_columns(study_traces(outcome.records)) if plan.traces else None
    rows = [flat_row(r) for r in outcome.records]
    return StudyResult(rows, closing["summary"], record, closing["failures"], columns, summaries, plan.varied)


def study_closing(
    plan: StudyPlan,
    outcome: StudyOutcome,
    records: Sequence[RunRecord],
    summaries: Sequence[StudySummary],
    paired: str | None,
) -> dict[str, Any]:
    """What a study's record says at its end, the same from `mazelab study` and `mazelab.study`: the runs
    finished (among `records`, a resumed study's kept ones too) and in the study, the failures, the summary
    (the summary CSV's rows, `summary_rows`), the filter paired with, the backend, each process's report
    and their start-up."""
    return {
        "runs_finished": len({(r.setting, r.run) for r in records}),
        "runs_in_study": len(plan.tasks),
        "failures": [f.describe() for f in outcome.failures],
        "summary": summary_rows(summaries, plan.option_columns),
        "paired": None if paired is None else resolve_filter(paired).name,
        "backend": outcome.backend,
        "workers": [asdict(report) for report in outcome.workers.values()],
        "startup_seconds": round(outcome.startup_seconds, 3),
    }


def call_arguments(call: Mapping[str, Any], seed: int) -> dict[str, Any]:
    """A plan's arguments, so that `mazelab.study(**record["call"]["arguments"])` makes the same rows: the
    root seed the study drew (when none was given), a filter class as the spec of its file
    (`path/to/file.py:Class`, what a name can say); the record writes them as data (record.jsonable)."""
    arguments = {**call, "seed": seed}
    filters = arguments["filters"]
    if not isinstance(filters, str):
        arguments["filters"] = [
            f"{inspect.getfile(f)}:{f.__name__}"
            if isinstance(f, type) and not is_lab_class(f)
            else resolve_filter(f).name
            for f in filters
        ]
    return arguments


__all__ = ["StudyResult", "call_arguments", "study", "study_plan"]
