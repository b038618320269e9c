"""The exact Bayes filter of the lab's model on a fine grid: the accuracy limit of the particle filters,
and the oracle the tests and the accuracy table measure them against."""

from __future__ import annotations

import math
from typing import Any, ClassVar

import numpy as np

from mazelab.checks import MAP_MARGIN, MAX_GRID_RESOLUTION, check_memory
from mazelab.contract import Density
from mazelab.declaration import Option, Options, number_in
from mazelab.model import (
    CONFIDENCE_RADIUS,
    CONFIDENCE_SHARE,
    LOG_UNDERFLOW,
    MODEL_OPTIONS,
    ModelFilter,
)
from mazelab.modes import ESTIMATE_OPTION, MODE_CELL, Mode, find_modes, modes_of_bins
from mazelab.weights import mass_within, weighted_mean

GRID_RESOLUTION = 0.02  # cell size of GridBayesFilter, map units (divides 1, so cells never straddle walls)
BYTES_PER_GRID_CELL = 250  # the density, positions, distances and FFT buffers per cell (about 130 measured)


class GridBayesFilter(ModelFilter):
    """The exact Bayes filter of the same model on a fine grid: the accuracy limit of the particle filters.

    The density lives on cells of size `resolution` covering the map plus a `margin` (mass that leaves
    it is dropped). Prediction convolves it with the arc kernel p(x_k | x_{k-1}) (an FFT convolution);
    the update multiplies by equation (3) with the outside penalty, evaluated at the cell centres.
    """

    name: ClassVar[str] = "GridBayesFilter"
    options: ClassVar[Options] = Options(
        Option(
            "resolution",
            GRID_RESOLUTION,
            "the cells' side, map units (memory grows as its inverse square)",
            check=number_in("resolution", 0.0, MAX_GRID_RESOLUTION, what=" map units (at most a maze cell)"),
        ),
        Option(
            "margin",
            1.0,
            "the grid's margin around the map, map units (mass leaving it is dropped)",
            check=number_in("margin", 0.0, MAP_MARGIN, low_open=False, what=" map units"),
        ),
        *MODEL_OPTIONS,  # the model's options, read by ModelFilter as a particle filter's LostRobot reads them
        ESTIMATE_OPTION,
    )

    def __init__(self, *args: Any, **options: Any):
        super().__init__(*args, **options)  # the exact filter starts from the exact prior, not from a sample
        world, resolution, margin = self.world, self.settings["resolution"], self.settings["margin"]
        self.resolution = resolution
        ny, nx = check_grid_memory(world.width, world.height, resolution, margin)
        centres_x = -margin + (np.arange(nx) + 0.5) * resolution  # the grid starts `margin` before the map
        centres_y = -margin + (np.arange(ny) + 0.5) * resolution
        gx, gy = np.meshgrid(centres_x, centres_y)  # row j is y, column i is x
        self.positions = np.column_stack([gx.ravel(), gy.ravel()])  # (M, 2) cell centres
        self.count = len(self.positions)  # each cell a point of the belief
        self.shape = (ny, nx)
        self.free = world.is_free(gx, gy)
        # log p(z | x) on the cells less the Gaussian's constant (Sensor.log_pdf_at): (z, out=None) -> (ny, nx)
        self.log_likelihood = self.sensor.log_pdf_at(world, self.positions, self.free)
        self.density = self._prior()
        self._work: GridWorkspace | None = None  # made at the first step (a filter only read never needs it)
        self.log_evidence = 0.0  # log p(z_1:k), exact on the grid

    def _prior(self) -> np.ndarray:
        return self.free / self.free.sum()

    def advance(self, compass_angle: float) -> None:
        """p(x_k | z_1:k-1), Chapman-Kolmogorov (`predict`), into the workspace: `update` then replaces it
        with p(x_k | z_1:k) ∝ p(z_k | x_k) p(x_k | z_1:k-1), a new array."""
        self.density = self.predict(self.density, compass_angle, out=self.workspace.predicted)

    @property
    def workspace(self) -> GridWorkspace:
        """The step's buffers, made on first use."""
        if self._work is None:
            self._work = GridWorkspace(self.shape, arc_kernel_shape(self.speed, self.resolution))
        return self._work

    def predict(self, density: np.ndarray, compass_angle: float, out: np.ndarray | None = None) -> np.ndarray:
        """Convolve with the arc kernel of this step's compass angle (linear, not circular, FFT), into
        `out` if given (an array of the grid's shape), else a new array."""

        def arc(angle: float) -> tuple[np.ndarray, np.ndarray]:  # the arc kernel and its FFT, kept per angle
            kernel = arc_kernel(angle, self.delta, self.speed, self.resolution)
            return kernel, self.workspace.kernel_spectrum(kernel)  # np.fft.rfft2(kernel, fft_shape(...)), in place

        kernel, spectrum = self.per_angle(compass_angle, arc)
        return np.clip(self.workspace.convolve(density, kernel.shape, spectrum), 0.0, None, out=out)

    def update(self, z: float) -> None:
        """Multiply the density by the likelihood of z (equation (3), the outside penalty), normalised:
        self.density becomes a new array."""
        work = self.workspace
        log_lik = self.log_likelihood(z, out=work.log_likelihood)
        posterior, log_total = self._weighted(self.density, log_lik, work)
        # log p(z_k | z_1:k-1) = log sum_cells p(x_k | z_1:k-1) p(z_k | x_k), the Gaussian's constant included
        self.log_evidence += log_total + self.sensor.log_norm
        if posterior is None:  # no cell explains z: restart from the prior, as the particle filters do
            self.reinitialised_at.append(self.steps_done + 1)
            posterior, _ = self._weighted(self._prior(), log_lik, work)
        self.density = self._prior() if posterior is None else posterior

    @staticmethod
    def _weighted(density: np.ndarray, log_lik: np.ndarray, work: GridWorkspace) -> tuple[np.ndarray | None, float]:
        """density x exp(log_lik - top) on the density's support (0 elsewhere), normalised, as a new
        array (None when that product's total underflows), and the log of the product's total,
        log sum density exp(log_lik). `top` is the largest log-likelihood on the support; the product
        is formed in the workspace."""
        support = np.greater(density, 0, out=work.support)
        outside = np.logical_not(support, out=work.outside)
        top = log_lik.max(where=support, initial=-math.inf)
        product = np.subtract(log_lik, top, out=work.product)
        np.copyto(product, 0.0, where=outside)
        np.exp(product, out=product)
        product *= density
        np.copyto(product, 0.0, where=outside)
        total = product.sum()
        log_total = math.log(total) + top if total > 0 else -math.inf
        if not log_total >= LOG_UNDERFLOW:
            return None, log_total
        return product / total, log_total

    def belief(self) -> Density:
        """What the viewer draws: the density's cells and masses, and its modes."""
        return Density(self.positions, self.weights, self.modes)

    @property
    def weights(self) -> np.ndarray:
        return self.density.ravel()

    @property
    def estimate(self) -> np.ndarray:
        """The posterior mean over the cell centres (or, with estimate="mode", the heaviest mode's), (2,)."""
        if self.settings["estimate"] == "mode":
            modes = self.modes
            return modes[0].mean.copy() if modes else self.mean
        return self.mean

    @property
    def mean(self) -> np.ndarray:
        """The posterior mean over the cell centres, shape (2,)."""
        return weighted_mean(self.weights, self.positions, out=self.workspace.cells)

    @property
    def modes(self) -> list[Mode]:
        """The density's modes (mazelab.modes), heaviest first: its cells summed into MODE_CELL bins
        (the bins line up with the maze's cells when the resolution divides MODE_CELL)."""
        f = round(MODE_CELL / self.resolution)
        ny, nx = self.shape
        if not math.isclose(f * self.resolution, MODE_CELL) or ny % f or nx % f:
            return find_modes(self.positions, self.weights)
        x, y = (self.positions[:, i].reshape(self.shape) for i in (0, 1))
        d = self.density
        terms = (d, d * x, d * y, d * x * x, d * x * y, d * y * y)
        return modes_of_bins(np.stack([t.reshape(ny // f, f, nx // f, f).sum(axis=(1, 3)) for t in terms]))

    @property
    def is_confident(self) -> bool:
        """At least 95% of the mass lies within distance 1 of the estimate (as for the particle filters)."""
        work = self.workspace
        out = (work.cells, work.cells_y, work.within)
        return mass_within(self.weights, self.positions, self.estimate, CONFIDENCE_RADIUS, out=out) >= CONFIDENCE_SHARE


def check_grid_memory(
    width: float, height: float, resolution: float = GRID_RESOLUTION, margin: float = 1.0
) -> tuple[int, int]:
    """The grid's (rows, columns) of cells on a map of width x height (map units) plus `margin`;
    refused in one line (MemoryLimitError) when its arrays would not fit in memory."""
    nx = round((width + 2 * margin) / resolution)
    ny = round((height + 2 * margin) / resolution)
    check_memory(f"the grid filter's {ny}x{nx} cells (resolution {resolution:g})", nx * ny * BYTES_PER_GRID_CELL)
    return ny, nx


class GridWorkspace:
    """The buffers of a grid filter's step, made once: its FFT convolution's (`convolve`), the
    predicted density, the log-likelihood, the support, the weighted product (each the grid's
    shape) and the mean's and confidence's (flat). Reusing them gives the same numbers, bit for bit,
    as fresh arrays."""

    def __init__(self, shape: tuple[int, int], kernel_shape: tuple[int, int]):
        self.shape, self.fft_shape = shape, fft_shape(shape, kernel_shape)
        (ny, _), (py, px) = shape, self.fft_shape
        self.rows = np.empty((ny, px // 2 + 1), dtype=complex)  # rfft of each image row, padded to px
        self.spectrum = np.empty((py, px // 2 + 1), dtype=complex)  # then along y, padded to py
        self.inverse = np.empty_like(self.spectrum)  # the product's inverse along y
        self.kept_rows = np.empty((ny, px))  # the inverse along x of the rows the crop keeps
        self.predicted, self.log_likelihood, self.product = (np.empty(shape) for _ in range(3))
        self.support, self.outside = np.empty(shape, dtype=bool), np.empty(shape, dtype=bool)
        self.kernel_rows = np.empty((kernel_shape[0], px // 2 + 1), dtype=complex)
        self.kernel_fft = np.empty_like(self.spectrum)
        cells = shape[0] * shape[1]  # the mean's products, the confidence's distances and mask (weights' out=)
        self.cells, self.cells_y, self.within = np.empty((1, cells)), np.empty((1, cells)), np.empty((1, cells), bool)

    def kernel_spectrum(self, kernel: np.ndarray) -> np.ndarray:
        """np.fft.rfft2(kernel, self.fft_shape), bit for bit, in the workspace (valid until the next call)."""
        py, px = self.fft_shape
        np.fft.rfft(kernel, px, axis=1, out=self.kernel_rows)
        return np.fft.fft(self.kernel_rows, py, axis=0, out=self.kernel_fft)

    def convolve(self, image: np.ndarray, kernel_shape: tuple[int, int], kernel_spectrum: np.ndarray) -> np.ndarray:
        """Linear 2-D convolution of `image` with an odd-sized centred kernel (of `kernel_shape`, its
        spectrum `kernel_spectrum`), cropped to the image's shape, in these buffers: the numbers of
        np.fft.irfft2(np.fft.rfft2(image, s) * spectrum, s) cropped, bit for bit (the same 1-D transforms,
        axis by axis; only the rows the crop keeps are transformed back along x). A view of the
        workspace: valid until the next call."""
        (ny, nx), (ky, kx), (py, px) = image.shape, kernel_shape, self.fft_shape
        np.fft.rfft(image, px, axis=1, out=self.rows)
        np.fft.fft(self.rows, py, axis=0, out=self.spectrum)
        self.spectrum *= kernel_spectrum
        np.fft.ifft(self.spectrum, py, axis=0, out=self.inverse)
        np.fft.irfft(self.inverse[ky // 2 : ky // 2 + ny], px, axis=1, out=self.kept_rows)
        return self.kept_rows[:, kx // 2 : kx // 2 + nx]


def arc_kernel(compass_angle: float, delta: float, speed: float, resolution: float) -> np.ndarray:
    """The transition density on the grid: the arc of radius `speed` spanning `delta` around
    `compass_angle`, spread bilinearly over cells so that its mean is exact. Shape (2R+1, 2R+1),
    centred on the origin cell, rows along y; sums to one."""
    radius = arc_kernel_shape(speed, resolution)[0] // 2
    samples = max(16, math.ceil(4 * speed * delta / resolution))
    angles = compass_angle + delta * ((np.arange(samples) + 0.5) / samples - 0.5)
    fx = radius + speed * np.cos(angles) / resolution
    fy = radius + speed * np.sin(angles) / resolution
    ix, iy = np.floor(fx).astype(int), np.floor(fy).astype(int)
    tx, ty = fx - ix, fy - iy
    kernel = np.zeros((2 * radius + 1, 2 * radius + 1))
    for dy, wy in ((0, 1 - ty), (1, ty)):
        for dx, wx in ((0, 1 - tx), (1, tx)):
            np.add.at(kernel, (iy + dy, ix + dx), wy * wx / samples)
    return kernel


def arc_kernel_shape(speed: float, resolution: float) -> tuple[int, int]:
    """The shape of `arc_kernel`'s array: (2R+1, 2R+1), R = ceil(speed / resolution) + 1 cells."""
    radius = math.ceil(speed / resolution) + 1
    return 2 * radius + 1, 2 * radius + 1


def fft_shape(image_shape: tuple[int, ...], kernel_shape: tuple[int, ...]) -> tuple[int, int]:
    """The padded size of a linear (not circular) FFT convolution of image and kernel: along each axis the
    smallest 2^a, 3 * 2^a or 5 * 2^a >= n, the full size n, as numpy's FFT is fastest on such lengths (640
    takes a third of the time of 625 = 5^4)."""
    full = [i + k - 1 for i, k in zip(image_shape, kernel_shape, strict=True)]
    rows, columns = (min(odd * 2 ** max(0, math.ceil(math.log2(n / odd))) for odd in (1, 3, 5)) for n in full)
    return rows, columns


__all__ = [
    "GRID_RESOLUTION",
    "GridBayesFilter",
    "GridWorkspace",
    "arc_kernel",
    "arc_kernel_shape",
    "check_grid_memory",
    "fft_shape",
]
