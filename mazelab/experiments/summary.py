"""A study's statistics per setting and filter: the mean final error with its BCa bootstrap interval
and the median with its percentile one, the converged share with its Wilson interval, the Kaplan-Meier median
convergence step (the runs that never converge count, as censored), with `--reference grid` the
distance to the exact posterior, with `--paired NAME` the paired difference to that filter; the
table, the rows' CSV and the summary CSV (the figure: mazelab.experiments.study_plot).

Converged, defined: the error stays below CONVERGENCE_RADIUS for at least the last K steps, K the
last-20% window (`convergence_window`, the steps `final_error` averages): a run that only gets below
the radius near its end is not counted, and "converged" agrees with a small last-20% error."""

from __future__ import annotations

import math
import statistics
from collections.abc import Sequence
from dataclasses import asdict, dataclass, fields
from pathlib import Path
from typing import Any

from mazelab.declaration import show_value
from mazelab.experiments.runs import FINAL_SHARE, is_particle_filter
from mazelab.experiments.stats import (
    BOOTSTRAP_SAMPLES,
    CONFIDENCE_LEVEL,
    MEAN_METHOD,
    MEDIAN_METHOD,
    bootstrap_interval,
    km_median,
    paired_difference,
    wilson_interval,
)
from mazelab.experiments.study import (
    BASE_PARAMETERS,
    RunRecord,
    StudySetting,
    option_cells,
    study_parameters,
    takes_parameter,
    varied_parameters,
)
from mazelab.experiments.tables import (
    format_interval,
    format_number,
    format_optional,
    format_table,
    records_csv,
)
from mazelab.model import CONVERGENCE_RADIUS
from mazelab.registry import described, resolve_filter

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
    interval: Interval  # BCa bootstrap interval for the mean last-20% error; NaN with one run
    converged_share: float  # share of the runs below the radius for at least the last K steps (`converged`)
    median_convergence_step: float | None  # Kaplan-Meier median (never-converged runs censored); None: not reached
    ms_per_step: float
    relocalised_share: float | None = None  # share of the runs re-localised; None without a kidnapping
    median_steps_to_recover: float | None = None  # median over the runs that recovered; None if none did
    mean_particle_count: float = math.nan
    median_final_error: float = math.nan
    median_interval: Interval = (math.nan, math.nan)  # percentile bootstrap interval for the median
    converged_interval: Interval = (math.nan, math.nan)  # Wilson interval for the converged share
    relocalised_interval: Interval | None = None  # Wilson interval for the re-localised share
    run_seconds: float = math.nan  # mean wall time per run
    convergence_interval: Interval = (math.nan, math.nan)  # the KM median's interval; NaN: not reached
    last_convergence_step: int = 0  # the last step a convergence can count from (steps - K + 1): the censoring time
    distance_to_exact: float = math.nan  # mean over the runs of the distance to the exact posterior mean
    distance_interval: Interval = (math.nan, math.nan)  # its BCa bootstrap interval
    paired_with: str | None = None  # the filter the paired difference is taken to (`--paired`)
    paired_runs: int = 0  # runs in both (the pairs)
    mean_difference: float = math.nan  # mean over the pairs of (this filter's - paired_with's) last-20% error
    difference_interval: Interval = (math.nan, math.nan)  # its paired BCa bootstrap interval
    mean_log_evidence: float = math.nan  # mean over the runs of log p(z_1:K) as the filter estimates it
    log_evidence_se: float = math.nan  # its standard error: the runs' standard deviation / sqrt(runs)
    log_evidence_caveat: str = ""  # why the filter's estimate is not of p(z_1:K) under the model ("": it is)
    backend: str = ""  # the backend its runs ran on (their ms_per_step's)

    def as_dict(self) -> dict[str, object]:
        """The summary as plain values (the setting's parameters spelled out), for a record or pandas."""
        data = {k: v for k, v in asdict(self).items() if k != "setting"}
        data["setting"] = data.pop("setting_index")
        for parameter in BASE_PARAMETERS:
            data[parameter] = self.setting.value(parameter)
        data.update(option_cells(self.setting, self.filter))  # every option the filter ran with, one key each
        return data


def summarise_study(
    records: Sequence[RunRecord], settings: Sequence[StudySetting], paired: str | None = None
) -> list[StudySummary]:
    """Per setting and filter (in the records' order): the statistics of the study's table; with
    `paired` (a filter of the study), each other filter's paired difference to it (`paired_runs`)."""
    groups: dict[tuple[int, str], list[RunRecord]] = {}
    for record in records:
        groups.setdefault((record.setting, record.filter), []).append(record)
    summaries = [summarise_group(index, settings[index - 1], name, group) for (index, name), group in groups.items()]
    reference = None if paired is None else resolve_filter(paired).name
    for s in summaries:
        if reference is not None and s.filter != reference and pairs_exactly(s.filter, reference, settings):
            group = groups[s.setting_index, s.filter]
            pairs = paired_finals(group, records, settings, reference)
            if pairs:
                mine, theirs = zip(*pairs, strict=True)
                s.paired_with, s.paired_runs = reference, len(pairs)
                s.mean_difference, s.difference_interval = paired_difference(mine, theirs, method=MEAN_METHOD)
    return summaries


def summarise_group(index: int, setting: StudySetting, name: str, group: Sequence[RunRecord]) -> StudySummary:
    """One setting and filter's statistics over its runs (`group`, its rows)."""
    finals, runs = [r.final_error for r in group], len(group)
    last = last_convergence_step(group[0].steps)
    converged = [converged_within(r.converged_at, r.steps) for r in group]
    median_step, step_interval = km_median([min(r.converged_at or last, last) for r in group], converged)
    relocalised, steps_to_recover = recovery_summary(group)
    relocalised_interval = None if relocalised is None else wilson_interval(sum(bool(r.relocalised) for r in group),
                                                                            runs)  # fmt: skip
    summary = StudySummary(
        index, setting, name, runs, statistics.fmean(finals), bootstrap_interval(finals, "mean", method=MEAN_METHOD),
        sum(converged) / runs, None if math.isnan(median_step) else median_step,
        statistics.fmean(r.ms_per_step for r in group), relocalised, steps_to_recover,
        statistics.fmean(r.mean_particle_count for r in group), statistics.median(finals),
        bootstrap_interval(finals, "median", method=MEDIAN_METHOD), wilson_interval(sum(converged), runs),
        relocalised_interval, statistics.fmean(r.run_seconds for r in group), step_interval, last,
        *_mean_and_interval([r.distance_to_exact for r in group]),
    )  # fmt: skip
    summary.mean_log_evidence, summary.log_evidence_se = _mean_and_error([r.log_evidence for r in group])
    summary.log_evidence_caveat, summary.backend = group[0].log_evidence_caveat, group[0].backend
    return summary


def convergence_window(steps: int) -> int:
    """K, the steps a run must stay below the radius to count as converged: the last-20% window
    (`final_error` averages the same steps), at least one."""
    return max(1, int(steps * FINAL_SHARE))


def last_convergence_step(steps: int) -> int:
    """The last step a run's convergence can count from: steps - K + 1 (K = `convergence_window`);
    a run not converged by then is censored there (for the Kaplan-Meier median)."""
    return steps - convergence_window(steps) + 1


def converged_within(converged_at: int | None, steps: int) -> bool:
    """Converged: below the radius from `converged_at` on, for at least the last K steps."""
    return converged_at is not None and converged_at <= last_convergence_step(steps)


def _mean_and_interval(values: Sequence[float]) -> tuple[float, Interval]:
    """The mean of the finite values with its BCa bootstrap interval; NaN when there are none."""
    finite = [v for v in values if not math.isnan(v)]
    if not finite:
        return math.nan, (math.nan, math.nan)
    return statistics.fmean(finite), bootstrap_interval(finite, "mean", method=MEAN_METHOD)


def _mean_and_error(values: Sequence[float]) -> tuple[float, float]:
    """The mean of the finite values and its standard error (NaN with fewer than two)."""
    finite = [v for v in values if math.isfinite(v)]
    if not finite:
        return math.nan, math.nan
    error = statistics.stdev(finite) / math.sqrt(len(finite)) if len(finite) > 1 else math.nan
    return statistics.fmean(finite), error


def pairs_exactly(name: str, reference: str, settings: Sequence[StudySetting]) -> bool:
    """Whether a filter's setting fixes the reference's: not when the reference takes a varied parameter
    the filter does not (the grid filter against SIR with several particle counts: which N?)."""
    varied = varied_parameters(settings)
    return not any(takes_parameter(reference, p) and not takes_parameter(name, p) for p in varied)


def paired_finals(
    group: Sequence[RunRecord], records: Sequence[RunRecord], settings: Sequence[StudySetting], reference: str
) -> list[tuple[float, float]]:
    """(this filter's, the reference filter's) last-20% error per run both ran on the same scenario:
    the reference's record of the same run in a setting that agrees on every parameter the reference
    takes (it runs once per such combination, `filters_per_setting`, so it may be another setting's)."""
    parameters = study_parameters(settings)

    def key(setting: StudySetting) -> tuple[str, ...]:
        return tuple(repr(setting.value(p)) for p in parameters if takes_parameter(reference, p))

    theirs = {(key(settings[r.setting - 1]), r.run): r.final_error for r in records if r.filter == reference}
    wanted = key(settings[group[0].setting - 1])
    return [(r.final_error, theirs[wanted, r.run]) for r in group if (wanted, r.run) in theirs]


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
    """The fixed parameters of a study in one line: the maze, the model's, and each option the study
    sets (a varied one is left out: `describe_varied` says it; an option not set runs at its default)."""
    parts = {
        "maze": f"maze {setting.maze.label}",
        "sigma": f"sigma {setting.sigma:g}",
        "delta": f"delta {setting.delta:g}",
        "particles": f"{setting.particles} particles",
        **{name: f"{name} {show_value(value)}" for name, value in setting.options},
    }
    kidnapping = "" if kidnap_at is None else f", kidnapped at step {kidnap_at}"
    fixed = [text for parameter, text in parts.items() if parameter not in varied]
    return ", ".join([*fixed, f"{steps} steps{kidnapping}", f"{runs} runs per setting"])


def describe_varied(settings: Sequence[StudySetting], varied: Sequence[str]) -> str:
    """The varied parameters with their values: 'varied: sigma 0.2, 0.4; bandwidth optimal, multimodal'."""
    if not varied:
        return ""
    values = {p: list(dict.fromkeys(show_value(s.value(p)) for s in settings)) for p in varied}
    return "varied: " + "; ".join(f"{p} {', '.join(v)}" for p, v in values.items())


def interval_note(summaries: Sequence[StudySummary] = ()) -> str:
    """The lines under the table: its intervals' methods, what converged means, and the paired columns."""
    last = max((s.last_convergence_step for s in summaries), default=0)
    steps = f"from step {last} on at the latest" if last else "for at least the last 20% of the steps"
    lines = [
        f"[{CONFIDENCE_LEVEL:.0%} intervals: means by BCa bootstrap, medians by percentile bootstrap (B = "
        f"{BOOTSTRAP_SAMPLES}, seeded), shares by Wilson score; '-' in a parameter's column: the filter does not "
        "take it]",
        f"[converged: the error stays below {CONVERGENCE_RADIUS:g} for at least the last 20% of the steps "
        f"({steps}); median conv. step: Kaplan-Meier, the runs that never converge censored there "
        f"('>{last or 'N'}': not reached), its interval from the log-log band]",
    ]
    caveats = {described(s.filter).label: s.log_evidence_caveat for s in summaries if s.log_evidence_caveat}
    lines += [f"[* {label}: the log evidence is {why}]" for label, why in caveats.items()]
    backend = ", ".join(sorted({s.backend for s in summaries}))
    lines.append(
        f"[log p(z_1:K): the mean over the runs of each run's log evidence, (its standard error); ms/step: "
        f"one run's filter step on the {backend} backend, a step of runs advanced together shared out]"
    )
    reference = next((s.paired_with for s in summaries if s.paired_with), None)
    if reference is not None:
        label = described(reference).label
        lines.append(
            f"[diff. vs {label}: the filter's last-20% error minus {label}'s on the same runs (negative: "
            f"smaller), mean over the pairs, paired BCa bootstrap interval (the runs resampled as pairs)]"
        )
    return "\n".join(lines)


def _step(value: float | None, last: int) -> str:
    """A KM median step, or '>last' when not reached."""
    return f">{last}" if value is None or math.isnan(value) else f"{value:g}"


def study_table(summaries: Sequence[StudySummary], varied: Sequence[str], kld: bool = False) -> str:
    """A row per setting and filter: the varied parameters ('-' where the filter does not take one), the
    filter's label, then the statistics with their intervals, the mean log evidence with its standard
    error ('*' where it is not of p(z_1:K) under the model, a line under the table says why) and the time
    per step with its backend; with a kidnapping the re-localised share and median steps to recover, with
    `kld` the mean particle count, with a reference or a paired filter their columns."""
    reference = next((s.paired_with for s in summaries if s.paired_with), None)
    backends = {s.backend for s in summaries}
    ci, nan = f"{CONFIDENCE_LEVEL:.0%} CI", (math.nan, math.nan)
    columns = [
        *((p, lambda s, p=p: show_value(s.setting.value(p)) if takes_parameter(s.filter, p) else "-")
          for p in varied),
        ("filter", lambda s: described(s.filter).label), ("runs", lambda s: str(s.runs)),
        ("mean last-20% error", lambda s: f"{s.mean_final_error:.3f}"), (ci, lambda s: format_interval(*s.interval)),
        ("median", lambda s: f"{s.median_final_error:.3f}"), (ci, lambda s: format_interval(*s.median_interval)),
        ("converged", lambda s: f"{s.converged_share:.0%}"),
        (ci, lambda s: format_interval(*s.converged_interval, spec="{:.0%}")),
        ("median conv. step", lambda s: _step(s.median_convergence_step, s.last_convergence_step)),
        (ci, lambda s: _step_interval(s.convergence_interval, s.last_convergence_step)),
        ("log p(z_1:K) (SE)", _evidence),
        (f"ms/step, {next(iter(backends))}" if len(backends) == 1 else "ms/step, backend",
         lambda s: f"{s.ms_per_step:.2f}" + ("" if len(backends) == 1 else f" {s.backend}")),
    ]  # fmt: skip
    if any(s.relocalised_share is not None for s in summaries):
        columns += [("re-localised", lambda s: format_optional(s.relocalised_share, "{:.0%}")),
                    (ci, lambda s: format_interval(*(s.relocalised_interval or nan), spec="{:.0%}")),
                    ("median steps to recover", lambda s: format_optional(s.median_steps_to_recover, "{:g}")),
                    ]  # fmt: skip
    if kld:
        columns.append(("mean N", lambda s: f"{s.mean_particle_count:.0f}" if is_particle_filter(s.filter) else "-"))
    if any(not math.isnan(s.distance_to_exact) for s in summaries):
        columns += [("dist. to exact", lambda s: format_number(s.distance_to_exact, "{:.3f}")),
                    (ci, lambda s: format_interval(*s.distance_interval))]  # fmt: skip
    if reference:
        columns += [(f"diff. vs {described(reference).label}",
                     lambda s: format_number(s.mean_difference, "{:+.3f}")),
                    (ci, lambda s: format_interval(*s.difference_interval, spec="{:+.3f}"))]  # fmt: skip
    rows = [[cell(s) for _, cell in columns] for s in summaries]
    return format_table([header for header, _ in columns], rows) + "\n" + interval_note(summaries)


def _evidence(s: StudySummary) -> str:
    """'-71.6 (0.4)': the mean log evidence and its standard error, '*' where it is not of p(z_1:K)."""
    if math.isnan(s.mean_log_evidence):
        return "-"
    error = "" if math.isnan(s.log_evidence_se) else f" ({s.log_evidence_se:.1f})"
    return f"{s.mean_log_evidence:.1f}{error}" + ("*" if s.log_evidence_caveat else "")


def _step_interval(bounds: Interval, last: int) -> str:
    """The KM median's interval: '-' when even its lower end is not reached, '>last' for an upper one."""
    low, high = bounds
    return "-" if math.isnan(low) else f"[{low:g}, {_step(high, last)}]"


CSV_COLUMNS = [f.name for f in fields(RunRecord) if f.name != "options"]  # then a column per declared option
# how to read the CSV's seeds back whole: maze_seed is empty for a maze file, so pandas would read the
# column as float64 and round a seed above 2**53 (the record says so; pandas: dtype={"maze_seed": str})
CSV_DTYPES = {"seed": "int64", "maze_seed": "str (empty for a maze file; as float64 a seed loses digits)"}

# the summary CSV's statistics, after `setting`, the study's parameters and `filter`: (column, how to read it)
SUMMARY_STATISTICS: tuple[tuple[str, Any], ...] = (
    ("runs", lambda s: s.runs),
    ("mean_final_error", lambda s: s.mean_final_error),
    ("mean_final_error_low", lambda s: s.interval[0]),
    ("mean_final_error_high", lambda s: s.interval[1]),
    ("median_final_error", lambda s: s.median_final_error),
    ("median_final_error_low", lambda s: s.median_interval[0]),
    ("median_final_error_high", lambda s: s.median_interval[1]),
    ("converged_share", lambda s: s.converged_share),
    ("converged_low", lambda s: s.converged_interval[0]),
    ("converged_high", lambda s: s.converged_interval[1]),
    ("last_convergence_step", lambda s: s.last_convergence_step),
    ("median_convergence_step", lambda s: s.median_convergence_step),
    ("median_convergence_step_low", lambda s: s.convergence_interval[0]),
    ("median_convergence_step_high", lambda s: s.convergence_interval[1]),
    ("mean_log_evidence", lambda s: s.mean_log_evidence),
    ("log_evidence_se", lambda s: s.log_evidence_se),
    ("log_evidence_caveat", lambda s: s.log_evidence_caveat or None),
    ("ms_per_step", lambda s: s.ms_per_step),
    ("backend", lambda s: s.backend),
    ("run_seconds", lambda s: s.run_seconds),
    ("mean_particle_count", lambda s: s.mean_particle_count),
    ("relocalised_share", lambda s: s.relocalised_share),
    ("relocalised_low", lambda s: (s.relocalised_interval or (None, None))[0]),
    ("relocalised_high", lambda s: (s.relocalised_interval or (None, None))[1]),
    ("median_steps_to_recover", lambda s: s.median_steps_to_recover),
    ("distance_to_exact", lambda s: s.distance_to_exact),
    ("distance_to_exact_low", lambda s: s.distance_interval[0]),
    ("distance_to_exact_high", lambda s: s.distance_interval[1]),
    ("paired_with", lambda s: s.paired_with),
    ("paired_runs", lambda s: s.paired_runs or None),
    ("mean_difference", lambda s: s.mean_difference),
    ("difference_low", lambda s: s.difference_interval[0]),
    ("difference_high", lambda s: s.difference_interval[1]),
)


def summary_rows(summaries: Sequence[StudySummary], columns: Sequence[str] = ()) -> list[dict[str, Any]]:
    """One dict per setting and filter, the summary CSV's columns: `setting`, the maze and the model's
    parameters (None where the filter does not take one, the table's '-'), then the option `columns`
    (the study's, `study.option_columns`: each the value the filter ran with, None where it does not
    declare the option), `filter`, `label` (the registry's), then SUMMARY_STATISTICS, each interval as
    _low and _high."""
    rows = []
    for s in summaries:
        cells = option_cells(s.setting, s.filter)
        rows.append(
            {
                "setting": s.setting_index,
                **{p: s.setting.value(p) if takes_parameter(s.filter, p) else None for p in BASE_PARAMETERS},
                **{name: cells.get(name) for name in columns},
                "filter": s.filter,
                "label": described(s.filter).label,
                **{name: read(s) for name, read in SUMMARY_STATISTICS},
            }
        )
    return rows


def summary_csv(summaries: Sequence[StudySummary], columns: Sequence[str] = ()) -> str:
    """The summary rows (`summary_rows`) as CSV: an empty cell for None, NaN and 'not reached'."""
    header = ["setting", *BASE_PARAMETERS, *columns, "filter", "label", *(n for n, _ in SUMMARY_STATISTICS)]
    return records_csv(summary_rows(summaries, columns), header)


def summary_path(csv_path: Path) -> Path:
    """Where the summary CSV goes by default: NAME.summary.csv beside the rows' NAME.csv."""
    return csv_path.with_name(f"{csv_path.stem}.summary.csv")
