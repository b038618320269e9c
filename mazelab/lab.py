"""The paper's entry point, run_model, over `simulate` (mazelab.simulation: one run, drawn where
`visualize` says)."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from mazelab.maze import Maze
from mazelab.robot import Robot
from mazelab.scenario import DEFAULT_PARAMETERS_PATH, save_scenario
from mazelab.simulation import simulate
from mazelab.viz.targets import in_jupyter


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
    if save_parameters:
        saved = save_scenario(result.scenario, parameters_path)
        if not in_jupyter():  # a notebook's cell says it in its own words (the Ukrainian one prints no English)
            print(f"scenario saved to {saved.resolve()}")  # where: a relative path is the working folder's
    return result.as_pairs()


__all__ = [
    "run_model",
    "simulate",
]
