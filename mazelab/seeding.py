"""The one seeding rule of the lab: how a seed becomes the random streams of a run, and how a study's
root seed becomes its runs' seeds. run, replay, compare, study, accuracy and kidnapping all use it, so
`run --seed S` repeats run S of any of them.

A run's seed S gives:
    start_place(maze, S) the robot's start place, drawn from default_rng(S)
    run_streams(S)      four independent streams (default_rng(S).spawn(4)): the robot's walk and noise,
                        the initial particles, the filter's draws, the kidnapping's place
A study's root seed gives run r the same seeds in every setting (common random numbers) whatever
the number of runs or workers (`study_seeds`).
"""

from typing import Any, NamedTuple

import numpy as np


class RunStreams(NamedTuple):
    """The independent random streams of one run."""

    robot: np.random.Generator
    particles: np.random.Generator
    filter: np.random.Generator
    kidnap: np.random.Generator


def new_seed() -> int:
    """A fresh random seed, recorded so that any run can be repeated."""
    return int(np.random.SeedSequence().entropy % 2**63)


def start_place(world: Any, seed: int) -> tuple[float, float]:
    """The robot's start of run `seed`: a free place of `world` (a Maze) drawn from default_rng(seed)."""
    return world.random_free_place(np.random.default_rng(seed))


def run_streams(seed: int) -> RunStreams:
    """The streams of run `seed`; spawn(4)'s first three are spawn(3)'s, so adding the kidnapping's
    stream changed no run without one."""
    return RunStreams(*np.random.default_rng(seed).spawn(4))


def study_seeds(root_seed: int, runs: int) -> list[tuple[int, int]]:
    """(seed, maze seed) of runs 1..R, children of one root SeedSequence: run r's seeds do not change
    when R grows (SeedSequence.spawn numbers its children), so a larger study extends a smaller one."""
    children = np.random.SeedSequence(root_seed).spawn(runs)
    return [tuple(int(v >> np.uint64(1)) for v in child.generate_state(2, np.uint64)) for child in children]


__all__ = ["RunStreams", "new_seed", "run_streams", "start_place", "study_seeds"]
