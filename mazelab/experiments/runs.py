"""Several filters on one robot walk, and the figures of one run.

Figures of one run:
    last-20% error    `final_error` (its CSV column): the mean error over the last FINAL_SHARE (20%) of the
                      steps, robust to one unlucky step (the last-step error is errors[-1]);
    convergence step  `convergence_step`: the step from which the error stays below CONVERGENCE_RADIUS.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from mazelab.backend import backend_by_work
from mazelab.contract import takes
from mazelab.experiments.warmup import warm_up_filters
from mazelab.maze import Maze
from mazelab.model import DEFAULT_PARTICLE_COUNT, DEFAULT_STEPS
from mazelab.plugins import canonical_spec, is_plugin_spec
from mazelab.registry import filter_entry, resolve_filter
from mazelab.robot import Robot
from mazelab.simulation import RunResult, simulate

FINAL_SHARE = 0.2  # the last-20% error (`final_error`) is the mean error over this share of the last steps


def final_error(errors: np.ndarray, share: float = FINAL_SHARE) -> float:
    """Mean error over the last `share` of the steps (at least one step), map units."""
    errors = np.asarray(errors, dtype=float)
    return float(errors[-max(1, int(len(errors) * share)) :].mean())


def mean_ess(result: RunResult) -> float:
    """Mean effective sample size over the steps; NaN for the grid filter, which has none."""
    return math.nan if np.isnan(result.ess).all() else float(np.nanmean(result.ess))


def parse_filters(text: str) -> list[str]:
    """'sir,apf,rpf' -> the filters' class names, in order, without repeats; a plug-in
    `file.py:Class` -> its spec with the file's absolute path (what worker processes import)."""
    names = [filter_key(part.strip()) for part in text.split(",") if part.strip()]
    if not names:
        raise ValueError("--filters is empty; give e.g. sir,apf,rpf")
    names = list(dict.fromkeys(names))
    labels = [resolve_filter(name).name for name in names]
    for label in labels:
        if labels.count(label) > 1:
            raise ValueError(f"--filters has two filters named {label}: rename one class (or its `name`)")
    return names


def filter_key(name: str) -> str:
    """A shipped filter's class name, or a plug-in's spec with its absolute path."""
    return canonical_spec(name) if is_plugin_spec(name) else resolve_filter(name).name


def filter_labels(names: Sequence[str]) -> list[str]:
    """How the results and the viewer name the filters: their `name` (a plug-in's is its class name)."""
    return [resolve_filter(name).name for name in names]


# -- several filters on one scenario ---------------------------------------------------------------
def filter_options(filter_name: str | type, **options: Any) -> dict[str, Any]:
    """Of the options given (None: not given), those the filter declares (mazelab.declaration): the
    RPF's threshold and bandwidth reach the RPF only, recovery and KLD-sampling the particle filters,
    the point estimate every filter that has one."""
    filter_class = resolve_filter(filter_name)
    return {name: value for name, value in options.items() if value is not None and takes(filter_class, name)}


def is_particle_filter(filter_name: str) -> bool:
    """Whether a filter is a sample of particles (its registry entry says it takes a particle count)."""
    return filter_entry(filter_name).takes_particles


def run_filters(
    world: Maze,
    robot: Robot,
    sigma: float,
    delta: float,
    filter_names: Sequence[str],
    *,
    seed: int,
    particles: Sequence[Sequence[float]] | np.ndarray | None = None,
    particle_count: int | None = None,
    steps: int | None = None,
    comparison: Any = None,
    kidnap_at: int | None = None,
    options: Mapping[str, Mapping[str, Any]] | None = None,
) -> dict[str, RunResult]:
    """Run every filter on the same scenario: the robot's walk, measurements and initial particles.

    The first run records the walk and measurements (if the robot has none) and draws the particles
    (if none are given); every later filter replays exactly those, the kidnapping (`kidnap_at`, its
    place drawn from `seed`) included. Each filter's random draws come from `seed`, and with
    `comparison` (open_comparison) each run draws into its own view. `options` maps a filter's name
    (as in `filter_names`) to its own options. Before the first timed step, each filter is warmed
    once per process (mazelab.experiments.warmup): a filter's time per step is the same in any order.
    """
    count = particle_count if particles is None else len(particles)
    total = steps or robot.recorded_steps or DEFAULT_STEPS
    work = (count or DEFAULT_PARTICLE_COUNT) * total * len(filter_names), total * len(filter_names)
    results: dict[str, RunResult] = {}
    with backend_by_work(*work):  # the warm-up and the runs on one backend (numba where it pays)
        warm_up_filters(world, sigma, delta, filter_names, count, options or {})
        for name in filter_names:
            result = simulate(
                robot,
                world,
                sigma,
                delta,
                particle_count,
                steps,
                particles,
                name,
                seed=seed,
                view=None if comparison is None else comparison.view_for(resolve_filter(name).name),
                kidnap_at=kidnap_at,
                **(options or {}).get(name, {}),
            )
            if particles is None:
                particles = result.initial_particles
            steps = len(result.errors)
            results[result.filter_name] = result
    return results


def mean_particle_count(result: RunResult) -> float:
    """The particle count averaged over the steps (it varies with KLD-sampling)."""
    return float(np.mean(result.extras["particle_count"]))


__all__ = [
    "FINAL_SHARE",
    "filter_key",
    "filter_labels",
    "filter_options",
    "final_error",
    "is_particle_filter",
    "mean_ess",
    "mean_particle_count",
    "parse_filters",
    "run_filters",
]
