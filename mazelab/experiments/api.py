"""The Python entry point of studies, `mazelab.study(...)`: the same study as `mazelab study`, its rows as
a list of dicts (`pandas.DataFrame(result.rows)`), its summary and its record.

A study is a plan value (mazelab.experiments.plan.StudyPlan) run on workers: `study_plan(**values)` makes
one from Python values, each checked with one line naming the argument, and `mazelab.study(plan=...)` runs
it; `mazelab.study(**values)` does both. Any declared filter option is a keyword of its own
(`bandwidth=["optimal", "multimodal"]`, `threshold=0.5`, `**{"rpf.threshold": [0.1, 0.2]}`) or an entry
of `options=`.
"""

from __future__ import annotations

import inspect
import numbers
import os
import sys
from collections.abc import Mapping
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from mazelab.checks import check_seed
from mazelab.contract import missing_parts
from mazelab.experiments.executor import run_study
from mazelab.experiments.plan import StudyPlan, plan_study, study_mazes
from mazelab.experiments.record import Recorder
from mazelab.experiments.summary import CSV_DTYPES, StudySummary, summarise_study, summary_rows
from mazelab.experiments.tables import flat_row, study_traces, trace_table_columns
from mazelab.model import DEFAULT_PARTICLE_COUNT, DEFAULT_STEPS
from mazelab.registry import is_lab_class, resolve_filter


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

        parameters = self.record["parameters"]
        draw_study(self.summaries, self.varied, Path(path), parameters["runs"], parameters["mazes"][0]["label"], x=x,
                   y=y, title=title)  # fmt: skip
        return Path(path)


NUMBER = (numbers.Real,)  # int, float, numpy's numbers; bool is refused apart
WHOLE = (numbers.Integral,)
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


def _filters(filters: Any) -> str | list[Any]:
    """The filters: a comma-separated string, or a list of names and filter classes (each class
    meeting mazelab.contract); anything else a TypeError naming it."""
    if isinstance(filters, str):
        return filters
    chosen = _listed("filters", filters, (str, type), "filter names or filter classes")
    for item in chosen or ():
        if isinstance(item, type) and missing_parts(item):
            raise TypeError(
                f"filters: {item.__name__} is not a filter class: it has no {', '.join(missing_parts(item))} "
                "(mazelab.contract)"
            )
    return chosen or []


def _options(options: Any, named: Mapping[str, Any]) -> dict[str, list[Any]]:
    """The filter options: `options` (a mapping of names to a value or a list of values) and those given
    as keywords of their own (`bandwidth=...`), each a list; one given both ways is refused in one line
    (the filters' declarations check them in plan_study)."""
    if options is not None and not isinstance(options, Mapping):
        raise TypeError(f"options takes a mapping of option names to values, got {type(options).__name__}")
    listed = {}
    for name, value in [*(options or {}).items(), *named.items()]:
        if str(name) in listed:
            raise ValueError(f"{name} is given twice, as {name}= and in options; give it once")
        values = list(value) if isinstance(value, (list, tuple, range, np.ndarray)) else [value]
        if not values:
            raise ValueError(f"options[{name!r}] is empty; give a value or a list of them")
        listed[str(name)] = values
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
        study_mazes(*(given[name] for name in ("maze", "maze_size", "stations", "wall_share"))), _filters(filters),
        sigma=given["sigma"] or [0.3], delta=given["delta"] or [0.5],
        particles=given["particles"] or [DEFAULT_PARTICLE_COUNT], options=_options(options, values),
        runs=_whole("runs", runs), steps=_whole("steps", steps), seed=seed,
        kidnap_at=_whole("kidnap_at", kidnap_at, optional=True), kld=_flag("kld", kld), traces=_flag("traces", traces),
        reference=reference,
    )  # fmt: skip
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
    """A Monte Carlo study, as `mazelab study` runs it: the plan (`plan`, or the one `study_plan(maze,
    **values)` makes: every combination of the values given, `runs` seeded runs per setting, every filter
    once per value of the options it takes) run on `workers` processes (None: all cores) or a Dask
    cluster (`dask`: a scheduler address or a distributed.Client); `paired` a filter of the study, each
    other filter's summary then gets its paired difference to it. Returns the rows, the summary, the
    record (the same JSON record `mazelab study` writes), the failures and the traces (StudyResult); an
    argument of the wrong type is a TypeError (runs=True, filters=[object], dask=42), a value out of its
    range or an empty list a ValueError, each one line naming it."""
    if plan is not None and (maze is not None or values):
        raise TypeError("give the study's plan or its values, not both")
    workers = _whole("workers", workers, optional=True)
    if workers is not None and workers < 1:
        raise ValueError(f"workers must be >= 1 (or None: all cores), got {workers}")
    plan = plan or study_plan(maze, **values)
    if paired is not None and resolve_filter(paired).name not in [resolve_filter(f).name for f in plan.filters]:
        raise ValueError(f"paired={paired!r} is not one of the study's filters")
    dask = _dask(dask)
    recorder = Recorder("study", [sys.argv[0] or "python", "mazelab.study(...)"], plan.parameters(),
                        csv_dtypes=CSV_DTYPES)  # fmt: skip
    outcome = run_study(plan.tasks(), workers, dask=dask)
    summaries = summarise_study(outcome.records, plan.settings, paired=paired)
    summary, failures = summary_rows(summaries, plan.option_columns), [f.describe() for f in outcome.failures]
    call = {
        **(plan.call or {}),
        "paired": paired,
        "workers": workers,
        **({"dask": dask} if isinstance(dask, str) else {}),
    }
    record = recorder.finish(
        "finished" if not failures else "finished with failures", summary=summary, failures=failures,
        runs_finished=len({(r.setting, r.run) for r in outcome.records}), backend=outcome.backend,
        paired=None if paired is None else resolve_filter(paired).name,
        call={"function": "mazelab.study", "arguments": call},
        workers=[asdict(report) for report in outcome.workers.values()],
        startup_seconds=round(outcome.startup_seconds, 3),
    )  # fmt: skip
    columns = trace_table_columns(study_traces(outcome.records)) if plan.traces else None
    rows = [flat_row(r) for r in outcome.records]
    return StudyResult(rows, summary, record, failures, columns, summaries, plan.varied)


def _dask(dask: Any) -> Any:
    """None, a scheduler address (text), or a distributed.Client; anything else a TypeError."""
    if dask is None or isinstance(dask, str):
        return dask
    try:
        from distributed import Client
    except ImportError:
        Client = None
    if Client is None or not isinstance(dask, Client):
        raise TypeError(
            f"dask must be a scheduler address like 'tcp://HOST:8786' or a distributed.Client, got {dask!r} "
            f"({type(dask).__name__})"
        )
    return dask


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
