"""The compiled backend (mazelab.kernels, numba) against the numpy reference: each kernel's values, to
the bit where it does the numpy path's float32 arithmetic (the likelihood, the move's headings of the
same uniforms, the resampling for the same cumulative weights), to an ulp where it has its own cos and
sin (the move) and to rounding where it sums in another order (the normalisation and the reads); the
kernels' own draws (the move's uniforms, the jitter's normals) have their laws; every kernel gives the
same values on one thread and on two, so whole runs repeat per backend on any thread count, R runs
together equal R single runs, arrays a caller holds are never written over, and the two backends
agree statistically (the accuracy table, a study's convergence shares).

Skipped without numba (the `fast` extra; uv's dev group installs it). The kernels are compiled once per
machine and cached (mazelab.kernels): the first run of this file compiles them, some 15-40 s on a busy
2-core machine, later runs load them in about a second."""

from __future__ import annotations

import math
import os
import shutil
import subprocess
import sys

import numpy as np
import pytest
from conftest import ROOT
from test_batch import step_together_and_alone

pytest.importorskip("numba")

from mazelab.backend import NUMPY_KERNELS, THREADS_VARIABLE, use_backend
from mazelab.bench import large_maze
from mazelab.checks import MAX_ANGLE
from mazelab.experiments.accuracy import accuracy_filters, accuracy_plan, accuracy_records, accuracy_summary
from mazelab.experiments.executor import run_study
from mazelab.experiments.study import MazeChoice, study_settings, study_tasks
from mazelab.kernels import CHUNK, THREADED_FROM, sources_digest
from mazelab.kernels.compiled import CompiledKernels, CompiledWeights
from mazelab.maze import Maze
from mazelab.model import PARTICLE_DTYPE, ROBOT_SPEED, headings_from_uniforms, move
from mazelab.registry import filter_entry
from mazelab.regularisation import GaussianKernel, mixture_kernel
from mazelab.resampling import systematic_resample
from mazelab.robot import Robot
from mazelab.simulation import simulate
from mazelab.weights import Weights, weighted_covariance

F32 = PARTICLE_DTYPE


@pytest.fixture(scope="module")
def ten():
    return Maze.from_file("maze_10x10")


def cloud_points(world: Maze, count: int, rng: np.random.Generator) -> np.ndarray:
    """float32 points (count, 2) order F: most in the free area, some in walls, some off the map and
    some far beyond the lookup table (the brute-force path)."""
    points = world.random_free_places(count, rng)
    points[: count // 5] = rng.uniform(-0.5, world.width + 0.5, (count // 5, 2))  # walls, just off the map
    points[-10:] = rng.uniform(-40, 40 + world.width, (10, 2))  # beyond the table's margin
    return np.asfortranarray(points, dtype=F32)


@pytest.mark.parametrize("maze", ["ten", "large"])
def test_the_likelihood_is_the_numpy_paths_to_the_bit(maze, ten):
    world = ten if maze == "ten" else large_maze(40)
    rng = np.random.default_rng(1)
    points = cloud_points(world, 3 * 4000, rng)
    z = np.array([0.3, 1.7, 4.0])
    x = points.reshape(3, 4000, 2)  # the particles' layout: (R, N, 2) over (R*N, 2) order F
    compiled = CompiledKernels(world).log_likelihood(z, x, world, 0.4, 0.5)
    reference = NUMPY_KERNELS.log_likelihood(z, x, world, 0.4, 0.5)
    assert compiled.dtype == reference.dtype == F32 and compiled.shape == (3, 4000)
    np.testing.assert_array_equal(compiled, reference)
    one = CompiledKernels(world).log_likelihood(z[1:2], x[1:2], world, 0.4, 0.5)
    np.testing.assert_array_equal(one, NUMPY_KERNELS.log_likelihood(z[1:2], x[1:2], world, 0.4, 0.5))


def splitmix(keys: np.ndarray, count: int) -> np.ndarray:
    """Numbers 0..count-1 of each key's stream (mazelab.kernels.vector_math.random_bits), uint64 (R, count):
    SplitMix64 in numpy's wrapping uint64 arithmetic."""
    z = keys[:, None] + (np.arange(count, dtype=np.uint64) + np.uint64(1)) * np.uint64(0x9E3779B97F4A7C15)
    z = (z ^ (z >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
    z = (z ^ (z >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
    return z ^ (z >> np.uint64(31))


@pytest.mark.parametrize("angle", [0.3, -2.0, 40.0, 1e4])
def test_the_move_draws_its_stream_and_is_the_models_equation_to_a_rounding(angle, ten):
    """The move's uniforms are numbers 0..M-1 of the stream of a key the run's Generator draws, its
    headings numpy's float32 operations on them to the bit, its points numpy's equation (1) of those
    headings to a rounding (its own cos and sin)."""
    rng = np.random.default_rng(2)
    points = cloud_points(ten, 2 * 3000, rng).reshape(2, 3000, 2)
    ancestors = np.sort(rng.integers(0, 3000, (2, 3000)), axis=1)
    angles = np.array([angle, angle + 3.0], dtype=F32)
    delta = 2 * math.pi  # the widest compass error the lab takes
    for gather in (None, ancestors):
        rngs = [np.random.default_rng(7), np.random.default_rng(8)]
        compiled, headings = CompiledKernels(ten).move(points, gather, rngs, angles, delta, ROBOT_SPEED)
        keys = np.array([np.random.default_rng(s).bit_generator.random_raw() for s in (7, 8)], dtype=np.uint64)
        uniforms = (splitmix(keys, 3000) >> np.uint64(40)).astype(F32) * F32(2**-24)
        np.testing.assert_array_equal(headings, headings_from_uniforms(uniforms, angles[:, None], delta))
        start = points if gather is None else np.take_along_axis(points, gather[..., None], axis=1)
        reference = move(start.reshape(-1, 2), headings.reshape(-1), ROBOT_SPEED).reshape(2, 3000, 2)
        # cos and sin two ulps apart at most (numpy's within 1.5 of the exact value, the kernel's within
        # 0.502), the steps L cos th three ulps of L (with their roundings), the sums one more rounding
        steps_apart = 3 * np.spacing(F32(ROBOT_SPEED))
        assert (np.abs(compiled - reference) <= np.spacing(np.abs(reference)) + steps_apart).all()
        assert compiled.shape == (2, 3000, 2) and compiled.dtype == F32
        # and it is the model's step: length L along the heading, exact to float32 rounding at any angle
        step = np.stack([np.cos(headings.astype(float)), np.sin(headings.astype(float))], axis=-1) * ROBOT_SPEED
        assert np.abs(compiled - start.astype(float) - step).max() < 4e-6
    _, lost_headings = CompiledKernels(ten).move(points, None, [None, rngs[0]], angles, delta, ROBOT_SPEED)
    assert (lost_headings[0] == angles[0]).all()  # a run that draws nothing moves along th0 (u = 1/2)


def test_the_moves_uniforms_are_uniform_and_independent_across_particles_runs_and_steps(ten):
    """A Kolmogorov-Smirnov test of 200,000 uniforms (5% level: 1.36 / sqrt(n)); neighbouring particles,
    runs and steps uncorrelated (|r| < 4 / sqrt(n): a 4 sigma bound for independent pairs)."""
    count = 100_000
    rngs = [np.random.default_rng(11), np.random.default_rng(12)]
    kernels = CompiledKernels(ten)
    points = np.zeros((2, count, 2), F32)
    _, first = kernels.move(points, None, rngs, np.zeros(2, F32), 1.0, ROBOT_SPEED)  # heading = u - 1/2
    _, second = kernels.move(points, None, rngs, np.zeros(2, F32), 1.0, ROBOT_SPEED)  # the next step's
    u = np.sort(first.reshape(-1).astype(float) + 0.5)
    ks = np.abs(u - np.arange(1, len(u) + 1) / len(u)).max()
    assert ks < 1.36 / math.sqrt(len(u)) and u[0] >= 0 and u[-1] < 1
    for a, b in ((first[0, :-1], first[0, 1:]), (first[0], first[1]), (first[0], second[0])):
        assert abs(np.corrcoef(a, b)[0, 1]) < 4 / math.sqrt(len(a))


def test_the_moves_cos_and_sin_are_within_half_an_ulp_and_a_little_over_the_models_angles(ten):
    rng = np.random.default_rng(12)
    widest = MAX_ANGLE + math.pi  # any compass angle the lab takes, plus half the widest Delta
    quarter_turns = np.arange(-math.floor(widest / (math.pi / 2)), math.floor(widest / (math.pi / 2)) + 1)
    nearest = (quarter_turns * (math.pi / 2)).astype(F32)  # the float32 angles nearest the zeros of cos and sin
    steps = np.arange(-3, 4)[:, None]
    angles = np.concatenate(
        [
            rng.uniform(-widest, widest, 400_000),
            rng.uniform(-4, 4, 100_000),
            np.geomspace(1e-30, 1, 1000),  # tiny angles: sin x is x
            (nearest + steps * np.spacing(nearest)).ravel(),  # and their neighbours
        ]
    ).astype(F32)
    moved, headings = CompiledKernels(ten).move(  # from the origin, a step of 1 along each angle (Delta 0)
        np.zeros((len(angles), 1, 2), F32), None, [None] * len(angles), angles, 0.0, 1.0
    )
    moved, headings = moved[:, 0], headings[:, 0]
    np.testing.assert_array_equal(headings, angles)
    exact = np.column_stack([np.cos(angles.astype(float)), np.sin(angles.astype(float))])
    error_in_ulps = np.abs(moved - exact) / np.spacing(np.abs(exact).astype(F32))
    # half an ulp from rounding to float32, plus the float64 polynomials' error: below 2^-33.6 of the
    # value (cos, and sin's 2^-37.5), 2^-33.6 / 2^-24 = 0.0013 ulp; the reduction's is below 1e-20
    assert error_in_ulps.max() <= 0.5 + 0.0013


def blocked_cumulative(W: np.ndarray) -> np.ndarray:
    """The cumulative weights the compiled resampler uses (mazelab.kernels.weights): in blocks of
    CHUNK, b_k (each block's sequential float64 total, added in order) plus the block's running sum."""
    blocks = [np.cumsum(W[i : i + CHUNK], dtype=float) for i in range(0, len(W), CHUNK)]
    bases = np.cumsum([0.0] + [block[-1] for block in blocks[:-1]])
    return np.concatenate([base + block for base, block in zip(bases, blocks, strict=True)])


@pytest.mark.parametrize("size", [1000, 3 * CHUNK + 123])  # one block, several
def test_systematic_resampling_gives_the_textbook_ancestors_for_the_same_cumulative_weights(size, ten):
    """The counting form in blocks (compiled) and the textbook inverse CDF (mazelab.resampling, numpy's)
    give the same ancestors for the same cumulative weights and offset, on one thread and on two: the
    textbook's own weights within one block, the blocks' cumulative weights beyond (exact for weights
    whose sums round nowhere). A point u_m on a cumulative boundary goes to the next particle in both
    (searchsorted's side "right", the count's ceil)."""
    rng = np.random.default_rng(3)
    weights = rng.random((6, size)) ** 8
    weights[1, ::3] = 0.0  # particles without weight are never drawn
    weights[3] = 0.0
    weights[3, 17] = 1.0  # one particle with all the weight
    weights[4] = 1.0  # equal weights: the points fall near the boundaries
    weights[5, ::2] = 0.0
    weights /= weights.sum(axis=1, keepdims=True)
    one, two = CompiledKernels(ten, threads=1), CompiledKernels(ten, threads=2)
    for row in weights:
        cumulative = blocked_cumulative(row)
        cumulative[-1] = 1.0  # the last particle takes the rest, as the textbook's
        for seed in range(10):
            u = np.random.default_rng(seed).random()
            textbook = np.searchsorted(cumulative, (u + np.arange(size)) / size, side="right")
            counted = one.schemes["systematic"](row, np.random.default_rng(seed))
            np.testing.assert_array_equal(counted, textbook)
            np.testing.assert_array_equal(two.systematic(row, np.random.default_rng(seed)), counted)
    dyadic = rng.integers(0, 64, size).astype(float)  # sums of multiples of 2^-k round nowhere: the textbook's
    dyadic /= 2.0 ** math.ceil(math.log2(dyadic.sum()))
    dyadic[-1] += 1 - dyadic.sum()
    for seed in range(10):
        counted = two.systematic(dyadic, np.random.default_rng(seed))
        np.testing.assert_array_equal(counted, systematic_resample(dyadic, np.random.default_rng(seed)))
    assert not np.isin(one.systematic(weights[1], rng), np.arange(0, size, 3)).any()
    assert (one.systematic(weights[3], rng) == 17).all()
    alone = [one.systematic(row, np.random.default_rng(seed)) for seed, row in enumerate(weights)]
    for kernels in (one, two):  # the rows in one call, a Generator each: each row's ancestors as alone
        rngs = [np.random.default_rng(seed) for seed in range(len(weights))]
        np.testing.assert_array_equal(kernels.systematic(weights, rngs), alone)
    row = np.full(8, 1 / 8)  # a point exactly on a boundary: u = 0 puts u_m = m / 8 on c_m
    offset = type("Zero", (), {"random": lambda self: 0.0})()
    np.testing.assert_array_equal(one.systematic(row, offset), systematic_resample(row, offset))
    np.testing.assert_array_equal(one.systematic(row, offset), np.arange(8))


def test_the_normalisation_and_its_reads_agree_with_numpy_to_rounding(ten):
    rng = np.random.default_rng(4)
    x = cloud_points(ten, 3 * 2000, rng).reshape(3, 2000, 2)
    log_w = (-0.5 * rng.standard_normal((3, 2000)) ** 2 * 30).astype(F32)
    log_w[2] = -np.inf  # nothing explains z: no weights, the filter restarts the run
    compiled = CompiledWeights.from_log(log_w, x)
    with np.errstate(invalid="ignore"):  # numpy's -inf - -inf for the run nothing explains
        reference = Weights.from_log(log_w)
        log_weights = compiled.lw
    np.testing.assert_allclose(compiled.log_total[:2], reference.log_total[:2], rtol=1e-6)  # numpy's: float32 sums
    np.testing.assert_allclose(log_weights[:2], reference.lw[:2], rtol=0, atol=1e-5)
    assert compiled.log_total[2] == -np.inf and compiled.lost.tolist() == [False, False, True]
    W = reference.W[:2]
    # float32 exponentials: 1 ulp (1.2e-7) and the difference log w - top rounded to float32 (half an ulp
    # of it, 4.8e-7 of the value while it is above -8, past that the weight is below 3.4e-4 of the top's:
    # 1e-5 relative covers both); 0 below exp(-87) = 1.6e-38 of the heaviest weight (W <= 1)
    assert compiled.W.dtype == F32
    np.testing.assert_allclose(compiled.W[:2], W, rtol=1e-5, atol=1.7e-38)
    np.testing.assert_allclose(compiled.ess[:2], reference.ess[:2], rtol=1e-5)
    kernels = CompiledKernels(ten)
    mean = NUMPY_KERNELS.weighted_mean(reference, x)[:2]
    np.testing.assert_allclose(kernels.weighted_mean(compiled, x)[:2], mean, rtol=0, atol=1e-5)
    share = NUMPY_KERNELS.mass_within(reference, x, kernels.weighted_mean(compiled, x), 1.0)[:2]
    np.testing.assert_allclose(
        kernels.mass_within(compiled, x, kernels.weighted_mean(compiled, x), 1.0)[:2], share, rtol=1e-5
    )
    assert 0 < share[0] < 1


def test_the_reweighting_agrees_with_numpy_to_rounding_and_its_covariance_is_positive(ten):
    rng = np.random.default_rng(5)
    previous = CompiledWeights.from_log(np.log(rng.dirichlet(np.ones(1500), size=2)).astype(F32))
    log_b = (-3 * rng.random((2, 1500))).astype(F32)
    compiled, reference = previous.add(log_b), Weights(previous.lw).add(log_b)
    # float32 log w (log W + log b rounded: 2e-6 of values near -15) and exponentials (1 ulp)
    np.testing.assert_allclose(compiled.W, reference.W, rtol=1e-5)
    np.testing.assert_allclose(compiled.log_total, reference.log_total, rtol=0, atol=2e-6)
    # the RPF's covariance of the compiled backend's float32 W (one function on both backends): positive
    covariance = weighted_covariance(compiled.W, cloud_points(ten, 2 * 1500, rng))
    assert covariance.shape == (2, 2, 2) and (np.linalg.eigvalsh(covariance) > 0).all()


def test_the_float32_exponential_is_within_one_ulp_of_exp_and_0_below_float32s_normal_range():
    from numba import njit

    from mazelab.kernels.vector_math import exp32

    @njit
    def exponentials(x, out):  # pragma: no cover - compiled
        for i in range(len(x)):
            out[i] = exp32(x[i])

    x = np.linspace(-87.0, 0.0, 1_000_001).astype(F32)  # the normalisations' range: log w - top <= 0
    out = np.empty_like(x)
    exponentials(x, out)
    exact = np.exp(x.astype(float))
    assert (np.abs(out - exact) <= np.spacing(exact.astype(F32))).all()
    edges = np.array([-np.inf, -100.0, -87.5, np.nan, 0.0], dtype=F32)
    exponentials(edges, out[:5])
    np.testing.assert_array_equal(out[:5], [0.0, 0.0, 0.0, np.nan, 1.0])


@pytest.mark.parametrize("dtype", [F32, np.float64])  # SIR's and the APF's log weights, the RPF's
def test_the_normalisation_of_runs_together_is_each_runs_alone_to_the_bit(dtype, ten):
    from mazelab.kernels.weights import LANES

    rng = np.random.default_rng(7)
    size = 2 * CHUNK + LANES + 5  # three chunks, the last with a part lane's worth
    x = cloud_points(ten, 3 * size, rng).reshape(3, size, 2)
    log_w = (-0.5 * rng.standard_normal((3, size)) ** 2 * 30).astype(dtype)
    log_b = (-3 * rng.random((3, size))).astype(F32)
    together = CompiledWeights.from_log(log_w, x)
    added = together.add(log_b, x)
    for r in range(3):
        alone = CompiledWeights.from_log(log_w[r : r + 1].copy(), x[r : r + 1].copy())
        for name in ("log_total", "W", "ess"):
            np.testing.assert_array_equal(getattr(alone, name), getattr(together, name)[r : r + 1])
        np.testing.assert_array_equal(alone.mean, together.mean[r : r + 1])
        np.testing.assert_array_equal(alone.add(log_b[r : r + 1], x[r : r + 1]).W, added.W[r : r + 1])


def test_the_rpf_jitter_draws_normals_and_spreads_by_h_d(ten):
    rng = np.random.default_rng(6)
    x = cloud_points(ten, 3 * 20_000, rng).reshape(3, 20_000, 2)
    A = rng.integers(0, 20_000, (3, 20_000))
    due = np.array([True, False, True])
    scales = [np.array([[0.3, 0.0], [0.1, 0.2]]), np.array([[0.05, 0.0], [-0.02, 0.01]])]
    kernels = [GaussianKernel(s) for s in scales]
    moved = CompiledKernels(ten).jitter(x, A, due, [np.random.default_rng(s) for s in range(3)], kernels)
    again = CompiledKernels(ten, threads=2).jitter(x, A, due, [np.random.default_rng(s) for s in range(3)], kernels)
    np.testing.assert_array_equal(moved, again)
    np.testing.assert_array_equal(moved[1], x[1])  # a run not due: its particles as they were
    for r, scale in zip((0, 2), scales, strict=True):  # run r's jitter: N(0, (h D_r)(h D_r)^T)
        jitter = (moved[r] - x[r][A[r]]).astype(float)
        eps = np.linalg.solve(scale, jitter.T)  # the normals drawn: N(0, I_2)
        # 20,000 normal pairs: the mean's standard error 1/sqrt(20,000) = 0.007, the variances' 0.01
        np.testing.assert_allclose(eps.mean(axis=1), 0, atol=5 * 0.007)
        np.testing.assert_allclose(np.cov(eps), np.eye(2), atol=5 * 0.01)
        ks = max(np.abs(np.sort(NormalCDF(e)) - np.arange(1, len(e) + 1) / len(e)).max() for e in eps)
        assert ks < 1.63 / math.sqrt(eps.shape[1])  # Kolmogorov-Smirnov at 1%, each coordinate
    rngs = [np.random.default_rng(s) for s in range(3)]
    multimodal = CompiledKernels(ten).jitter(x, A, due, rngs, [mixture_kernel] * 2)
    expected = NUMPY_KERNELS.jitter(x, A, due, [np.random.default_rng(s) for s in range(3)], [mixture_kernel] * 2)
    np.testing.assert_array_equal(multimodal, expected)


NormalCDF = np.vectorize(lambda v: 0.5 * (1 + math.erf(v / math.sqrt(2))))


def run_once(world: Maze, name: str, backend: str, seed: int = 11, particles: int = 500, steps: int = 40, **options):
    robot = Robot(0.3, 0.5, world.random_free_place(np.random.default_rng(3)))
    with use_backend(backend):
        return simulate(robot, world, 0.3, 0.5, particles, steps, filtering_algorithm=name, seed=seed, **options)


@pytest.mark.parametrize("name", ["sir", "apf", "rpf"])
def test_a_seed_repeats_a_run_on_the_compiled_backend_which_says_so(name, paper_world):
    first, again = run_once(paper_world, name, "compiled"), run_once(paper_world, name, "compiled")
    assert first.extras["backend"] == "compiled"
    np.testing.assert_array_equal(first.estimates, again.estimates)
    np.testing.assert_array_equal(first.ess, again.ess)
    np.testing.assert_array_equal(first.confident, again.confident)
    numpy_run = run_once(paper_world, name, "numpy")
    assert numpy_run.extras["backend"] == "numpy"
    assert not np.array_equal(first.estimates, numpy_run.estimates)  # the backends differ in rounding ...
    assert np.abs(first.errors[-10:] - numpy_run.errors[-10:]).max() < 0.5  # ... not in where they find it


@pytest.mark.parametrize("name", ["sir", "apf", "rpf"])
def test_reading_the_log_weights_does_not_change_a_compiled_run(name, paper_world):
    walk_rng = np.random.default_rng(5)
    robot = Robot(0.3, 0.5, paper_world.random_free_place(walk_rng), rng=walk_rng)
    walk = [robot.step(paper_world) for _ in range(25)]
    with use_backend("compiled"):
        read, unread = (
            filter_entry(name).filter_class(paper_world, 0.3, 0.5, paper_world.random_free_places(500, rng), rng)
            for rng in (np.random.default_rng(6), np.random.default_rng(6))
        )
    for compass_angle, z in walk:
        read.step(compass_angle, z)
        unread.step(compass_angle, z)
        read.log_weights  # noqa: B018 (read every step)
        np.testing.assert_array_equal(read.positions, unread.positions)
        np.testing.assert_array_equal(read.weights, unread.weights)
    np.testing.assert_array_equal(read.log_weights, unread.log_weights)  # derived when read, kept or not


@pytest.mark.parametrize("name", ["sir", "apf", "rpf"])
def test_batched_runs_equal_single_runs_bit_for_bit_on_the_compiled_backend(name, paper_world):
    seeds, steps = (21, 22, 23), 30
    walks = []
    for seed in seeds:
        rng = np.random.default_rng(seed)
        robot = Robot(0.3, 0.5, paper_world.random_free_place(rng), rng=rng)
        walks.append([robot.step(paper_world) for _ in range(steps)])
    walks[1][15] = (walks[1][15][0], 50.0)  # nothing explains this z: run 1 restarts from the prior
    particles = np.stack([paper_world.random_free_places(300, np.random.default_rng(s)) for s in seeds])
    cls = filter_entry(name).filter_class
    with use_backend("compiled"):
        batch = cls(paper_world, 0.3, 0.5, particles, [np.random.default_rng(s + 7) for s in seeds])
        singles = [cls(paper_world, 0.3, 0.5, particles[r], np.random.default_rng(s + 7)) for r, s in enumerate(seeds)]
    assert batch.backend == "compiled" and all(single.backend == "compiled" for single in singles)
    step_together_and_alone(batch, singles, walks, steps)
    assert batch.reinitialised_at == [single.reinitialised_at for single in singles] and batch.reinitialised_at[1]


def test_runs_together_equal_single_runs_wherever_their_arrays_lie_in_memory(paper_world):
    seeds = (21, 22, 23)
    walks = []
    for seed in seeds:
        rng = np.random.default_rng(seed)
        robot = Robot(0.3, 0.5, paper_world.random_free_place(rng), rng=rng)
        walks.append([robot.step(paper_world) for _ in range(2)])
    particles = np.stack([paper_world.random_free_places(300, np.random.default_rng(s)) for s in seeds])
    spacers = []  # each trial's arrays land elsewhere: the sums' order must not follow them
    for trial in range(40):
        spacers.append(np.empty(int(np.random.default_rng(trial).integers(1, 3000))))
        for name in ("sir", "apf", "rpf"):
            cls = filter_entry(name).filter_class
            with use_backend("compiled"):
                batch = cls(paper_world, 0.3, 0.5, particles, [np.random.default_rng(s + 7) for s in seeds])
                singles = [
                    cls(paper_world, 0.3, 0.5, particles[r], np.random.default_rng(s + 7)) for r, s in enumerate(seeds)
                ]
            step_together_and_alone(batch, singles, walks, 2)


@pytest.mark.parametrize("name", ["sir", "apf", "rpf"])
def test_arrays_a_caller_keeps_are_never_written_over(name, paper_world):
    rng = np.random.default_rng(8)
    with use_backend("compiled"):
        filt = filter_entry(name).filter_class(paper_world, 0.3, 0.5, paper_world.random_free_places(400, rng), rng)
    walk_rng = np.random.default_rng(9)
    robot = Robot(0.3, 0.5, paper_world.random_free_place(walk_rng), rng=walk_rng)
    kept = []
    for _ in range(12):
        filt.step(*robot.step(paper_world))
        arrays = (filt.positions, filt.headings, filt.weights, filt.log_weights)
        kept.append((arrays, [a.copy() for a in arrays]))
    for arrays, copies in kept:  # a student's list of every step's particles keeps every step's particles
        for array, copy in zip(arrays, copies, strict=True):
            np.testing.assert_array_equal(array, copy)
    assert len({id(arrays[0]) for arrays, _ in kept}) == len(kept)


def test_a_second_process_loads_the_kernels_from_the_cache(tmp_path):
    script = (
        "import numpy as np\n"
        "from mazelab.backend import use_backend\n"
        "from mazelab.simulation import simulate\n"
        "from mazelab.maze import Maze\n"
        "from mazelab.robot import Robot\n"
        "from mazelab.kernels import model, weights\n"
        "w = Maze.from_file('paper_5x5')\n"
        "with use_backend('compiled'):\n"
        "    for name in ('sir', 'apf', 'rpf'):\n"
        "        start = w.random_free_place(np.random.default_rng(3))\n"
        "        simulate(Robot(0.3, 0.5, start), w, 0.3, 0.5, 200, 5, filtering_algorithm=name, seed=1)\n"
        "kernels = [k.serial for k in (model.move, model.log_likelihood, model.jitter, weights.systematic,\n"
        "           weights.normalise)]\n"
        "import sys\n"
        "print(sum(sum(k.stats.cache_misses.values()) for k in kernels),"
        " sum(sum(k.stats.cache_hits.values()) for k in kernels),"
        " sum(name in sys.modules for name in ('numba.np.arrayobj', 'numba.np.arraymath', 'numba.np.npyimpl')))\n"
    )
    for _ in range(2):  # the first may compile (a fresh clone); the second must not
        done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=600, check=True)
    misses, hits, array_modules = map(int, done.stdout.split())
    assert misses == 0 and hits >= 5
    assert array_modules == 0  # loading a kernel imports none of numba's array modules (some 40 ms a process)


def mean_and_interval(rows, name):
    row = next(r for r in rows if r["filter"] == name)
    return row["mean_distance_to_exact"], row["interval"]


def test_the_backends_agree_on_the_distance_to_the_exact_posterior(paper_world):
    filters = accuracy_filters(["sir", "apf", "rpf"])
    plan = accuracy_plan([MazeChoice.from_maze("paper", paper_world)], filters, sigma=0.3, delta=0.5, particles=400,
                         runs=8, steps=60, seed=5)  # fmt: skip
    tables = {}
    for backend in ("numpy", "compiled"):
        records = run_study(plan.tasks, 1, backend=backend).records
        tables[backend] = accuracy_summary(accuracy_records(records, filters))
    for label in [
        label for label, name, _ in filters if filter_entry(name).filter_class is not filter_entry("grid").filter_class
    ]:
        mean_n, (low_n, high_n) = mean_and_interval(tables["numpy"], label)
        mean_c, (low_c, high_c) = mean_and_interval(tables["compiled"], label)
        # each backend's mean distance lies inside the other's 95% bootstrap interval
        assert low_n <= mean_c <= high_n and low_c <= mean_n <= high_c, (label, tables)


def fisher_exact(a: int, b: int, n: int) -> float:
    """The two-sided p-value of Fisher's exact test that a of n and b of n come from one proportion: the
    chance, given a + b successes in 2n, of tables no likelier than the one seen."""
    total = a + b
    chance = [math.comb(n, k) * math.comb(n, total - k) / math.comb(2 * n, total) for k in range(total + 1)]
    return sum(p for p in chance if p <= chance[a] * (1 + 1e-9))


def test_the_backends_agree_on_a_studys_convergence_shares(paper_world):
    """The two backends' convergence shares are one proportion by Fisher's exact test at 5% (each share
    inside the other's Wilson interval, the check before, refused 19 of 20 against 20 of 20)."""
    settings = study_settings([MazeChoice.from_maze("paper", paper_world)], [0.3, 0.6], [0.5], [300])
    filters = ["SIRParticleFilter", "AuxiliaryParticleFilter", "RegularizedParticleFilter"]
    shares = {}
    for backend in ("numpy", "compiled"):
        with use_backend(backend):
            records = run_study(study_tasks(settings, filters, 10, 60, 2024), 1).records
        shares[backend] = {
            name: sum(r.converged_at is not None for r in records if r.filter == name) for name in filters
        }
    for name in filters:
        assert fisher_exact(shares["numpy"][name], shares["compiled"][name], 2 * 10) > 0.05, (name, shares)
    assert fisher_exact(19, 20, 20) == 1.0 and fisher_exact(10, 20, 20) < 0.001  # the test tells them apart


CACHE_RUN = (
    "import sys\n"
    "from mazelab.cli.app import main\n"
    "code = main(['run', '--backend', 'compiled', '--maze', 'paper_5x5', '--steps', '3', '--particles', '200',"
    " '--filter', 'sir', '--no-viz', '--quiet'])\n"
    "from mazelab.kernels import model\n"
    "stats = model.move.serial.stats\n"
    "print(code, sum(stats.cache_misses.values()), sum(stats.cache_hits.values()))\n"
)


def run_with_cache(folder, prefix: list[str] | None = None, before: str = "") -> subprocess.CompletedProcess:
    """CACHE_RUN in a process of its own with NUMBA_CACHE_DIR=folder (after `prefix`, a command that
    runs the rest; `before`, Python run first)."""
    env = {**os.environ, "NUMBA_CACHE_DIR": str(folder)}
    command = [*(prefix or []), sys.executable, "-c", before + CACHE_RUN]
    return subprocess.run(command, capture_output=True, text=True, env=env, cwd=ROOT, timeout=900, check=False)


def test_a_damaged_cache_is_compiled_over(tmp_path):
    first = run_with_cache(tmp_path)
    assert first.returncode == 0, first.stderr
    files = [f for f in tmp_path.rglob("*") if f.suffix in (".nbi", ".nbc")]
    assert files
    for file in files:  # a cut-off copy: each file's first bytes, then garbage
        file.write_bytes(file.read_bytes()[:7] + b"garbage")
    damaged = run_with_cache(tmp_path)
    assert damaged.returncode == 0 and "Traceback" not in damaged.stderr, damaged.stderr
    code, misses, hits = damaged.stdout.split()[-3:]
    assert (code, int(hits)) == ("0", 0) and int(misses) >= 1  # compiled again
    mended = run_with_cache(tmp_path)
    code, misses, hits = mended.stdout.split()[-3:]
    assert (code, misses) == ("0", "0") and int(hits) >= 1  # and saved over the damaged files


def test_an_edit_to_any_kernel_source_compiles_the_kernels_again(tmp_path):
    """numba's own stamp is the kernel's file; model.move inlines vector_math's cos and sin: a digest of
    every kernel source is in the stamp too (here a changed digest stands for an edit of vector_math)."""
    assert run_with_cache(tmp_path).returncode == 0
    edited = run_with_cache(tmp_path, [], "import mazelab.kernels as k\nk._SOURCES = 'edited' + k._SOURCES\n")
    code, misses, hits = edited.stdout.split()[-3:]
    assert (code, int(hits)) == ("0", 0) and int(misses) >= 1, edited.stderr  # compiled again, not loaded
    again = run_with_cache(tmp_path, [], "import mazelab.kernels as k\nk._SOURCES = 'edited' + k._SOURCES\n")
    code, misses, hits = again.stdout.split()[-3:]
    assert (code, misses) == ("0", "0") and int(hits) >= 1  # and kept for the edited sources


def test_the_sources_digest_changes_with_any_kernel_file(tmp_path):
    for name in ("model.py", "vector_math.py"):
        (tmp_path / name).write_text("x = 1\n")
    before = sources_digest(tmp_path)
    (tmp_path / "vector_math.py").write_text("x = 2\n")
    assert sources_digest(tmp_path) != before


def test_a_full_cache_folder_is_one_line_naming_it_and_the_run_goes_on(tmp_path):
    """The full disk is a 16 kB tmpfs mounted over the cache folder in a mount namespace of the test's own
    (unshare); skipped where no namespace can be made."""
    mount = f'mount -t tmpfs -o size=16k tmpfs {tmp_path} && exec "$@"'
    prefix = ["unshare", "--map-root-user", "--mount", "sh", "-c", mount, "sh"]
    probe = shutil.which("unshare") and subprocess.run([*prefix, "true"], capture_output=True, check=False)
    if not probe or probe.returncode != 0:
        pytest.skip("no mount namespace here (unshare) to mount a tiny tmpfs in")
    done = run_with_cache(tmp_path, prefix)
    assert done.returncode == 0 and done.stdout.split()[-3] == "0", done.stderr
    problems = [line for line in done.stderr.splitlines() if "cannot be saved" in line]
    assert len(problems) == 1, done.stderr
    assert problems[0].startswith(f"warning: mazelab's compiled kernels cannot be saved in {tmp_path}/")
    assert problems[0].endswith(
        " (No space left on device): they are compiled again in each process; free space there, or set "
        "NUMBA_CACHE_DIR to a writable folder"
    )
    assert "Traceback" not in done.stderr


needs_two_threads = pytest.mark.skipif((os.cpu_count() or 1) < 2, reason="one core here")


@needs_two_threads
def test_every_kernel_gives_the_same_values_on_one_thread_and_on_two(ten):
    """Each kernel's chunks fix its draws and its sums' order: its two compilations (in order, on
    numba's threads) agree to the bit, over runs of several chunks with a last one of its own size."""
    rng = np.random.default_rng(6)
    count = THREADED_FROM + 12_345
    x = cloud_points(ten, 2 * count, rng).reshape(2, count, 2)
    z, A = np.array([1.3, 2.1]), np.sort(rng.integers(0, count, (2, count)), axis=1)
    one, two = CompiledKernels(ten, threads=1), CompiledKernels(ten, threads=2)
    for kernels in (one, two):
        kernels.log_g = kernels.log_likelihood(z, x, ten, 0.3, 0.5)
        kernels.moved = kernels.move(x, A, [np.random.default_rng(s) for s in (1, 2)], z.astype(F32), 0.5, 0.2)
        kernels.W = kernels.Weights.uniform(2, count).add(kernels.log_g, x)
        kernels.ancestors = kernels.systematic(kernels.W.W[1], np.random.default_rng(3))
        kernels.share = kernels.mass_within(kernels.W, x, np.array([[2.0, 3.0], [4.0, 5.0]]), 1.5)
        kernels.jittered = kernels.jitter(x, A, np.array([True, True]), [np.random.default_rng(4)] * 2,
                                          [GaussianKernel(np.eye(2) * 0.1)] * 2)  # fmt: skip
    for name in ("log_g", "ancestors", "share", "jittered"):
        np.testing.assert_array_equal(getattr(one, name), getattr(two, name), err_msg=name)
    for a, b in zip(one.moved, two.moved, strict=True):
        np.testing.assert_array_equal(a, b)
    for name in ("W", "log_total", "ess", "lw"):
        np.testing.assert_array_equal(getattr(one.W, name), getattr(two.W, name), err_msg=name)
    np.testing.assert_array_equal(one.W.reads[1], two.W.reads[1])  # the log totals, means, ESS and confidence shares


def threaded_run(world: Maze, name: str, threads: int, monkeypatch) -> object:
    monkeypatch.setenv(THREADS_VARIABLE, str(threads))
    return run_once(world, name, "compiled", seed=4, particles=THREADED_FROM + 1000, steps=8)


@needs_two_threads
@pytest.mark.parametrize("name", ["sir", "apf", "rpf"])
def test_a_seed_gives_the_same_run_on_one_thread_and_on_two(name, paper_world, monkeypatch):
    one, two = (threaded_run(paper_world, name, threads, monkeypatch) for threads in (1, 2))
    for field in ("estimates", "ess", "confident", "log_evidence"):
        np.testing.assert_array_equal(getattr(one, field), getattr(two, field), err_msg=field)


@needs_two_threads
def test_a_kernel_called_while_the_threads_are_busy_runs_in_order_with_the_same_values(ten):
    """numba's workqueue takes one launch at a time: a second thread's large call runs on its own thread
    (the same values) instead of crashing the process."""
    from mazelab.kernels import _LAUNCH

    rng = np.random.default_rng(6)
    x = cloud_points(ten, THREADED_FROM, rng).reshape(1, THREADED_FROM, 2)
    kernels = CompiledKernels(ten, threads=2)
    threaded = kernels.log_likelihood(np.array([1.0]), x, ten, 0.3, 0.5)
    with _LAUNCH:  # the threads are taken
        np.testing.assert_array_equal(kernels.log_likelihood(np.array([1.0]), x, ten, 0.3, 0.5), threaded)
    done = []
    workers = [
        __import__("threading").Thread(
            target=lambda: done.append(kernels.log_likelihood(np.array([1.0]), x, ten, 0.3, 0.5))
        )
        for _ in range(4)
    ]
    for worker in workers:
        worker.start()
    for worker in workers:
        worker.join()
    assert len(done) == 4 and all(np.array_equal(d, threaded) for d in done)


def test_the_threads_come_from_tbb_where_the_fast_extra_installed_it():
    """The fast extra installs Intel's TBB on Linux x86-64, whose library the loader does not find by
    itself: the kernels must load it (numba's workqueue, which wakes its threads for every call, would
    run instead and make two threads slower than one below some 300,000 particles)."""
    import importlib.metadata

    try:
        importlib.metadata.version("tbb")
    except importlib.metadata.PackageNotFoundError:
        pytest.skip("no tbb package here (only Linux x86-64 installs it)")
    from mazelab.kernels import threading_layer

    assert threading_layer() == "tbb"


@needs_two_threads
def test_the_threads_work_in_a_process_forked_after_they_ran():
    """The study's worker processes are forked: numba's threads must start again in them (TBB's and
    the workqueue layer do; GNU OpenMP's would abort the child)."""
    script = (
        "import multiprocessing, numpy as np\n"
        "from mazelab.kernels import THREADED_FROM\n"
        "from mazelab.kernels.compiled import CompiledKernels\n"
        "from mazelab.maze import Maze\n"
        "world = Maze.from_file('paper_5x5')\n"
        "x = world.random_free_places(THREADED_FROM, np.random.default_rng(1)).astype(np.float32)[None]\n"
        "def run(_=None):\n"
        "    return CompiledKernels(world, threads=2).log_likelihood(np.array([1.0]), x, world, 0.3, 0.5).sum()\n"
        "here = run()\n"
        "with multiprocessing.get_context('fork').Pool(1) as pool:\n"
        "    print(pool.apply(run) == here, __import__('numba').threading_layer())\n"
    )
    import numba

    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=600, check=False)
    assert done.returncode == 0 and done.stdout.split() == ["True", numba.config.THREADING_LAYER], done.stderr
