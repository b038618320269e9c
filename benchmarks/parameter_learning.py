"""A PMMH chain on (sigma, delta) against the exact parameter posterior, on a seeded walk:

    uv run python benchmarks/parameter_learning.py                  # paper_5x5, 30 steps, 20,000 iterations
    uv run python benchmarks/parameter_learning.py --filter apf --iterations 5000

The walk is a seeded robot's with sigma = 0.4, delta = 0.3 (mazelab.robot.Robot). The exact posterior is the
grid filter's evidence on S x S cells of the lab's box (sigma in [0.2, 0.8], delta in [0.05, 0.6]) under the
uniform prior, at a grid resolution r; its own error is measured by halving r and, apart, the cells' width
(2 x (both differences): the bound for an error of order >= 1). The chain is mazelab.learning.pmmh's with
the filter's log evidence. Printed per quantity: the exact value, its grid error, the chain's value, its
Monte Carlo standard error, and the difference in those standard errors; then the acceptance rate, the
effective sample sizes, the times and the load average (the machine may be shared).
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np

from mazelab.learning import ParameterGrid, exact_parameter_posterior, pmmh
from mazelab.maze import load_maze
from mazelab.robot import Robot

TRUE_SIGMA, TRUE_DELTA = 0.4, 0.3


def summary(posterior_or_chain) -> np.ndarray:
    """(2, 3): rows sigma, delta; columns the posterior mean, the 90% interval's low and high ends."""
    return np.column_stack([posterior_or_chain.mean, posterior_or_chain.interval()])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--maze", default="paper_5x5")
    parser.add_argument("--steps", type=int, default=30)
    parser.add_argument("--seed", type=int, default=7, help="the walk's seed")
    parser.add_argument("--resolution", type=float, default=0.05, help="the grid filter's cells (map units)")
    parser.add_argument("--cells", type=int, default=12, help="S, the cells along sigma and along delta")
    parser.add_argument("--filter", default="sir")
    parser.add_argument("--particles", type=int, default=200)
    parser.add_argument("--iterations", type=int, default=20_000)
    parser.add_argument("--chain-seed", type=int, default=1)
    args = parser.parse_args()
    world = load_maze(args.maze)
    rng = np.random.default_rng(args.seed)
    robot = Robot(TRUE_SIGMA, TRUE_DELTA, world.random_free_place(rng), rng=rng)
    angles, zs = zip(*[robot.step(world) for _ in range(args.steps)], strict=True)

    started = time.perf_counter()
    cells = ParameterGrid(cells=(args.cells, args.cells))
    exact = summary(exact_parameter_posterior(world, angles, zs, cells, resolution=args.resolution))
    finer = summary(exact_parameter_posterior(world, angles, zs, cells, resolution=args.resolution / 2))
    halved = ParameterGrid(cells=(2 * args.cells, 2 * args.cells))  # cells half as wide: the grid's own error
    narrower = summary(exact_parameter_posterior(world, angles, zs, halved, resolution=args.resolution))
    grid_error = 2 * (abs(finer - exact) + abs(narrower - exact))
    exact_seconds = time.perf_counter() - started

    started = time.perf_counter()
    chain = pmmh(
        world, angles, zs, args.iterations, filter_name=args.filter, particle_count=args.particles,
        burn_in=args.iterations // 10, seed=args.chain_seed,
    )  # fmt: skip
    chain_seconds = time.perf_counter() - started
    chained = summary(chain)
    monte_carlo = np.column_stack([chain.mean_error, chain.interval_error()])

    print(
        f"{args.maze}, {args.steps} steps (walked with sigma {TRUE_SIGMA}, delta {TRUE_DELTA}, seed {args.seed}); "
        f"load average {os.getloadavg()[0]:.2f}"
    )
    print(f"exact: {args.cells}x{args.cells} cells of the lab's box, grid resolution {args.resolution:g}")
    burn_in = args.iterations // 10
    print(f"PMMH: {args.filter}, {args.particles} particles, {args.iterations} iterations ({burn_in} burn-in)")
    print(f"{'':14} {'exact':>8} {'grid err':>9} {'chain':>8} {'MC err':>8} {'diff/MC':>8}")
    for row, name in enumerate(("sigma", "delta")):
        for column, what in enumerate(("mean", "5%", "95%")):
            e, g, c, m = (a[row, column] for a in (exact, grid_error, chained, monte_carlo))
            print(f"{name + ' ' + what:14} {e:8.4f} {g:9.4f} {c:8.4f} {m:8.4f} {(c - e) / m:8.2f}")
    ess = chain.ess
    print(f"acceptance rate {chain.acceptance_rate:.3f}; ESS sigma {ess[0]:.0f}, delta {ess[1]:.0f}")
    print(f"seconds: exact (three grids) {exact_seconds:.0f}, chain {chain_seconds:.0f}")
    within = abs(chained - exact) <= 3 * monte_carlo + grid_error
    print("every quantity within 3 Monte Carlo errors plus the grid error:", bool(within.all()))


if __name__ == "__main__":
    main()
