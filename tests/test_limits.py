"""Limits up front: the memory budget (RAM, RLIMIT_AS, cgroups), the bounds of angles, places and json
nesting, and the progress of a long nearest-station table build."""

from __future__ import annotations

import json
import os
import resource
import subprocess
import sys

import numpy as np
import pytest
from conftest import PAPER_MAZE, ROOT

from mazelab import checks
from mazelab.checks import (
    MAX_ANGLE,
    MemoryBudget,
    MemoryLimitError,
    angle,
    cgroup_limits,
    check_memory,
    check_within_map,
    process_limits,
)
from mazelab.cli.maze import prepare_world
from mazelab.grid_filter import GridBayesFilter
from mazelab.lookup import _LOOKUP_TILE, NearestStationLookup
from mazelab.maze import Maze, MazeError
from mazelab.maze_generator import generate_maze, parse_size
from mazelab.robot import Robot
from mazelab.scenario import json_depth, load_scenario
from mazelab.simulation import simulate

GIB = 2**30


# -- the budget -------------------------------------------------------------------------------------
def test_a_request_beyond_the_share_of_the_budget_is_refused_naming_the_limit():
    budget = MemoryBudget(10 * GIB, "the address-space limit, ulimit -v")
    check_memory("particle_count 20000000", 8 * GIB, budget)  # exactly MEMORY_SHARE of it: accepted
    with pytest.raises(MemoryLimitError) as error:
        check_memory("particle_count 20000001", 8 * GIB + 1, budget)
    assert str(error.value) == (
        "particle_count 20000001 needs about 8.0 GiB, but only 10.0 GiB of memory is available "
        "(the address-space limit, ulimit -v)"
    )


def test_a_need_of_a_mib_or_less_reads_no_budget_and_is_never_refused(monkeypatch):
    """A run's particles and steps are checked several times a run: below the floor the budget (read from
    /proc and the cgroup files) is not read at all; above it, the same budget refuses."""
    tiny = MemoryBudget(1, "a test's budget")
    monkeypatch.setattr(checks, "memory_budget", lambda: pytest.fail("the budget was read"))
    check_memory("a small need", checks.MEMORY_CHECKED_BYTES)
    check_memory("a small need", checks.MEMORY_CHECKED_BYTES, tiny)
    with pytest.raises(MemoryLimitError, match=r"^a larger need needs about 0\.00 GiB"):
        check_memory("a larger need", checks.MEMORY_CHECKED_BYTES + 1, tiny)


def write_files(folder, files):
    for name, text in files.items():
        path = folder / name
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)


def test_a_cgroup_v2_limit_counts_its_ancestors_and_leaves_out_inactive_file_cache(tmp_path):
    """The group's own memory.max is "max" and its parent's is 4 GiB with 3 GiB used, 1 GiB of it
    inactive file cache: 2 GiB are left."""
    write_files(
        tmp_path,
        {
            "proc/cgroup": "0::/user.slice/job\n",
            "sys/user.slice/job/memory.max": "max\n",
            "sys/user.slice/job/memory.current": "1000\n",
            "sys/user.slice/memory.max": f"{4 * GIB}\n",
            "sys/user.slice/memory.current": f"{3 * GIB}\n",
            "sys/user.slice/memory.stat": f"anon 123\ninactive_file {GIB}\nactive_file 5\n",
        },
    )
    budgets = cgroup_limits(tmp_path / "sys", tmp_path / "proc")
    assert budgets == [MemoryBudget(2 * GIB, f"the cgroup memory limit, {tmp_path / 'sys/user.slice/memory.max'}")]


def test_a_cgroup_v1_limit_is_read_and_its_unlimited_value_ignored(tmp_path):
    write_files(
        tmp_path,
        {
            "proc/cgroup": "4:memory:/docker/abc\n3:cpu:/docker/abc\n",
            "sys/memory/docker/abc/memory.limit_in_bytes": f"{2 * GIB}\n",
            "sys/memory/docker/abc/memory.usage_in_bytes": f"{GIB}\n",
            "sys/memory/docker/abc/memory.stat": f"total_inactive_file {GIB // 2}\n",
            "sys/memory/memory.limit_in_bytes": "9223372036854771712\n",
        },
    )
    assert [b.available for b in cgroup_limits(tmp_path / "sys", tmp_path / "proc")] == [2 * GIB - GIB // 2]
    (tmp_path / "sys/memory/docker/abc/memory.limit_in_bytes").write_text("9223372036854771712\n")
    assert cgroup_limits(tmp_path / "sys", tmp_path / "proc") == []


def test_the_process_limits_are_read_as_set():
    soft, _ = resource.getrlimit(resource.RLIMIT_AS)
    budgets = process_limits()
    if soft == resource.RLIM_INFINITY and resource.getrlimit(resource.RLIMIT_DATA)[0] == resource.RLIM_INFINITY:
        assert budgets == []
    else:
        assert budgets and min(budget.available for budget in budgets) < soft


def test_rlimit_as_in_a_real_process_lowers_the_budget_so_a_moderate_particle_count_is_refused():
    """Under `ulimit -v` 1.5 GiB, 3 million particles (1.1 GiB of arrays) are refused with one line
    before anything is allocated, and the line names the limit."""
    limit = 3 * GIB // 2

    def lowered() -> None:
        resource.setrlimit(resource.RLIMIT_AS, (limit, limit))

    command = [sys.executable, str(ROOT / "main.py"), "run", "--steps", "1", "--no-viz", "--quiet"]
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1"}  # no per-core buffers to map
    refused = subprocess.run(
        [*command, "--particles", "3000000"], capture_output=True, text=True, timeout=120, preexec_fn=lowered, env=env
    )
    assert refused.returncode == 2, refused.stderr
    assert refused.stderr.startswith("error: particle_count 3000000 needs about 1.1 GiB, but only 1.")
    assert refused.stderr.endswith("GiB of memory is available (the address-space limit, ulimit -v)\n")
    assert len(refused.stderr.splitlines()) == 1
    budget = checks.memory_budget()
    if budget is not None and budget.available > 2 * GIB:  # without the limit, this machine takes them
        checks.particle_count(3_000_000)


def test_a_maze_too_large_is_refused_before_it_is_allocated():
    with pytest.raises(MazeError, match=r"^a 100000x100000 maze is too large: at most 4000 rows and 4000 columns$"):
        parse_size("100000x100000")
    with pytest.raises(MazeError, match="a 4001x2 maze is too large"):
        generate_maze(4001, 2, 1, np.random.default_rng(0))
    with pytest.raises(MazeError, match=r"^maze map: a 4001x2 maze is too large"):
        Maze(np.zeros((4001, 2), dtype=np.int8))


# -- the model's sense ------------------------------------------------------------------------------
@pytest.mark.parametrize("value", [MAX_ANGLE * (1 + 1e-15), -1e5, 1e300, 1.4e226])
def test_angles_beyond_the_bound_are_refused_by_the_robot(value):
    with pytest.raises(ValueError, match=r"^compass angle must lie within \[-10000, 10000\] radians"):
        Robot(0.3, 0.5, (3.5, 1.5), actual_angles=[1.0], compass_angles=[value])
    assert angle("a", -MAX_ANGLE) == -MAX_ANGLE


def test_points_beyond_the_map_and_margin_are_refused_naming_the_first():
    check_within_map("p", [[-10.0, -10.0], [15.0, 15.0]], 5, 5)  # on the margin's edge: accepted
    with pytest.raises(ValueError, match=r"^p\[1\] = \(15.5, 2\) lies more than 10 map units beyond the 5 x 5 map"):
        check_within_map("p", [[1.0, 1.0], [15.5, 2.0], [np.inf, 0]], 5, 5)


def test_simulate_refuses_far_particles_and_a_kidnap_position_in_a_wall(paper_world):
    robot = Robot(0.3, 0.5, (3.5, 1.5))
    with pytest.raises(ValueError, match=r"init_particles_pos\[0\] = \(1e\+39, 1\) lies more than 10 map units"):
        simulate(robot, paper_world, 0.3, 0.5, init_particles_pos=[[1e39, 1.0]], steps=2, seed=1)
    robot.kidnap(2, (0.5, 4.5))
    with pytest.raises(ValueError, match=r"the kidnap position \(0.5, 4.5\) is not in the free area"):
        simulate(robot, paper_world, 0.3, 0.5, 10, steps=3, seed=1)


@pytest.mark.parametrize(
    ("text", "depth"),
    [("", 0), ("1", 0), ("[]", 1), ('{"a": [[1, 2], [3]]}', 3), ('{"a": "[[[{{{", "b": ["\\"]]["]}', 2)],
)
def test_json_depth_counts_brackets_outside_strings(text, depth):
    assert json_depth(text) == depth


def test_a_scenario_at_the_depth_bound_loads_and_one_level_deeper_is_refused(tmp_path):
    scenario = {
        "init_robot_pos": [3.5, 1.5],
        "init_particles_pos": [[1.5, 3.5]],
        "robot_actual_angles": [1.1],
        "robot_compass_angles": [1.2],
        "maze": [list(row) for row in PAPER_MAZE],
    }
    path = tmp_path / "s.json"
    path.write_text(json.dumps(scenario))
    assert load_scenario(path).init_particles_pos == [(1.5, 3.5)]
    path.write_text(json.dumps({**scenario, "seed": json.loads("[" * 15 + "]" * 15)}))
    with pytest.raises(ValueError, match="seed: Input should be a valid integer"):  # 16 deep: parsed, then refused
        load_scenario(path)
    path.write_text(json.dumps({**scenario, "seed": json.loads("[" * 16 + "]" * 16)}))
    with pytest.raises(ValueError, match="json nested 17 deep; a scenario nests at most 16 deep"):
        load_scenario(path)


# -- progress of a long build -----------------------------------------------------------------------
def test_the_lookup_reports_every_tile_and_builds_the_same_table_with_or_without_a_callback():
    world = Maze(PAPER_MAZE)
    calls = []
    lookup = NearestStationLookup(world.stations, world.grid == 0, lambda done, total: calls.append((done, total)))
    tiles = -(-lookup.nx // _LOOKUP_TILE) * -(-lookup.ny // _LOOKUP_TILE)
    assert calls == [(done, tiles) for done in range(1, tiles + 1)]
    plain = NearestStationLookup(world.stations, world.grid == 0)
    for name in ("kind", "row", "_first", "_all", "_border"):
        assert np.array_equal(getattr(lookup, name), getattr(plain, name))


def test_the_cli_shows_a_progress_line_while_a_large_table_is_built(capsys):
    world = prepare_world(Maze(PAPER_MAZE, source="paper"), min_cells=0)
    assert world.has_lookup  # built up front
    err = capsys.readouterr().err.splitlines()
    assert err[0] == "building the nearest-station table of paper ..."
    assert err[-1].startswith("building the nearest-station table of paper: done in ") and err[-1].endswith(" s")
    small = prepare_world(Maze(PAPER_MAZE))  # a small table: built on first use, silently
    assert not small.has_lookup and capsys.readouterr().err == ""


def test_the_grid_filter_refuses_a_grid_that_would_not_fit(paper_world):
    with pytest.raises(MemoryLimitError, match=r"^the grid filter's 700000x700000 cells \(resolution 1e-05\) needs"):
        GridBayesFilter(paper_world, 0.3, 0.5, resolution=1e-5)
