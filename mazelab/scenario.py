"""Saved scenarios (lab step 9): the pydantic model of the json file, and saving and loading it.

A file with only the paper's four keys (init_robot_pos, init_particles_pos, robot_actual_angles,
robot_compass_angles) loads; the program writes the measurements and metadata too, and the filter's
options (`filter_options`, in the JSON form its declaration gives them), so that a replay repeats the
run that made the file.

Loading a scenario never imports code: it names its filter, a shipped one by name, or a plug-in by
reference (`filter_plugin`: the spec as written, the file's sha256, the class), which a replay runs
only when the user names the plug-in again (`--filter file.py:Class`).
"""

from __future__ import annotations

import itertools
import json
import math
import re
from pathlib import Path
from typing import Annotated, Any

import numpy as np
from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    StrictBool,
    StrictInt,
    StrictStr,
    ValidationError,
    field_serializer,
    field_validator,
    model_validator,
)

from mazelab.atomic import write_atomically
from mazelab.checks import (
    MAX_ANGLE,
    MAX_COORDINATE,
    MAX_SEED,
    NORMAL_TAIL,
    check_all_within,
    check_within_map,
    map_diagonal,
    read_text_file,
)
from mazelab.declaration import options_of
from mazelab.maze import MAZES_DIR, Maze, find_shipped, shipped_mazes
from mazelab.registry import FilterEntry, PluginReference, filter_entry, loaded_plugin, shipped_entry
from mazelab.robot import Robot, check_walk_lists

DEFAULT_PARAMETERS_PATH = Path("model_parameters.json")  # the paper's file (lab steps 9-10), in the working folder
LEGACY_PARAMETERS_PATH = Path("model_parameters") / "model_parameters.json"  # where older versions saved it
SCENARIOS_DIR = MAZES_DIR.parent / "model_parameters"  # the shipped scenarios, beside mazes/ (found by name)
SCENARIO_FORMAT_VERSION = 4  # the newest scenario format this program reads and writes
# the version that brought each key (a kidnapping, the filter's options, a plug-in's reference); without them, 1
FORMAT_VERSIONS = {"kidnap_at": 2, "filter_options": 3, "filter_plugin": 4}


MAX_JSON_DEPTH = 16  # a scenario nests 3 deep; deeper files are refused before parsing (no RecursionError)
BYTES_PER_JSON_BYTE = 40  # memory the parsed json and its validation take per byte of the file (generous)

# -- saved scenarios -------------------------------------------------------------------------------
# Strict types: "0.3" is not a number and true is not a seed in a scenario file (a whole number
# still counts as a float).
FiniteFloat = Annotated[float, Field(strict=True, allow_inf_nan=False)]
Whole = Annotated[int, Field(strict=True)]
Point = tuple[FiniteFloat, FiniteFloat]
OptionScalar = StrictBool | StrictInt | FiniteFloat | StrictStr | None
OptionValue = OptionScalar | dict[str, OptionScalar]  # a number, a word, or an object's fields (Recovery, KLD)


class Scenario(BaseModel):
    """A saved run (lab step 9): the paper's four keys, the measurements, and metadata.

    Version 2 adds the kidnapping (kidnap_at, kidnap_position: at step kidnap_at the robot is put down
    at kidnap_position before that step's move); version 3 the filter's options (filter_options: every
    keyword option of `filtering_algorithm` that made the run, in the JSON form its declaration gives);
    version 4 a plug-in's reference (filter_plugin), for a run of a filter that is not the lab's.
    A scenario is written with the lowest version that holds it, so files without these stay version 1
    and older readers still read them.
    """

    model_config = ConfigDict(extra="forbid", arbitrary_types_allowed=True)  # filter_plugin: a PluginReference

    format_version: Whole = Field(1, ge=1)
    init_robot_pos: Point
    init_particles_pos: list[Point] = Field(min_length=1)
    robot_actual_angles: list[FiniteFloat] = Field(min_length=1)
    robot_compass_angles: list[FiniteFloat] = Field(min_length=1)
    robot_measurements: list[FiniteFloat] | None = None
    maze: list[list[Whole]] | None = None
    sigma: FiniteFloat | None = Field(None, gt=0)
    delta: FiniteFloat | None = Field(None, ge=0, le=2 * math.pi)
    seed: Whole | None = Field(None, ge=0, lt=MAX_SEED)
    steps: Whole | None = Field(None, ge=1)
    filtering_algorithm: Annotated[str, Field(strict=True)] | None = None
    kidnap_at: Whole | None = Field(None, ge=1)
    kidnap_position: Point | None = None
    filter_options: dict[str, OptionValue] | None = None
    filter_plugin: PluginReference | None = None

    @model_validator(mode="before")
    @classmethod
    def _lowest_version(cls, data: Any) -> Any:
        """Without an explicit format_version, the lowest that holds the data."""
        if isinstance(data, dict) and "format_version" not in data:
            versions = [v for key, v in FORMAT_VERSIONS.items() if data.get(key) is not None]
            data = {**data, "format_version": max(versions, default=1)}
        return data

    @field_validator("filter_plugin", mode="before")
    @classmethod
    def _a_reference(cls, stored: Any) -> PluginReference | None:
        """A plug-in's reference as stored (mazelab.registry.PluginReference.from_json); never imported."""
        return stored if stored is None or isinstance(stored, PluginReference) else PluginReference.from_json(stored)

    @field_serializer("filter_plugin")
    def _stored(self, plugin: PluginReference | None) -> dict[str, str] | None:
        return None if plugin is None else plugin.as_json()

    @field_validator("filtering_algorithm")
    @classmethod
    def _a_name(cls, name: str | None) -> str | None:
        """A filter's name: one of the lab's, or a plug-in's (never imported here: see filter_plugin)."""
        if name is not None and (not name.strip() or len(name) > 4096 or not name.isprintable()):
            raise ValueError(f"filtering_algorithm must be a filter's name, got {name[:60]!r}")
        return name

    @property
    def shipped_filter(self) -> FilterEntry | None:
        """The lab's filter the scenario names (None: none stored, or a plug-in's or another program's)."""
        if self.filtering_algorithm is None or self.filter_plugin is not None:
            return None
        return shipped_entry(self.filtering_algorithm)

    @model_validator(mode="after")
    def _consistent(self) -> Scenario:
        particles = self._check_bounds()
        if self.format_version > SCENARIO_FORMAT_VERSION:
            raise ValueError(
                f"format_version {self.format_version} is newer than this program reads ({SCENARIO_FORMAT_VERSION})"
            )
        for key, version in FORMAT_VERSIONS.items():
            if getattr(self, key) is not None and self.format_version < version:
                raise ValueError(f"{key} needs format_version {version}, got {self.format_version}")
        steps = len(self.robot_actual_angles)
        check_walk_lists(
            self.robot_actual_angles,
            self.robot_compass_angles,
            self.robot_measurements,
            self.kidnap_at,
            self.kidnap_position,
            keys="robot_",
        )
        if self.kidnap_at is not None and self.kidnap_at > steps:
            raise ValueError(f"kidnap_at {self.kidnap_at} is after the last step ({steps})")
        if self.steps is not None and self.steps != steps:
            raise ValueError(f"steps is {self.steps} but there are {steps} angles")
        world = self.world()
        check_measurements_within(self.robot_measurements, world, self.sigma)
        self._check_filter_options()
        if world is not None:  # the robot's start is checked where every run is, in simulation.check_walk
            check_within_map("init_particles_pos", particles, world.width, world.height)
            if self.kidnap_position is not None and not world.is_free(*self.kidnap_position):
                raise ValueError(
                    f"kidnap_position {self.kidnap_position} is not in the free area of the scenario's maze"
                )
        return self

    def _check_bounds(self) -> np.ndarray:
        """Angles within MAX_ANGLE radians, places and distances within MAX_COORDINATE map units,
        checked in numpy (a scenario may hold a million particles); returns the particles (N, 2)."""
        pairs = self.init_particles_pos  # as an (N, 2) array, at fromiter's speed
        particles = np.fromiter(itertools.chain.from_iterable(pairs), dtype=float, count=2 * len(pairs)).reshape(-1, 2)
        for name, values, bound, unit in (
            ("robot_actual_angles", _numbers(self.robot_actual_angles), MAX_ANGLE, "radians"),
            ("robot_compass_angles", _numbers(self.robot_compass_angles), MAX_ANGLE, "radians"),
            ("robot_measurements", _numbers(self.robot_measurements or []), MAX_COORDINATE, "map units"),
            ("init_robot_pos", _numbers(self.init_robot_pos), MAX_COORDINATE, "map units"),
            ("init_particles_pos", particles, MAX_COORDINATE, "map units"),
            ("kidnap_position", _numbers(self.kidnap_position or []), MAX_COORDINATE, "map units"),
        ):
            check_all_within(name, values, bound, unit)
        return particles

    def _check_filter_options(self) -> None:
        """filter_options need format_version 3 and a filter; for a filter of the lab's they are checked
        by its declaration as its constructor checks them (a plug-in's when the user names it to replay);
        filter_plugin needs format_version 4 and the plug-in's name."""
        if self.filter_plugin is not None and self.filtering_algorithm is None:
            raise ValueError("filter_plugin needs the filtering_algorithm (the plug-in's name) it belongs to")
        if self.filter_options is None:
            return
        if self.filtering_algorithm is None:
            raise ValueError("filter_options need the filtering_algorithm they belong to")
        entry = self.shipped_filter
        if entry is not None:
            entry.options.from_json(self.filter_options, entry.name)

    def filter_kwargs(self, filter_class: type) -> dict[str, Any]:
        """The stored filter options as keyword arguments of `filter_class`, those it declares, checked by
        its declaration; empty when none are stored. The options are the run's filter's (`maker`): every
        one for that filter, and another filter takes only those that run chose away from its own
        defaults (SIR's `threshold` 1 is not the RPF's 0.2), and none when the filter that made the run is
        not known here (a plug-in not loaded in this process: its defaults cannot be told apart)."""
        maker = self.maker()
        declared = options_of(filter_class)
        stored = {k: v for k, v in (self.filter_options or {}).items() if k in declared and not declared[k].derived}
        if maker is not filter_class:
            own = {} if maker is None else options_of(maker).to_json(options_of(maker).defaults())
            stored = {k: v for k, v in stored.items() if maker is not None and (k not in own or own[k] != v)}
        return declared.from_json(stored, filter_class.name)

    def maker(self) -> type | None:
        """The class of the filter that made the run, if this process knows it: the lab's filter it names,
        or its plug-in once loaded here (the same class, file and sha256); else None."""
        if self.filter_plugin is None:
            return None if self.shipped_filter is None else self.shipped_filter.filter_class
        loaded = loaded_plugin(self.filtering_algorithm or "")
        reference = None if loaded is None else filter_entry(loaded).plugin
        same = reference is not None and (reference.sha256, reference.class_name) == (
            self.filter_plugin.sha256,
            self.filter_plugin.class_name,
        )
        return loaded if same else None

    def world(self) -> Maze | None:
        """The maze stored in the scenario, if any."""
        return None if self.maze is None else Maze(self.maze, source="the scenario's maze")

    def robot(self, sigma: float | None = None, delta: float | None = None) -> Robot:
        """A Robot that replays this scenario's path (and measurements, if stored)."""
        sigma = self.sigma if sigma is None else sigma
        delta = self.delta if delta is None else delta
        if sigma is None or delta is None:
            raise ValueError("the scenario stores no sigma/delta: give them")
        return Robot(
            sigma,
            delta,
            self.init_robot_pos,
            actual_angles=self.robot_actual_angles,
            compass_angles=self.robot_compass_angles,
            measurements=self.robot_measurements,
            kidnap_at=self.kidnap_at,
            kidnap_position=self.kidnap_position,
        )

    def to_json(self) -> str:
        """Json with the paper's keys first, one particle per line (readable, and diff-able)."""
        data = self.model_dump(exclude_none=True)
        lines = []
        for key, value in data.items():
            if key in ("filter_options", "filter_plugin"):
                lines.append(f'  "{key}": {json.dumps(value, sort_keys=True)}')
            elif key in ("init_particles_pos", "maze"):
                inner = ",\n".join(f"    {json.dumps(list(item))}" for item in value)
                lines.append(f'  "{key}": [\n{inner}\n  ]')
            else:
                lines.append(f'  "{key}": {json.dumps(value)}')
        return "{\n" + ",\n".join(lines) + "\n}\n"


def check_measurements_within(measurements: list[float] | None, world: Maze | None, sigma: float | None) -> None:
    """A measurement is a distance plus N(0, sigma^2) noise, and no draw of the noise reaches NORMAL_TAIL
    sigma (without a stored sigma, 0): it is at least -NORMAL_TAIL sigma and, on `world` (if given), at
    most its diagonal plus NORMAL_TAIL sigma (no station lies farther from a free place than the map's
    diagonal). The first beyond is refused in one line."""
    if not measurements:
        return
    tail = NORMAL_TAIL * (sigma or 0.0)
    z = _numbers(measurements)
    below = np.flatnonzero(z < -tail)
    if len(below):
        i = int(below[0])
        raise ValueError(
            f"robot_measurements[{i}] = {z[i]:g} is below {-tail:g}: a noisy distance is at least "
            f"-{NORMAL_TAIL:g} sigma" + ("" if sigma else " (the scenario stores no sigma)")
        )
    ceiling = math.inf if world is None else map_diagonal(world.width, world.height) + tail
    above = np.flatnonzero(z > ceiling)
    if len(above):
        i = int(above[0])
        raise ValueError(
            f"robot_measurements[{i}] = {z[i]:g} is beyond {ceiling:.3g}: on this {world.height}x{world.width} maze a "
            f"distance to the nearest station is at most the map's diagonal (plus {NORMAL_TAIL:g} sigma of noise)"
        )


def _numbers(values: Any) -> np.ndarray:
    """A list of floats as an array (fromiter: several times faster than asarray on long lists)."""
    return np.fromiter(values, dtype=float, count=len(values))


class ScenarioError(ValueError):
    """A scenario file that cannot be used; the message is one line naming the file and the problem."""


def save_scenario(scenario: Scenario, path: str | Path = DEFAULT_PARAMETERS_PATH, *, replace: bool = True) -> Path:
    """Write the scenario as json, atomically (a reader never sees half a file). Returns the path.
    Without `replace` an existing file is never replaced (mazelab.atomic.NameTakenError)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    write_atomically(path, scenario.to_json(), replace=replace)
    return path


def find_scenario(name_or_path: str | Path) -> Path:
    """A scenario file path, or the name of a shipped one (in model_parameters/, with or without .json),
    from any folder, as mazes are found (mazelab.maze.find_shipped)."""
    return find_shipped(name_or_path, SCENARIOS_DIR, ".json", "scenario", ScenarioError)


def load_scenario(path: str | Path = DEFAULT_PARAMETERS_PATH) -> Scenario:
    """Read and validate a scenario json file (a file with only the paper's four keys is fine), or a
    shipped scenario by its name (see find_scenario)."""
    path = find_scenario(path)
    try:  # the file's text (mazelab.checks.read_text_file), or what to try when there is none
        text = read_text_file(path, "scenario", "json", ScenarioError, per_byte=BYTES_PER_JSON_BYTE)
    except FileNotFoundError:
        older = LEGACY_PARAMETERS_PATH.is_file() and path.name == "model_parameters.json"
        hint = f" (older versions saved to {LEGACY_PARAMETERS_PATH})" if older else ""
        if not hint and path.parent == Path(".") and path.stem in shipped_mazes() and path.suffix in ("", ".txt"):
            hint = f"; {path.stem} is a maze: --maze {path.stem} (a scenario is a .json saved by run --save-scenario)"
        raise ScenarioError(f"{path}: no such scenario file{hint}") from None
    depth = json_depth(text)
    if depth > MAX_JSON_DEPTH:
        raise ScenarioError(f"{path}: json nested {depth} deep; a scenario nests at most {MAX_JSON_DEPTH} deep")
    try:
        data = json.loads(text)
    except json.JSONDecodeError as error:
        raise ScenarioError(f"{path}:{error.lineno}: not valid json ({error.msg}){_what_it_is(path, text)}") from None
    except ValueError as error:  # e.g. a number of more than 4300 digits
        raise ScenarioError(f"{path}: not a usable json file ({str(error).splitlines()[0]})") from None
    except RecursionError:  # the depth scan keeps this from happening; a last guard
        raise ScenarioError(f"{path}: json nested too deeply") from None
    try:
        return Scenario.model_validate(data)
    except ValidationError as error:
        raise ScenarioError(f"{path}: {describe_validation_error(error)}") from None


def _what_it_is(path: Path, text: str) -> str:
    """For a file that is no json: what it looks like, and what takes it instead."""
    lines = [line.split("#")[0].strip() for line in text.splitlines()]
    first = next((line for line in lines if line), "")
    saved = "a scenario is the .json that run --save-scenario FILE.json writes"
    if first and set(first.replace(",", " ").split()) <= {"0", "1", "2"}:
        return f"; {path.name} looks like a maze file: --maze {path}; {saved}"
    if path.suffix.lower() == ".csv" or ("," in first and not first.startswith(("{", "["))):
        return f"; {path.name} looks like a CSV (a study's or compare's table), not a scenario: {saved}"
    if path.suffix.lower() == ".rrd":
        return f"; {path.name} is a recording: mazelab view {path}; {saved}"
    return ""


_JSON_STRING = re.compile(r'"(?:[^"\\]|\\.)*"')


def json_depth(text: str) -> int:
    """How deep the arrays and objects of a json text nest (brackets inside strings do not count); a
    cheap scan, so that a file nested 100,000 deep is refused before the parser recurses."""
    codes = np.frombuffer(_JSON_STRING.sub("", text).encode("utf-8", "replace"), dtype=np.uint8)
    opening = (codes == ord("[")) | (codes == ord("{"))
    brackets = opening[opening | (codes == ord("]")) | (codes == ord("}"))]  # the brackets alone, in order
    return int(np.cumsum(np.where(brackets, 1, -1), dtype=np.int64).max(initial=0))


def describe_validation_error(error: ValidationError) -> str:
    """The first problem of a pydantic error, on one line: 'where: what' (and how many more)."""
    first = error.errors()[0]
    parts = (str(part) for part in first["loc"])  # a key may hold a newline: quote those, to keep one line
    where = ".".join(part if part.isprintable() else repr(part) for part in parts)
    message = first["msg"].removeprefix("Value error, ")  # our own checks' messages, without pydantic's label
    more = len(error.errors()) - 1
    return (f"{where}: {message}" if where else message) + (f" (and {more} more problem(s))" if more else "")


__all__ = [
    "DEFAULT_PARAMETERS_PATH",
    "FORMAT_VERSIONS",
    "MAX_JSON_DEPTH",
    "SCENARIOS_DIR",
    "SCENARIO_FORMAT_VERSION",
    "FiniteFloat",
    "Point",
    "Scenario",
    "ScenarioError",
    "check_measurements_within",
    "describe_validation_error",
    "find_scenario",
    "json_depth",
    "load_scenario",
    "save_scenario",
]
