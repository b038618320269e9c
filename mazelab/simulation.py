"""One run: one filter on one robot walk, step by step, kept as arrays in a RunResult (`simulate`), and
the paper's entry point over it (`run_model`, which can save the run's scenario).

The one recording loop (`record_steps`) steps a filter along a walk and keeps each step's values, read
where the contract says and checked, for one run and for R runs advanced together (a batched study)
alike; a filter's own figures (`diagnostics`: the RPF's regularisation, recovery's injection
probability) are kept the same way, so they reach RunResult and a study's traces with no code of their own.

Step k: the robot moves with its actual angle k and measures z_k; the filter predicts with compass
angle k and updates with z_k. The run draws where `visualize` says (mazelab.viz.views, imported only by
a run that draws) or into a view its caller hands it (anything with log_step and close).
"""

from __future__ import annotations

import math
import time
import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from mazelab.backend import backend_by_work, backend_of
from mazelab.checks import as_points, check_recording, check_seed, check_steps, check_within_map, step_number
from mazelab.checks import particle_count as checked_count
from mazelab.contract import ContractError, NullView, check_filter, check_step_values
from mazelab.declaration import options_of
from mazelab.maze import Maze, check_world
from mazelab.model import CONVERGENCE_RADIUS, DEFAULT_STEPS, check_model_parameters
from mazelab.registry import entries, filter_entry
from mazelab.robot import Robot
from mazelab.seeding import RunStreams, new_seed, run_streams
from mazelab.stops import student_code
from mazelab.viz.recording import Visualization, in_jupyter
from mazelab.viz.style import DEFAULT_MAX_DRAWN

if TYPE_CHECKING:
    from mazelab.scenario import Scenario


@dataclass
class RunResult:
    """Everything one run produced, per step k = 1..steps (arrays of length `steps`); what it started
    from (its seed, filter, initial particles, kidnapping) is `inputs`, read there and nowhere else."""

    true_positions: np.ndarray  # (steps, 2), after the robot's move of step k
    estimates: np.ndarray  # (steps, 2), the posterior mean after the update with z_k
    ess: np.ndarray  # (steps,), NaN for the grid filter
    confident: np.ndarray  # (steps,) bool
    step_seconds: np.ndarray  # (steps,), the filter's own time per step: its step and its estimate, ESS, confidence
    reinitialised_at: list[int]
    inputs: RunInputs
    extras: dict[str, Any]  # "particle_count" (steps,), "diagnostics" by name (steps,), "backend": of_recorded
    log_evidence: np.ndarray  # (steps,), log p(z_1:k) as the filter estimates it (NaN: none kept)

    @classmethod
    def of_recorded(
        cls,
        recorded: Recorded,
        r: int,
        true_positions: np.ndarray,
        restarts: list[int],
        inputs: RunInputs,
        backend: str,
    ) -> RunResult:
        """Run `r` of what the recording loop kept (Recorded), named by `inputs`' filter:
        the robot's `true_positions` (steps, 2), the filter's restarts and the backend it ran on."""
        diagnostics = {name: values[r] for name, values in recorded.diagnostics.items()}
        extras = {"particle_count": recorded.counts[r], "diagnostics": diagnostics, "backend": backend}
        return cls(
            true_positions,
            recorded.estimates[r],
            recorded.ess[r],
            recorded.confident[r],
            recorded.seconds,
            list(restarts),
            inputs,
            extras,
            recorded.log_evidence[r],
        )

    @cached_property
    def scenario(self) -> Scenario:
        """The run as a Scenario (what save_scenario writes), its inputs key for key (None keys stay out of
        the file), built on first use: lists and validation cost more than a large run's filter steps, so a
        run that is not saved never pays for them (nor imports the pydantic models)."""
        from mazelab.scenario import Scenario

        inputs = self.inputs
        lists = {"init_particles_pos": inputs.init_particles_pos.tolist(), "maze": inputs.maze.as_lists()}
        return Scenario(**{**vars(inputs), **lists})

    @property
    def errors(self) -> np.ndarray:
        """Distance between estimate and truth per step (map units)."""
        return np.hypot(*(self.estimates - self.true_positions).T)

    @property
    def converged_at(self) -> int | None:
        """The first step from which the error stays below CONVERGENCE_RADIUS, or None."""
        return convergence_step(self.errors)


@dataclass(frozen=True)
class RunInputs:
    """What a run started from and walked, under its Scenario's keys (mazelab.scenario.Scenario says what
    each is) as arrays and plain values: the Scenario's content before it is turned into lists and
    validated, which RunResult.scenario does on demand (a study never builds one)."""

    init_robot_pos: tuple[float, float]
    init_particles_pos: np.ndarray  # (N, 2) float64
    robot_actual_angles: list[float]
    robot_compass_angles: list[float]
    robot_measurements: list[float]
    maze: Maze  # the run's maze itself (the scenario stores its grid)
    sigma: float
    delta: float
    seed: int
    steps: int
    filtering_algorithm: str
    kidnap_at: int | None = None
    kidnap_position: tuple[float, float] | None = None
    filter_options: dict[str, Any] | None = None  # every option of the filter, defaults filled in (JSON form)
    filter_plugin: dict[str, str] | None = None  # a plug-in's reference (spec, sha256, class), or None

    @classmethod
    def of_run(
        cls,
        robot: Robot,
        particles: np.ndarray,
        world: Maze,
        sigma: float,
        delta: float,
        seed: int,
        steps: int,
        name: str,
        filter_options: dict[str, Any] | None = None,
        filter_plugin: dict[str, str] | None = None,
    ) -> RunInputs:
        """The inputs of a run of `steps` steps by `robot` (its recorded walk is copied); `filter_options`
        the filter's options in JSON form (its declaration's), or None; `filter_plugin` a plug-in's reference."""
        kidnapped = robot.kidnap_at is not None and robot.kidnap_at <= steps
        return cls(
            robot.initial_position,
            particles,
            robot.actual_angles[:steps],
            robot.compass_angles[:steps],
            robot.measurements[:steps],
            world,
            sigma,
            delta,
            seed,
            steps,
            name,
            robot.kidnap_at if kidnapped else None,
            robot.kidnap_position if kidnapped else None,
            filter_options,
            filter_plugin,
        )


def convergence_step(errors: np.ndarray, radius: float = CONVERGENCE_RADIUS) -> int | None:
    """The first step (1-based) after which every error is below `radius`; None if the last is not."""
    outside = np.flatnonzero(~(np.asarray(errors) < radius))  # NaN (a failed estimate) never converges
    if len(outside) == 0:
        return 1
    return None if outside[-1] == len(errors) - 1 else int(outside[-1]) + 2


def check_walk(world: Maze, robot: Robot, particles: np.ndarray | None = None, steps: int | None = None) -> None:
    """A run's walk on `world`, checked before the run: one line for the first thing wrong.

    The robot must start (and be put down by a kidnapping) in the free area; particles handed in may lie
    anywhere within the map plus a margin (a warning says how many lie outside the free area; None:
    drawn from the free area, nothing to check). A recorded walk (a replayed scenario's
    robot_actual_angles, its first `steps` steps) must stay in the free area, as every walk made on
    `world` does: the first step that leaves it is refused (a hand-edited walk through walls, or another
    maze's). Positions are computed in Robot.step's own arithmetic, so a walk made on `world` always passes.
    """
    for what, place in (("the robot's start", robot.initial_position), ("the kidnap position", robot.kidnap_position)):
        if place is not None and not world.is_free(*place):
            raise ValueError(f"{what} {place} is not in the free area of the maze ({world.source})")
    if particles is not None:
        check_within_map("init_particles_pos", particles, world.width, world.height)
        outside = int((~world.is_free(particles[:, 0], particles[:, 1])).sum())
        if outside:
            warnings.warn(
                f"{outside} of the {len(particles)} initial particles lie outside the free area", stacklevel=3
            )
    x, y = robot.initial_position
    for k in range(1, (robot.recorded_steps if steps is None else min(steps, robot.recorded_steps)) + 1):
        if k == robot.kidnap_at:
            x, y = robot.kidnap_position
        heading = robot.actual_angles[k - 1]
        x, y = x + robot.speed * math.cos(heading), y + robot.speed * math.sin(heading)
        if not world.is_free(x, y):
            raise ValueError(
                f"robot_actual_angles[{k - 1}]: step {k} of the replayed walk leaves the free area of the maze "
                f"({world.source}) at ({x:.2f}, {y:.2f}); a walk made on this maze never does"
            )


def open_run_view(view: Any, world: Maze, filter_name: str, robot: Robot) -> Any:
    """The view a run draws into, told of the robot's planned kidnapping: `view` itself (anything with
    log_step and close), NullView for None or False, what a view-opening function `(world, filter_name)
    -> view` returns, or the Rerun view a `visualize` value asks for (the viewer's code imported only then)."""
    if view is None or view is False:
        view = NullView()
    elif not hasattr(view, "log_step"):
        from mazelab.viz.views import open_view

        view = view(world, filter_name) if callable(view) else open_view(view, world, filter_name)
    if robot.kidnap_at is not None and hasattr(view, "expect_kidnapping"):
        view.expect_kidnapping(robot.kidnap_at, robot.kidnap_position)
    return view


def simulate(
    robot: Robot,
    world: Maze,
    sigma: float,
    delta: float,
    particle_count: int | None = None,
    steps: int | None = None,
    init_particles_pos: Sequence[Sequence[float]] | np.ndarray | None = None,
    filtering_algorithm: str | type = "SIRParticleFilter",
    *,
    seed: int | None = None,
    visualize: Any = False,
    on_step: Callable[[int, Robot, Any], None] | None = None,
    kidnap_at: int | None = None,
    view: Any = None,
    **filter_options: Any,
) -> RunResult:
    """Run one filter on the robot's walk and return the full `RunResult` (what run_model summarises).

    Step k is the module's (`walk_and_record`); `on_step(k, robot, filter)` is called after each step.
    `seed` seeds the robot (unless it has its own rng), the initial particles and the filter (mazelab.seeding):
    the same seed gives the same result bit for bit. `kidnap_at=K`: at step K the robot is carried to a free
    place drawn from the seed (`plan_kidnapping`). `result.extras` holds the particle count per step
    ("particle_count": KLD-sampling varies it) and the backend the filter ran on ("backend").
    `visualize` says where the run is drawn (the values mazelab.viz.views lists), its memory checked up
    front; `view` (instead) is a view or a function `(world, filter_name) -> view` (`open_run_view`),
    called once the inputs are checked (a comparison's view of each filter).
    """
    check_world(world)
    sigma, delta = check_model_parameters(sigma, delta, (world.width, world.height))
    entry = filter_entry(filtering_algorithm)
    settings = entry.options.resolve(filter_options, entry.name)  # declared, checked, defaults filled in
    seed = new_seed() if seed is None else check_seed("seed", seed)
    streams = run_streams(seed)
    particles, steps = checked_walk(
        robot, world, particle_count, steps, init_particles_pos, visualize, streams, kidnap_at
    )
    filt = build_filter(
        entry.filter_class, world, sigma, delta, particles, streams.filter, steps, robot, filter_options
    )
    view = open_run_view(visualize if view is None else view, world, entry.name, robot)
    true_positions, recorded = walk_and_record(entry.filter_class, filt, robot, world, steps, view, on_step)
    stored = entry.options.to_json(settings)  # every option, defaults filled in, as the declaration writes them
    reference = None if entry.plugin is None else entry.plugin.as_json()
    inputs = RunInputs.of_run(
        robot, particles, world, sigma, delta, seed, steps, entry.name, dict(sorted(stored.items())), reference
    )
    return RunResult.of_recorded(recorded, 0, true_positions, filt.reinitialised_at, inputs, backend_of(filt))


def build_filter(
    filter_class: type,
    world: Maze,
    sigma: float,
    delta: float,
    particles: np.ndarray,
    rng: np.random.Generator,
    steps: int,
    robot: Robot,
    options: dict[str, Any],
) -> Any:
    """The run's filter, built on the backend its work repays (numba where it does) and checked against
    the contract before its first step (a missing or mistyped part is one line naming it). A class that
    declares the option `start` is handed the robot's start too (the EKF's `init="start"` tracks from it)."""
    if "start" in options_of(filter_class):
        options = {"start": robot.initial_position, **options}
    with backend_by_work(len(particles) * steps, steps), student_code(filter_class):
        filt = filter_class(maze_for(filter_class, world), sigma, delta, particles, rng, **options)
        check_filter(filt)
    return filt


def walk_and_record(
    filter_class: type, filt: Any, robot: Robot, world: Maze, steps: int, view: Any, on_step: Callable | None
) -> tuple[np.ndarray, Recorded]:
    """The run's steps: at step k the robot moves with its actual angle and measures z_k, the filter
    steps on them (`record_steps`), then the view draws it and `on_step(k, robot, filt)`
    is called; the view is closed however the run ends. Returns the robot's positions (steps, 2) and
    what the filter's steps recorded."""
    true_positions = np.empty((steps, 2))

    def observe(k: int) -> tuple[float, float]:
        compass_angle, z = robot.step(world)
        true_positions[k] = robot.position
        return compass_angle, z

    def after(k: int, filt: Any) -> None:
        view.log_step(k, robot.position, robot.heading, filt)
        if on_step is not None:
            on_step(k, robot, filt)

    try:
        with student_code(filter_class) as at:  # a failing user's filter: its frames and the step
            recorded = record_steps(filt, steps, observe, after=after, at=at)
    finally:
        view.close()
    return true_positions, recorded


# -- the recording loop: a filter stepped along a walk, each step's reads kept ------------------------
class Recorded:
    """Per step k = 1..steps, for R runs: the estimate (R, steps, 2), ESS, green circle, particle count
    and log evidence log p(z_1:k) (R, steps; NaN for a filter that keeps none), the filter's own time
    per step (steps,), and its diagnostics by name (R, steps): made empty for `runs` runs of `steps`
    steps, filled step by step by record_steps."""

    def __init__(self, runs: int, steps: int):
        self.estimates = np.empty((runs, steps, 2))
        self.ess = np.empty((runs, steps))
        self.confident = np.empty((runs, steps), dtype=bool)
        self.counts = np.empty((runs, steps), dtype=np.int64)
        self.log_evidence = np.empty((runs, steps))
        self.seconds = np.empty(steps)
        self.diagnostics: dict[str, np.ndarray] = {}


def record_steps(
    filt: Any,
    steps: int,
    observe: Callable[[int], tuple[Any, Any]],
    *,
    runs: int | None = None,
    after: Callable[[int, Any], None] | None = None,
    at: Any = None,
) -> Recorded:
    """Step `filt` `steps` times and keep what each step reads.

    Parameters
    ----------
    filt : a filter (mazelab.contract)
    steps : int
    observe : callable
        k (0-based) -> (compass angle th0_k, measurement z_k): numbers for one run, arrays (R,) for R runs.
    runs : int, optional
        R for a filter advancing R runs together (None: one run, the paper's shapes).
    after : callable, optional
        (k, filt) after step k (1-based): the viewer, a progress line.
    at : object with a `number` attribute, optional
        Set to the step being run (for the error that names it, mazelab.stops.student_code).

    Returns
    -------
    Recorded
        Arrays with a run axis of length R (1 for one run). The time per step is the filter's step
        and its reads (estimate, ESS, confidence), divided among the R runs.
    """
    count = 1 if runs is None else runs
    recorded = Recorded(count, steps)
    for k in range(steps):
        if at is not None:
            at.number = k + 1
        compass_angle, z = observe(k)
        started = time.perf_counter()
        filt.step(compass_angle, z)
        values = filt.estimate, filt.ess, filt.is_confident, filt.count
        recorded.seconds[k] = (time.perf_counter() - started) / count
        estimate, ess, confident, particles = check_step_values(type(filt), values, runs)  # into column k
        recorded.estimates[:, k], recorded.ess[:, k], recorded.confident[:, k] = estimate, ess, confident
        recorded.counts[:, k] = particles
        recorded.log_evidence[:, k] = getattr(filt, "log_evidence", np.nan)  # optional in the contract
        _keep_diagnostics(recorded, getattr(filt, "diagnostics", None), k, type(filt))
        if after is not None:
            after(k + 1, filt)
    return recorded


def _keep_diagnostics(recorded: Recorded, now: Any, k: int, filter_class: type) -> None:
    """This step's diagnostics into column k of their (R, steps) arrays, made NaN at a name's first step
    (a name missing at a step is NaN there): one number a step for one run, a number or one per run for
    R runs (spread over the runs as numpy broadcasts it)."""
    if now and not isinstance(now, dict):
        raise ContractError(f"{filter_class.name}.diagnostics must be a dict of this step's figures, got {now!r}")
    for name, value in (now or {}).items():
        if name not in recorded.diagnostics:
            recorded.diagnostics[name] = np.full(recorded.ess.shape, np.nan)
        try:
            value = np.asarray(value, dtype=float)
            if value.ndim > 1:  # a column takes (1, R) too; a step's diagnostic is not a table
                raise ValueError
            recorded.diagnostics[name][:, k] = value
        except (TypeError, ValueError):
            raise ContractError("a diagnostic must be a number (or one per run) at every step") from None


def checked_walk(
    robot: Robot,
    world: Maze,
    particle_count: int | None,
    steps: int | None,
    init_particles_pos: Any,
    visualize: Any,
    streams: RunStreams,
    kidnap_at: int | None = None,
) -> tuple[np.ndarray, int]:
    """A run's initial particles (N, 2) (given, or drawn from `streams.particles`) and its step count
    (given, else the robot's recorded steps, else DEFAULT_STEPS), each checked, with the robot's start,
    its kidnapping's place, its recorded walk and the recording's memory: one line for the first wrong.
    The robot is then made ready to walk: kidnapped at `kidnap_at` (`plan_kidnapping`), back at its
    start, and drawing from `streams.robot` unless it has its own rng."""
    if init_particles_pos is not None:
        particles = as_points("init_particles_pos", init_particles_pos)
        checked_count(particle_count, given=len(particles))
    else:
        particles = world.random_free_places(checked_count(particle_count), streams.particles)
    steps = check_steps((robot.recorded_steps or DEFAULT_STEPS) if steps is None else steps)
    given = particles if init_particles_pos is not None else None  # drawn ones lie in the free area
    check_walk(world, robot, given, steps)
    if visualize is not False and visualize is not None:  # what a drawn step records, at most
        drawn = visualize.max_drawn if isinstance(visualize, Visualization) else DEFAULT_MAX_DRAWN
        check_recording(len(particles), steps, drawn)
    if kidnap_at is not None:
        plan_kidnapping(robot, world, kidnap_at, steps, streams.kidnap)
    robot.reset()
    if not robot.rng_given:
        robot.rng = streams.robot
    return particles, steps


def run_model(
    robot: Robot,
    world: Maze,
    sigma: float,
    delta: float,
    particle_count: int | None = None,
    steps: int | None = None,
    save_parameters: bool = False,
    init_particles_pos: Sequence[Sequence[float]] | np.ndarray | None = None,
    filtering_algorithm: str | type = "SIRParticleFilter",
    *,
    visualize: Any = True,
    parameters_path: str | Path | None = None,
    **options: Any,
) -> list[tuple[tuple[float, float], tuple[float, float]]]:
    """The paper's entry point: run a filter and return [((x_true, y_true), (x_est, y_est)), ...].

    With `init_particles_pos` the particle count follows from it, and with a robot that replays
    angles the step count follows from them. `save_parameters=True` saves the scenario so the filters
    can be compared on identical data: to `parameters_path`, by default the paper's model_parameters.json
    in the working folder.
    The other keywords are `simulate`'s: `seed=`, `kidnap_at=K` (the robot kidnapped at step K), and
    filter options such as `resampling=`, `recovery=` and `kld=` (see ParticleFilter).
    """
    result = simulate(
        robot,
        world,
        sigma,
        delta,
        particle_count,
        steps,
        init_particles_pos,
        filtering_algorithm,
        visualize=visualize,
        **options,
    )
    if save_parameters:
        from mazelab.scenario import DEFAULT_PARAMETERS_PATH, save_scenario  # pydantic: only a run that saves

        saved = save_scenario(result.scenario, DEFAULT_PARAMETERS_PATH if parameters_path is None else parameters_path)
        if not in_jupyter():  # a notebook's cell says it in its own words (the Ukrainian one prints no English)
            print(f"scenario saved to {saved.resolve()}")  # where: a relative path is the working folder's
    pairs = zip(result.true_positions.tolist(), result.estimates.tolist(), strict=True)  # plain floats
    return [(tuple(true), tuple(estimate)) for true, estimate in pairs]


def maze_for(filter_class: type, world: Maze) -> Maze:
    """The maze a filter is handed: the run's own for a filter of the lab's; for any other (a plug-in,
    a class of the user's) a copy that shares no array with it, its nearest-station table built first
    (so the copy does not build it again: 0.4 ms for maze_10x10, 2 ms for a 50x50 maze). A Maze is
    read-only, which stops ordinary writes with an error at their line; the copy makes sure that a
    filter forcing its way past that (through `__dict__`, say) changes only its own map."""
    return world if any(entry.filter_class is filter_class for entry in entries()) else world.prepare().copy()


def plan_kidnapping(robot: Robot, world: Maze, kidnap_at: int, steps: int, rng: np.random.Generator) -> None:
    """Kidnap `robot` at step `kidnap_at` to a free place drawn from `rng`, unless it already replays
    that kidnapping; a different recorded kidnapping, or one after the last step, is refused."""
    kidnap_at = step_number("kidnap_at", kidnap_at)
    if kidnap_at > steps:
        raise ValueError(f"kidnap_at {kidnap_at} is after the last step ({steps})")
    if robot.kidnap_at is None:
        robot.kidnap(kidnap_at, world.random_free_place(rng))
    elif robot.kidnap_at != kidnap_at:
        raise ValueError(f"the robot replays a kidnapping at step {robot.kidnap_at}, not at step {kidnap_at}")


__all__ = [
    "Recorded",
    "RunInputs",
    "RunResult",
    "check_walk",
    "convergence_step",
    "open_run_view",
    "plan_kidnapping",
    "record_steps",
    "run_model",
    "simulate",
]
