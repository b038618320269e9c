"""A study's statistics per setting and filter (`StudySummary`), the table, the rows' CSV and the summary
CSV (the figure: mazelab.experiments.study_plot), with intervals that fit the quantities (no scipy; Student's
t-interval for comparison: benchmarks/interval_coverage.py): a mean or median of errors (heavy-tailed, never
negative), the bootstrap, percentile or BCa (`bootstrap_interval`), paired for the difference of two filters
on the same runs (`paired_difference`); a share, the Wilson score interval (`wilson_interval`); the
convergence step, which some runs never reach, the Kaplan-Meier median and its log-log band (`km_median`).
Converged: the error stays below CONVERGENCE_RADIUS for at least the last-20% window (`converged_within`).
"""

from __future__ import annotations

import functools
import math
import statistics
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, fields
from statistics import NormalDist
from typing import Any

import numpy as np

from mazelab.declaration import show_value
from mazelab.experiments.runs import FIGURES, FINAL_SHARE
from mazelab.experiments.study import (
    BASE_PARAMETERS,
    RunRecord,
    StudySetting,
    option_cells,
    study_parameters,
    takes_parameter,
    varied_parameters,
)
from mazelab.experiments.tables import beside, column_table, format_interval, format_number, records_csv
from mazelab.model import CONVERGENCE_RADIUS
from mazelab.registry import described, resolve_filter

CONFIDENCE_LEVEL = 0.95  # of every interval of a study's table
BOOTSTRAP_SAMPLES = 2000  # B, the bootstrap's resamples
BOOTSTRAP_SEED = 20240531  # the bootstrap's resamples are drawn from this seed: the same rows, the same interval
MEAN_METHOD = "bca"  # a study's means (errors, distances, paired differences): BCa (benchmarks/interval_coverage.py)
MEDIAN_METHOD = "percentile"  # its medians: percentile (BCa's jackknife acceleration does not suit a median)
_RESAMPLES = f"B = {BOOTSTRAP_SAMPLES} resamples of the runs, seed {BOOTSTRAP_SEED}"
INTERVAL_METHODS = {
    "mean": f"a study's table: BCa bootstrap, {_RESAMPLES} (accuracy's table: percentile bootstrap)",
    "median": f"percentile bootstrap, {_RESAMPLES}",
    "paired difference": f"paired BCa bootstrap (the runs resampled as pairs), {_RESAMPLES}",
    "share": "Wilson score interval",
    "convergence step": "Kaplan-Meier median, the runs that never converge censored; interval from the log-log band",
}


INTERVAL_KINDS = ("percentile", "bca")  # what bootstrap_interval's `method` takes
REDUCERS: dict[str, Callable[..., np.ndarray]] = {"mean": np.mean, "median": np.median}


def bootstrap_interval(
    values: Sequence[float],
    statistic: str = "mean",
    level: float = CONFIDENCE_LEVEL,
    samples: int = BOOTSTRAP_SAMPLES,
    seed: int = BOOTSTRAP_SEED,
    method: str = "percentile",
) -> tuple[float, float]:
    """Bootstrap interval for the mean or median of `values`: percentile (the default) or BCa.

    Parameters
    ----------
    values : sequence of float
        One value per run (NaN values are left out).
    statistic : str
        "mean" or "median".
    level : float
        The coverage, e.g. 0.95: the (1 - level) / 2 and (1 + level) / 2 quantiles of the statistic
        over `samples` resamples (with replacement, of the same size) drawn from `seed`.
    method : str
        "percentile", or "bca": the same resamples' quantiles at levels moved by the bias correction
        z0 and the jackknife acceleration a (`bca_levels`).

    Returns
    -------
    (low, high), within [min(values), max(values)]; (NaN, NaN) for fewer than two values.
    """
    if method not in INTERVAL_KINDS:
        raise ValueError(f"method must be one of {', '.join(INTERVAL_KINDS)}, got {method!r}")
    data = np.asarray(values, dtype=float)
    data = data[~np.isnan(data)]
    if len(data) < 2:
        return math.nan, math.nan
    reduce = REDUCERS[statistic]
    estimates = resampled(data, reduce, samples, seed)
    levels = [(1 - level) / 2, (1 + level) / 2]
    if method == "bca":
        levels = bca_levels(data, reduce, estimates, levels)
    low, high = np.quantile(estimates, levels)
    return float(low), float(high)


def resampled(data: np.ndarray, reduce: Callable[..., np.ndarray], samples: int, seed: int) -> np.ndarray:
    """The statistic of `samples` resamples of `data` (with replacement, of its size) from `seed`, (samples,)."""
    picks = np.random.default_rng(seed).integers(0, len(data), size=(samples, len(data)))
    return reduce(data[picks], axis=1)


def bca_levels(
    data: np.ndarray, reduce: Callable[..., np.ndarray], estimates: np.ndarray, levels: Sequence[float]
) -> list[float]:
    """The BCa interval's quantile levels (Efron & Tibshirani 1993, section 14.3): alpha ->
    Phi(z0 + (z0 + z_alpha) / (1 - a (z0 + z_alpha))), with the bias correction z0 = Phi^-1(share of
    the resampled statistics below the observed one, ties counted half) and the acceleration
    a = sum(d^3) / (6 (sum d^2)^1.5), d the jackknife statistics' deviations from their mean.
    Equal to `levels` (the percentile interval) when z0 = a = 0."""
    normal = NormalDist()
    observed = float(reduce(data))
    below = (np.count_nonzero(estimates < observed) + 0.5 * np.count_nonzero(estimates == observed)) / len(estimates)
    below = min(max(below, 0.5 / len(estimates)), 1 - 0.5 / len(estimates))  # z0 finite
    z0 = normal.inv_cdf(below)
    jackknife = leave_one_out(data, reduce)
    d = jackknife.mean() - jackknife
    spread = float((d * d).sum())
    a = float((d**3).sum()) / (6 * spread**1.5) if spread > 0 else 0.0
    moved = []
    for alpha in levels:
        z = z0 + normal.inv_cdf(alpha)
        moved.append(normal.cdf(z0 + z / (1 - a * z)))
    return moved


def leave_one_out(data: np.ndarray, reduce: Callable[..., np.ndarray]) -> np.ndarray:
    """The jackknife: the mean or median of `data` without each value in turn, (n,); O(n log n)."""
    n = len(data)
    if reduce is np.mean:
        return (data.sum() - data) / (n - 1)
    order = np.argsort(data, kind="stable")
    ranks = np.empty(n, dtype=int)
    ranks[order] = np.arange(n)
    ordered = data[order]

    def kept(k: int) -> np.ndarray:  # the k-th smallest of the n - 1 values left, for each left-out one
        return ordered[np.where(k < ranks, k, k + 1)]

    m = n - 1
    return kept(m // 2) if m % 2 else (kept(m // 2 - 1) + kept(m // 2)) / 2


def paired_difference(
    values: Sequence[float],
    reference: Sequence[float],
    level: float = CONFIDENCE_LEVEL,
    samples: int = BOOTSTRAP_SAMPLES,
    seed: int = BOOTSTRAP_SEED,
    method: str = "percentile",
) -> tuple[float, tuple[float, float]]:
    """The mean difference values - reference over pairs (one pair per run: the same scenario) and its
    paired bootstrap interval: the runs are resampled, each keeping its pair, so the luck the two
    share (an easy or a hard walk) cancels. Pairs with a NaN are left out; (NaN, (NaN, NaN)) for no pair.

    The unpaired interval (each filter's runs resampled apart) is wider when the two are positively
    correlated, as filters on the same walk are: its variance adds both spreads, the paired one subtracts
    twice their covariance (tests/test_statistics.py compares the two)."""
    a, b = np.asarray(values, dtype=float), np.asarray(reference, dtype=float)
    if a.shape != b.shape:
        raise ValueError(f"paired values need one reference each, got {len(a)} and {len(b)}")
    differences = a - b
    differences = differences[~np.isnan(differences)]
    if len(differences) == 0:
        return math.nan, (math.nan, math.nan)
    return float(differences.mean()), bootstrap_interval(differences, "mean", level, samples, seed, method)


@dataclass(frozen=True)
class SurvivalCurve:
    """A Kaplan-Meier estimate: at each distinct event time t_j, the number at risk n_j, the events
    d_j, S(t_j) and its log-log pointwise band (low, high) at the given level."""

    times: np.ndarray
    at_risk: np.ndarray
    events: np.ndarray
    survival: np.ndarray
    low: np.ndarray
    high: np.ndarray


def kaplan_meier(times: Sequence[float], observed: Sequence[bool], level: float = CONFIDENCE_LEVEL) -> SurvivalCurve:
    """The Kaplan-Meier estimate of S(t) = P(T > t) from times, each an event (observed) or a
    censoring (the run ended, or was cut off, at that time without the event).

    S(t_j) = prod_{i <= j} (1 - d_i / n_i), n_i the runs with time >= t_i (a run censored at t_i is
    still at risk there). The band is the log-log one (Kalbfleisch & Prentice): with Greenwood's
    v_j = sum_{i <= j} d_i / (n_i (n_i - d_i)), S^exp(+z sqrt(v)/|log S|) to S^exp(-z sqrt(v)/|log S|);
    it stays within [0, 1]. Where S = 1 the band is [1, 1]; where S = 0, [0, 0]."""
    t = np.asarray(times, dtype=float)
    seen = np.asarray(observed, dtype=bool)
    if t.shape != seen.shape:
        raise ValueError(f"kaplan_meier needs one flag per time, got {len(t)} and {len(seen)}")
    event_times = np.unique(t[seen])
    at_risk = np.array([np.count_nonzero(t >= u) for u in event_times], dtype=float)
    events = np.array([np.count_nonzero(seen & (t == u)) for u in event_times], dtype=float)
    survival = np.cumprod(1 - events / at_risk) if len(event_times) else np.empty(0)
    with np.errstate(divide="ignore", invalid="ignore"):
        greenwood = np.cumsum(events / (at_risk * (at_risk - events)))
        spread = NormalDist().inv_cdf((1 + level) / 2) * np.sqrt(greenwood) / np.abs(np.log(survival))
        low, high = survival ** np.exp(spread), survival ** np.exp(-spread)
    low = np.where(survival >= 1, 1.0, np.where(survival <= 0, 0.0, low))
    high = np.where(survival >= 1, 1.0, np.where(survival <= 0, 0.0, high))
    return SurvivalCurve(event_times, at_risk, events, survival, low, high)


def km_median(
    times: Sequence[float], observed: Sequence[bool], level: float = CONFIDENCE_LEVEL
) -> tuple[float, tuple[float, float]]:
    """The Kaplan-Meier median time and its interval (Brookmeyer & Crowley's construction): the first
    time at which S, and each end of its log-log band, reaches 0.5 or below (where a curve equals
    0.5 exactly up to its next event time, the midpoint of the two: with no censoring the median is
    the ordinary median). NaN where a curve never gets to 0.5 (more than half the runs not yet
    reached the event when observed last): not reached."""
    curve = kaplan_meier(times, observed, level)
    return (
        _first_at_half(curve.times, curve.survival),
        (_first_at_half(curve.times, curve.low), _first_at_half(curve.times, curve.high)),
    )


def _first_at_half(times: np.ndarray, curve: np.ndarray) -> float:
    """The first time the step function `curve` (its value from each of `times` on) is <= 0.5."""
    reached = np.flatnonzero(curve <= 0.5 + 1e-12)
    if len(reached) == 0:
        return math.nan
    j = int(reached[0])
    if abs(curve[j] - 0.5) <= 1e-12 and j + 1 < len(times):
        return float((times[j] + times[j + 1]) / 2)
    return float(times[j])


def wilson_interval(successes: int, trials: int, level: float = CONFIDENCE_LEVEL) -> tuple[float, float]:
    """Wilson score interval for a share successes / trials: (p + z^2/2n -/+ z sqrt(p(1-p)/n +
    z^2/4n^2)) / (1 + z^2/n), z the normal (1 + level) / 2 quantile; within [0, 1], (NaN, NaN) for
    no trials."""
    if trials < 1:
        return math.nan, math.nan
    z = NormalDist().inv_cdf((1 + level) / 2)
    p, n = successes / trials, trials
    centre = p + z * z / (2 * n)
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n))
    scale = 1 + z * z / n
    low = 0.0 if successes == 0 else max(0.0, (centre - half) / scale)
    return low, 1.0 if successes == trials else min(1.0, (centre + half) / scale)


Interval = tuple[float, float]
SUMMARISED = [figure for figure in FIGURES if figure.summary]  # the figures a study summarises by their mean
NO_FIGURES = {k: v for f in SUMMARISED for k, v in ((f.name, math.nan), (f"{f.name}_interval", (math.nan, math.nan)))}


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
    paired_with: str | None = None  # the filter the paired difference is taken to (`--paired`)
    paired_runs: int = 0  # runs in both (the pairs)
    mean_difference: float = math.nan  # mean over the pairs of (this filter's - paired_with's) last-20% error
    difference_interval: Interval = (math.nan, math.nan)  # its paired BCa bootstrap interval
    mean_log_evidence: float = math.nan  # mean over the runs of log p(z_1:K) as the filter estimates it
    log_evidence_se: float = math.nan  # its standard error: the runs' standard deviation / sqrt(runs)
    log_evidence_caveat: str = ""  # why the filter's estimate is not of p(z_1:K) under the model ("": it is)
    backend: str = ""  # the backend its runs ran on (their ms_per_step's)
    # the figures summarised by their mean (Figure.summary): NAME the mean over the runs that have one (NaN:
    # none), NAME_interval its BCa bootstrap interval for "interval"; read as attributes (s.distance_to_exact)
    figures: dict[str, Any] = field(default_factory=lambda: dict(NO_FIGURES))

    def __getattr__(self, name: str) -> Any:
        try:
            return self.__dict__["figures"][name]
        except KeyError:
            raise AttributeError(name) from None


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
        if reference is not None and s.filter != reference:
            pairs = paired_finals(groups[s.setting_index, s.filter], records, settings, reference)
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
    relocalised_interval = (
        None if relocalised is None else wilson_interval(sum(bool(r.relocalised) for r in group), runs)
    )
    summary = StudySummary(
        index,
        setting,
        name,
        runs,
        statistics.fmean(finals),
        bootstrap_interval(finals, "mean", method=MEAN_METHOD),
        sum(converged) / runs,
        None if math.isnan(median_step) else median_step,
        statistics.fmean(r.ms_per_step for r in group),
        relocalised,
        steps_to_recover,
        statistics.fmean(r.mean_particle_count for r in group),
        statistics.median(finals),
        bootstrap_interval(finals, "median", method=MEDIAN_METHOD),
        wilson_interval(sum(converged), runs),
        relocalised_interval,
        statistics.fmean(r.run_seconds for r in group),
        step_interval,
        last,
    )
    for figure in SUMMARISED:  # the mean of the runs' finite values, with its BCa interval (NaN: none)
        finite = [v for v in (getattr(r, figure.name) for r in group) if v is not None and not math.isnan(v)]
        if finite:
            summary.figures[figure.name] = statistics.fmean(finite)
            summary.figures[f"{figure.name}_interval"] = bootstrap_interval(finite, "mean", method=MEAN_METHOD)
    evidence = [r.log_evidence for r in group if math.isfinite(r.log_evidence)]
    if evidence:  # the mean of the finite ones, and its standard error (NaN with fewer than two)
        summary.mean_log_evidence = statistics.fmean(evidence)
        summary.log_evidence_se = (
            statistics.stdev(evidence) / math.sqrt(len(evidence)) if len(evidence) > 1 else math.nan
        )
    summary.log_evidence_caveat, summary.backend = group[0].log_evidence_caveat, group[0].backend
    return summary


def last_convergence_step(steps: int) -> int:
    """The last step a run's convergence can count from: steps - K + 1, K the steps a run must stay below
    the radius to count as converged: the last-20% window (`final_error` averages the same steps), at least
    one; a run not converged by then is censored there (for the Kaplan-Meier median)."""
    return steps - max(1, int(steps * FINAL_SHARE)) + 1


def converged_within(converged_at: int | None, steps: int) -> bool:
    """Converged: below the radius from `converged_at` on, for at least the last K steps (a run that gets
    below it only near its end is not counted: "converged" agrees with a small last-20% error)."""
    return converged_at is not None and converged_at <= last_convergence_step(steps)


def paired_finals(
    group: Sequence[RunRecord], records: Sequence[RunRecord], settings: Sequence[StudySetting], reference: str
) -> list[tuple[float, float]]:
    """(this filter's, the reference filter's) last-20% error per run both ran on the same scenario:
    the reference's record of the same run in a setting that agrees on every parameter the reference
    takes (it runs once per such combination, `filters_per_setting`, so it may be another setting's); none
    when the filter's setting does not fix the reference's: the reference takes a varied parameter the filter
    does not (the grid filter against SIR with several particle counts: which N?)."""
    name = group[0].filter
    if any(takes_parameter(reference, p) and not takes_parameter(name, p) for p in varied_parameters(settings)):
        return []
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
        *((p, lambda s, p=p: show_value(s.setting.value(p)) if takes_parameter(s.filter, p) else "-") for p in varied),
        ("filter", lambda s: described(s.filter).label),
        ("runs", lambda s: str(s.runs)),
        ("mean last-20% error", lambda s: f"{s.mean_final_error:.3f}"),
        (ci, lambda s: format_interval(*s.interval)),
        ("median", lambda s: f"{s.median_final_error:.3f}"),
        (ci, lambda s: format_interval(*s.median_interval)),
        ("converged", lambda s: f"{s.converged_share:.0%}"),
        (ci, lambda s: format_interval(*s.converged_interval, spec="{:.0%}")),
        ("median conv. step", lambda s: _step(s.median_convergence_step, s.last_convergence_step)),
        (ci, lambda s: _step_interval(s.convergence_interval, s.last_convergence_step)),
        ("log p(z_1:K) (SE)", _evidence),
        (
            f"ms/step, {next(iter(backends))}" if len(backends) == 1 else "ms/step, backend",
            lambda s: f"{s.ms_per_step:.2f}" + ("" if len(backends) == 1 else f" {s.backend}"),
        ),
    ]
    if any(s.relocalised_share is not None for s in summaries):
        columns += [
            ("re-localised", lambda s: format_number(s.relocalised_share, "{:.0%}")),
            (ci, lambda s: format_interval(*(s.relocalised_interval or nan), spec="{:.0%}")),
            ("median steps to recover", lambda s: format_number(s.median_steps_to_recover, "{:g}")),
        ]
    if kld:
        columns.append(
            ("mean N", lambda s: f"{s.mean_particle_count:.0f}" if described(s.filter).takes_particles else "-")
        )
    for f in (f for f in SUMMARISED if any(not math.isnan(getattr(s, f.name)) for s in summaries)):
        columns.append((f.header, lambda s, f=f: format_number(getattr(s, f.name), f.spec)))
        if f.summary == "interval":
            columns.append((ci, lambda s, f=f: format_interval(*getattr(s, f"{f.name}_interval"), spec=f.spec)))
    if reference:
        columns += [
            (f"diff. vs {described(reference).label}", lambda s: format_number(s.mean_difference, "{:+.3f}")),
            (ci, lambda s: format_interval(*s.difference_interval, spec="{:+.3f}")),
        ]
    return column_table(columns, summaries) + "\n" + interval_note(summaries)


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


summary_path = functools.partial(beside, suffix=".summary.csv")  # the summary CSV by default: NAME.summary.csv
CSV_COLUMNS = [f.name for f in fields(RunRecord) if f.name != "options"]  # then a column per declared option
# how to read the CSV's seeds back whole: maze_seed is empty for a maze file, so pandas would read the
# column as float64 and round a seed above 2**53 (the record says so; pandas: dtype={"maze_seed": str})
CSV_DTYPES = {"seed": "int64", "maze_seed": "str (empty for a maze file; as float64 a seed loses digits)"}

# the summary CSV's statistics, after `setting`, the study's parameters and `filter`: a StudySummary field each,
# an interval (FIELD, NAME) as two columns, NAME_low and NAME_high
SUMMARY_FIELDS: tuple[str | tuple[str, str], ...] = (
    "runs",
    "mean_final_error",
    ("interval", "mean_final_error"),
    "median_final_error",
    ("median_interval", "median_final_error"),
    "converged_share",
    ("converged_interval", "converged"),
    "last_convergence_step",
    "median_convergence_step",
    ("convergence_interval", "median_convergence_step"),
    "mean_log_evidence",
    "log_evidence_se",
    "log_evidence_caveat",
    "ms_per_step",
    "backend",
    "run_seconds",
    "mean_particle_count",
    "relocalised_share",
    ("relocalised_interval", "relocalised"),
    "median_steps_to_recover",
    *(name for f in SUMMARISED for name in [f.name, *[(f"{f.name}_interval", f.name)] * (f.summary == "interval")]),
    "paired_with",
    "paired_runs",
    "mean_difference",
    ("difference_interval", "difference"),
)
SUMMARY_STATISTICS = tuple(
    name for f in SUMMARY_FIELDS for name in ((f"{f[1]}_low", f"{f[1]}_high") if isinstance(f, tuple) else (f,))
)


def summary_rows(summaries: Sequence[StudySummary], columns: Sequence[str] = ()) -> list[dict[str, Any]]:
    """One dict per setting and filter, the summary CSV's columns: `setting`, the maze and the model's
    parameters (None where the filter does not take one, the table's '-'), then the option `columns`
    (the study's, `study.option_columns`: each the value the filter ran with, None where it does not
    declare the option), `filter`, `label` (the registry's), then SUMMARY_FIELDS as SUMMARY_STATISTICS, each
    interval as _low and _high (None for a missing one), None for no caveat and no pairs."""
    rows = []
    for s in summaries:
        cells = option_cells(s.setting, s.filter)
        row = {
            "setting": s.setting_index,
            **{p: s.setting.value(p) if takes_parameter(s.filter, p) else None for p in BASE_PARAMETERS},
            **{name: cells.get(name) for name in columns},
            "filter": s.filter,
            "label": described(s.filter).label,
        }
        for spec in SUMMARY_FIELDS:
            if isinstance(spec, tuple):
                row[f"{spec[1]}_low"], row[f"{spec[1]}_high"] = getattr(s, spec[0]) or (None, None)
            else:
                value = getattr(s, spec)
                row[spec] = None if spec in ("log_evidence_caveat", "paired_runs") and not value else value
        rows.append(row)
    return rows


def summary_csv(summaries: Sequence[StudySummary], columns: Sequence[str] = ()) -> str:
    """The summary rows (`summary_rows`) as CSV: an empty cell for None, NaN and 'not reached'."""
    header = ["setting", *BASE_PARAMETERS, *columns, "filter", "label", *SUMMARY_STATISTICS]
    return records_csv(summary_rows(summaries, columns), header)
