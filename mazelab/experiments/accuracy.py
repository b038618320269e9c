"""How close each filter comes to the exact posterior (`mazelab accuracy`): a study with the exact grid filter
as its reference (`study --reference grid`) on each maze, so that a row per maze, run and filter gives the
distance between its estimate and the exact posterior mean over the second half of the steps (after the first
localisation, mazelab.experiments.study.distance_to_exact) and its convergence step against the truth.

The table's filters are labelled rows (label, filter, options): the default table has the RPF twice, with
the paper's optimal bandwidth and the multimodal one, so the study runs the RPF once per bandwidth."""

from __future__ import annotations

import functools
import statistics
from collections.abc import Sequence
from typing import Any

from mazelab.experiments.api import StudyPlan, plan_study
from mazelab.experiments.study import REFERENCE, MazeChoice, RunRecord, option_cell
from mazelab.experiments.summary import bootstrap_interval, wilson_interval
from mazelab.experiments.tables import column_table, format_interval, format_number, records_csv
from mazelab.registry import filter_entry, is_plugin_spec, resolve_filter

AccuracyFilter = tuple[str, Any, dict[str, Any]]  # (label, filter name or class, options)
# the filters of the default table, each against the exact grid filter
ACCURACY_FILTERS: tuple[AccuracyFilter, ...] = (
    ("SIR", "sir", {}),
    ("APF", "apf", {}),
    ("RPF (paper: optimal)", "rpf", {}),
    ("RPF multimodal", "rpf", {"bandwidth": "multimodal"}),
    ("grid (exact)", "grid", {}),
)
EXACT = ("grid (exact)", "grid", {})


def accuracy_filters(names: Sequence[Any] | None) -> tuple[AccuracyFilter, ...]:
    """The filters of the table: ACCURACY_FILTERS, or the given names or classes (each with its default
    options), the exact grid filter last."""
    if names is None:
        return ACCURACY_FILTERS
    chosen: dict[str, AccuracyFilter] = {}
    for name in names:
        filter_class = resolve_filter(name)
        if filter_class is not resolve_filter("grid"):
            label = filter_class.name
            key = name if isinstance(name, type) or is_plugin_spec(str(name)) else filter_class.name
            chosen.setdefault(label, (label, key, {}))  # a plug-in goes to the workers as its spec
    return (*chosen.values(), EXACT)


def accuracy_plan(
    mazes: Sequence[MazeChoice],
    rows: Sequence[AccuracyFilter],
    *,
    sigma: float,
    delta: float,
    particles: int,
    runs: int,
    steps: int,
    seed: int,
) -> StudyPlan:
    """The study that measures the rows: their filters on every maze, the exact grid filter the reference, and
    each option a row sets studied with every value the rows of its filters give it (their default where a
    row sets none), so that each row's filter runs once with its own options on every run."""
    names = list(dict.fromkeys(name for _, name, _ in rows))
    options: dict[str, list[Any]] = {key: [] for _, _, given in rows for key in given}
    for key, values in options.items():
        for _, name, given in rows:
            declared = filter_entry(name).options
            value = given.get(key, declared[key].default if key in declared else None)
            if key in declared and value not in values:
                values.append(value)
    return plan_study(
        mazes,
        names,
        {"sigma": [sigma], "delta": [delta], "particles": [particles], **options},
        runs=runs,
        steps=steps,
        seed=seed,
        reference=REFERENCE,
    )


# a row of the table's CSV, one filter in one run: its mean distance to the exact posterior mean over the
# second half of the steps (map units; 0 for the grid itself) and its convergence step against the truth
# (None: never); `filter` is the table's label of the row
ACCURACY_COLUMNS = ["maze", "seed", "filter", "distance_to_exact", "converged_at", "run", "maze_seed"]
accuracy_csv = functools.partial(records_csv, columns=ACCURACY_COLUMNS)  # accuracy_records' rows; "never": empty


def accuracy_records(records: Sequence[RunRecord], rows: Sequence[AccuracyFilter]) -> list[dict[str, Any]]:
    """Each row's record of every run whose rows have all finished (ACCURACY_COLUMNS), by maze and run in
    the records' order: the study's row of the row's filter with the row's options (its declared defaults
    for the rest)."""
    wanted = []
    for label, name, given in rows:
        entry = filter_entry(name)
        values = entry.options.resolve(given, entry.name)
        wanted.append((label, entry.name, {o.name: option_cell(values[o.name]) for o in entry.options.settable()}))
    runs: dict[tuple[str, int], list[RunRecord]] = {}
    for record in records:
        runs.setdefault((record.maze, record.run), []).append(record)
    found = []
    for (maze, run), mine in runs.items():
        chosen = [next((r for r in mine if r.filter == name and r.options == cells), None) for _, name, cells in wanted]
        if all(chosen):
            for (label, _, _), r in zip(wanted, chosen, strict=True):
                cells = (maze, r.seed, label, r.distance_to_exact, r.converged_at, run, r.maze_seed)
                found.append(dict(zip(ACCURACY_COLUMNS, cells, strict=True)))
    return found


def accuracy_summary(records: Sequence[dict[str, Any]]) -> list[dict[str, Any]]:
    """Per maze and filter: runs, the mean distance to the exact mean with its percentile bootstrap
    interval, the worst run, the converged share with its Wilson interval, the median convergence step."""
    groups: dict[tuple[str, str], list[dict[str, Any]]] = {}
    for record in records:
        groups.setdefault((record["maze"], record["filter"]), []).append(record)
    rows = []
    for (maze, name), group in groups.items():
        distances = [r["distance_to_exact"] for r in group]
        converged = [r["converged_at"] for r in group if r["converged_at"] is not None]
        rows.append(
            {
                "maze": maze,
                "filter": name,
                "runs": len(group),
                "mean_distance_to_exact": statistics.fmean(distances),
                "interval": bootstrap_interval(distances, "mean"),
                "worst_distance": max(distances),
                "converged_share": len(converged) / len(group),
                "converged_interval": wilson_interval(len(converged), len(group)),
                "median_convergence_step": statistics.median(converged) if converged else None,
            }
        )
    return rows


def accuracy_table(summary: Sequence[dict[str, Any]]) -> str:
    """The summary (`accuracy_summary`) as a table, per maze and filter: the mean (and worst) distance to the
    exact posterior mean over the second half of the steps with its 95% bootstrap interval, the converged
    share with its Wilson interval and the median convergence step."""
    columns = [
        ("maze", lambda s: s["maze"]),
        ("filter", lambda s: s["filter"]),
        ("runs", lambda s: str(s["runs"])),
        ("distance to exact mean", lambda s: f"{s['mean_distance_to_exact']:.3f}"),
        ("worst run", lambda s: f"{s['worst_distance']:.3f}"),
        ("95% CI", lambda s: format_interval(*s["interval"])),
        ("converged", lambda s: f"{s['converged_share']:.0%}"),
        ("95% CI", lambda s: format_interval(*s["converged_interval"], "{:.0%}")),
        ("median conv. step", lambda s: format_number(s["median_convergence_step"], "{:g}")),
    ]
    note = "[95% intervals: the mean by percentile bootstrap (B = 2000, seeded), the share by Wilson score]"
    return column_table(columns, summary) + "\n" + note
