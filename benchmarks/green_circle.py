"""How often the green circle's two rules disagree: 95% of the weight within 1 of the estimate (the
rule the program uses) against the paper's 95% of the particles (a plain count).

    python benchmarks/green_circle.py [--runs 20] [--maze maze_10x10]

Seeded runs of SIR, APF and RPF (1500 particles, 200 steps, sigma 0.3, delta 0.5); at every step,
after the update, both rules are read on the same weighted particles and the same estimate. The
table gives the share of steps on which they disagree, and on which each alone says "confident".
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from mazelab.maze import load_maze
from mazelab.model import CONFIDENCE_RADIUS, CONFIDENCE_SHARE
from mazelab.robot import Robot
from mazelab.simulation import simulate

FILTERS = ["SIRParticleFilter", "AuxiliaryParticleFilter", "RegularizedParticleFilter"]


def both_rules(filt) -> tuple[bool, bool]:
    """(share of the weight, share of the particles) within CONFIDENCE_RADIUS of the estimate, each >= 95%."""
    inside = np.hypot(*(filt.positions - filt.estimate).T) <= CONFIDENCE_RADIUS
    return float(filt.weights[inside].sum()) >= CONFIDENCE_SHARE, float(inside.mean()) >= CONFIDENCE_SHARE


def measure(maze: str, runs: int) -> dict[str, np.ndarray]:
    """Per filter, an array (steps over all runs, 2) of the two rules' verdicts."""
    world, verdicts = load_maze(maze), {name: [] for name in FILTERS}
    for seed in range(runs):
        for name in FILTERS:
            robot = Robot(0.3, 0.5, world.random_free_place(np.random.default_rng(seed)))
            simulate(robot, world, 0.3, 0.5, 1500, 200, filtering_algorithm=name, seed=seed,
                     on_step=lambda k, _robot, filt, name=name: verdicts[name].append(both_rules(filt)))  # fmt: skip
    return {name: np.array(rows) for name, rows in verdicts.items()}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=20)
    parser.add_argument("--maze", default="maze_10x10")
    arguments = parser.parse_args()
    print(f"{arguments.runs} runs x 200 steps on {arguments.maze}, 1500 particles")
    print(f"{'filter':<28}{'disagree':>10}{'weight only':>13}{'count only':>12}")
    for name, rows in measure(arguments.maze, arguments.runs).items():
        weight, count = rows[:, 0], rows[:, 1]
        print(f"{name:<28}{np.mean(weight != count):>10.1%}{np.mean(weight & ~count):>13.1%}"
              f"{np.mean(count & ~weight):>12.1%}")  # fmt: skip


if __name__ == "__main__":
    main()
