"""What the compiled backend's buffers hold between steps (mazelab.kernels.compiled.BufferPool): a step
lets go of what it has spent, so that with nothing held by the caller the pool keeps, per buffer, only
the arrays a step needs at once, none float64 (W and log w float32, log W derived only when read), and
a step allocates nothing else of the particles' size:

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


@pytest.mark.parametrize("name", ["sir", "apf", "rpf"])
def test_a_step_keeps_no_float64_array_nor_log_w(name, paper_world):
    # W, the first stage's W and the log w float32; log W never made: the APF's first stage and the
    # RPF's step without resampling read log w and its totals; the RPF's jitter gathers no headings
    filt = stepped("rpf", paper_world, 20) if name == "rpf" else stepped(name, paper_world)
    held = {name: np.dtype(slot[1]) for name, slot in filt.ops.pool._slots.items() if slot[-1]}
    assert all(dtype.itemsize == 4 for dtype in held.values()), held
    assert "headings" not in held and "log_weights" not in held
    assert "lw" not in vars(filt.weights_value)  # log W: derived only when read
    if name == "rpf":  # the move after the jitter drew every heading: the filter's own array
        assert filt.headings.flags.writeable and len(filt.headings) == len(filt.positions)


@pytest.mark.parametrize("name", ["sir", "apf", "rpf"])
def test_a_step_allocates_nothing_of_the_particles_size_beyond_its_buffers(name, paper_world):
    # once the buffers are made, a step (and its reads) allocates only small arrays: no log W derived
    # (8 bytes a particle), no gathered second stage (4), no float64 log w (8)
    import tracemalloc

    count, rng, walk_rng = 100_000, np.random.default_rng(4), np.random.default_rng(6)
    with use_backend("compiled"):
        filt = resolve_filter(name)(paper_world, 0.3, 0.5, paper_world.random_free_places(count, rng), rng)
    robot = Robot(0.3, 0.5, paper_world.random_free_place(walk_rng), rng=walk_rng)
    peaks = []
    for _ in range(20):
        inputs = robot.step(paper_world)
        tracemalloc.start()
        try:
            filt.step(*inputs)
            _ = filt.estimate, filt.ess, filt.is_confident
            peaks.append(tracemalloc.get_traced_memory()[1] / count)
        finally:
            tracemalloc.stop()
    if name == "rpf":
        assert any(at >= 6 for at in filt.regularised_at), "the walk must regularise after the buffers are made"
    assert max(peaks[6:]) < 1.0, peaks  # bytes a particle


@pytest.mark.parametrize("backend", ["numpy", "compiled"])
def test_making_a_filter_copies_no_given_float64_particles(backend, paper_world):
    import tracemalloc

    rng = np.random.default_rng(3)
    particles = paper_world.random_free_places(200_000, rng)  # float64 (N, 2): 3.2 MB
    with use_backend(backend):
        resolve_filter("sir")(paper_world, 0.3, 0.5, particles[:10], rng)  # the one-off imports first
        tracemalloc.start()
        try:
            resolve_filter("sir")(paper_world, 0.3, 0.5, particles, rng)
            peak = tracemalloc.get_traced_memory()[1]
        finally:
            tracemalloc.stop()
    # the filter's own arrays: float32 positions, headings and log w (half, a quarter and a quarter of
    # the given array's bytes), a few small ones; a float64 copy of the particles would add as much again
    assert peak < 1.5 * particles.nbytes
