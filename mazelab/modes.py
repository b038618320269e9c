"""The modes of a weighted cloud: its points binned on a square grid, the occupied bins joined into
clusters when they touch (8-neighbours), as AMCL clusters its particles for its pose estimate.

A mode is a cluster's share of the weight, its weighted mean and its spread. The point estimate
"mode" is the mean of the heaviest cluster (AMCL's pose); "mean" is the paper's posterior mean.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mazelab.declaration import Option, choice

MODE_CELL = 0.5  # bin size of the clustering, map units: half a maze cell, so a wall cell keeps modes apart
MIN_BIN_MASS = 1e-4  # a bin holding less than this share of the weight counts as empty


@dataclass(frozen=True)
class Mode:
    """One cluster of the cloud: `weight` its share of the total weight, `mean` (2,) its weighted mean,
    `spread` the root of the trace of its weighted covariance (map units)."""

    weight: float
    mean: np.ndarray
    spread: float


ESTIMATE_OPTION = Option(
    "estimate",
    "mean",
    "the point estimate: mean (the paper's posterior mean) or mode (the heaviest mode's mean)",
    parse=str.strip,
    check=choice("estimate", ("mean", "mode")),
    flag="--estimate",
)


def label_components(occupied: np.ndarray, diagonal: bool = True) -> np.ndarray:
    """Connected components of a boolean grid, of 8-neighbours (of 4 without `diagonal`): labels 0..K-1,
    -1 where unoccupied.

    Each occupied bin starts with its own flat index; every round takes the smallest label of its
    neighbourhood and then follows labels as pointers (pointer jumping), until nothing changes."""
    rows, columns = occupied.shape
    empty = rows * columns  # larger than any index
    labels = np.where(occupied, np.arange(empty).reshape(occupied.shape), empty)
    while True:
        padded = np.pad(labels, 1, constant_values=empty)
        smallest = labels.copy()
        for dy, dx in ((dy, dx) for dy in range(3) for dx in range(3) if diagonal or 1 in (dy, dx)):
            np.minimum(smallest, padded[dy : dy + rows, dx : dx + columns], out=smallest)
        smallest = np.where(occupied, smallest, empty)
        flat = smallest.ravel()
        for _ in range(2):  # a label is a bin index: point at that bin's label
            inside = flat < empty
            flat[inside] = flat[flat[inside]]
        if np.array_equal(smallest, labels):
            break
        labels = smallest
    out = np.full(labels.shape, -1, dtype=np.int64)
    _, out[occupied] = np.unique(labels[occupied], return_inverse=True)
    return out


def _binned(points: np.ndarray, cell: float = MODE_CELL) -> tuple[np.ndarray, int, int]:
    """Each point's bin (N,), a flat index into a grid of square `cell` bins over the points (N, 2) (N >= 1),
    and the grid's rows and columns."""
    bins = np.floor(points / cell).astype(np.int64)
    bins -= bins.min(axis=0)
    rows, columns = int(bins[:, 1].max()) + 1, int(bins[:, 0].max()) + 1
    return bins[:, 1] * columns + bins[:, 0], rows, columns


def cluster_labels(positions: np.ndarray, cell: float = MODE_CELL) -> tuple[np.ndarray, int]:
    """Each point's cluster (N,) of an unweighted cloud of N >= 1 points (a resampled one: every bin holding
    a point is occupied) and the cluster count."""
    flat, rows, columns = _binned(np.asarray(positions, dtype=float), cell)
    grid = label_components((np.bincount(flat, minlength=rows * columns) > 0).reshape(rows, columns))
    return grid.ravel()[flat], int(grid.max()) + 1


def find_modes(
    positions: np.ndarray, weights: np.ndarray, cell: float = MODE_CELL, min_mass: float = MIN_BIN_MASS
) -> list[Mode]:
    """The modes of a weighted cloud (positions (N, 2), weights (N,)), heaviest first; weights are shares
    of the total (the bins lighter than `min_mass` belong to none, so they may sum to a little less than 1)."""
    points, w = np.asarray(positions, dtype=float), np.asarray(weights, dtype=float)
    if len(points) == 0:
        return []
    flat, rows, columns = _binned(points, cell)
    x, y = points[:, 0], points[:, 1]
    terms = (w, w * x, w * y, w * x * x, w * x * y, w * y * y)
    sums = np.stack([np.bincount(flat, t, minlength=rows * columns) for t in terms]).reshape(6, rows, columns)
    return modes_of_bins(sums, min_mass)


def modes_of_bins(sums: np.ndarray, min_mass: float = MIN_BIN_MASS) -> list[Mode]:
    """The modes from per-bin sums (6, rows, columns) of w, wx, wy, wx^2, wxy, wy^2 over the points of
    each bin (a grid density can sum its cells without listing them), heaviest first."""
    total = sums[0].sum()
    if not total > 0:
        return []
    labels = label_components(sums[0] > min_mass * total).ravel()
    inside = labels >= 0
    count = int(labels.max()) + 1
    per = np.stack([np.bincount(labels[inside], s.ravel()[inside], minlength=count) for s in sums])
    mass = np.where(per[0] > 0, per[0], 1.0)
    mean_x, mean_y = per[1] / mass, per[2] / mass
    variance = per[3] / mass - mean_x**2 + per[5] / mass - mean_y**2
    spread = np.sqrt(np.clip(variance, 0.0, None))
    share = per[0] / total
    order = np.argsort(-share, kind="stable")
    return [Mode(float(share[i]), np.array([mean_x[i], mean_y[i]]), float(spread[i])) for i in order]


__all__ = [
    "ESTIMATE_OPTION",
    "MIN_BIN_MASS",
    "MODE_CELL",
    "Mode",
    "cluster_labels",
    "find_modes",
    "label_components",
    "modes_of_bins",
]
