"""The particle smoothers against the exact smoother on the shipped scenarios, over seeded runs:

    uv run python benchmarks/particle_smoothers.py                   # paper_5x5 and maze_10x10, 5 seeds, lag 10
    uv run python benchmarks/particle_smoothers.py --scenario paper_5x5 --seeds 2 --lag 5

For each scenario and filter (SIR, the APF, the RPF; the scenario's particles): the means over the walk's
steps and the seeds of each estimate's distance to the exact smoothed mean (map units) and of its total
variation to the exact smoothed posterior over the maze's unit cells, for the filter's own estimate (lag
0), the fixed-lag smoother (lag L) and the path smoother (mazelab.smoothing.score_smoothers); the fewest
and the median distinct ancestors the path smoother rests on (the path degeneracy); the exact filtered and
smoothed means' distance to the truth; the seconds (with the load average: the machine may be shared).
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np

from mazelab.maze import load_maze
from mazelab.scenario import find_scenario, load_scenario
from mazelab.smoothing import SMOOTHERS, score_smoothers


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenario", default="paper_5x5,maze_10x10", help="shipped names or files, comma-separated")
    parser.add_argument("--seeds", type=int, default=5, help="the filters' seeds 1..S")
    parser.add_argument("--lag", type=int, default=10)
    parser.add_argument("--resolution", type=float, default=0.05, help="the exact grid's cells (map units)")
    args = parser.parse_args()
    for name in args.scenario.split(","):
        stored = load_scenario(find_scenario(name))
        world = stored.world() or load_maze(name)
        started = time.perf_counter()
        rows = []
        for seed in range(1, args.seeds + 1):
            scores = score_smoothers(world, stored.robot(), stored.sigma, stored.delta, ["sir", "apf", "rpf"],
                                     lag=args.lag, seed=seed, initial_particles=stored.init_particles_pos,
                                     grid_options={"resolution": args.resolution})  # fmt: skip
            rows += scores.rows
        seconds = time.perf_counter() - started
        steps, count = len(stored.robot_measurements), len(stored.init_particles_pos)
        print(f"{name}: {steps} steps, {count} particles, lag {args.lag}, grid {args.resolution:g}, seeds "
              f"1..{args.seeds}; {seconds:.0f} s, load average {os.getloadavg()[0]:.2f}")  # fmt: skip
        exact = [np.mean([r[f"exact_{w}_to_truth"] for r in rows]) for w in ("filtered", "smoothed")]
        print(f"  exact to the truth: filtered mean {exact[0]:.3f}, smoothed mean {exact[1]:.3f}")
        header = "".join(f"{n + ' err':>11}{n + ' TV':>10}" for n in SMOOTHERS)
        print(f"  {'filter':6}{header}{'fewest':>8}{'median':>8}  (path smoother's ancestors)")
        for label in dict.fromkeys(r["filter"] for r in rows):
            mine = [r for r in rows if r["filter"] == label]
            cells = "".join(
                f"{np.mean([r[f'{n}_error'] for r in mine]):11.3f}{np.mean([r[f'{n}_tv'] for r in mine]):10.3f}"
                for n in SMOOTHERS
            )
            ancestors = [r["path_ancestors"] for r in mine]
            print(f"  {label:6}{cells}{min(ancestors):8d}{int(np.median(ancestors)):8d}")


if __name__ == "__main__":
    main()
