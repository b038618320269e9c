"""The whole filter against the exact posterior: on fixed seeded scenarios of the shipped mazes, the
distance between its estimate and the exact grid filter's posterior mean over the second half of the
steps, and whether it converged, with the shipped SIR's figures on the same scenarios beside it.

The verdict is a one-sided sign test: on each scenario the student's filter and the shipped SIR (with
the resampling scheme the student's resembles) see the same walk, measurements and initial particles.
A filter that is the SIR in distribution is the farther of the two from the exact mean with probability
1/2 on each scenario, independently; it fails when it is farther on at least WORSE_LIMIT of the
SCENARIOS, which happens with probability P(Binomial(12, 1/2) >= 11) = 13/4096 = 0.0032.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass

import numpy as np

from mazelab.exercise.parts import Row
from mazelab.mazes import load_maze
from mazelab.plugins import StudentCodeError
from mazelab.robot import Robot
from mazelab.seeding import start_place
from mazelab.simulation import RunResult, convergence_step, simulate

SCENARIOS = tuple((maze, seed) for maze in ("paper_5x5", "maze_10x10") for seed in range(11, 17))
SIGMA, DELTA = 0.3, 0.5  # the lab's example
PARTICLES, STEPS = 1000, 150
GRID_RESOLUTION = 0.05  # the exact filter's cells: fine next to L = 0.2, coarse enough to be quick
WORSE_LIMIT = 11  # fail when farther than the SIR from the exact mean on this many of the 12 scenarios


def sign_test_alpha(limit: int = WORSE_LIMIT, scenarios: int = len(SCENARIOS)) -> float:
    """P(Binomial(scenarios, 1/2) >= limit): the whole-filter check's false-alarm rate."""
    return sum(math.comb(scenarios, k) for k in range(limit, scenarios + 1)) / 2**scenarios


@dataclass
class ScenarioFigures:
    """One scenario: the student's and the SIR's distance to the exact mean (second half) and convergence."""

    maze: str
    seed: int
    distance: float
    sir_distance: float
    converged: bool
    sir_converged: bool


def distance_to_exact(result: RunResult, exact: RunResult) -> float:
    """Mean distance between a run's estimates and the exact posterior means over the second half."""
    window = slice(len(exact.estimates) // 2, None)
    return float(np.hypot(*(result.estimates - exact.estimates)[window].T).mean())


def run_scenario(filter_class: type, maze: str, seed: int, scheme: str) -> ScenarioFigures:
    """The exact filter, the student's and the shipped SIR on one seeded scenario."""
    world = load_maze(maze)
    robot = Robot(SIGMA, DELTA, start_place(world, seed))
    exact = simulate(robot, world, SIGMA, DELTA, PARTICLES, STEPS, None, "grid", seed=seed, resolution=GRID_RESOLUTION)
    particles = exact.initial_particles
    mine = simulate(robot, world, SIGMA, DELTA, None, STEPS, particles, filter_class, seed=seed)
    sir = simulate(robot, world, SIGMA, DELTA, None, STEPS, particles, "sir", seed=seed, resampling=scheme)
    return ScenarioFigures(
        maze,
        seed,
        distance_to_exact(mine, exact),
        distance_to_exact(sir, exact),
        convergence_step(mine.errors) is not None,
        convergence_step(sir.errors) is not None,
    )


def check_whole(filter_class: type, scheme: str = "systematic") -> tuple[Row, list[ScenarioFigures]]:
    """The whole filter's row (the sign test against the shipped SIR) and the figures per scenario."""
    expected = (
        f"no worse than SIR ({scheme}): farther on < {WORSE_LIMIT} of {len(SCENARIOS)} (alpha {sign_test_alpha():.4f})"
    )
    figures = []
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        for maze, seed in SCENARIOS:
            try:
                figures.append(run_scenario(filter_class, maze, seed, scheme))
            except StudentCodeError as error:
                where = "; ".join(line.strip() for line in str(error).splitlines())  # one line: a table cell
                got = f"{maze}, seed {seed}: {where}"
                return Row("whole filter", False, expected, got, "fix the error first"), figures
    worse = sum(f.distance > f.sir_distance for f in figures)
    mean, sir_mean = np.mean([f.distance for f in figures]), np.mean([f.sir_distance for f in figures])
    converged, sir_converged = sum(f.converged for f in figures), sum(f.sir_converged for f in figures)
    got = (
        f"farther on {worse} of {len(figures)}; to exact {mean:.3f} (SIR {sir_mean:.3f}); "
        f"converged {converged}/{len(figures)} (SIR {sir_converged})"
    )
    passed = worse < WORSE_LIMIT
    hint = "" if passed else "the parts pass alone but not together: check what weigh and predict assume of each other"
    return Row("whole filter", passed, expected, got, hint), figures


def figures_table(figures: list[ScenarioFigures]) -> list[list[str]]:
    """Rows of the per-scenario table: maze, seed, distances to the exact mean and convergence."""
    return [
        [
            f.maze,
            str(f.seed),
            f"{f.distance:.3f}",
            f"{f.sir_distance:.3f}",
            "yes" if f.converged else "no",
            "yes" if f.sir_converged else "no",
        ]
        for f in figures
    ]


FIGURE_HEADERS = ["maze", "seed", "to exact (yours)", "to exact (SIR)", "converged (yours)", "converged (SIR)"]

__all__ = [
    "FIGURE_HEADERS",
    "SCENARIOS",
    "ScenarioFigures",
    "check_whole",
    "distance_to_exact",
    "figures_table",
    "run_scenario",
    "sign_test_alpha",
]
