"""The benchmark's parts on tiny sizes (its figures are printed by `python main.py bench`, not tested)."""

from __future__ import annotations

from conftest import PAPER_MAZE

from mazelab import bench as benchmark
from mazelab.maze import Maze


def test_large_maze_is_seeded_and_has_thousands_of_stations():
    first, second = benchmark.large_maze(), benchmark.large_maze()
    assert (first.grid == second.grid).all()
    assert first.grid.shape == (100, 100) and len(first.stations) >= 2000


def test_measure_gives_every_filter_and_the_reference_and_a_table():
    world = Maze(PAPER_MAZE)
    rows = list(benchmark.measure("paper", world, (300,), steps=2, warmup=1))
    names = [row.filter_name for row in rows]
    assert names == ["SIRParticleFilter", "AuxiliaryParticleFilter", "RegularizedParticleFilter", "reference"]
    assert all(row.seconds_per_step > 0 and row.peak_bytes > 0 for row in rows)
    table = benchmark.format_table(rows)
    lines = table.splitlines()
    header = next(i for i, line in enumerate(lines) if line.startswith("maze"))
    assert "particle-steps per second" in "\n".join(lines[:header])  # the columns are explained above them
    assert len(lines) == header + 1 + len(rows)
    ratios = [line.split()[-1] for line in lines[header + 1 :]]
    assert [r.endswith("x") for r in ratios] == [True, True, True, False]  # each filter against the reference
    assert ratios[-1] == "(itself)" and all(line.split()[4] != "0.00" for line in lines[header + 1 :])
