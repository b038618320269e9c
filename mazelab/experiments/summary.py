"""A study's statistics per setting and filter: the mean and median final error with percentile
bootstrap intervals, the converged share with its Wilson interval, the median convergence step; the
table and the CSV (the figure: mazelab.experiments.study_plot)."""

from __future__ import annotations

import math
import statistics
from collections.abc import Sequence
from dataclasses import asdict, dataclass, fields

from mazelab.experiments.runs import is_particle_filter
from mazelab.experiments.stats import (
    BOOTSTRAP_SAMPLES,
    CONFIDENCE_LEVEL,
    bootstrap_interval,
    wilson_interval,
)
from mazelab.experiments.study import RunRecord, StudySetting, option_cells, takes_parameter
from mazelab.experiments.tables import format_optional, format_table, format_value, records_csv

Interval = tuple[float, float]


# -- a study's statistics ---------------------------------------------------------------------------
@dataclass
class StudySummary:
    """One setting and filter over its runs."""

    setting_index: int
    setting: StudySetting
    filter: str
    runs: int
    mean_final_error: float
    interval: Interval  # percentile bootstrap interval for the mean last-20% error; NaN with one run
    converged_share: float  # share of the runs with a convergence step
    median_convergence_step: float | None  # median over the converged runs; None if none converged
    ms_per_step: float
    relocalised_share: float | None = None  # share of the runs re-localised; None without a kidnapping
    median_steps_to_recover: float | None = None  # median over the runs that recovered; None if none did
    mean_particle_count: float = math.nan
    median_final_error: float = math.nan
    median_interval: Interval = (math.nan, math.nan)  # percentile bootstrap interval for the median
    converged_interval: Interval = (math.nan, math.nan)  # Wilson interval for the converged share
    relocalised_interval: Interval | None = None  # Wilson interval for the re-localised share
    run_seconds: float = math.nan  # mean wall time per run

    def as_dict(self) -> dict[str, object]:
        """The summary as plain values (the setting's parameters spelled out), for a record or pandas."""
        data = {k: v for k, v in asdict(self).items() if k != "setting"}
        data["setting"] = data.pop("setting_index")
        for parameter in ("maze", "sigma", "delta", "particles", "threshold", "recovery", "bandwidth", "estimate"):
            data[parameter] = self.setting.value(parameter)
        data.update(option_cells(self.setting))  # the setting's other filter options, one key each
        return data


def summarise_study(records: Sequence[RunRecord], settings: Sequence[StudySetting]) -> list[StudySummary]:
    """Per setting and filter (in the records' order): the statistics of the study's table."""
    groups: dict[tuple[int, str], list[RunRecord]] = {}
    for record in records:
        groups.setdefault((record.setting, record.filter), []).append(record)
    summaries = []
    for (index, name), group in groups.items():
        finals = [r.final_error for r in group]
        converged = [r.converged_at for r in group if r.converged_at is not None]
        relocalised, steps_to_recover = recovery_summary(group)
        summaries.append(
            StudySummary(
                index,
                settings[index - 1],
                name,
                len(group),
                statistics.fmean(finals),
                bootstrap_interval(finals, "mean"),
                len(converged) / len(group),
                statistics.median(converged) if converged else None,
                statistics.fmean(r.ms_per_step for r in group),
                relocalised,
                steps_to_recover,
                statistics.fmean(r.mean_particle_count for r in group),
                statistics.median(finals),
                bootstrap_interval(finals, "median"),
                wilson_interval(len(converged), len(group)),
                None if relocalised is None else wilson_interval(sum(bool(r.relocalised) for r in group), len(group)),
                statistics.fmean(r.run_seconds for r in group),
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


def describe_setting(
    setting: StudySetting, steps: int, runs: int, kidnap_at: int | None = None, varied: Sequence[str] = ()
) -> str:
    """The fixed parameters of a study in one line (a varied one is left out: `describe_varied` says it)."""
    parts = {
        "maze": f"maze {setting.maze.label}",
        "sigma": f"sigma {setting.sigma:g}",
        "delta": f"delta {setting.delta:g}",
        "particles": f"{setting.particles} particles",
        "threshold": f"RPF N_T = {setting.threshold:g} N_S",
        "bandwidth": f"RPF bandwidth {format_value(setting.bandwidth)}",
        "estimate": f"{setting.estimate} estimate",
    }
    kidnapping = "" if kidnap_at is None else f", kidnapped at step {kidnap_at}"
    if kidnap_at is not None and "recovery" not in varied:
        kidnapping += f", recovery {setting.recovery}"
    fixed = [text for parameter, text in parts.items() if parameter not in varied]
    return ", ".join([*fixed, f"{steps} steps{kidnapping}", f"{runs} runs per setting"])


def describe_varied(settings: Sequence[StudySetting], varied: Sequence[str]) -> str:
    """The varied parameters with their values: 'varied: sigma 0.2, 0.4; bandwidth optimal, multimodal'."""
    if not varied:
        return ""
    values = {p: list(dict.fromkeys(format_value(s.value(p)) for s in settings)) for p in varied}
    return "varied: " + "; ".join(f"{p} {', '.join(v)}" for p, v in values.items())


def interval_note() -> str:
    """The line under the table that names its intervals' methods."""
    return (
        f"[{CONFIDENCE_LEVEL:.0%} intervals: mean and median by percentile bootstrap (B = {BOOTSTRAP_SAMPLES}, "
        "seeded), shares by Wilson score; '-' in a parameter's column: the filter does not take it]"
    )


def _interval(low: float, high: float, spec: str = "{:.3f}") -> str:
    return "-" if math.isnan(low) else f"[{spec.format(low)}, {spec.format(high)}]"


def study_table(summaries: Sequence[StudySummary], varied: Sequence[str], kld: bool = False) -> str:
    """A row per setting and filter: the varied parameters ('-' where the filter does not take one),
    then the statistics with their intervals; with a kidnapping the re-localised share and median
    steps to recover, with `kld` the mean particle count."""
    kidnapped = any(s.relocalised_share is not None for s in summaries)
    ci = f"{CONFIDENCE_LEVEL:.0%} CI"
    headers = [
        *varied,
        "filter",
        "runs",
        "mean last-20% error",
        ci,
        "median",
        ci,
        "converged",
        ci,
        "median conv. step",
        "ms/step",
        *(["re-localised", ci, "median steps to recover"] if kidnapped else []),
        *(["mean N"] if kld else []),
    ]
    rows = []
    for s in summaries:
        row = [
            *(format_value(s.setting.value(p)) if takes_parameter(s.filter, p) else "-" for p in varied),
            s.filter,
            str(s.runs),
            f"{s.mean_final_error:.3f}",
            _interval(*s.interval),
            f"{s.median_final_error:.3f}",
            _interval(*s.median_interval),
            f"{s.converged_share:.0%}",
            _interval(*s.converged_interval, spec="{:.0%}"),
            format_optional(s.median_convergence_step, "{:g}"),
            f"{s.ms_per_step:.2f}",
        ]
        if kidnapped:
            row += [
                format_optional(s.relocalised_share, "{:.0%}"),
                _interval(*(s.relocalised_interval or (math.nan, math.nan)), spec="{:.0%}"),
                format_optional(s.median_steps_to_recover, "{:g}"),
            ]
        if kld:
            row.append(f"{s.mean_particle_count:.0f}" if is_particle_filter(s.filter) else "-")
        rows.append(row)
    return format_table(headers, rows) + "\n" + interval_note()


CSV_COLUMNS = [f.name for f in fields(RunRecord) if f.name != "options"]  # then a column per other option
# how to read the CSV's seeds back whole: maze_seed is empty for a maze file, so pandas would read the
# column as float64 and round a seed above 2**53 (the record says so; pandas: dtype={"maze_seed": str})
CSV_DTYPES = {"seed": "int64", "maze_seed": "str (empty for a maze file; as float64 a seed loses digits)"}


def study_csv(records: Sequence[RunRecord], columns: Sequence[str] = CSV_COLUMNS) -> str:
    """One row per run and filter, columns CSV_COLUMNS then the study's other options; an empty cell for
    None and NaN."""
    return records_csv(records, columns)


__all__ = [
    "CSV_COLUMNS",
    "CSV_DTYPES",
    "StudySummary",
    "describe_setting",
    "describe_varied",
    "interval_note",
    "recovery_summary",
    "study_csv",
    "study_table",
    "summarise_study",
]
