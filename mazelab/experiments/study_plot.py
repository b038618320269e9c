"""A study's figure as small multiples: the mean last-20% error with its interval against one varied
parameter (the x axis), one line per filter and varied option (e.g. "RPF, bandwidth multimodal"), and
one panel per combination of the other varied parameters (e.g. maze x sigma)."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from mazelab.experiments.runs import FINAL_SHARE
from mazelab.experiments.study import is_option_parameter, takes_parameter
from mazelab.experiments.summary import StudySummary
from mazelab.experiments.tables import format_value, pyplot, save_figure
from mazelab.registry import labels

NUMERIC_PARAMETERS = ("sigma", "delta", "particles", "threshold")  # an x axis with a scale
PARAMETER_LABELS = {
    "sigma": "sigma, measurement noise std (map units)",
    "delta": "Delta, compass error width (radians)",
    "particles": "particle count N_S",
    "threshold": "RPF threshold N_T / N_S",
}
MAX_COLUMNS = 3  # panels per row


@dataclass(frozen=True)
class FigureLayout:
    """What a study's figure shows: the x parameter (None: the lines side by side), the panels'
    titles, the lines' labels."""

    x: str | None
    panels: list[str]
    lines: list[str]


def figure_layout(summaries: Sequence[StudySummary], varied: Sequence[str]) -> tuple[FigureLayout, dict, dict]:
    """Split the varied parameters into the x axis, the lines and the panels; returns the layout and
    the summaries by panel and by line."""
    x = next((p for p in varied if p in NUMERIC_PARAMETERS and not is_option_parameter(p)), None)
    x = x or next((p for p in varied if p in NUMERIC_PARAMETERS), None)
    options = [p for p in varied if is_option_parameter(p) and p != x]
    if x is None:
        x = next((p for p in varied if p not in options), None)
    facets = [p for p in varied if p != x and p not in options]
    panels: dict[str, list[StudySummary]] = {}
    lines: dict[str, list[StudySummary]] = {}
    for s in summaries:
        panel = ", ".join(_named(p, s.setting.value(p)) for p in facets)
        panels.setdefault(panel, []).append(s)
        lines.setdefault(line_label(s, options), []).append(s)
    return FigureLayout(x, list(panels), list(lines)), panels, lines


def line_label(summary: StudySummary, options: Sequence[str]) -> str:
    """'RPF, bandwidth multimodal': the filter and the varied options it takes."""
    name = labels([summary.filter])[summary.filter]  # the registry's label (SIR), as the viewer's
    taken = [_named(p, summary.setting.value(p)) for p in options if takes_parameter(summary.filter, p)]
    return ", ".join([name, *taken])


def _named(parameter: str, value: Any) -> str:
    return format_value(value) if parameter == "maze" else f"{parameter} {format_value(value)}"


def plot_study(
    summaries: Sequence[StudySummary], varied: Sequence[str], path: Path, title: str, *, replace: bool = True
) -> FigureLayout:
    """Draw the study's small multiples to `path` (png, pdf or svg) and return their layout (an
    existing file is replaced only with `replace`)."""
    plt = pyplot()
    layout, panels, _ = figure_layout(summaries, varied)
    x = layout.x
    numeric = x in NUMERIC_PARAMETERS
    count = len(layout.panels)
    columns = min(MAX_COLUMNS, count)
    rows = math.ceil(count / columns)
    figure, axes = plt.subplots(
        rows, columns, figsize=(4.2 * columns + 1.5, 3.4 * rows + 1.2), sharey=True, squeeze=False, layout="constrained"
    )
    categories = list(dict.fromkeys(format_value(s.setting.value(x)) for s in summaries)) if x and not numeric else []
    colours = {label: f"C{i % 10}" for i, label in enumerate(layout.lines)}
    options = [p for p in varied if is_option_parameter(p) and p != x]
    for k, (panel, mine) in enumerate(panels.items()):
        ax = axes[k // columns][k % columns]
        by_line: dict[str, list[StudySummary]] = {}
        for s in mine:
            by_line.setdefault(line_label(s, options), []).append(s)
        for j, (label, points) in enumerate(by_line.items()):
            if x is None:
                xs = np.array([float(layout.lines.index(label))])
            elif numeric:
                points = sorted(points, key=lambda s: s.setting.value(x))
                xs = np.array([float(s.setting.value(x)) for s in points])
            else:
                xs = np.array([float(categories.index(format_value(s.setting.value(x)))) for s in points])
            if not numeric:
                xs = xs + 0.08 * (j - (len(by_line) - 1) / 2)  # side by side: the bars do not hide each other
            mean = np.array([s.mean_final_error for s in points])
            low, high = np.array([s.interval for s in points]).T
            bars = np.nan_to_num(np.vstack([mean - low, high - mean]))
            style = "-o" if numeric else "o"
            ax.errorbar(xs, mean, yerr=bars, fmt=style, capsize=3, color=colours[label], label=label)
        if x is None:
            ax.set_xticks(range(len(layout.lines)), layout.lines, rotation=20, ha="right")
        elif not numeric:
            ax.set_xticks(range(len(categories)), categories, rotation=20, ha="right")
        ax.set_xlabel(PARAMETER_LABELS.get(x or "", x or "filter"))
        ax.set_title(panel, fontsize=9)
        ax.set_ylim(bottom=0)
        ax.grid(alpha=0.3)
    for k in range(count, rows * columns):
        axes[k // columns][k % columns].set_visible(False)
    for row in axes:
        row[0].set_ylabel(f"last-{FINAL_SHARE:.0%} error (mean error over the last {FINAL_SHARE:.0%} of the steps)")
    handles, labels = axes[0][0].get_legend_handles_labels()
    seen = dict(zip(labels, handles, strict=True))
    for ax in axes.flat[1:count]:
        for h, label in zip(*ax.get_legend_handles_labels(), strict=True):
            seen.setdefault(label, h)
    figure.legend(list(seen.values()), list(seen), loc="outside lower center", ncols=min(4, len(seen)))
    figure.suptitle(title, fontsize=10)
    save_figure(figure, path, replace=replace)
    return layout


__all__ = ["NUMERIC_PARAMETERS", "FigureLayout", "figure_layout", "line_label", "plot_study"]
