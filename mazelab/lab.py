"""The paper's entry points, run_model and simulate, with drawing: they open the Rerun view that
`visualize` asks for and hand it to the simulation loop (mazelab.simulation), which never imports it."""

from __future__ import annotations

import functools
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from mazelab import simulation
from mazelab.maze import Maze
from mazelab.robot import Robot
from mazelab.scenario import DEFAULT_PARAMETERS_PATH, save_scenario
from mazelab.simulation import RunResult
from mazelab.viz.style import DEFAULT_MAX_DRAWN
from mazelab.viz.targets import Visualization, in_jupyter
from mazelab.viz.views import open_view


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
    visualize: Any = False,
    **options: Any,
) -> RunResult:
    """Run one filter on the robot's walk and return the full `RunResult` (what run_model summarises).

    `visualize` says where the run is drawn (see mazelab.viz.views: False, True, "viewer", "web",
    "notebook", an .rrd path, a RecordingStream or a view); every other option is
    mazelab.simulation.simulate's (`seed`, `on_step`, `kidnap_at`) or the filter's.
    """
    return simulation.simulate(
        robot,
        world,
        sigma,
        delta,
        particle_count,
        steps,
        init_particles_pos,
        filtering_algorithm,
        view=functools.partial(open_view, visualize),
        recorded=drawn_at_most(visualize),
        **options,
    )


def drawn_at_most(visualize: Any) -> int | None:
    """How many particles a step of this `visualize` records at most (None: nothing is drawn)."""
    if visualize is False or visualize is None:
        return None
    return visualize.max_drawn if isinstance(visualize, Visualization) else DEFAULT_MAX_DRAWN


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
    seed: int | None = None,
    visualize: Any = True,
    parameters_path: str | Path = DEFAULT_PARAMETERS_PATH,
    kidnap_at: int | None = None,
    **filter_options: Any,
) -> list[tuple[tuple[float, float], tuple[float, float]]]:
    """The paper's entry point: run a filter and return [((x_true, y_true), (x_est, y_est)), ...].

    With `init_particles_pos` the particle count follows from it, and with a robot that replays
    angles the step count follows from them. `save_parameters=True` saves the scenario so the filters
    can be compared on identical data: to the paper's model_parameters.json in the working folder, or
    to `parameters_path`.
    `kidnap_at=K` kidnaps the robot at step K; filter options such as `resampling=`, `recovery=`
    and `kld=` pass through to the filter (see ParticleFilter).
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
        seed=seed,
        visualize=visualize,
        kidnap_at=kidnap_at,
        **filter_options,
    )
    if save_parameters:  # say where: a relative path is relative to the folder Python runs in
        saved = save_scenario(result.scenario, parameters_path)
        # in Jupyter that folder is the notebook's: the name as given, no machine path in a report handed in
        print(f"scenario saved to {saved if in_jupyter() and not saved.is_absolute() else saved.resolve()}")
    return result.as_pairs()


__all__ = [
    "run_model",
    "simulate",
]
