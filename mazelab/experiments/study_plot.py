"""A study's figure as small multiples, sized for a paper (docs/studies.md, `--plot`): a statistic of the
runs with its interval (`Y_QUANTITIES`) against one varied parameter, one line per filter and varied option,
one panel per combination of the other varied parameters, laid out as the design (`figure_layout`); each
panel with its own y range (`y_range`), a filter that does not take the x parameter drawn as a reference
(`draw_panel`), points at one x set apart so that their bars do not hide each other (`XScale.places`), each
line in its filter's colour with a marker and a line style of its own, apart in grey print (`panel_lines`);
PAPER_WIDTH inches wide with FONT_POINTS type, PNG at PNG_DPI, or PDF / SVG with their text as text.
"""

from __future__ import annotations

import dataclasses
import math
import numbers
import textwrap
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from mazelab.declaration import show_value
from mazelab.experiments.runs import FINAL_SHARE, LINE_STYLES, MARKERS
from mazelab.experiments.study import BASE_PARAMETERS, MODEL_PARAMETERS, declared_option, hashable, takes_parameter
from mazelab.experiments.summary import CONFIDENCE_LEVEL, StudySummary
from mazelab.experiments.tables import pyplot, save_figure
from mazelab.registry import described, rgb

PARAMETER_LABELS = {
    "sigma": "σ, noise std (map units)",  # noqa: RUF001
    "delta": "Δ, compass error width (rad)",
    "particles": "particle count $N_S$",
}  # an option's label: its declared help (`axis_label`)
PAPER_WIDTH = 7.0  # inches: a two-column paper's text width (one column: about 3.4)
PANEL_HEIGHT = 2.0  # inches per row of panels
FONT_POINTS = 8  # the text; tick labels one point smaller
PNG_DPI = 300
CAPTION_WIDTH = 110  # characters per line of the title's caption (the figure's width at FONT_POINTS)
MAX_COLUMNS = 3  # panels per row
DODGE = 0.3  # on a categorical axis, the lines of a panel spread over this share of a category's width
NUMERIC_DODGE = 0.12  # on a numeric one over this share of the smallest spacing of the x values (bars apart)


@dataclass(frozen=True)
class YQuantity:
    """What the figure's y axis shows: its label, the value and interval of a summary, and the interval's
    method (for the title)."""

    label: str
    value: Any  # StudySummary -> float
    interval: Any  # StudySummary -> (low, high)
    method: str
    share: bool = False  # a share: drawn in percent, from 0% to 100%
    signed: bool = False  # a difference: may be below 0 (a line at 0 drawn)
    from_zero: bool = True  # its axis starts at 0 (or below, for a difference); else it spans the values

    def of(self, points: Sequence[StudySummary]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The value, low and high end of the interval of each point (summary), in percent for a share."""
        unit = 100.0 if self.share else 1.0
        value = unit * np.array([self.value(s) for s in points], dtype=float)
        low, high = unit * np.array([self.interval(s) for s in points], dtype=float).T
        return value, low, high


Y_QUANTITIES = {
    "mean": YQuantity(
        f"mean last-{FINAL_SHARE:.0%} error (map units)",
        lambda s: s.mean_final_error,
        lambda s: s.interval,
        "BCa bootstrap intervals for the mean",
    ),
    "median": YQuantity(
        f"median last-{FINAL_SHARE:.0%} error (map units)",
        lambda s: s.median_final_error,
        lambda s: s.median_interval,
        "percentile bootstrap intervals for the median",
    ),
    "converged": YQuantity(
        "runs converged (%)",
        lambda s: s.converged_share,
        lambda s: s.converged_interval,
        "Wilson score intervals for the share",
        share=True,
    ),
    "exact": YQuantity(
        "distance to the exact posterior mean (map units)",
        lambda s: s.distance_to_exact,
        lambda s: s.distance_to_exact_interval,
        "BCa bootstrap intervals for the mean distance",
    ),
    "paired": YQuantity(
        f"paired difference in last-{FINAL_SHARE:.0%} error (map units)",
        lambda s: s.mean_difference,
        lambda s: s.difference_interval,
        "paired BCa bootstrap intervals for the mean difference",
        signed=True,
    ),
    "evidence": YQuantity(
        "mean log evidence log p(z_1:K)",
        lambda s: s.mean_log_evidence,
        lambda s: (s.mean_log_evidence - 1.96 * s.log_evidence_se, s.mean_log_evidence + 1.96 * s.log_evidence_se),
        "intervals of the mean, 1.96 standard errors",
        from_zero=False,
    ),
}


def figure_axes(
    varied: Sequence[str], x: str | None, y: str, title: str | None, *, exact: bool, paired: bool
) -> YQuantity:
    """What the figure draws, checked in one place (`mazelab study` before any run, the figure when it is
    drawn): `x` a varied parameter (None: `choose_x`'s), `y` a key of Y_QUANTITIES (exact needs the
    distance to the exact posterior, `exact`; paired a filter to pair with, `paired`), `title` one line.

    Raises
    ------
    ValueError
        One line naming the option (--plot-x, --plot-y, --title) and what it takes.
    """
    if x is not None and x not in varied:
        shown = ", ".join(varied) or "none: give a parameter two values"
        raise ValueError(f"--plot-x {x}: the x axis is a varied parameter of the study ({shown})")
    if y not in Y_QUANTITIES:
        raise ValueError(f"--plot-y {y}: choose one of {', '.join(Y_QUANTITIES)}")
    if y == "exact" and not exact:
        raise ValueError("--plot-y exact: the distance to the exact posterior needs --reference grid")
    if y == "paired" and not paired:
        raise ValueError("--plot-y paired: the paired difference needs --paired FILTER")
    if title is not None and ("\n" in title or not title.strip()):
        raise ValueError("--title: give one line of text")
    return Y_QUANTITIES[y]


STYLE = {
    "font.size": FONT_POINTS,
    "axes.titlesize": FONT_POINTS,
    "axes.labelsize": FONT_POINTS,
    "figure.titlesize": FONT_POINTS,
    "legend.fontsize": FONT_POINTS - 1,
    "xtick.labelsize": FONT_POINTS - 1,
    "ytick.labelsize": FONT_POINTS - 1,
    "axes.linewidth": 0.6,
    "lines.linewidth": 1.0,
    "lines.markersize": 3.5,
    "errorbar.capsize": 2,
    "pdf.fonttype": 42,  # TrueType in the PDF: its text is text (journals ask for it)
    "svg.fonttype": "none",  # the SVG's text as <text>, editable
}


@dataclass(frozen=True)
class FigureLayout:
    """What a study's figure shows: the x parameter (None: the lines side by side), the panels'
    titles, the lines' labels; once drawn, each panel's y range and its box in figure coordinates
    (x0, y0, x1, y1, from the bottom left, 0 to 1)."""

    x: str | None
    panels: list[str]
    lines: list[str]
    shape: tuple[int, int] = (1, 1)  # rows x columns of panels, as the design
    options: list[str] = field(default_factory=list)  # the varied options the lines tell apart
    facets: list[str] = field(default_factory=list)  # the other varied parameters, a panel per combination
    y_ranges: list[tuple[float, float]] = field(default_factory=list)
    boxes: list[tuple[float, float, float, float]] = field(default_factory=list)


def is_numeric(summaries: Sequence[StudySummary], parameter: str) -> bool:
    """Whether every value a parameter takes in the study is a number (not a flag): an x axis with a scale."""
    values = [s.setting.value(parameter) for s in summaries]
    return all(isinstance(v, numbers.Real) and not isinstance(v, bool) for v in values)


def choose_x(summaries: Sequence[StudySummary], varied: Sequence[str], x: str | None = None) -> str | None:
    """The x axis: `x` if given (a varied parameter: `figure_axes` checks it), else the first numeric
    varied one (sigma, delta, N, then any numeric option, e.g. the RPF's threshold), else the first varied
    parameter that is not an option."""
    if x is not None:
        return x
    numeric = [p for p in varied if is_numeric(summaries, p)]
    ordered = [p for p in MODEL_PARAMETERS if p in numeric] + [p for p in numeric if p not in MODEL_PARAMETERS]
    if ordered:
        return ordered[0]
    return next((p for p in varied if p in BASE_PARAMETERS), None)


def figure_layout(
    summaries: Sequence[StudySummary], varied: Sequence[str], x: str | None = None
) -> tuple[FigureLayout, dict[str, list[StudySummary]]]:
    """Split the varied parameters into the x axis, the lines and the panels; returns the layout and
    the summaries by panel. A filter that does not take a panel's parameter (the grid filter and the
    RPF's bandwidth) is in every panel that agrees on the parameters it does take."""
    x = choose_x(summaries, varied, x)
    options = [p for p in varied if p not in BASE_PARAMETERS and p != x]  # the filter options
    facets = [p for p in varied if p != x and p not in options]
    panel_values: dict[str, dict[str, Any]] = {}
    for s in summaries:
        title = ", ".join(_named(p, s.setting.value(p)) for p in facets)
        panel_values.setdefault(title, {p: s.setting.value(p) for p in facets})
    panels: dict[str, list[StudySummary]] = {title: [] for title in panel_values}
    for s in summaries:
        for title, values in panel_values.items():
            if all(not takes_parameter(s.filter, p) or s.setting.value(p) == v for p, v in values.items()):
                panels[title].append(s)
    lines = list(dict.fromkeys(line_label(s, options) for s in summaries))
    shape = panel_grid(summaries, facets, len(panels))
    return FigureLayout(x, list(panels), lines, shape, options, facets), panels


def panel_grid(summaries: Sequence[StudySummary], facets: Sequence[str], count: int) -> tuple[int, int]:
    """Rows x columns of the panels, as the design: a column per value of the last panel parameter and
    a row per combination of the others (maze x sigma, 2 x 2: two rows of two); one panel parameter
    alone fills rows of at most MAX_COLUMNS."""
    if count <= 1:
        return 1, 1
    if len(facets) >= 2:
        columns = len({hashable(s.setting.value(facets[-1])) for s in summaries})
        if count % columns == 0:
            return count // columns, columns
    columns = min(MAX_COLUMNS, count) if count != 4 else 2
    return math.ceil(count / columns), columns


def line_label(summary: StudySummary, options: Sequence[str]) -> str:
    """'RPF, bandwidth multimodal': the filter and the varied options it takes."""
    name = described(summary.filter).label  # the registry's label (SIR), as the viewer's
    taken = [_named(p, summary.setting.value(p)) for p in options if takes_parameter(summary.filter, p)]
    return ", ".join([name, *taken])


def _named(parameter: str, value: Any) -> str:
    return show_value(value) if parameter == "maze" else f"{parameter} {show_value(value)}"


def axis_label(parameter: str | None) -> str:
    """The x axis's label: the lab's words for a model parameter, an option's declared help."""
    if parameter is None:
        return "filter"
    if parameter in PARAMETER_LABELS:
        return PARAMETER_LABELS[parameter]
    option = declared_option(parameter)
    words = option.help.split(" (")[0] if option is not None else ""
    return f"{parameter}, {words}" if words and len(words) <= 50 else parameter


@dataclass
class _Line:
    """One line of a panel: its label, colour, marker, points (summaries in x order)."""

    label: str
    colour: tuple[float, float, float]
    marker: str
    points: list[StudySummary]
    reference: bool  # its filter does not take the x parameter: one value for the whole panel
    style: str = "-"


def panel_lines(
    mine: Sequence[StudySummary], x: str | None, options: Sequence[str], order: Sequence[str] = ()
) -> list[_Line]:
    """A panel's lines, each filter in its registry colour; each line of the figure (its place in
    `order`, the figure's lines) has a marker and a line style of its own, the same in every panel."""
    by_label: dict[str, list[StudySummary]] = {}
    for s in mine:
        by_label.setdefault(line_label(s, options), []).append(s)
    lines = []
    for label, points in by_label.items():
        name = points[0].filter
        index = list(order).index(label) if label in order else len(order) + list(by_label).index(label)
        reference = x is not None and not takes_parameter(name, x)
        if x is not None and not reference:
            points = sorted(points, key=lambda s: _sort_key(s.setting.value(x)))
        marker, style = MARKERS[index % len(MARKERS)], LINE_STYLES[index % len(LINE_STYLES)]
        lines.append(_Line(label, rgb(described(name).colour), marker, points, reference, style))
    return lines


def _sort_key(value: Any) -> tuple[int, Any]:
    return (0, value) if isinstance(value, numbers.Real) else (1, str(value))


def draw_study(
    summaries: Sequence[StudySummary],
    varied: Sequence[str],
    path: Path,
    runs: int,
    maze: str,
    *,
    x: str | None = None,
    y: str = "mean",
    title: str | None = None,
    replace: bool = True,
) -> FigureLayout:
    """Draw the study's small multiples to `path` (.png at PNG_DPI, .pdf or .svg), as `mazelab study --plot`
    and `mazelab.study(...).figure` draw them, and return their layout with each panel's y range and box
    (an existing file is replaced only with `replace`). `x` chooses the x axis among the varied parameters
    (default: `choose_x`), `y` what is drawn (a key of Y_QUANTITIES); the program's title (`study_title`,
    of `runs` per point on `maze`) with a caption under it saying how, or `title` alone."""
    plt = pyplot()
    import matplotlib

    shown_varied = varied or ["maze"]  # nothing varied: a panel of one point per filter
    exact = not all(math.isnan(s.distance_to_exact) for s in summaries)
    quantity = figure_axes(shown_varied, x, y, None, exact=exact, paired=any(s.paired_with for s in summaries))
    if y == "paired":  # the filter paired with has no difference to itself; the axis names it
        summaries = [s for s in summaries if s.paired_with]
        other = described(summaries[0].paired_with or "").label
        quantity = dataclasses.replace(quantity, label=f"last-{FINAL_SHARE:.0%} error minus {other}'s (map units)")
    with matplotlib.rc_context(STYLE):
        layout, panels = figure_layout(summaries, shown_varied, x)
        rows, columns = layout.shape
        figure, axes = plt.subplots(
            rows, columns, figsize=(PAPER_WIDTH, PANEL_HEIGHT * rows + 1.0), squeeze=False, layout="constrained"
        )
        scale = XScale.of(summaries, layout.x)
        layout = draw_panels(axes, layout, list(panels.values()), scale, quantity)
        caveats = {
            line_label(s, []): s.log_evidence_caveat for s in summaries if s.log_evidence_caveat and y == "evidence"
        }
        _legend(figure, axes.flat[: len(layout.panels)], layout.lines, set(caveats))
        marks = [f"* {label}: its log evidence is {why}" for label, why in caveats.items()]
        how = [describe(scale, len(layout.panels), quantity)] if title is None else []
        lines = [title or study_title(layout, varied, summaries, runs, maze, y), *how, *marks]
        figure.suptitle("\n".join(wrapped for line in lines for wrapped in textwrap.wrap(line, CAPTION_WIDTH)))
        save_figure(figure, path, replace=replace, dpi=PNG_DPI)
        boxes = [tuple(float(v) for v in ax.get_position().extents) for ax in axes.flat[: len(layout.panels)]]
    return dataclasses.replace(layout, boxes=boxes)


def draw_panels(
    axes: Any, layout: FigureLayout, panels: Sequence[Sequence[StudySummary]], scale: XScale, quantity: YQuantity
) -> FigureLayout:
    """Each panel's lines and references (`draw_panel`), its title and axes' labels; the panels past
    the last hidden. Returns the layout with each panel's y range."""
    columns, ranges = layout.shape[1], []
    for k, mine in enumerate(panels):
        ax = axes[k // columns][k % columns]
        lines = panel_lines(mine, layout.x, layout.options, layout.lines)
        ranges.append(draw_panel(ax, lines, scale, layout.lines, k + 1, quantity))
        ax.set(ylim=ranges[-1], title=layout.panels[k] or None, xlabel=axis_label(layout.x), gid=f"panel-{k + 1}")
        ax.grid(alpha=0.3, linewidth=0.5)
    for k, ax in enumerate(axes.flat):
        ax.set_visible(k < len(panels))
        ax.set_ylabel(quantity.label if k % columns == 0 else "")
    return dataclasses.replace(layout, y_ranges=ranges)


def describe(scale: XScale, panels: int, quantity: YQuantity) -> str:
    """The title's second line: the intervals, each panel's own y range, where points overlap."""
    notes = [f"{CONFIDENCE_LEVEL:.0%} {quantity.method}"]
    if panels > 1 and not quantity.share:
        notes.append("each panel its own y range")
    if scale.kind == "category":
        notes.append("lines set side by side within a category")
    else:
        notes.append(
            f"points at one x set {NUMERIC_DODGE:.0%} of the x spacing apart, so their bars do not hide each other"
        )
    return "\n".join(textwrap.wrap("(" + "; ".join(notes) + ")", CAPTION_WIDTH))


def study_title(
    layout: FigureLayout, varied: Sequence[str], summaries: Sequence[StudySummary], runs: int, maze: str, y: str
) -> str:
    """The figure's first line: what is drawn against what (the x axis, then the panels' and the lines'
    parameters), and the runs per point."""
    against = f" against {layout.x}" if layout.x is not None and varied else " per filter"  # nothing varied: one point
    parts = [f"panels by {', '.join(layout.facets)}"] if layout.facets else []
    parts += [f"lines by filter, {', '.join(layout.options)}"] if layout.options else []
    where = "" if "maze" in varied else f" on {maze}"
    extra = f" ({'; '.join(parts)})" if parts else ""
    what = Y_QUANTITIES[y].label.split(" (")[0].capitalize()
    paired = next((s.paired_with for s in summaries if s.paired_with), None)
    if y == "paired" and paired is not None:
        what = f"Paired difference to {described(paired).label} in last-{FINAL_SHARE:.0%} error"
    return f"{what}{against}{where}{extra}, {runs} runs per point"


@dataclass(frozen=True)
class XScale:
    """Where a value goes on the x axis: a number (linear, or log10 for particle counts spanning 10x or
    more), or a category's index; `gap` is the smallest distance between two values there (for the dodge)."""

    kind: str  # "linear", "log" or "category"
    parameter: str | None = None  # the x parameter (None: the lines side by side)
    categories: tuple[str, ...] = ()
    values: tuple[float, ...] = ()  # the numeric x values
    gap: float = 1.0

    @classmethod
    def of(cls, summaries: Sequence[StudySummary], x: str | None) -> XScale:
        if x is None:
            return cls("category")
        if not is_numeric(summaries, x):
            return cls("category", x, tuple(dict.fromkeys(show_value(s.setting.value(x)) for s in summaries)))
        values = sorted({float(s.setting.value(x)) for s in summaries})
        log = x == "particles" and values[0] > 0 and values[-1] / values[0] >= 2  # N doubling: equal steps
        where = np.log10(values) if log else np.array(values)
        gap = float(np.diff(where).min()) if len(where) > 1 else 1.0
        return cls("log" if log else "linear", x, gap=gap, values=tuple(values))

    def position(self, value: Any) -> float:
        """The value's place in the transformed coordinate (log10 for a log axis)."""
        if self.kind == "category":
            return float(self.categories.index(show_value(value)))
        return math.log10(float(value)) if self.kind == "log" else float(value)

    def places(self, line: _Line, slot: int, slots: int, all_labels: Sequence[str]) -> np.ndarray:
        """Where a line's points go: their x values' places, the line in `slot` of `slots` set a share of
        the x spacing apart from the others at one x; with nothing varied on x, a category per line."""
        if self.kind == "category" and not self.categories:
            return np.array([float(all_labels.index(line.label))])
        spread = DODGE if self.kind == "category" else NUMERIC_DODGE * self.gap
        offset = spread * (slot / (slots - 1) - 0.5) if slots > 1 else 0.0
        return np.array([self.position(s.setting.value(self.parameter)) for s in line.points]) + offset

    def back(self, where: np.ndarray) -> np.ndarray:
        """Transformed coordinates back to data (what matplotlib plots on a log axis)."""
        return 10**where if self.kind == "log" else where


def draw_panel(
    ax: Any,
    lines: Sequence[_Line],
    scale: XScale,
    all_labels: Sequence[str],
    panel: int,
    quantity: YQuantity = Y_QUANTITIES["mean"],
) -> tuple[float, float]:
    """Draw a panel's lines (with error bars; points at one x set a little apart) and references (dashed,
    shaded interval); returns its y range (`y_range`)."""
    drawn = [line for line in lines if not line.reference]
    slots = [label for label in all_labels if label in {line.label for line in drawn}]
    shown: list[float] = []
    for line in drawn:
        j = slots.index(line.label)  # the same slot in every panel: a line keeps its place
        where = scale.places(line, j, len(slots), all_labels)
        value, low, high = quantity.of(line.points)
        bars = np.clip(np.nan_to_num(np.vstack([value - low, high - value])), 0, None)  # BCa may miss the mean
        container = ax.errorbar(
            scale.back(where),
            value,
            yerr=bars,
            fmt=line.marker,
            linestyle=line.style if len(where) > 1 else "none",
            color=line.colour,
            label=line.label,
            elinewidth=0.8,
            markerfacecolor="white" if j % 2 else line.colour,
            capsize=2 + j % 3,
        )
        container.lines[0].set_gid(f"panel-{panel}:line:{line.label}")
        shown += [*value, *low, *high]
    for line in (line for line in lines if line.reference):
        value, low, high = (float(v[0]) for v in quantity.of(line.points[:1]))
        dashes = line.style if line.style != "-" else "--"  # a reference is never a solid line
        ax.axhline(
            value,
            color=line.colour,
            linestyle=dashes,
            linewidth=1.0,
            label=line.label,
            gid=f"panel-{panel}:reference:{line.label}",
        )
        if not math.isnan(low):
            ax.axhspan(low, high, color=line.colour, alpha=0.15, linewidth=0)
        shown += [value, low, high]
    if quantity.signed:
        ax.axhline(0.0, color="black", linewidth=0.6)
    x_axis(ax, scale, all_labels)
    return y_range(shown, quantity)


def x_axis(ax: Any, scale: XScale, all_labels: Sequence[str]) -> None:
    """A panel's x axis: log for particle counts that span a doubling, the studied values as its ticks;
    a category's names on a categorical one."""
    if scale.kind == "log":
        ax.set_xscale("log")
        ax.minorticks_off()
    if scale.kind != "category" and 1 < len(scale.values) <= 8:
        ax.set_xticks(scale.values, [show_value(v) for v in scale.values])  # the studied values, as given
    if scale.kind == "category":
        names = scale.categories or tuple(all_labels)
        ax.set_xticks(range(len(names)), names, rotation=20 if max(map(len, names)) > 8 else 0, ha="right")
        ax.set_xlim(-0.5, len(names) - 0.5)


def y_range(shown: Sequence[float], quantity: YQuantity) -> tuple[float, float]:
    """A panel's y range from the values and intervals it shows: 0-105% for a share; from 0 (or 10%
    below the lowest, for a difference) to 10% above the highest; or the values' span, 5% either side."""
    values = [v for v in shown if not math.isnan(v)]
    if quantity.share:
        return 0.0, 105.0
    low, high = min(values, default=0.0), max(values, default=0.0)
    if not quantity.from_zero:
        return low - 0.05 * (high - low or 1.0), high + 0.05 * (high - low or 1.0)
    return (1.1 * low if low < 0 else 0.0), (1.1 * high if high > 0 else 1.0)


def _legend(figure: Any, axes: Sequence[Any], order: Sequence[str], marked: set[str] = frozenset()) -> None:
    """One legend for all panels, below them, in the lines' order (each line once, a reference as its
    dashed line); a line of a `marked` filter (its log evidence not of p(z_1:K)) labelled with '*'."""
    seen: dict[str, Any] = {}
    for ax in axes:
        for handle, label in zip(*ax.get_legend_handles_labels(), strict=True):
            seen.setdefault(label, handle)
    names = sorted(seen, key=lambda label: order.index(label) if label in order else len(order))
    shown = [
        name.replace(name.split(",")[0], name.split(",")[0] + "*", 1) if name.split(",")[0] in marked else name
        for name in names
    ]
    figure.legend([seen[n] for n in names], shown, loc="outside lower center", ncols=min(4, len(names)), frameon=False)
