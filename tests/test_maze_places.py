"""`Maze.random_free_places(count)` takes a whole count >= 0 whose arrays fit in memory; anything else is
one line (TypeError, ValueError, or MemoryLimitError for 10**12 points), not numpy's memory error."""

from __future__ import annotations

import numpy as np
import pytest

from mazelab.checks import MemoryLimitError, memory_budget
from mazelab.maze import load_maze


def test_random_free_places_takes_a_whole_count_that_fits():
    world = load_maze("paper_5x5")
    assert world.random_free_places(np.int64(3), np.random.default_rng(1)).shape == (3, 2)
    assert world.random_free_places(0).shape == (0, 2)
    if memory_budget() is not None:  # (a system that tells nothing of its memory: numpy's own error)
        with pytest.raises(MemoryLimitError, match=r"^random_free_places\(1000000000000\) needs about "):
            world.random_free_places(10**12)
    for count, error in ((1e12, TypeError), (2.0, TypeError), (True, TypeError), (-1, ValueError)):
        with pytest.raises(error, match="random_free_places: count must be"):
            world.random_free_places(count)
