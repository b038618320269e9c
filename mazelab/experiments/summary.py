"""A study's statistics per setting and filter: the mean final error with its 95% t-interval, the
converged share, the median convergence step; the table, the CSV and the figure."""

from __future__ import annotations

import csv
import io
import math
import statistics
from collections.abc import Sequence
from dataclasses import asdict, dataclass, fields
from pathlib import Path

import numpy as np

from mazelab.experiments.runs import FINAL_SHARE, is_particle_filter
from mazelab.experiments.stats import CONFIDENCE_LEVEL, t_interval
from mazelab.experiments.study import RunRecord, StudySetting
from mazelab.experiments.tables import csv_cell, format_optional, format_table, format_value, pyplot, save_figure


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
        f"RPF N_T = {setting.threshold:g} N_S, RPF bandwidth {format_value(setting.bandwidth)}, "
        f"{steps} steps{kidnapping}, {runs} runs per setting"
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
            *(format_value(s.setting.value(p)) for p in varied),
            s.filter,
            str(s.runs),
            f"{s.mean_final_error:.3f}",
            "-" if math.isnan(low) else f"[{low:.3f}, {high:.3f}]",
            f"{s.converged_share:.0%}",
            format_optional(s.median_convergence_step, "{:g}"),
            f"{s.ms_per_step:.2f}",
        ]
        if kidnapped:
            row += [format_optional(s.relocalised_share, "{:.0%}"), format_optional(s.median_steps_to_recover, "{:g}")]
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
        writer.writerow({k: csv_cell(v) for k, v in asdict(record).items()})
    return buffer.getvalue()


def plot_study(
    summaries: Sequence[StudySummary], varied: Sequence[str], path: Path, title: str, *, replace: bool = True
) -> None:
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
    save_figure(figure, path, replace=replace)


def _setting_label(setting: StudySetting, parameter: str) -> str:
    value = format_value(setting.value(parameter))
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


__all__ = [
    "CSV_COLUMNS",
    "StudySummary",
    "describe_setting",
    "plot_study",
    "recovery_summary",
    "study_csv",
    "study_table",
    "summarise_study",
]
