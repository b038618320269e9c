"""The Python entry point of studies, `mazelab.study(...)`: the same study as `mazelab study`, its
rows as a list of dicts (`pandas.DataFrame(result.rows)`), its summary and its record."""

from __future__ import annotations

import sys
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from mazelab.experiments.executor import run_study
from mazelab.experiments.plan import plan_study, study_mazes
from mazelab.experiments.record import Recorder
from mazelab.experiments.summary import StudySummary, summarise_study
from mazelab.experiments.tables import flat_row
from mazelab.experiments.traces import TRACE_COLUMNS, study_traces
from mazelab.model import DEFAULT_PARTICLE_COUNT, DEFAULT_STEPS, RPF_THRESHOLD
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

    def figure(self, path: str | Path, x: str | None = None, title: str | None = None) -> Path:
        """The study's figure, as `mazelab study --plot PATH` draws it (.png, .pdf or .svg by the
        suffix; `x` a varied parameter for the x axis, as --plot-x); an existing file is replaced."""
        from mazelab.experiments.study_plot import plot_study

        path = Path(path)
        runs = self.record["parameters"]["runs"]
        plot_study(
            self.summaries, self.varied or ["maze"], path, title or f"Last-20% error ({runs} runs per point)", x=x
        )
        return path


def _listed(value: Any) -> list[Any] | None:
    """A value or a sequence of values as a list (None stays None)."""
    if value is None:
        return None
    return list(value) if isinstance(value, (list, tuple)) else [value]


def study(
    maze: str | Sequence[str] | None = None,
    *,
    maze_size: str | Sequence[str] | None = None,
    stations: int | Sequence[int] | None = None,
    wall_share: float | Sequence[float] | None = None,
    sigma: float | Sequence[float] = 0.3,
    delta: float | Sequence[float] = 0.5,
    particles: int | Sequence[int] = DEFAULT_PARTICLE_COUNT,
    threshold: float | Sequence[float] = RPF_THRESHOLD,
    recovery: str | Sequence[str] = "none",
    bandwidth: str | float | Sequence[str | float] = "optimal",
    estimate: str | Sequence[str] = "mean",
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
    sigma, delta, particles, threshold, recovery, bandwidth, estimate
        The studied values (see `mazelab study --help`).
    filters
        Names ("sir", "rpf", ...) or filter classes (a student's own, meeting mazelab.contract).
    options
        Any other declared filter option, by name: a value or a list of values to vary (e.g.
        {"resampling": ["systematic", "residual"]}); each filter takes those it declares.
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
    """
    plan = plan_study(
        study_mazes(_listed(maze), _listed(maze_size), _listed(stations), _listed(wall_share)),
        filters if isinstance(filters, str) else list(filters),
        sigma=_listed(sigma),
        delta=_listed(delta),
        particles=_listed(particles),
        threshold=_listed(threshold),
        recovery=_listed(recovery),
        bandwidth=_listed(bandwidth),
        estimate=_listed(estimate),
        options={name: _listed(value) for name, value in (options or {}).items()},
        runs=runs,
        steps=steps,
        seed=seed,
        kidnap_at=kidnap_at,
        kld=kld,
        traces=traces,
        reference=reference,
    )
    if paired is not None and resolve_filter(paired).name not in [resolve_filter(f).name for f in plan.filters]:
        raise ValueError(f"paired={paired!r} is not one of the study's filters")
    recorder = Recorder("study", [sys.argv[0] or "python", "mazelab.study(...)"], plan.parameters())
    outcome = run_study(plan.tasks(), workers, dask=dask)
    summaries = summarise_study(outcome.records, plan.settings, paired=paired)
    summary = [s.as_dict() for s in summaries]
    failures = [f.describe() for f in outcome.failures]
    record = recorder.finish(
        "finished" if not failures else "finished with failures",
        summary=summary,
        failures=failures,
        runs_finished=len({(r.setting, r.run) for r in outcome.records}),
    )
    blocks = study_traces(outcome.records) if traces else []
    columns = {c: np.concatenate([b[c] for b in blocks]) for c in TRACE_COLUMNS} if blocks else None
    rows = [flat_row(r) for r in outcome.records]
    return StudyResult(rows, summary, record, failures, columns, summaries, plan.varied)


__all__ = ["StudyResult", "study"]
