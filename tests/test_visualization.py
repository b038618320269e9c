"""The Rerun drawing: every run's recording is read back (rerun.chunk.RrdReader) and checked.

No display and no network: recordings go to .rrd files; the one web-viewer test talks to 127.0.0.1.
"""

from __future__ import annotations

import os
import subprocess
import sys
import uuid
from collections import defaultdict
from pathlib import Path

import numpy as np
import pytest
import rerun as rr
import rerun.blueprint as rrb
from conftest import PAPER_MAZE, ROOT
from rerun.chunk import RrdReader

from mazelab.cli.app import main
from mazelab.grid_filter import GRID_RESOLUTION
from mazelab.maze import Maze
from mazelab.model import CONFIDENCE_RADIUS
from mazelab.robot import Robot
from mazelab.simulation import simulate
from mazelab.viz import processes
from mazelab.viz import recording as viz_recording
from mazelab.viz.recording import NO_DISPLAY, Visualization, heading_vectors
from mazelab.viz.style import (
    CONFIDENT_COLOR,
    ESTIMATE_COLOR,
    INJECTED_COLOR,
    KIDNAP_COLOR,
    PARTICLE_ARROW_LENGTH,
    ROBOT_ARROW_LENGTH,
    STATION_COLOR,
    entity_name,
)
from mazelab.viz.views import open_comparison

FILTERS = ["SIRParticleFilter", "AuxiliaryParticleFilter", "RegularizedParticleFilter"]
# positions are logged as float32: on a map of at most 10 units that keeps ~1e-6 of them
FLOAT32_ATOL = 1e-5


# -- reading a recording back ----------------------------------------------------------------------
def load(path: Path, kind: str = "recording") -> dict[str, dict]:
    """{entity: {step | "static" | blueprint time: {component: list of instances}}} of an .rrd file."""
    reader = RrdReader(path)
    stores = reader.recordings() if kind == "recording" else reader.blueprints()
    assert len(stores) == 1
    out: dict[str, dict] = defaultdict(dict)
    for chunk in reader.stream(store=stores[0]):  # an entity may be spread over several chunks
        batch = chunk.to_record_batch()
        components = [f.name for f in batch.schema if (f.metadata or {}).get(b"rerun:kind") == b"data"]
        if chunk.is_static:
            keys = ["static"] * batch.num_rows
        else:
            index = "step" if kind == "recording" else "blueprint"
            keys = batch.column(index).to_pylist()
        for i, key in enumerate(keys):
            row = out[chunk.entity_path].setdefault(key, {})
            for component in components:
                value = batch.column(component)[i].as_py()
                if value is not None:
                    row[component] = value
    return out


def latest(rows: dict) -> dict:
    """The last logged row of a blueprint entity."""
    return rows[max(rows, key=str)]


def layout(path: Path) -> tuple:
    """The blueprint as a tree: ("container", kind, [children]) or ("view", class, name, origin, query)."""
    bp = load(path, "blueprint")

    def node(ref: str) -> tuple:
        rows = latest(bp[f"/{ref}"])
        if ref.startswith("view/"):
            query = latest(bp[f"/{ref}/ViewContents"])["ViewContents:query"]
            return ("view", rows["ViewBlueprint:class_identifier"][0], rows["ViewBlueprint:display_name"][0],
                    rows["ViewBlueprint:space_origin"][0], query)  # fmt: skip
        kind = {1: "tabs", 2: "horizontal", 3: "vertical", 4: "grid"}[rows["ContainerBlueprint:container_kind"][0]]
        return ("container", kind, [node(child) for child in rows["ContainerBlueprint:contents"]])

    root = uuid.UUID(bytes=bytes(latest(bp["/viewport"])["ViewportBlueprint:root_container"][0]))
    return node(f"container/{root}")


def views(tree: tuple) -> list[tuple]:
    """Every view in a layout tree, in order."""
    return [tree] if tree[0] == "view" else [v for child in tree[2] for v in views(child)]


def rgb(packed: int) -> tuple[int, int, int]:
    """Rerun stores colours as packed RGBA (0xRRGGBBAA)."""
    return (packed >> 24) & 255, (packed >> 16) & 255, (packed >> 8) & 255


def steps_of(entity: dict) -> list[int]:
    return sorted(k for k in entity if k != "static")


# -- runs to draw ----------------------------------------------------------------------------------
@pytest.fixture
def world() -> Maze:
    return Maze(PAPER_MAZE)


def recorded_run(world, visualize, *, particles=200, steps=12, name="SIRParticleFilter", seed=4):
    """Run a filter, keeping a copy of what the filter held after each step (to compare with the drawing)."""
    states: dict[int, dict] = {}

    def keep(k, robot, filt):
        belief = filt.belief()
        headings = getattr(belief, "headings", None)
        states[k] = {"positions": belief.positions.copy(), "headings": headings, "weights": belief.weights}
        states[k]["heading"] = robot.heading

    robot = Robot(0.3, 0.5, (3.5, 1.5))
    result = simulate(robot, world, 0.3, 0.5, particles, steps, filtering_algorithm=name, seed=seed,
                      visualize=visualize, on_step=keep)  # fmt: skip
    return result, states


# -- one run ---------------------------------------------------------------------------------------
def test_the_static_maze_walls_stations_and_the_y_up_map_frame(tmp_path, world):
    path = tmp_path / "run.rrd"
    recorded_run(world, path, steps=2)
    rec = load(path)
    image = rec["/map/maze"]["static"]
    (fmt,) = image["Image:format"]
    assert (fmt["height"], fmt["width"]) == world.grid.shape
    pixels = np.array(image["Image:buffer"], dtype=np.uint8).reshape(world.height, world.width, 3)
    walls = (pixels == 0).all(axis=2)
    assert walls.sum() == np.count_nonzero(world.grid) == 9  # the paper's maze: 9 wall blocks, filled
    assert ((pixels == 255).all(axis=2) == ~walls).all()  # every other cell white
    np.testing.assert_array_equal(walls, world.grid[::-1] != 0)  # image row j is map y in [j, j+1)
    stations = rec["/map/stations"]["static"]
    np.testing.assert_array_equal(stations["Points2D:positions"], world.stations)
    assert len(stations["Points2D:positions"]) == 8  # two station blocks, four corners each
    assert {rgb(c) for c in stations["Points2D:colors"]} == {STATION_COLOR}
    # the map frame (y up) is turned into the view's (y down): y_view = H - y, x unchanged
    transform = rec["/map"]["static"]
    assert transform["Transform3D:translation"] == [[0.0, world.height, 0.0]]
    assert transform["Transform3D:scale"] == [[1.0, -1.0, 1.0]]


def test_every_step_has_the_robot_all_particles_the_estimate_and_the_series(tmp_path, world):
    path = tmp_path / "run.rrd"
    result, states = recorded_run(world, path, particles=300, steps=12)
    rec = load(path)
    steps = list(range(1, 13))
    slug = entity_name("SIRParticleFilter")
    for entity in ["/map/robot", "/map/robot/heading", "/title", f"/map/{slug}/particles", f"/map/{slug}/estimate"]:
        assert steps_of(rec[entity]) == steps, entity
    for k in steps:
        truth = result.true_positions[k - 1]
        np.testing.assert_allclose(rec["/map/robot"][k]["Points2D:positions"], [truth], atol=FLOAT32_ATOL)
        heading = rec["/map/robot/heading"][k]
        np.testing.assert_allclose(heading["Arrows2D:origins"], [truth], atol=FLOAT32_ATOL)
        expected = heading_vectors(np.array([states[k]["heading"]]), ROBOT_ARROW_LENGTH)
        np.testing.assert_allclose(heading["Arrows2D:vectors"], expected, atol=FLOAT32_ATOL)
        assert rec["/title"][k]["TextDocument:text"] == [f"### Step {k}"]

        particles = rec[f"/map/{slug}/particles"][k]
        assert len(particles["Arrows2D:origins"]) == len(particles["Arrows2D:colors"]) == 300
        np.testing.assert_allclose(particles["Arrows2D:origins"], states[k]["positions"], atol=FLOAT32_ATOL)
        vectors = heading_vectors(states[k]["headings"], PARTICLE_ARROW_LENGTH)
        np.testing.assert_allclose(particles["Arrows2D:vectors"], vectors, atol=FLOAT32_ATOL)
        colors = np.array([rgb(c) for c in particles["Arrows2D:colors"]])
        heaviest = np.argmax(states[k]["weights"])
        assert tuple(colors[heaviest]) == (255, 0, 0)  # the heaviest particle is red
        assert (colors[:, 0].astype(int) + colors[:, 2] >= 254).all() and (colors[:, 1] == 0).all()  # blue..red

        estimate = rec[f"/map/{slug}/estimate"][k]
        np.testing.assert_allclose(estimate["Ellipses2D:centers"], [result.estimates[k - 1]], atol=FLOAT32_ATOL)
        assert estimate["Ellipses2D:half_sizes"] == [[CONFIDENCE_RADIUS, CONFIDENCE_RADIUS]]
        color = CONFIDENT_COLOR if result.confident[k - 1] else ESTIMATE_COLOR
        assert [rgb(c) for c in estimate["Ellipses2D:colors"]] == [color]

    def series(kind: str) -> np.ndarray:
        entity = rec[f"/metrics/{kind}/{slug}"]
        assert entity["static"]["SeriesLines:names"] == ["SIRParticleFilter"]
        assert steps_of(entity) == steps
        return np.array([entity[k]["Scalars:scalars"][0] for k in steps])

    np.testing.assert_allclose(series("error"), result.errors, rtol=1e-12)
    np.testing.assert_allclose(series("ess"), result.ess, rtol=1e-12)
    np.testing.assert_array_equal(series("confident"), result.confident.astype(float))


def test_the_single_run_blueprint(tmp_path, world):
    path = tmp_path / "run.rrd"
    recorded_run(world, path, steps=2, name="apf")
    tree = layout(path)
    slug = entity_name("AuxiliaryParticleFilter")
    assert tree[:2] == ("container", "horizontal")
    found = views(tree)
    assert [v[1] for v in found] == ["TextDocument", "2D", "TimeSeries", "TimeSeries", "TimeSeries"]
    assert found[1][2:] == (
        "AuxiliaryParticleFilter",
        "/",
        ["/map/maze", "/map/stations", "/map/robot/**", f"/map/{slug}/**"],
    )
    assert [v[3] for v in found[2:]] == ["/metrics/error", "/metrics/ess", "/metrics/confident"]


@pytest.mark.parametrize("kind", ["run", "comparison"])
def test_the_viewer_opens_with_the_labs_panels_and_the_whole_estimate_in_each_map(tmp_path, world, kind):
    """Rerun's own side panels (the blueprint tree, the selection) start collapsed, and the time panel as
    its play bar on the step timeline: expanded they took about 45% of a 1400 x 900 window. Each map
    view shows the map and around it the estimate's circle and a mode's label, wherever the estimate
    lies on the map (they were clipped at the view's left edge)."""
    path = tmp_path / f"{kind}.rrd"
    if kind == "run":
        recorded_run(world, path, steps=2)
    else:
        open_comparison(path, world, FILTERS).close()
    blueprint = load(path, "blueprint")
    collapsed = rrb.PanelState.Collapsed.value
    assert latest(blueprint["/blueprint_panel"]) == {"PanelBlueprint:state": [collapsed]}
    assert latest(blueprint["/selection_panel"]) == {"PanelBlueprint:state": [collapsed]}
    time_panel = latest(blueprint["/time_panel"])
    assert time_panel["TimePanelBlueprint:state"] == [collapsed]
    assert time_panel["TimePanelBlueprint:timeline"] == ["step"]
    bounds = [latest(rows)["VisualBounds2D:range"][0] for entity, rows in blueprint.items()
              if entity.endswith("/VisualBounds2D")]  # fmt: skip
    assert len(bounds) == (1 if kind == "run" else 3)
    room = CONFIDENCE_RADIUS + 0.2  # the circle, its line and a label such as "100%" above a mode, in map units
    for bound in bounds:
        (left, right), (bottom, top) = bound["x_range"], bound["y_range"]
        assert left <= -room and right >= world.width + room and bottom <= -room and top >= world.height + room


def test_max_drawn_thins_what_is_drawn_not_what_is_filtered(tmp_path, world):
    path = tmp_path / "run.rrd"
    _, states = recorded_run(world, Visualization(path, max_drawn=150), particles=1000, steps=3)
    particles = load(path)[f"/map/{entity_name('SIRParticleFilter')}/particles"]
    for k in (1, 2, 3):
        drawn = np.array(particles[k]["Arrows2D:origins"])
        assert len(drawn) == 150
        assert len(states[k]["positions"]) == 1000  # the filter kept all its particles
        # every drawn arrow is one of the filter's particles, spread evenly over its indices
        picked = np.linspace(0, 999, 150).round().astype(int)
        np.testing.assert_allclose(drawn, states[k]["positions"][picked], atol=FLOAT32_ATOL)


def test_the_grid_filter_draws_at_most_max_drawn_cells_where_its_mass_is(tmp_path, world):
    path = tmp_path / "run.rrd"
    _, states = recorded_run(world, Visualization(path, max_drawn=400), name="grid", steps=3)
    rec = load(path)
    slug = entity_name("GridBayesFilter")
    assert f"/metrics/ess/{slug}" not in rec or steps_of(rec[f"/metrics/ess/{slug}"]) == []  # no ESS: not a sample
    for k in (1, 2, 3):
        cells = np.array(rec[f"/map/{slug}/particles"][k]["Points2D:positions"])
        assert 0 < len(cells) <= 400 and len(np.unique(cells, axis=0)) == len(cells)
        # each dot is a cell centre of the grid (origin -1, cell size GRID_RESOLUTION) inside the map
        offsets = (cells + 1.0) / GRID_RESOLUTION - 0.5
        np.testing.assert_allclose(offsets, np.round(offsets), atol=1e-3)
        # a systematic pick of 400 points of the mass: each cell holding 1/400 of it is hit
        weights, positions = states[k]["weights"], states[k]["positions"]
        heavy = positions[weights >= 1 / 400]
        drawn = {tuple(np.round(c, 4)) for c in cells}
        assert all(tuple(np.round(p, 4)) in drawn for p in heavy)


def test_a_kidnapping_shows_the_jump_the_injected_particles_and_the_particle_count(tmp_path, world):
    """Kidnapped at step 8 with sensor resetting and KLD-sampling: at step 8 a line joins the robot's
    place at step 7 to where it was put down, the title says so; every particle that recovery injected
    is drawn in INJECTED_COLOR and no other is; the count series is the filter's count per step."""
    path = tmp_path / "kidnap.rrd"
    injected: dict[int, np.ndarray | None] = {}

    def keep(k, robot, filt):
        injected[k] = None if filt.injected is None else filt.injected.copy()

    robot = Robot(0.3, 0.5, (3.5, 1.5))
    result = simulate(robot, world, 0.3, 0.5, 400, 25, seed=3, visualize=path, on_step=keep, kidnap_at=8,
                      recovery="sensor", kld=True)  # fmt: skip
    rec = load(path)
    jump = rec["/map/robot/kidnapping"]
    assert steps_of(jump) == [8]
    expected = [result.true_positions[6], result.scenario.kidnap_position]
    np.testing.assert_allclose(jump[8]["LineStrips2D:strips"], [expected], atol=FLOAT32_ATOL)
    assert [rgb(c) for c in jump[8]["LineStrips2D:colors"]] == [KIDNAP_COLOR]
    assert steps_of(rec["/map/robot/kidnapping/place"]) == [8]
    assert rec["/title"][8]["TextDocument:text"] == ["### Step 8: the robot is kidnapped"]
    assert rec["/title"][9]["TextDocument:text"] == ["### Step 9"]

    slug = entity_name("SIRParticleFilter")
    assert any(mask is not None and mask.any() for mask in injected.values())  # the test sees an injection
    for k, mask in injected.items():
        colors = [rgb(c) for c in rec[f"/map/{slug}/particles"][k]["Arrows2D:colors"]]
        drawn_injected = np.array([c == INJECTED_COLOR for c in colors])
        assert len(colors) == result.extras["particle_count"][k - 1]
        np.testing.assert_array_equal(drawn_injected, np.zeros(len(colors), bool) if mask is None else mask)

    count = rec[f"/metrics/ess/{slug}/particle_count"]
    assert count["static"]["SeriesLines:names"] == ["SIRParticleFilter N"]
    assert [count[k]["Scalars:scalars"][0] for k in steps_of(count)] == result.extras["particle_count"].tolist()


def test_without_kld_no_particle_count_is_drawn(tmp_path, world):
    path = tmp_path / "run.rrd"
    recorded_run(world, path, steps=3)
    assert not any(entity.endswith("/particle_count") for entity in load(path))


# -- the comparison --------------------------------------------------------------------------------
def test_the_comparison_shows_each_filter_side_by_side_and_every_error_below(tmp_path, world):
    path = tmp_path / "compare.rrd"
    robot = Robot(0.3, 0.5, (3.5, 1.5))
    scenario = simulate(robot, world, 0.3, 0.5, 250, 10, seed=9).scenario
    comparison = open_comparison(path, world, FILTERS)
    results = {}
    for name in FILTERS:
        replay = scenario.robot(0.3, 0.5)
        results[name] = simulate(replay, world, 0.3, 0.5, init_particles_pos=scenario.init_particles_pos,
                                 filtering_algorithm=name, seed=1, visualize=comparison.view_for(name))  # fmt: skip
    comparison.close()

    tree = layout(path)
    assert tree[:2] == ("container", "vertical")
    title, maps, errors = tree[2]
    assert title[:2] == ("view", "TextDocument")
    assert maps[:2] == ("container", "horizontal")
    assert [(v[1], v[2], v[3]) for v in maps[2]] == [("2D", name, "/") for name in FILTERS]
    for view, name in zip(maps[2], FILTERS, strict=True):
        assert view[4] == ["/map/maze", "/map/stations", "/map/robot/**", f"/map/{entity_name(name)}/**"]
    assert errors[:4] == ("view", "TimeSeries", errors[2], "/metrics/error")
    assert [v[1] for v in views(tree)].count("TimeSeries") == 1
    legends = [latest(rows) for entity, rows in load(path, "blueprint").items() if entity.endswith("/PlotLegend")]
    assert [row["PlotLegend:corner"] for row in legends] == [[rrb.Corner2D.RightTop.value]]  # off the first steps

    rec = load(path)
    steps = list(range(1, 11))
    assert steps_of(rec["/map/robot"]) == steps
    assert all(len(rec["/map/robot"][k]["Points2D:positions"]) == 1 for k in steps)  # the robot, once
    for name in FILTERS:
        slug = entity_name(name)
        assert all(len(rec[f"/map/{slug}/particles"][k]["Arrows2D:origins"]) == 250 for k in steps)
        errors = [rec[f"/metrics/error/{slug}"][k]["Scalars:scalars"][0] for k in steps]
        np.testing.assert_allclose(errors, results[name].errors, rtol=1e-12)
        assert rec[f"/metrics/error/{slug}"]["static"]["SeriesLines:names"] == [name]
    with pytest.raises(ValueError, match="not in this comparison"):
        comparison.view_for("GridBayesFilter")


# -- where it goes ---------------------------------------------------------------------------------
def test_without_a_display_a_run_is_saved_in_recordings_and_says_where(world, capsys):
    recorded_run(world, True, steps=2)
    (path,) = viz_recording.RECORDINGS_DIR.glob("*.rrd")
    assert path.name.startswith("sir_particle_filter-")
    out = capsys.readouterr().out
    assert f"; {NO_DISPLAY}, so open it with: " in out and f"mazelab view {path}" in out
    assert steps_of(load(path)["/map/robot"]) == [1, 2]
    recorded_run(world, "viewer", steps=1)  # asked for the viewer: falls back to a file, saying so
    assert len(list(viz_recording.RECORDINGS_DIR.glob("*.rrd"))) == 2
    assert f"; {NO_DISPLAY}, so open it with: " in capsys.readouterr().out
    assert not list(viz_recording.RECORDINGS_DIR.glob(".*partial"))  # complete files only


def test_a_callers_own_recording_gets_the_run_and_stays_open(tmp_path, world):
    path = tmp_path / "mine.rrd"
    stream = rr.RecordingStream("my_experiment")
    stream.save(path)
    recorded_run(world, stream, steps=3)
    stream.log("/my/note", rr.TextLog("still open"), static=True)
    stream.disconnect()
    rec = load(path)
    assert steps_of(rec["/map/robot"]) == [1, 2, 3] and "/my/note" in rec


def test_bad_targets_are_one_clear_error(tmp_path, world):
    with pytest.raises(ValueError, match="does not exist"):
        recorded_run(world, tmp_path / "missing" / "x.rrd", steps=1)
    with pytest.raises(ValueError, match="is a folder"):
        recorded_run(world, tmp_path, steps=1)
    with pytest.raises(ValueError, match="max_drawn"):
        Visualization(True, max_drawn=0)


def test_the_web_viewer_binds_localhost_and_ctrl_c_ends_it_cleanly(world, monkeypatch, capsys):
    servers = []
    start = processes.WebServer.start
    monkeypatch.setattr(processes.WebServer, "start", classmethod(lambda cls: servers.append(start()) or servers[-1]))

    def interrupt(k, robot, filt):
        if k == 3:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        simulate(Robot(0.3, 0.5, (3.5, 1.5)), world, 0.3, 0.5, 100, 10, seed=1, visualize="web", on_step=interrupt)
    (server,) = servers
    assert server.url.startswith(f"http://127.0.0.1:{server.web_port}/?url=rerun%2Bhttp%3A%2F%2F127.0.0.1%3A")
    assert server.process.poll() is not None  # interrupted mid-run: stopped at once, no waiting
    assert server.process.args[1:4] == ["--serve-web", "--bind", "127.0.0.1"]
    (path,) = viz_recording.RECORDINGS_DIR.glob("*.rrd")  # the copy on disk holds the steps done
    assert steps_of(load(path)["/map/robot"]) == [1, 2, 3]
    assert "Serving the web viewer at http://127.0.0.1:" in capsys.readouterr().out


def test_after_a_web_run_the_viewer_is_served_until_ctrl_c(world, monkeypatch, capsys):
    servers = []
    start = processes.WebServer.start

    def start_and_interrupt_the_wait(cls):
        server = start()
        server.process.wait = _ctrl_c_once(server.process.wait)
        servers.append(server)
        return server

    monkeypatch.setattr(processes.WebServer, "start", classmethod(start_and_interrupt_the_wait))
    simulate(Robot(0.3, 0.5, (3.5, 1.5)), world, 0.3, 0.5, 100, 4, seed=1, visualize="web")
    (server,) = servers
    assert server.process.poll() is not None
    out = capsys.readouterr().out
    assert "press Ctrl-C to stop serving" in out and "Stopped serving" in out
    assert out.count(server.url) == 1 and "Open the address above in a browser" in out  # printed as the run started


def _ctrl_c_once(wait):
    """A Popen.wait whose first untimed call is interrupted by Ctrl-C (as a user waiting would)."""
    calls = []

    def wrapped(timeout=None):
        if timeout is None and not calls:
            calls.append(1)
            raise KeyboardInterrupt
        return wait(timeout=timeout)

    return wrapped


def test_the_rerun_processes_we_start_have_analytics_off_and_ours_is_left_alone(monkeypatch):
    monkeypatch.delenv("CI", raising=False)
    assert processes.rerun_environment()["CI"] == "1" and "CI" not in os.environ
    monkeypatch.setenv("CI", "true")
    assert processes.rerun_environment()["CI"] == "true"


def test_a_viewer_that_cannot_open_falls_back_to_a_file_at_once(world, monkeypatch, capsys):
    """A display that is set but unusable: the viewer exits, and the run is saved instead (no waiting)."""
    import time

    monkeypatch.setattr(viz_recording, "has_display", lambda: True)
    monkeypatch.setattr(processes, "VIEWER_PORT", processes.free_port())
    monkeypatch.setenv("DISPLAY", ":424242")  # no such X server
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    started = time.monotonic()
    recorded_run(world, "viewer", steps=2)
    assert time.monotonic() - started < 10
    assert "the Rerun viewer did not start" in capsys.readouterr().out
    (path,) = viz_recording.RECORDINGS_DIR.glob("*.rrd")
    assert steps_of(load(path)["/map/robot"]) == [1, 2]


# -- the command line ------------------------------------------------------------------------------
def test_cli_rrd_and_max_drawn(tmp_path, capsys):
    path = tmp_path / "run.rrd"
    args = ["run", "--maze", "paper_5x5", "--steps", "4", "--particles", "120", "--seed", "3", "--quiet"]
    assert main([*args, "--rrd", str(path), "--max-drawn", "50"]) == 0
    particles = load(path)[f"/map/{entity_name('SIRParticleFilter')}/particles"]
    assert [len(particles[k]["Arrows2D:origins"]) for k in (1, 2, 3, 4)] == [50] * 4
    assert f"mazelab view {path}" in capsys.readouterr().out
    assert main([*args, "--rrd", str(path)]) == 2  # exists: refused without --force
    assert "use --force" in capsys.readouterr().err
    assert main([*args, "--rrd", str(path), "--force"]) == 0
    assert main([*args, "--rrd", str(path), "--web"]) == 2
    assert main([*args, "--max-drawn", "0"]) == 2


@pytest.mark.skipif(sys.platform in ("darwin", "win32"), reason="there a display always exists: the viewer opens")
def test_the_demo_without_a_display_writes_a_recording_and_says_where(tmp_path):
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}
    done = subprocess.run([sys.executable, str(ROOT / "main.py")], cwd=tmp_path, env=env, capture_output=True,
                          text=True, timeout=120)  # fmt: skip
    assert done.returncode == 0, done.stderr
    (path,) = (tmp_path / "recordings").glob("sir_particle_filter-*.rrd")
    relative = path.relative_to(tmp_path)
    assert f"Recording saved to {relative}; " in done.stdout
    assert f"{NO_DISPLAY}, so open it with: " in done.stdout
    assert f"main.py view {relative}" in done.stdout  # started as the script: the hint names the script
    rec = load(path)
    assert steps_of(rec["/map/robot"]) == list(range(1, 201))
    assert len(rec["/map/sir_particle_filter/particles"][200]["Arrows2D:origins"]) == 1500


# -- rendering (optional: pytest --rendering -k rendered; needs a Vulkan driver, e.g. Mesa's lavapipe) -----
@pytest.mark.rendering
def test_the_rendered_recording_shows_the_upright_maze(tmp_path, world):
    """The headless viewer renders a saved run; in the PNG the maze is a white square whose black
    share is the wall share of the paper's maze (9 of 25 cells), walls where the map puts them."""
    import time

    from PIL import Image
    from rerun.experimental import ViewerClient

    path, png = tmp_path / "run.rrd", tmp_path / "run.png"
    recorded_run(world, path, steps=5)
    client = ViewerClient.spawn(headless=True, port=processes.free_port(), hide_welcome_screen=True,
                                executable_path=processes.viewer_executable())  # fmt: skip
    with client:
        client.open(str(path))
        client.set_time("step", sequence=5, play_state="paused")
        time.sleep(1.0)
        client.save_screenshot(str(png))
        client.quit()
    pixels = np.asarray(Image.open(png).convert("RGB")).astype(int)
    white = (pixels >= 250).all(axis=2)
    # the maze's rows and columns hold long runs of white; the viewer's text only short ones
    rows = np.flatnonzero(white.sum(axis=1) > white.sum(axis=1).max() / 4)
    cols = np.flatnonzero(white.sum(axis=0) > white.sum(axis=0).max() / 4)
    top, bottom, left, right = rows.min(), rows.max() + 1, cols.min(), cols.max() + 1
    assert abs((bottom - top) / (right - left) - 1) < 0.05  # a square maze, drawn square
    maze = pixels[top:bottom, left:right]
    black = (maze <= 5).all(axis=2)
    assert 0.30 < black.mean() < 0.40  # 9/25 = 0.36 of the maze is wall, filled black
    cell = (bottom - top) / world.height
    # upright: the top-left cell (row 0, column 0) is a station block (black), the cell right of it free
    assert black[int(cell / 2), int(cell / 2)] and not black[int(cell / 2), int(1.5 * cell)]
