"""Property-based checks that bad files never escape as unhandled exceptions."""

from __future__ import annotations

import json
import math

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from mazelab.maze import Maze, MazeError, parse_maze_text
from mazelab.scenario import Scenario, ScenarioError, load_scenario

VALID = {
    "format_version": 1,
    "init_robot_pos": [3.5, 1.5],
    "init_particles_pos": [[1.5, 3.5], [3.5, 3.5], [4.5, 0.5]],
    "robot_actual_angles": [1.1, 1.4, 0.35],
    "robot_compass_angles": [1.2, 1.2, 0.3],
    "robot_measurements": [1.0, 0.9, 1.3],
    "maze": [[2, 0, 1, 0, 0], [0, 0, 0, 0, 1], [1, 1, 1, 0, 0], [1, 0, 0, 0, 0], [0, 0, 2, 0, 1]],
    "sigma": 0.3,
    "delta": 0.5,
    "seed": 4,
    "steps": 3,
}

json_values = st.recursive(
    st.none() | st.booleans() | st.integers(-(10**30), 10**30) | st.floats() | st.text(max_size=5),
    lambda inner: st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=4), inner, max_size=3),
    max_leaves=8,
)


@st.composite
def mutated_scenarios(draw) -> str:
    """A valid scenario with one or two random mutations, as json text (possibly truncated)."""
    data = json.loads(json.dumps(VALID))
    for _ in range(draw(st.integers(1, 2))):
        key = draw(st.sampled_from(sorted(data) or ["init_robot_pos"]))
        action = draw(st.sampled_from(["delete", "replace", "shorten", "extra", "element"]))
        if action == "delete":
            data.pop(key, None)
        elif action == "replace":
            data[key] = draw(json_values)
        elif action == "shorten" and isinstance(data.get(key), list) and data[key]:
            data[key] = data[key][:-1]
        elif action == "extra":
            data[draw(st.text(min_size=1, max_size=6))] = draw(json_values)
        elif action == "element" and isinstance(data.get(key), list) and data[key]:
            data[key][draw(st.integers(0, len(data[key]) - 1))] = draw(json_values)
    text = json.dumps(data, allow_nan=True)
    if draw(st.booleans()) and draw(st.booleans()):
        text = text[: draw(st.integers(0, len(text)))]
    return text


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(mutated_scenarios())
def test_any_mutated_scenario_loads_or_gets_a_one_line_error(tmp_path, text):
    path = tmp_path / "scenario.json"
    path.write_text(text)
    try:
        scenario = load_scenario(path)
    except ScenarioError as error:
        message = str(error)
        assert message.startswith(str(path)) and "\n" not in message
        return
    assert isinstance(scenario, Scenario)
    assert len(scenario.robot_actual_angles) == len(scenario.robot_compass_angles)
    assert all(math.isfinite(v) for point in scenario.init_particles_pos for v in point)
    if scenario.maze is not None:
        Maze(scenario.maze)


@settings(max_examples=200, deadline=None)
@given(st.text(alphabet="012 ,#x\n\t9", max_size=60))
def test_any_maze_text_parses_or_gets_a_one_line_error(text):
    try:
        Maze(parse_maze_text(text, source="m.txt"), source="m.txt")
    except MazeError as error:
        assert str(error).startswith("m.txt") and "\n" not in str(error)
