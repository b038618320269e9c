"""The Python entry point of studies, `mazelab.study(...)`: the same study as `mazelab study`, its
rows as a list of dicts (`pandas.DataFrame(result.rows)`), its summary and its record."""

from __future__ import annotations

import inspect
import numbers
import os
import sys
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from mazelab.checks import check_seed
from mazelab.contract import missing_parts
from mazelab.experiments.executor import run_study
from mazelab.experiments.plan import plan_study, study_mazes
from mazelab.experiments.record import Recorder
from mazelab.experiments.summary import CSV_DTYPES, StudySummary, summarise_study, summary_rows
from mazelab.experiments.tables import flat_row
from mazelab.experiments.traces import study_traces, trace_table_columns
from mazelab.model import DEFAULT_PARTICLE_COUNT, DEFAULT_STEPS
from mazelab.plugins import is_lab_class
from mazelab.registry import resolve_filter


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
        suffix; `x` a varied parameter for the x axis, as --plot-x; `y` what it draws, as --plot-y:
        mean, median, converged, exact or paired; `title` instead of the program's, as --title); an
        existing file is replaced."""
        from mazelab.experiments.study_plot import plot_study, study_title

        path = Path(path)
        parameters = self.record["parameters"]
        maze = parameters["mazes"][0]["label"]
        title = title or study_title(self.varied, self.summaries, parameters["runs"], maze, x, y)
        plot_study(self.summaries, self.varied or ["maze"], path, title, x=x, y=y)
        return path


NUMBER = (numbers.Real,)  # int, float, numpy's numbers; bool is refused apart
WHOLE = (numbers.Integral,)
TEXT = (str,)
PATH = (str, os.PathLike)


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


def _options(options: Any) -> dict[str, list[Any]]:
    """The other filter options: a mapping of names to a value or a list of values (checked by the
    filters' declarations in plan_study)."""
    if options is None:
        return {}
    if not isinstance(options, Mapping):
        raise TypeError(f"options takes a mapping of option names to values, got {type(options).__name__}")
    listed = {}
    for name, value in options.items():
        values = list(value) if isinstance(value, (list, tuple, range)) else [value]
        if not values:
            raise ValueError(f"options[{name!r}] is empty; give a value or a list of them")
        listed[str(name)] = values
    return listed


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
    for item in chosen:
        if isinstance(item, type) and missing_parts(item):
            raise TypeError(
                f"filters: {item.__name__} is not a filter class: it has no {', '.join(missing_parts(item))} "
                "(mazelab.contract)"
            )
    return chosen


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


def study(
    maze: str | Sequence[str] | None = None,
    *,
    maze_size: str | Sequence[str] | None = None,
    stations: int | Sequence[int] | None = None,
    wall_share: float | Sequence[float] | None = None,
    sigma: float | Sequence[float] = 0.3,
    delta: float | Sequence[float] = 0.5,
    particles: int | Sequence[int] = DEFAULT_PARTICLE_COUNT,
    threshold: float | Sequence[float] | None = None,
    recovery: str | Sequence[str] | None = None,
    bandwidth: str | float | Sequence[str | float] | None = None,
    estimate: str | Sequence[str] | None = None,
    filters: str | Sequence[Any] = ("sir", "apf", "rpf"),
    options: Mapping[str, Any] | None = None,
    runs: int = 30,
    steps: int = DEFAULT_STEPS,
    seed: int | None = None,
    kidnap_at: int | None = None,
    kld: bool = False,
    traces: bool = False,
    reference: str | None = None,
    paired: str | None = None,
    workers: int | None = 1,
    dask: Any = None,
) -> StudyResult:
    """A Monte Carlo study, as `mazelab study` runs it: every combination of the values given (a value
    or a list each), `runs` seeded runs per setting, every filter once per value of the options it takes.

    Parameters
    ----------
    maze, maze_size, stations, wall_share
        Maze files or shipped names; generated mazes ("20x20"), their station blocks and wall share.
    sigma, delta, particles
        The studied values of the model (see `mazelab study --help`).
    threshold, recovery, bandwidth, estimate
        The paper's options by their names, as `mazelab study --threshold ...` spells them: the same as
        giving them in `options` (None: not given, each filter runs its declared default).
    filters
        Names ("sir", "rpf", ...) or filter classes (a student's own, meeting mazelab.contract).
    options
        Any declared filter option, by name: a value or a list of values to vary (e.g.
        {"resampling": ["systematic", "residual"]}); each filter takes those it declares, and the rows
        have a column for every option the studied filters declare.
    runs, steps, seed, kidnap_at, kld
        Runs per setting, steps per run, the root seed (None: a new one, in the record), a
        kidnapping step, KLD-sampling.
    traces
        Keep every run's per-step trace (StudyResult.traces).
    reference
        "grid": every run also runs the exact grid filter, every row gets `distance_to_exact`.
    paired
        A filter of the study: each other filter's summary gets its paired difference to it.
    workers, dask
        Processes (None: all cores), or a Dask scheduler address or Client.

    Returns
    -------
    StudyResult
        rows, summary, record (the same JSON record `mazelab study` writes), failures, traces.

    Raises
    ------
    TypeError
        An argument of the wrong type (runs=True, sigma="0.3", filters=[object], dask=42), named.
    ValueError
        A value out of its range, or an empty list (sigma=[]), named.
    """
    call = dict(locals())  # the arguments as given: the record's `call` re-runs them (`call_arguments`)
    workers = _whole("workers", workers, optional=True)
    if workers is not None and workers < 1:
        raise ValueError(f"workers must be >= 1 (or None: all cores), got {workers}")
    seed = None if seed is None else check_seed("seed", _whole("seed", seed))
    plan = plan_study(
        study_mazes(
            _listed("maze", maze, PATH, "a maze file or shipped name"),
            _listed("maze_size", maze_size, TEXT, "a size like '20x20'"),
            _listed("stations", stations, WHOLE, "a whole number of station blocks"),
            _listed("wall_share", wall_share, NUMBER, "a share of walls"),
        ),
        _filters(filters),
        sigma=_listed("sigma", sigma, NUMBER, "a number"),
        delta=_listed("delta", delta, NUMBER, "a number"),
        particles=_listed("particles", particles, WHOLE, "a whole number"),
        options=_named_options(
            _options(options),
            threshold=_listed("threshold", threshold, NUMBER, "a number"),
            recovery=_listed("recovery", recovery, TEXT, "a recovery name"),
            bandwidth=_listed("bandwidth", bandwidth, (str, *NUMBER), "a kernel name or a number"),
            estimate=_listed("estimate", estimate, TEXT, "'mean' or 'mode'"),
        ),
        runs=_whole("runs", runs),
        steps=_whole("steps", steps),
        seed=seed,
        kidnap_at=_whole("kidnap_at", kidnap_at, optional=True),
        kld=_flag("kld", kld),
        traces=_flag("traces", traces),
        reference=reference,
    )
    if paired is not None and resolve_filter(paired).name not in [resolve_filter(f).name for f in plan.filters]:
        raise ValueError(f"paired={paired!r} is not one of the study's filters")
    dask = _dask(dask)
    recorder = Recorder(
        "study", [sys.argv[0] or "python", "mazelab.study(...)"], plan.parameters(), csv_dtypes=CSV_DTYPES
    )
    outcome = run_study(plan.tasks(), workers, dask=dask)
    summaries = summarise_study(outcome.records, plan.settings, paired=paired)
    summary = summary_rows(summaries, plan.option_columns)
    failures = [f.describe() for f in outcome.failures]
    record = recorder.finish(
        "finished" if not failures else "finished with failures",
        summary=summary,
        failures=failures,
        runs_finished=len({(r.setting, r.run) for r in outcome.records}),
        paired=None if paired is None else resolve_filter(paired).name,
        call={"function": "mazelab.study", "arguments": call_arguments(call, plan.seed)},
        workers=[asdict(report) for report in outcome.workers.values()],
        startup_seconds=round(outcome.startup_seconds, 3),
    )
    blocks = study_traces(outcome.records) if traces else []
    columns = trace_table_columns(blocks)
    rows = [flat_row(r) for r in outcome.records]
    return StudyResult(rows, summary, record, failures, columns, summaries, plan.varied)


def _named_options(options: dict[str, list[Any]], **named: list[Any] | None) -> dict[str, list[Any]]:
    """The options with the paper's named ones added (None: not given); one given both ways is refused."""
    for name, values in named.items():
        if values is not None and name in options:
            raise ValueError(f"{name} is given twice, as {name}= and in options; give it once")
    return {**options, **{name: values for name, values in named.items() if values is not None}}


def call_arguments(call: Mapping[str, Any], seed: int) -> dict[str, Any]:
    """`study`'s arguments as data, so that `mazelab.study(**record["call"]["arguments"])` makes the
    same rows: the root seed the study drew (when none was given), a filter class as the spec of its
    file (`path/to/file.py:Class`, what a name can say), arrays as lists; a Dask Client (not data) is
    left out, the study then runs on this machine's workers."""
    arguments = {name: value for name, value in call.items() if name != "dask" or isinstance(value, str)}
    arguments["seed"] = seed
    filters = arguments["filters"]
    if not isinstance(filters, str):
        arguments["filters"] = [
            f"{inspect.getfile(f)}:{f.__name__}" if isinstance(f, type) and not is_lab_class(f) else _name_of(f)
            for f in filters
        ]
    return {name: _data(value) for name, value in arguments.items()}


def _data(value: Any) -> Any:
    """An argument as JSON data: arrays and tuples as lists, paths as text."""
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, os.PathLike):
        return os.fspath(value)
    if isinstance(value, (list, tuple, range)):
        return [_data(item) for item in value]
    return value


def _name_of(filter_name: Any) -> str:
    """A shipped filter's registry name (a class of the lab's, or a name as given)."""
    return resolve_filter(filter_name).name


__all__ = ["StudyResult", "call_arguments", "study"]
