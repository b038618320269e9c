"""The grid filter's step in buffers made once (mazelab.grid_filter.GridWorkspace): the same numbers,
bit for bit, as numpy's fresh arrays, and no fresh pages per step inside a real Dask worker, whose
nanny sets MALLOC_TRIM_THRESHOLD_ (which fixes glibc's mmap threshold at 128 KiB: every array of a
megabyte would otherwise be new pages from the kernel on every step)."""

from __future__ import annotations

import platform
import sys

import numpy as np
import pytest
from conftest import PAPER_MAZE

from mazelab.grid_filter import GridBayesFilter, GridWorkspace, arc_kernel, arc_kernel_shape
from mazelab.maze import Maze
from mazelab.weights import mass_within, weighted_mean


def numpy_convolution(image, kernel, shape):
    """The linear convolution in numpy's fresh arrays (rfft2, irfft2), cropped to the image's shape."""
    full = np.fft.irfft2(np.fft.rfft2(image, shape) * np.fft.rfft2(kernel, shape), shape)
    (ky, kx), (ny, nx) = kernel.shape, image.shape
    return full[ky // 2 : ky // 2 + ny, kx // 2 : kx // 2 + nx]


@pytest.mark.parametrize("shape", [(350, 350), (101, 257), (64, 30)])
def test_the_workspace_convolution_is_numpys_bit_for_bit(shape):
    rng = np.random.default_rng(sum(shape))
    kernel = arc_kernel(0.7, 0.5, 1.0, 0.05)
    work = GridWorkspace(shape, kernel.shape)
    spectrum = work.kernel_spectrum(kernel)
    assert np.array_equal(spectrum, np.fft.rfft2(kernel, work.fft_shape))
    for _ in range(2):  # the buffers reused: the same as fresh arrays again
        image = rng.random(shape)
        expected = numpy_convolution(image, kernel, work.fft_shape)
        assert np.array_equal(work.convolve(image, kernel.shape, spectrum), expected)


def test_the_weights_reads_in_a_workspace_are_their_fresh_arrays_bit_for_bit():
    """The grid filter's mean and confidence, formed in its workspace (out=), are weights' own numbers."""
    rng = np.random.default_rng(3)
    weights = rng.random(5000)
    weights /= weights.sum()
    points = rng.uniform(-1, 6, (5000, 2))
    work = GridWorkspace((50, 100), arc_kernel_shape(1.0, 0.02))
    centre = weighted_mean(weights, points)
    assert np.array_equal(weighted_mean(weights, points, out=work.cells), centre)
    within = mass_within(weights, points, centre, 1.0, out=(work.cells, work.cells_y, work.within))
    assert within == mass_within(weights, points, centre, 1.0)


def test_a_grid_step_in_buffers_leaves_no_reference_behind():
    """The density after each step is an array of its own (not a buffer the next step overwrites),
    and the posterior is the normalised product of the prediction and the likelihood's weights."""
    grid = GridBayesFilter(Maze(PAPER_MAZE), 0.3, 0.5)
    grid.step(0.3, 1.2)
    first = grid.density
    kept = first.copy()
    grid.step(0.3, 1.1)
    assert np.array_equal(first, kept) and grid.density is not first
    assert grid.density.sum() == pytest.approx(1.0) and (grid.density >= 0).all()
    assert not any(np.shares_memory(grid.density, buffer) for buffer in vars(grid.workspace).values()
                   if isinstance(buffer, np.ndarray))  # fmt: skip


@pytest.mark.skipif(
    not sys.platform.startswith("linux") or platform.libc_ver()[0] != "glibc", reason="glibc's malloc on Linux"
)
def test_the_grid_filter_takes_no_fresh_pages_per_step_in_a_dask_worker():
    """In a real LocalCluster worker (the nanny's MALLOC_TRIM_THRESHOLD_ in its environment), a grid step
    on the paper's maze (350 x 350 cells, 0.98 MB a density) faults in at most two densities' pages:
    the new posterior, and slack. Before the workspace it was about 9 (2259 faults a step)."""
    distributed = pytest.importorskip("distributed")

    def faults_per_step() -> tuple[float, str | None]:
        import os
        import resource

        from mazelab.grid_filter import GridBayesFilter
        from mazelab.maze import Maze

        grid = GridBayesFilter(Maze(PAPER_MAZE), 0.3, 0.5)
        rng = np.random.default_rng(1)
        grid.step(0.0, 1.0)
        before = resource.getrusage(resource.RUSAGE_THREAD).ru_minflt
        for k in range(20):
            grid.step(float(rng.uniform(-3, 3)) if k % 4 == 0 else grid._motion[0], float(rng.uniform(0.2, 2)))
            _ = grid.estimate, grid.is_confident
        faults = (resource.getrusage(resource.RUSAGE_THREAD).ru_minflt - before) / 20
        return faults, os.environ.get("MALLOC_TRIM_THRESHOLD_")

    with (
        distributed.LocalCluster(n_workers=1, threads_per_worker=1, host="127.0.0.1", dashboard_address=None) as c,
        distributed.Client(c) as client,
    ):
        faults, trim = client.submit(faults_per_step, pure=False).result()
    density_pages = 350 * 350 * 8 / 4096
    assert trim is not None  # the nanny's setting, the one that fixes the mmap threshold
    assert faults <= 2 * density_pages
