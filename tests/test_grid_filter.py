"""The exact grid filter's pieces (mazelab.grid_filter): the motion kernel is a density with the arc's
exact mean, the FFT convolution is the direct one, and the prediction moves the belief along the compass.
(Its agreement with the particle filters and its convergence are in test_filters.py.)"""

from __future__ import annotations

import math

import numpy as np
import pytest

from mazelab.grid_filter import GRID_RESOLUTION, GridBayesFilter, GridWorkspace, arc_kernel
from mazelab.model import ROBOT_SPEED, log_likelihood


@pytest.mark.parametrize(("theta", "delta"), [(0.3, 0.5), (2.0, 0.05), (-1.0, 2 * math.pi), (4.0, 0.0)])
def test_arc_kernel_is_a_density_with_the_arcs_exact_mean(theta, delta):
    kernel = arc_kernel(theta, delta, ROBOT_SPEED, GRID_RESOLUTION)
    radius = kernel.shape[0] // 2
    assert kernel.sum() == pytest.approx(1.0)
    offsets = (np.arange(kernel.shape[0]) - radius) * GRID_RESOLUTION
    mean_x, mean_y = kernel.sum(axis=0) @ offsets, kernel.sum(axis=1) @ offsets
    # E[L (cos th, sin th)] for th ~ U(theta - delta/2, theta + delta/2) is L sinc(delta/2) (cos, sin)(theta);
    # the kernel's arc is a midpoint rule of that integral, exact to O((delta/samples)^2).
    shrink = 1.0 if delta == 0 else math.sin(delta / 2) / (delta / 2)
    assert mean_x == pytest.approx(ROBOT_SPEED * shrink * math.cos(theta), abs=1e-3 * ROBOT_SPEED)
    assert mean_y == pytest.approx(ROBOT_SPEED * shrink * math.sin(theta), abs=1e-3 * ROBOT_SPEED)


def test_fft_convolution_equals_direct_convolution(rng):
    image, kernel = rng.random((17, 23)), rng.random((5, 7))
    direct = np.zeros_like(image)
    for dy in range(5):
        for dx in range(7):
            shifted = np.zeros_like(image)
            sy, sx = dy - 2, dx - 3  # kernel cell (dy, dx) moves mass by (sy, sx)
            shifted[max(sy, 0) : 17 + min(sy, 0), max(sx, 0) : 23 + min(sx, 0)] = image[
                max(-sy, 0) : 17 - max(sy, 0), max(-sx, 0) : 23 - max(sx, 0)
            ]
            direct += kernel[dy, dx] * shifted
    work = GridWorkspace(image.shape, kernel.shape)
    convolved = work.convolve(image, kernel.shape, work.kernel_spectrum(kernel))
    np.testing.assert_allclose(convolved, direct, atol=1e-12)


def test_grid_prediction_moves_the_belief_along_the_compass(paper_world):
    grid = GridBayesFilter(paper_world, 0.3, 0.5)
    before = grid.estimate.copy()
    grid.density = grid.predict(grid.density, compass_angle=0.0)
    # mass only leaves through the grid's outer edge, which the prior does not reach in one step
    assert grid.density.sum() == pytest.approx(1.0)
    shift = grid.estimate - before
    assert shift[0] == pytest.approx(ROBOT_SPEED * math.sin(0.25) / 0.25, rel=1e-3)
    assert shift[1] == pytest.approx(0.0, abs=1e-9)


def test_the_grid_filters_log_likelihood_is_equation_3_less_the_gaussians_constant(paper_world):
    """GridBayesFilter.log_likelihood (the update's and the smoother's): the model's log p(z | x) on the
    cell centres, outside penalty included, less -log(sigma sqrt(2 pi)); written into `out` when given."""
    grid = GridBayesFilter(paper_world, 0.3, 0.5, resolution=0.25)
    constant = math.log(0.3 * math.sqrt(2 * math.pi))
    expected = (log_likelihood(2.0, grid.positions, paper_world, 0.3) + constant).reshape(grid.shape)
    np.testing.assert_allclose(grid.log_likelihood(2.0), expected, rtol=0, atol=1e-9)
    out = np.empty(grid.shape)
    assert grid.log_likelihood(2.0, out=out) is out
