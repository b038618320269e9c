"""A saved recording opens with the lab's layout: looked at in a real headless Chromium by what the
web viewer draws (the stations' cyan, the particles' blue..red, the step panel's heading above the
map), not by what the file holds; and the file's own part of it (its layout marked active, a file
that is not a whole recording refused by `mazelab view`), checked without a browser.

The browser tests are skipped, saying why, where no Chromium is installed (.ci/run installs one).
Chromium talks to 127.0.0.1 only (see headless_browser.FLAGS). A page is looked at every two seconds
until what it should show is there or DEADLINE passes: the web viewer on a software rasteriser
takes 5 to 40 s to load here; the deadline only bounds a failing test, it measures nothing.
"""

from __future__ import annotations

import re
import signal
import subprocess
import sys
import time
from collections import deque
from pathlib import Path

import numpy as np
import pytest
import rerun as rr
from conftest import PAPER_MAZE, ROOT
from headless_browser import DevToolsError, HeadlessBrowser, find_browser
from rerun.chunk import RrdReader

from mazelab.cli.app import main
from mazelab.cli.recordings import recording_problem, replay_with_layout
from mazelab.maze import Maze
from mazelab.robot import Robot
from mazelab.simulation import simulate
from mazelab.viz.processes import WebServer, free_port, rerun_environment, start_rerun, viewer_executable
from mazelab.viz.style import APPLICATION_ID, STATION_COLOR

BROWSER = find_browser()
needs_browser = pytest.mark.skipif(
    BROWSER is None,
    reason="no headless Chromium (chromium, chromium-browser or google-chrome on PATH, or $CHROMIUM): "
    "the saved recording is not looked at in a browser (Debian: apt-get install chromium)",
)
DEADLINE = 150.0  # seconds for a page to show everything it should (a failing page is given this long)
STATIONS = 8  # the paper's maze: two station blocks, a station at each of their four corners
SHORT_RUN = ["run", "--maze", "paper_5x5", "--steps", "6", "--particles", "300", "--seed", "3", "--quiet"]


# -- what a screenshot shows -----------------------------------------------------------------------
def blobs(mask: np.ndarray, least: int = 4) -> list[tuple[int, int, int, int]]:
    """The 8-connected regions of `mask` of at least `least` pixels, as bounding boxes (top, left,
    bottom, right), left to right."""
    seen = np.zeros_like(mask)
    found = []
    for y, x in zip(*np.nonzero(mask), strict=True):
        if seen[y, x]:
            continue
        seen[y, x] = True
        queue, pixels = deque([(y, x)]), []
        while queue:
            cy, cx = queue.popleft()
            pixels.append((cy, cx))
            for ny in range(max(cy - 1, 0), min(cy + 2, mask.shape[0])):
                for nx in range(max(cx - 1, 0), min(cx + 2, mask.shape[1])):
                    if mask[ny, nx] and not seen[ny, nx]:
                        seen[ny, nx] = True
                        queue.append((ny, nx))
        if len(pixels) >= least:
            ys, xs = np.array(pixels).T
            found.append((ys.min(), xs.min(), ys.max() + 1, xs.max() + 1))
    return sorted(found, key=lambda box: box[1])


def station_mask(pixels: np.ndarray) -> np.ndarray:
    """Pixels of the stations' cyan (STATION_COLOR, shaded darker at the rim): no red, blue above green.
    (A few pixels of the viewer's blue chips and icons have it too: see station_dots.)"""
    r, g, b = (pixels[..., i].astype(int) for i in range(3))
    assert STATION_COLOR == (0, 200, 255)  # the test's hue band below is this colour's
    return (r < 60) & (g > 120) & (b > 180) & (b > g + 15)


def station_dots(pixels: np.ndarray) -> list[tuple[int, int, int, int]]:
    """The stations drawn: round cyan dots (filling about pi/4 of their box), all of about one size."""
    mask = station_mask(pixels)
    dots = [box for box in blobs(mask) if 0.6 * area(box) <= mask[box[0] : box[2], box[1] : box[3]].sum()]
    biggest = max(map(area, dots), default=0)
    return [box for box in dots if area(box) >= biggest / 2]


def area(box: tuple[int, int, int, int]) -> int:
    return (box[2] - box[0]) * (box[3] - box[1])


def particle_mask(pixels: np.ndarray) -> np.ndarray:
    """Pixels of the particles: weights are drawn blue (light) .. red (heavy) with no green; only
    the particles' colour map puts blue with no green (the UI's blues have green, the filter's
    circles are red)."""
    r, g, b = (pixels[..., i].astype(int) for i in range(3))
    return (g < 40) & (b > 60) & (r + b > 170)


def text_lines(pixels: np.ndarray, top: int, bottom: int, left: int, right: int) -> list[tuple[int, int]]:
    """The lines of text in a region, as (first row, height in pixels): rows holding ink, pixels far
    from the region's background (its median), dark on the web viewer's light theme, light on the
    native viewer's dark one."""
    region = pixels[top:bottom, left:right].astype(int).sum(axis=2)
    if region.size == 0:
        return []
    ink = np.abs(region - np.median(region)) > 3 * 100
    rows = np.flatnonzero(ink.sum(axis=1) > 0)
    lines, start = [], None
    for i, row in enumerate(rows):
        if start is None:
            start = row
        if i + 1 == len(rows) or rows[i + 1] != row + 1:
            lines.append((top + start, row - start + 1))
            start = None
    return lines


def panel_left(pixels: np.ndarray, row: int, x: int) -> int:
    """The first column right of the panel border left of (row, x): walking left along the panel's
    background until a pixel differs from it (the border line, the side panel)."""
    background = pixels[row, x].astype(int)
    while x > 0 and np.abs(pixels[row, x - 1].astype(int) - background).max() <= 30:
        x -= 1
    return x


def the_lab_layout(pixels: np.ndarray, maps: int) -> list[str]:
    """What is missing for the lab's layout with `maps` map panels side by side, drawn whole: in each
    map the STATIONS stations and particles; above the maps the step panel with its heading ("Step N"
    in markdown, taller than the viewer's own labels). Empty when everything is there."""
    missing = []
    stations = station_dots(pixels)
    if len(stations) != STATIONS * maps:
        missing.append(f"{len(stations)} station dots, not {STATIONS * maps}")
        return missing
    groups = [stations[i * STATIONS : (i + 1) * STATIONS] for i in range(maps)]
    for number, group in enumerate(groups, 1):
        top, left = min(box[0] for box in group), min(box[1] for box in group)
        bottom, right = max(box[2] for box in group), max(box[3] for box in group)
        if number < maps and right > min(box[1] for box in groups[number]):
            missing.append(f"map {number}'s stations overlap the next map's: not side by side")
        if particle_mask(pixels[top:bottom, left:right]).sum() < 30:
            missing.append(f"no particles drawn in map {number}")
    first_station = min(box[0] for box in stations)
    left, right = (
        panel_left(pixels, first_station - 5, min(box[1] for box in stations)),
        max(box[3] for box in stations),
    )
    lines = text_lines(pixels, 40, first_station - 12, left, right)
    # lines[0] is the step panel's header ("step" and its icon, 15 px), lines[-1] the map panel's (14-15
    # px); between them the step's heading, "Step N" in markdown: 18 px from cap to descender
    if not any(height >= 16 for _, height in lines[1:-1]):
        missing.append(f"no heading in the panel above the maps (lines of text there: {lines})")
    return missing


def looks_like(page: HeadlessBrowser, url: str, maps: int, shot: Path) -> list[str]:
    """Open `url` and look until the lab's layout with `maps` maps is drawn or DEADLINE passes; what
    is still missing (empty: all there). The last screenshot is kept at `shot`."""
    from PIL import Image

    page.open(url)
    deadline = time.monotonic() + DEADLINE
    while True:
        time.sleep(2.0)
        pixels = page.screenshot()
        missing = the_lab_layout(pixels, maps)
        if not missing or time.monotonic() > deadline:
            Image.fromarray(pixels).save(shot)
            return missing


# -- the browser and the recordings ----------------------------------------------------------------
@pytest.fixture
def page():
    """A fresh Chromium for each test (one page of the web viewer per browser: a second one in the
    same tab lost its page there)."""
    try:
        browser = HeadlessBrowser(BROWSER)
    except (DevToolsError, OSError) as error:  # e.g. a snap's wrapper that cannot run in a container
        pytest.skip(f"{BROWSER} does not start as a headless Chromium here ({error})")
    with browser:
        if not browser.evaluate("!!document.createElement('canvas').getContext('webgl2')"):
            pytest.skip("this Chromium has no WebGL 2 (it needs SwiftShader): the web viewer cannot draw")
        yield browser


def recording_with_a_default_layout(path: Path) -> Path:
    """A run in a caller's own stream saved to `path`: the recording first, then the lab's blueprint
    as the application's default only (what every file held before its layout was written active)."""
    stream = rr.RecordingStream(APPLICATION_ID)
    stream.save(path)
    simulate(Robot(0.3, 0.5, (3.5, 1.5)), Maze(PAPER_MAZE), 0.3, 0.5, 300, 6, seed=3, visualize=stream)
    stream.disconnect()
    return path


def activations(path: Path) -> list[tuple[bool, bool]]:
    """(make_active, make_default) of each blueprint activation in an .rrd file, in order, as Rerun's
    own `rerun rrd print` reads them (the Python reader does not show them)."""
    done = subprocess.run([viewer_executable(), "rrd", "print", str(path)], env=rerun_environment(),
                          capture_output=True, text=True, timeout=120)  # fmt: skip
    assert done.returncode == 0, done.stderr
    found = re.findall(r"^BlueprintActivationCommand\(.*make_active: (\w+), make_default: (\w+)\)$", done.stdout, re.M)
    return [(active == "true", default == "true") for active, default in found]


def contents(path: Path) -> dict[str, int]:
    """{entity: rows} of the recording in an .rrd file (its blueprint left out)."""
    reader = RrdReader(path)
    (store,) = reader.recordings()
    rows: dict[str, int] = {}
    for chunk in reader.stream(store=store):
        rows[chunk.entity_path] = rows.get(chunk.entity_path, 0) + chunk.to_record_batch().num_rows
    return rows


def served_by_mazelab_view(path: Path):
    """`main.py view PATH` as a user starts it; the address it prints (a line of its own, copied whole),
    then Ctrl-C."""
    process = subprocess.Popen([sys.executable, str(ROOT / "main.py"), "view", str(path)], stdout=subprocess.PIPE,
                               stderr=subprocess.PIPE, text=True)  # fmt: skip
    printed = "".join(process.stdout.readline() for _ in range(3))
    return process, re.search(r"^(http://127\.0\.0\.1:\d+/\S*)$", printed, re.M)


def stop(process: subprocess.Popen) -> str:
    process.send_signal(signal.SIGINT)
    out, err = process.communicate(timeout=30)
    assert process.returncode == 0 and "Traceback" not in err, err
    return out


@needs_browser
def test_mazelab_view_shows_a_comparison_with_its_three_maps(tmp_path, page):
    """`compare` saved: three maps side by side across the window, each with its stations and its
    filter's particles."""
    path, scenario = tmp_path / "compare.rrd", tmp_path / "walk.json"
    assert main([*SHORT_RUN, "--no-viz", "--save-scenario", str(scenario)]) == 0
    assert main(["compare", str(scenario), "--rrd", str(path)]) == 0
    process, address = served_by_mazelab_view(path)
    try:
        assert address, "mazelab view printed no address"
        assert looks_like(page, address.group(1), maps=3, shot=tmp_path / "compare.png") == []
    finally:
        stop(process)
    from PIL import Image

    # Rerun's own side panels start collapsed: the three maps have the window's width (with them open,
    # about 45% of a 1400 x 900 window went to the panels and the stations spanned less than half of it)
    pixels = np.asarray(Image.open(tmp_path / "compare.png").convert("RGB"))
    dots = station_dots(pixels)
    assert (max(box[3] for box in dots) - min(box[1] for box in dots)) / pixels.shape[1] > 0.65


@needs_browser
def test_mazelab_view_shows_the_layout_of_a_file_that_only_has_it_as_default(tmp_path, page):
    """A recording whose blueprint is only the application's default, not the active one: what a
    caller's own stream gets and what runs saved before the layout was written active hold. Served
    as a file, the web viewer shows its automatic grid for it; `mazelab view` shows the layout."""
    path = recording_with_a_default_layout(tmp_path / "own.rrd")
    assert activations(path) == [(False, True)]
    process, address = served_by_mazelab_view(path)
    try:
        assert looks_like(page, address.group(1), maps=1, shot=tmp_path / "own.png") == []
    finally:
        stop(process)


@needs_browser
def test_a_saved_run_has_its_layout_in_the_web_viewer_whoever_serves_the_file(tmp_path, page):
    """The file itself makes its layout the active one: `rerun --serve-web FILE` (Rerun's own
    server, the file as it is on disk) shows it too."""
    path = tmp_path / "run.rrd"
    assert main([*SHORT_RUN, "--rrd", str(path)]) == 0
    grpc_port, web_port = free_port(), free_port()
    arguments = ["--serve-web", "--bind", "127.0.0.1", "--port", str(grpc_port), "--web-viewer-port", str(web_port)]
    server = WebServer(start_rerun([*arguments, str(path)], [grpc_port, web_port], detached=False), grpc_port, web_port)
    try:
        assert looks_like(page, server.url, maps=1, shot=tmp_path / "served.png") == []
    finally:
        server.stop()


# -- the file's part, without a browser ------------------------------------------------------------
def test_a_saved_run_and_comparison_make_their_one_layout_active(tmp_path):
    """Every file the lab writes holds one blueprint, the application's default and active too, so
    that a viewer that has the recording before the layout still shows the layout."""
    run, compare, scenario = tmp_path / "run.rrd", tmp_path / "compare.rrd", tmp_path / "walk.json"
    assert main([*SHORT_RUN, "--rrd", str(run), "--save-scenario", str(scenario)]) == 0
    assert main(["compare", str(scenario), "--rrd", str(compare)]) == 0
    for path in (run, compare):
        assert len(RrdReader(path).blueprints()) == 1
        assert activations(path) == [(True, True)]


def test_view_replays_a_file_with_its_layout_first_and_active_and_the_recording_whole(tmp_path):
    """What `mazelab view` sends for a file whose layout is only the default: the layout made active,
    then every row of the recording, under the file's own ids."""
    original = recording_with_a_default_layout(tmp_path / "own.rrd")
    sinks = []
    replay_with_layout(original, lambda stream: sinks.append(stream.binary_stream()))
    replayed = tmp_path / "replayed.rrd"
    replayed.write_bytes(sinks[0].read())
    assert activations(replayed) == [(True, True)]
    assert contents(replayed) == contents(original)
    (before,), (after,) = RrdReader(original).recordings(), RrdReader(replayed).recordings()
    assert (after.application_id, after.recording_id) == (before.application_id, before.recording_id)


@pytest.mark.parametrize(
    ("damage", "problem"),
    [
        (lambda data: data + b"garbage\n", "not a whole Rerun recording: something follows the end"),
        (lambda data: data + np.random.default_rng(1).bytes(4096), "not a whole Rerun recording: something follows"),
        (lambda data: data[: len(data) // 2], "not a Rerun recording (.rrd), or a damaged one"),
        (lambda data: data[:-40], "not a Rerun recording (.rrd), or a damaged one"),
        (lambda data: data[:1000] + bytes(64) + data[1064:], "a damaged Rerun recording: part of it cannot be"),
    ],
    ids=["text appended", "bytes appended", "cut in half", "end marker cut", "damaged in the middle"],
)
def test_view_refuses_a_file_that_is_not_a_whole_recording(tmp_path, capsys, monkeypatch, damage, problem):
    def served(cls, *recordings):
        raise AssertionError("mazelab view went on to serve it")

    monkeypatch.setattr(WebServer, "start", classmethod(served))  # a refused file never gets this far
    whole = tmp_path / "run.rrd"
    assert main([*SHORT_RUN, "--rrd", str(whole)]) == 0
    assert recording_problem(whole) is None
    damaged = tmp_path / "damaged.rrd"
    damaged.write_bytes(damage(whole.read_bytes()))
    capsys.readouterr()
    assert main(["view", str(damaged)]) == 2
    captured = capsys.readouterr()
    assert captured.err.startswith(f"error: {damaged}: {problem}") and captured.err.count("\n") == 1
    assert "Serving" not in captured.out


def test_view_with_rerun_switched_off_says_so_in_one_line(tmp_path, capsys, monkeypatch):
    whole = tmp_path / "run.rrd"
    assert main([*SHORT_RUN, "--rrd", str(whole)]) == 0
    capsys.readouterr()
    monkeypatch.setenv("RERUN", "off")
    assert main(["view", str(whole)]) == 2
    captured = capsys.readouterr()
    assert captured.err == f"error: {whole}: viewing needs Rerun, which RERUN=off switches off: unset RERUN\n"
    assert captured.out == ""


def test_view_prints_the_address_alone_on_its_line(tmp_path, capsys, monkeypatch):
    """The address is copied whole by selecting its line: no word or punctuation glued on."""
    whole, served = tmp_path / "run.rrd", []
    assert main([*SHORT_RUN, "--rrd", str(whole)]) == 0
    start = WebServer.start

    def start_and_stop_waiting(cls):
        server = start()
        wait = server.process.wait
        server.process.wait = lambda timeout=None: wait(timeout) if timeout is not None else _interrupt()
        served.append(server)
        return server

    monkeypatch.setattr(WebServer, "start", classmethod(start_and_stop_waiting))
    capsys.readouterr()
    assert main(["view", str(whole)]) == 0  # Ctrl-C ends serving, cleanly
    (server,) = served
    lines = capsys.readouterr().out.splitlines()
    assert server.url in lines and "press Ctrl-C to stop serving" in lines[lines.index(server.url) - 1]
    assert server.process.poll() is not None


def _interrupt() -> None:
    raise KeyboardInterrupt


# -- the native viewer (optional: pytest --rendering; needs a Vulkan driver, e.g. Mesa's lavapipe) -----
@pytest.mark.rendering
@pytest.mark.parametrize("written", ["by the lab", "with the layout as default only"])
def test_the_native_viewer_opens_a_saved_run_with_the_labs_layout(tmp_path, written):
    """`rerun FILE` (here Rerun's headless native viewer): the stations, the particles, the step
    panel above the map, for a file the lab writes and for one whose layout is only the default."""
    from PIL import Image
    from rerun.experimental import ViewerClient

    from mazelab.viz import processes

    path = tmp_path / "run.rrd"
    if written == "by the lab":
        assert main([*SHORT_RUN, "--rrd", str(path)]) == 0
    else:
        recording_with_a_default_layout(path)
    client = ViewerClient.spawn(headless=True, port=processes.free_port(), hide_welcome_screen=True,
                                executable_path=processes.viewer_executable())  # fmt: skip
    with client:
        client.open(str(path))
        deadline = time.monotonic() + DEADLINE
        while True:
            time.sleep(2.0)
            client.save_screenshot(str(tmp_path / "native.png"))
            missing = the_lab_layout(np.asarray(Image.open(tmp_path / "native.png").convert("RGB")), maps=1)
            if not missing or time.monotonic() > deadline:
                break
        client.quit()
    assert missing == []
