"""Every check's inputs, drawn from one seed (docs/exercise.md, "Inputs a student cannot know"): the
seed of a student's own check comes from the submission's files, a grading's from the grader's secret
key and the files. Each check draws from its own stream `default_rng([seed, tag])`, so changing one
check's inputs leaves the others'. The grader keeps these objects; the student's process is sent only
what a filter is given (`request`): never the seed, a scenario's true path or where the robot started.
"""

from __future__ import annotations

import hashlib
import hmac
import warnings
from dataclasses import dataclass
from types import SimpleNamespace

import numpy as np

from mazelab.experiments.study import MazeChoice, RunTask, StudySetting, walk_of
from mazelab.maze import Maze, load_maze
from mazelab.robot import Robot
from mazelab.simulation import simulate

PART_MAZES = ("paper_5x5", "twin_rooms_6x12", "maze_10x10", "maze_20x20")
WHOLE_MAZES = ("paper_5x5", "maze_10x10")  # quick for the grid filter; not the twin rooms (a coin flip)
PART_SIGMA = (0.4, 0.8)  # the parts' sigma and delta: within the lab's ranges, away from its example
PART_DELTA = (0.1, 0.4)  # (0.3, 0.5), so that a part that hard-codes them fails
WHOLE_SIGMA = (0.2, 0.6)  # the scenarios' noise; delta >= 0.2 keeps the arc (L delta) wider than a grid cell
WHOLE_DELTA = (0.2, 0.6)
SCENARIO_COUNT = 12
SCENARIO_STEPS = 150
SCENARIO_PARTICLES = (800, 1200)
PRIOR_COUNT = 200  # the particles a part check's filter is built with
PREDICT_COUNT = (10_000, 20_000)
WEIGH_COUNT = (2000, 4000)
ESTIMATE_COUNT = (500, 3000)
RESAMPLE_COUNT = (30, 80)
RESAMPLE_DRAWS = 4000  # R calls of resample on each weight vector
RESAMPLE_KINDS = ("even", "mild", "fractional", "one dominant", "a few heavy")
ESTIMATE_KINDS = ("even", "unequal", "very unequal", "one dominant")
# one stream per check: default_rng([seed, tag])
PARTS_TAG, PREDICT_TAG, WEIGH_TAG, RESAMPLE_TAG, ESTIMATE_TAG, WHOLE_TAG = range(1, 7)


def default_seed(data: bytes) -> int:
    """The seed of `data`: the first 63 bits of its sha256."""
    return int.from_bytes(hashlib.sha256(data).digest()[:8], "big") >> 1


def files_seed(files: dict[str, bytes], key: bytes | None = None) -> int:
    """A submission's seed from its files ({name: bytes}, the graded file first): the first 63 bits of
    the sha256 of the file's bytes, then each helper module's name and bytes, or with the grader's
    secret `key` of their HMAC-SHA256."""
    first, *helpers = files.items()
    data = first[1] + b"".join(b"\0" + name.encode() + b"\0" + text for name, text in helpers)
    return default_seed(data) if key is None else int.from_bytes(hmac.digest(key, data, "sha256")[:8], "big") >> 1


@dataclass(frozen=True)
class _OnAMaze:
    """A maze by name and cells, and the noise: what a filter is built on."""

    maze: str
    grid: np.ndarray
    sigma: float
    delta: float

    @property
    def world(self) -> Maze:
        return Maze(self.grid, source=self.maze)


@dataclass(frozen=True)
class PartInputs(_OnAMaze):
    """The part checks' inputs: the seed, the prior the filter is built with (and its Generator's
    seed), and each part's by name (how each call uses them: mazelab.exercise.child.part_calls)."""

    seed: int
    prior: np.ndarray
    filter_seed: int
    predict: SimpleNamespace  # start (N, 2), angles, seeds
    weigh: SimpleNamespace  # points (N, 2), z
    resample: SimpleNamespace  # weights (a vector each), kinds, seeds, draws
    estimate: SimpleNamespace  # points (N, 2), weights (a vector each), kinds


@dataclass(frozen=True)
class ScenarioInputs(_OnAMaze):
    """One scenario of the whole-filter check: run `seed`'s walk, as `run --seed` walks it (the filter is
    told the compass angles and measurements, never the true path or the start), and its initial particles."""

    seed: int  # the run's seed: the robot's start and walk, the particles, the filters' draws
    particles: np.ndarray
    compass_angles: tuple[float, ...]
    measurements: tuple[float, ...]
    true_positions: np.ndarray  # (steps, 2)

    @property
    def key(self) -> tuple:
        """What identifies the scenario (its reference runs are computed once per key)."""
        return (self.maze, self.sigma, self.delta, self.seed, len(self.particles), len(self.measurements))

    def replay(self, filter_name: str, **options: object) -> np.ndarray:
        """A shipped filter's estimates (steps, 2) on the scenario's walk, run again from its seed: the
        exact grid filter's posterior means ("grid"), or the SIR's ("sir", resampling with the student's scheme)."""
        world = self.world
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", UserWarning)
            result = simulate(
                Robot.of_seed(world, self.sigma, self.delta, self.seed),
                world,
                self.sigma,
                self.delta,
                steps=len(self.measurements),
                init_particles_pos=self.particles,
                filtering_algorithm=filter_name,
                seed=self.seed,
                **options,
            )
        return result.estimates


def _count(rng: np.random.Generator, bounds: tuple[int, int]) -> int:
    return int(rng.integers(bounds[0], bounds[1] + 1))


def _seeds(rng: np.random.Generator, count: int) -> tuple[int, ...]:
    return tuple(int(s) for s in rng.integers(0, 2**62, size=count))


def draw_part_inputs(seed: int) -> PartInputs:
    """The four part checks' inputs for `seed`."""
    rng = np.random.default_rng([seed, PARTS_TAG])
    maze = str(rng.choice(PART_MAZES))
    world = load_maze(maze)
    sigma, delta = float(rng.uniform(*PART_SIGMA)), float(rng.uniform(*PART_DELTA))
    prior = world.random_free_places(PRIOR_COUNT, rng)
    each = (
        _predict_inputs(seed, world, delta),
        _weigh_inputs(seed, world, sigma),
        _resample_inputs(seed),
        _estimate_inputs(seed, world),
    )
    return PartInputs(maze, world.grid.copy(), sigma, delta, seed, prior, _seeds(rng, 1)[0], *each)


def _predict_inputs(seed: int, world: Maze, delta: float) -> SimpleNamespace:
    rng = np.random.default_rng([seed, PREDICT_TAG])
    start = world.random_free_places(_count(rng, PREDICT_COUNT), rng)
    near = rng.uniform(-delta / 4, delta / 4, size=2)  # headings on both sides of pi, and of 0 (2 pi)
    angles = (float(rng.uniform(0, 2 * np.pi)), float(np.pi + near[0]), float(near[1] % (2 * np.pi)))
    return SimpleNamespace(start=start, angles=angles, seeds=_seeds(rng, len(angles)))


def _weigh_inputs(seed: int, world: Maze, sigma: float) -> SimpleNamespace:
    """Points over the map and half a unit beyond (inside and outside the free area); measurements
    as the robot would make them at three free places."""
    rng = np.random.default_rng([seed, WEIGH_TAG])
    count = _count(rng, WEIGH_COUNT)
    points = rng.uniform([-0.5, -0.5], [world.width + 0.5, world.height + 0.5], size=(count, 2))
    places = world.random_free_places(3, rng)
    z = world.distance_to_nearest_station(places) + rng.normal(0.0, sigma, size=3)
    return SimpleNamespace(points=points, z=tuple(float(v) for v in z))


def resample_vector(kind: str, count: int, rng: np.random.Generator) -> np.ndarray:
    """Normalised weights (count,) of one kind. Every N W_i is at least about 0.2 (so each particle's
    mean offspring count over the calls is close to normal), except under even weights (exactly 1).
    even: 1/N; mild: 1 + U(0, 0.5) (ESS about 0.99 N: keeping every particle is wrong here too);
    fractional: N W_i with fractional parts in about [0.2, 0.8], some 1 + f and 2 + f; one dominant: one
    particle carries half the weight; a few heavy: three to five carry 80%."""
    if kind == "even":
        weights = np.ones(count)
    elif kind == "mild":
        weights = 1 + rng.uniform(0, 0.5, size=count)
    elif kind == "fractional":
        pairs = count // 2
        fractions = rng.uniform(0.2, 0.8, size=pairs)
        whole = np.zeros((pairs, 2))
        whole[pairs // 2 : 3 * pairs // 4] = (1, 1)
        whole[3 * pairs // 4 :] = (2, 0)
        weights = (whole + np.column_stack([fractions, 1 - fractions])).ravel()
        weights = np.concatenate([weights, np.ones(count - len(weights))])
    elif kind == "one dominant":
        weights = np.full(count, 1 / (count - 1))
        weights[0] = 1.0
    elif kind == "a few heavy":
        heavy = int(rng.integers(3, 6))
        weights = np.full(count, 0.2 / (count - heavy))
        weights[:heavy] = 0.8 / heavy
    else:
        raise ValueError(f"unknown weight vector {kind!r}")
    return rng.permutation(weights / weights.sum())


def _resample_inputs(seed: int) -> SimpleNamespace:
    rng = np.random.default_rng([seed, RESAMPLE_TAG])
    weights = tuple(resample_vector(kind, _count(rng, RESAMPLE_COUNT), rng) for kind in RESAMPLE_KINDS)
    return SimpleNamespace(weights=weights, kinds=RESAMPLE_KINDS, seeds=_seeds(rng, len(weights)), draws=RESAMPLE_DRAWS)


def _estimate_inputs(seed: int, world: Maze) -> SimpleNamespace:
    rng = np.random.default_rng([seed, ESTIMATE_TAG])
    points = world.random_free_places(_count(rng, ESTIMATE_COUNT), rng)
    n = len(points)
    vectors = [np.ones(n), rng.exponential(size=n) ** 4, rng.exponential(size=n) ** 12, np.full(n, 0.1 / n)]
    vectors[3][rng.integers(n)] = 0.9
    return SimpleNamespace(points=points, weights=tuple(v / v.sum() for v in vectors), kinds=ESTIMATE_KINDS)


def draw_scenarios(seed: int, count: int = SCENARIO_COUNT, steps: int = SCENARIO_STEPS) -> list[ScenarioInputs]:
    """The whole filter's scenarios for `seed`: a maze, sigma, delta, particle count and run seed each,
    then run seed's walk of `steps` steps as a study walks it (mazelab.experiments.study.walk_of): the
    robot and the initial particles of `run --seed` (mazelab.seeding)."""
    rng = np.random.default_rng([seed, WHOLE_TAG])
    scenarios = []
    for run_seed in _seeds(rng, count):
        maze = str(rng.choice(WHOLE_MAZES))
        sigma, delta = float(rng.uniform(*WHOLE_SIGMA)), float(rng.uniform(*WHOLE_DELTA))
        world = load_maze(maze)
        setting = StudySetting(MazeChoice.from_maze(maze, world), sigma, delta, _count(rng, SCENARIO_PARTICLES))
        inputs, path = walk_of(RunTask(1, setting, 1, run_seed, None, ("sir",), steps), world)
        walk = (tuple(inputs.robot_compass_angles), tuple(inputs.robot_measurements), path)
        scenarios.append(
            ScenarioInputs(maze, world.grid.copy(), sigma, delta, run_seed, inputs.init_particles_pos, *walk)
        )
    return scenarios


SENT = {  # what the student's process is sent of each: only what a filter is given
    "parts": ("maze", "grid", "sigma", "delta", "prior", "filter_seed", "predict", "weigh", "resample", "estimate"),
    "scenario": ("maze", "grid", "sigma", "delta", "seed", "particles", "compass_angles", "measurements"),
}


def _flatten(prefix: str, thing: object, fields: tuple[str, ...], inputs: dict, arrays: dict) -> None:
    """The named fields of `thing` as `prefix.NAME` (a part's as `prefix.NAME.FIELD`): arrays (a tuple
    of them as NAME.0, NAME.1, ...) into `arrays`, other values into `inputs`."""
    for name in fields:
        value, key = getattr(thing, name), f"{prefix}.{name}"
        if isinstance(value, SimpleNamespace):
            _flatten(key, value, tuple(vars(value)), inputs, arrays)
        elif isinstance(value, np.ndarray):
            arrays[key] = value
        elif isinstance(value, tuple) and value and isinstance(value[0], np.ndarray):
            arrays.update({f"{key}.{k}": v for k, v in enumerate(value)})
        else:
            inputs[key] = list(value) if isinstance(value, tuple) else value


def request(
    file: str,
    class_name: str | None,
    stages: list[str],
    parts: PartInputs,
    scenarios: list[ScenarioInputs],
    shown: str = "",
) -> tuple[dict, dict]:
    """The request to the student's process (meta, arrays): what to load (`file` as the child sees it,
    `shown` its name in messages), the stages, and their inputs (mazelab.exercise.child.Inputs)."""
    inputs: dict = {"whole.count": len(scenarios)}
    arrays: dict = {}
    _flatten("parts", parts, SENT["parts"], inputs, arrays)
    for i, scenario in enumerate(scenarios):
        _flatten(f"whole.{i}", scenario, SENT["scenario"], inputs, arrays)
    return {"file": file, "class": class_name, "shown": shown, "stages": stages, "inputs": inputs}, arrays
