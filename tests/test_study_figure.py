"""The study's figure for a paper (item 7 of issue 32), read back from the files it writes: PNG pixels
(each panel's lines in the registry's colours, none cut at a panel's top, the grid reference in every
panel), the SVG's and the PDF's text (units on the y label, the panels' titles, a size of 7 inches),
and a numeric --option as the x axis."""

from __future__ import annotations

import re
import xml.etree.ElementTree as ET
import zlib
from pathlib import Path

import numpy as np
import pytest

import mazelab
from mazelab.cli.app import main
from mazelab.experiments.study import MazeChoice, StudySetting
from mazelab.experiments.study_plot import FONT_POINTS, PAPER_WIDTH, PNG_DPI, Y_QUANTITIES, draw_study
from mazelab.experiments.summary import StudySummary
from mazelab.registry import described

Y_LABEL = Y_QUANTITIES["mean"].label  # the default figure's y axis
SVG = "{http://www.w3.org/2000/svg}"
FILTERS = ("SIRParticleFilter", "RegularizedParticleFilter", "GridBayesFilter")
TINY = ["--runs", "2", "--steps", "10", "--particles", "60", "--seed", "2", "--workers", "1", "--no-viz"]


def summaries() -> list[StudySummary]:
    """Two mazes whose errors differ 30-fold (0.1 and 3 map units), three particle counts, the RPF's two
    bandwidths; the grid filter (no particle count) once per maze. A shared y range clips the second."""
    out, index = [], 0
    for maze, scale in (
        (MazeChoice("small errors", grid=((0, 2),)), 0.1),
        (MazeChoice("big errors", grid=((2, 0),)), 3.0),
    ):
        for particles in (100, 1000, 10000):
            for bandwidth in ("optimal", "multimodal"):
                index += 1
                setting = StudySetting(maze, 0.3, 0.5, particles, (("bandwidth", bandwidth),))
                for name in FILTERS:
                    if name != "RegularizedParticleFilter" and bandwidth != "optimal":
                        continue
                    if name == "GridBayesFilter" and particles != 100:
                        continue
                    mean = scale * (0.5 if name == "GridBayesFilter" else 1 + 100 / particles)
                    out.append(StudySummary(index, setting, name, 5, mean, (0.6 * mean, 1.5 * mean), 1.0, 5, 1.0))
    return out


VARIED = ["maze", "particles", "bandwidth"]


def near(pixels: np.ndarray, colour: tuple[int, int, int], tolerance: float = 40) -> np.ndarray:
    """Where a PNG's pixels are within `tolerance` (0-255 units) of an RGB colour."""
    return np.linalg.norm(pixels[..., :3] * 255 - np.array(colour), axis=-1) < tolerance


def test_png_panels_have_their_own_range_the_reference_and_nothing_clipped(tmp_path):
    import matplotlib.image

    path = tmp_path / "f.png"
    layout = draw_study(summaries(), VARIED, path, 5, "m", title="test")
    pixels = matplotlib.image.imread(path)
    height, width = pixels.shape[:2]
    assert width == round(PAPER_WIDTH * PNG_DPI)
    assert layout.x == "particles" and layout.panels == ["small errors", "big errors"]
    assert [top for _, top in layout.y_ranges] == pytest.approx([1.1 * 1.5 * 0.1 * 2, 1.1 * 1.5 * 3.0 * 2])
    for x0, y0, x1, y1 in layout.boxes:
        top, bottom = round((1 - y1) * height), round((1 - y0) * height)
        left, right = round(x0 * width), round(x1 * width)
        inside = pixels[top + 3 : bottom - 3, left + 3 : right - 3]  # within the frame
        for name in FILTERS:
            rows = np.flatnonzero(near(inside, described(name).colour).any(axis=1))
            assert len(rows) > 0, f"{name} missing from a panel"  # the grid reference too, in every panel
            assert rows.min() > 0.03 * (bottom - top), f"{name} reaches the panel's top: clipped"


def test_svg_text_units_titles_size_and_references(tmp_path):
    path = tmp_path / "f.svg"
    draw_study(summaries(), VARIED, path, 5, "m")  # the program's title and caption
    root = ET.parse(path).getroot()
    assert root.get("width") == f"{PAPER_WIDTH * 72:g}pt"
    texts = {"".join(t.itertext()).strip(): t.get("style", "") for t in root.iter(f"{SVG}text")}
    assert Y_LABEL in texts and "(map units)" in Y_LABEL
    assert f"font-size: {FONT_POINTS}px" in texts[Y_LABEL]
    squeezed = {re.sub(r"\s", "", t) for t in texts}  # mathtext ($N_S$, 10^2) is a span per glyph
    assert {"small errors", "big errors"} <= set(texts) and "particlecountNS" in squeezed
    assert "each panel its own y range" in " ".join(texts)
    ids = {element.get("id") for element in root.iter() if element.get("id")}
    for panel in (1, 2):
        assert f"panel-{panel}:reference:grid" in ids  # the grid filter takes no N: a reference line
        assert {f"panel-{panel}:line:SIR", f"panel-{panel}:line:RPF, bandwidth multimodal"} <= ids


def pdf_text(path: Path) -> str:
    """The text a PDF of matplotlib's shows (TJ arrays of two-byte codes, Type 42 fonts), joined."""
    data = path.read_bytes()
    shown = []
    for stream in re.findall(rb"stream\r?\n(.*?)\r?\nendstream", data, re.S):
        try:
            content = zlib.decompress(stream)
        except zlib.error:
            continue
        for array in re.findall(rb"\[(.*?)\] TJ", content, re.S):
            pieces = re.findall(rb"\(((?:\\.|[^\\)])*)\)", array, re.S)
            raw = b"".join(re.sub(rb"\\([\\()])", rb"\1", piece) for piece in pieces)
            shown.append(raw.decode("utf-16-be", errors="replace"))
    return "\n".join(shown)


def test_pdf_is_seven_inches_wide_with_its_text_as_text(tmp_path):
    path = tmp_path / "f.pdf"
    draw_study(summaries(), VARIED, path, 5, "m", title="test")
    width = float(re.search(rb"/MediaBox \[ 0 0 ([0-9.]+) ", path.read_bytes()).group(1))
    assert width == PAPER_WIDTH * 72
    text = pdf_text(path)
    assert Y_LABEL in text and "big errors" in text


def test_a_study_draws_a_numeric_option_as_its_x_axis_in_any_format(tmp_path, capsys):
    """--option outside_penalty=0.3,0.6 (a number every filter declares) as the x axis, with sigma
    varied too (--plot-x chooses), into an SVG; the same study as a PNG."""
    figure = tmp_path / "f.svg"
    args = ["study", "--filters", "sir,grid", "--sigma", "0.3,0.5", "--option", "outside_penalty=0.3,0.6", *TINY]
    assert main([*args, "--plot", str(figure), "--plot-x", "outside_penalty"]) == 0
    texts = ["".join(t.itertext()) for t in ET.parse(figure).getroot().iter(f"{SVG}text")]
    assert any(t.startswith("outside_penalty, the likelihood factor") for t in texts)
    assert {"0.3", "0.6"} <= set(texts) and "sigma 0.3" in texts and "sigma 0.5" in texts  # ticks, panels
    assert main([*args, "--plot", str(tmp_path / "f.png"), "--force"]) == 0  # its record exists: replaced
    capsys.readouterr()
    assert main([*args, "--plot", str(tmp_path / "g.png"), "--plot-x", "delta"]) == 2
    assert capsys.readouterr().err.strip() == (
        "error: --plot-x delta: the x axis is a varied parameter of the study (sigma, outside_penalty)"
    )


def test_the_help_says_the_suffix_chooses_the_format(capsys):
    assert main(["study", "--help"]) == 0
    assert ".png, .pdf or .svg (the suffix chooses)" in " ".join(capsys.readouterr().out.split())


def test_the_grid_reference_is_in_every_panel_of_a_facet_it_does_not_take(tmp_path):
    """x = sigma, a panel per particle count: the grid filter ran once (it takes no N), yet its line is
    in every panel."""
    maze = MazeChoice("m", grid=((0, 2),))
    out = []
    for index, (sigma, particles) in enumerate([(s, n) for n in (100, 1000) for s in (0.2, 0.4)], start=1):
        setting = StudySetting(maze, sigma, 0.5, particles)
        for name in ("SIRParticleFilter", "GridBayesFilter") if particles == 100 else ("SIRParticleFilter",):
            out.append(StudySummary(index, setting, name, 5, sigma, (0.5 * sigma, 2 * sigma), 1.0, 5, 1.0))
    path = tmp_path / "g.svg"
    layout = draw_study(out, ["sigma", "particles"], path, 5, "m", title="test")
    assert layout.x == "sigma" and layout.panels == ["particles 100", "particles 1000"]
    ids = {element.get("id") for element in ET.parse(path).getroot().iter() if element.get("id")}
    assert {"panel-1:line:grid", "panel-2:line:grid", "panel-1:line:SIR", "panel-2:line:SIR"} <= ids


def test_a_python_study_draws_its_figure_without_glue(tmp_path):
    result = mazelab.study("paper_5x5", sigma=[0.3, 0.5], filters=["sir", "grid"], runs=2, steps=10, particles=60,
                           seed=3)  # fmt: skip
    path = result.figure(tmp_path / "f.pdf")
    assert Y_LABEL in pdf_text(path) and result.varied == ["sigma"]


def test_a_study_that_varies_nothing_is_titled_per_filter(tmp_path):
    """One setting: the figure draws each filter's point, not a line "against maze"."""
    path = tmp_path / "one.svg"
    words = ["study", "--maze", "paper_5x5", "--filters", "sir,rpf", "--runs", "2", "--steps", "8",
             "--particles", "60", "--workers", "1", "--no-viz", "--plot", str(path)]  # fmt: skip
    assert main(words) == 0
    title = next(
        t for t in ("".join(t.itertext()) for t in ET.parse(path).getroot().iter(f"{SVG}text")) if "runs per" in t
    )
    assert "per filter on paper_5x5" in title and "against" not in title


# -- figures a reader tells apart (round 7) -------------------------------------------------------------------
def figure_of(monkeypatch, module) -> dict:
    """The figure `module` saves, kept open to read its lines (save_figure replaced by a keeper)."""
    kept: dict = {}
    monkeypatch.setattr(module, "save_figure", lambda figure, path, **kwargs: kept.setdefault("figure", figure))
    return kept


def test_compares_figure_tells_the_filters_apart_without_colour(tmp_path, monkeypatch):
    from mazelab.experiments import runs as compare_module

    kept = figure_of(monkeypatch, compare_module)
    scenario = Path(__file__).resolve().parent.parent / "model_parameters" / "paper_5x5.json"
    assert main(["compare", str(scenario), "--filters", "sir,apf,grid", "--plot", str(tmp_path / "c.png"),
                 "--no-viz"]) == 0  # fmt: skip
    lines = [line for line in kept["figure"].axes[0].get_lines() if line.get_label() in ("SIR", "APF", "grid")]
    assert len(lines) == 3 and len({(line.get_linestyle(), line.get_marker()) for line in lines}) == 3


def test_error_bars_at_one_x_are_set_apart_and_capped_apart(monkeypatch, tmp_path):
    from mazelab.experiments import study_plot

    kept = figure_of(monkeypatch, study_plot)
    draw_study(summaries(), VARIED, tmp_path / "f.png", 5, "m", title="t")
    ax = kept["figure"].axes[0]
    wanted = ("SIR", "RPF, bandwidth optimal")
    xs = {c.get_label(): tuple(c.lines[0].get_xdata()) for c in ax.containers if c.get_label() in wanted}
    assert len(xs) == 2 and all(a != b for a, b in zip(*xs.values(), strict=True))  # the same N, drawn apart
    assert all(abs(np.log10(a / b)) < 0.1 for a, b in zip(*xs.values(), strict=True))  # by a few % of the spacing
    caps = {c.lines[1][0].get_markersize() for c in ax.containers if c.lines[1]}
    assert len(caps) > 1


def test_particle_counts_spanning_a_doubling_get_a_log_axis():
    from mazelab.experiments.study_plot import XScale

    maze = MazeChoice("m", grid=((0, 2),))
    counts = [StudySummary(i, StudySetting(maze, 0.3, 0.5, n), "SIRParticleFilter", 3, 0.1, (0.05, 0.2), 1.0, 5, 1.0)
              for i, n in enumerate((250, 500, 1000, 2000), start=1)]  # fmt: skip
    assert XScale.of(counts, "particles").kind == "log"
    assert XScale.of(counts[:1] + counts[1:2], "particles").kind == "log"


def test_a_title_of_ones_own_replaces_the_caption_too(tmp_path):
    path = tmp_path / "t.svg"
    words = ["study", "--maze", "paper_5x5", "--sigma", "0.3,0.5", "--filters", "sir", *TINY, "--plot", str(path),
             "--title", "My own title"]  # fmt: skip
    assert main(words) == 0
    texts = " ".join("".join(t.itertext()) for t in ET.parse(path).getroot().iter(f"{SVG}text"))
    assert "My own title" in texts and "BCa" not in texts and "intervals" not in texts
