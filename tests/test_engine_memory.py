"""What the compiled backend's buffers hold between steps (mazelab.kernels.compiled.BufferPool): a step
lets go of what it has spent, so that with nothing held by the caller the pool keeps, per buffer, only
the arrays a step needs at once:

- the weights: one array (the first-stage weights are spent once the ancestors are drawn, the old
  weights once every run has resampled: the new ones are written over them);
- the SIR's likelihood: one array (the old weights that kept it for their log W are spent);
- the positions: two, the filter's and the moved ones (the RPF's jittered particles are moved again
  within the step: the reads kept for the old particles go with them, not a third array);
- the uniforms that become the headings: one for the SIR and the RPF (the old headings go as every
  particle moves, their array drawn into); the APF's auxiliary points draw theirs while the old ones
  are still the filter's.

Skipped without numba (the `fast` extra)."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("numba")

from mazelab.backend import use_backend
from mazelab.registry import resolve_filter
from mazelab.robot import Robot


def stepped(name: str, world, steps: int = 8):
    """A compiled filter of 500 particles after `steps` steps, its reads made every step (as a run's)."""
    rng = np.random.default_rng(4)
    with use_backend("compiled"):
        filt = resolve_filter(name)(world, 0.3, 0.5, world.random_free_places(500, rng), rng)
    walk_rng = np.random.default_rng(6)
    robot = Robot(0.3, 0.5, world.random_free_place(walk_rng), rng=walk_rng)
    for _ in range(steps):
        filt.step(*robot.step(world))
        _ = filt.estimate, filt.ess, filt.is_confident
    return filt


def kept(filt, name: str) -> int:
    """How many arrays the filter's buffer pool keeps under `name`."""
    return len(filt.ops.pool._slots[name][-1])


@pytest.mark.parametrize("name", ["sir", "apf", "rpf"])
def test_a_step_keeps_one_weights_array(name, paper_world):
    assert kept(stepped(name, paper_world), "weights") == 1


def test_the_sir_keeps_one_likelihood_array(paper_world):
    assert kept(stepped("sir", paper_world), "log_likelihood") == 1


@pytest.mark.parametrize("name", ["sir", "apf", "rpf"])
def test_a_step_keeps_two_position_arrays(name, paper_world):
    filt = stepped("rpf", paper_world, 20) if name == "rpf" else stepped(name, paper_world)
    if name == "rpf":
        assert len(filt.regularised_at) > 0, "the walk must regularise for the RPF's case"
    assert kept(filt, "positions") == 2


@pytest.mark.parametrize("name", ["sir", "rpf"])
def test_a_step_that_moves_every_particle_keeps_one_uniforms_array(name, paper_world):
    filt = stepped(name, paper_world)
    assert kept(filt, "uniforms") == 1
    assert filt.headings is not None and len(filt.headings) == len(filt.positions)
