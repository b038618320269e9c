"""The RPF's kernel K_h: the jitter added to each resampled particle (Arulampalam et al., Algorithm 6).

bandwidth="optimal" (the paper's): h_opt D eps, h_opt = A N^(-1/(n+4)) and D D^T = S the covariance of
  the whole weighted cloud; optimal when the posterior is one Gaussian, it over-smooths a posterior
  with several modes (S spans all of them).
bandwidth="multimodal" (beyond the paper): the mixture RPF of Murangira, Musso and Dahia (2016). The
  resampled cloud is split into its modes (mazelab.modes: connected occupied half-cell bins); cluster c
  of n_c particles gets its own kernel h_c D_c eps, D_c D_c^T = S_c its own covariance (at least that
  of one bin, so that a cluster of a few copies is still spread), h_c = MIXTURE_SHRINK h_opt(n_c): a
  mode is no Gaussian either (walls cut it), and Musso, Oudjane and Le Gland (2001) advise a smaller h
  than h_opt for such densities; the factor was chosen by measuring against the exact grid filter
  (see docs/multimodal.md).
bandwidth=h (a number): h D eps with the whole cloud's D, h given.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from mazelab.checks import MAX_BANDWIDTH, MIN_BANDWIDTH
from mazelab.declaration import Option
from mazelab.modes import MODE_CELL, cluster_labels

BANDWIDTHS = ("optimal", "multimodal")
MIXTURE_SHRINK = 0.5  # h_c = MIXTURE_SHRINK * h_opt(n_c) in the multimodal kernel (measured, see docs/multimodal.md)
MIN_CLUSTER_VARIANCE = MODE_CELL**2 / 12  # the variance of a uniform spread over one bin, per axis

Kernel = Callable[[np.ndarray, np.ndarray], np.ndarray]  # (resampled points (N, 2), eps (N, 2)) -> jitter (N, 2)


def optimal_bandwidth(count: int | np.ndarray, dimension: int = 2) -> float | np.ndarray:
    """h_opt = A N^(-1/(n+4)), A = (4/(n+2))^(1/(n+4)): optimal for a Gaussian kernel and posterior.

    Parameters
    ----------
    count : int or array of int
        N, the particles (of the cloud, or of each mode).
    dimension : int
        n, the state's dimension.

    Returns
    -------
    float, or an array the shape of `count`
    """
    n = dimension
    return (4 / (n + 2)) ** (1 / (n + 4)) * count ** (-1 / (n + 4))


def check_bandwidth(bandwidth: str | float) -> str | float:
    """ "optimal", "multimodal" or a number h within [MIN_BANDWIDTH, MAX_BANDWIDTH] (mazelab.checks: h
    scales the cloud's spread, at most the map's diagonal); a numeric string counts as its number.
    """
    if isinstance(bandwidth, str) and bandwidth in BANDWIDTHS:
        return bandwidth
    try:
        number = float(bandwidth) if isinstance(bandwidth, str) else bandwidth
    except ValueError:
        number = None
    if isinstance(number, bool) or not isinstance(number, (int, float)) or not MIN_BANDWIDTH <= number <= MAX_BANDWIDTH:
        raise ValueError(
            f"bandwidth must be optimal, multimodal or a positive number h within [{MIN_BANDWIDTH:g}, "
            f"{MAX_BANDWIDTH:g}] (h scales the cloud's spread, at most the map's diagonal), got {bandwidth!r}"
        )
    return float(number)


BANDWIDTH_OPTION = Option(
    "bandwidth",
    "optimal",
    "the RPF's kernel: optimal (the paper's h_opt), multimodal (one kernel per mode) or h",
    parse=str.strip,
    check=check_bandwidth,
    flag="--bandwidth",
)


@dataclass(frozen=True, eq=False)
class GaussianKernel:
    """The kernel h D eps of one run: `scale` is h D, lower triangular (2, 2), D D^T = S_k.

    Called as a Kernel, (resampled points (N, 2), eps (N, 2)) -> the jitter (N, 2) in eps's dtype; the
    compiled backend reads `scale` and jitters in its own pass (mazelab.kernels.model.jitter).
    """

    scale: np.ndarray

    def __call__(self, points: np.ndarray, eps: np.ndarray) -> np.ndarray:
        """h D eps for each row of eps (a Kernel, as `mixture_kernel` takes and returns; `points` unused: the
        kernel is the same everywhere)."""
        return gaussian_jitter(
            eps, *(eps.dtype.type(v) for v in (self.scale[0, 0], self.scale[1, 0], self.scale[1, 1]))
        )


def mixture_kernel(points: np.ndarray, eps: np.ndarray) -> np.ndarray:
    """h_c D_c eps for each resampled point of cluster c, h_c = MIXTURE_SHRINK h_opt(n_c) (Murangira,
    Musso and Dahia 2016, with a narrower h).

    Parameters
    ----------
    points : array (N, 2)
        The resampled points.
    eps : array (N, 2)
        Standard normal draws.

    Returns
    -------
    array (N, 2), order F, in eps's dtype
    """
    labels, count = cluster_labels(points)  # every resampled point lies in an occupied bin: no -1
    x, y = (np.asarray(points, dtype=float)[:, i] for i in (0, 1))
    sizes = np.bincount(labels, minlength=count)
    safe = np.where(sizes > 0, sizes, 1)
    dx = x - (np.bincount(labels, x, minlength=count) / safe)[labels]  # centred first: the spread may be tiny
    dy = y - (np.bincount(labels, y, minlength=count) / safe)[labels]  # beside the position
    # S_c, each cluster's covariance, its variances at least MIN_CLUSTER_VARIANCE
    s_xx = np.maximum(np.bincount(labels, dx * dx, minlength=count) / safe, MIN_CLUSTER_VARIANCE)
    s_xy = np.bincount(labels, dx * dy, minlength=count) / safe
    s_yy = np.maximum(np.bincount(labels, dy * dy, minlength=count) / safe, MIN_CLUSTER_VARIANCE)
    h = MIXTURE_SHRINK * optimal_bandwidth(sizes)
    a = np.sqrt(s_xx)  # D_c = [[a, 0], [c, d]], the Cholesky factor of each S_c, in closed form
    c = s_xy / a
    d = np.sqrt(np.clip(s_yy - c * c, 0.0, None))
    return gaussian_jitter(eps, *((h * v).astype(eps.dtype)[labels] for v in (a, c, d)))


def gaussian_jitter(eps: np.ndarray, a: Any, c: Any, d: Any) -> np.ndarray:
    """[[a, 0], [c, d]] eps for standard normal eps, in eps's dtype: the kernel's draws, written out (a
    BLAS matmul would start threads for two columns).

    Parameters
    ----------
    eps : array (N, 2)
    a, c, d : numbers, or arrays (N,) (each point's own factor)
        The lower-triangular h D, D D^T = S.

    Returns
    -------
    array (N, 2), order F
    """
    jitter = np.empty(eps.shape, eps.dtype, order="F")
    jitter[:, 0] = a * eps[:, 0]
    jitter[:, 1] = c * eps[:, 0] + d * eps[:, 1]
    return jitter


__all__ = [
    "BANDWIDTHS",
    "BANDWIDTH_OPTION",
    "MIN_CLUSTER_VARIANCE",
    "MIXTURE_SHRINK",
    "GaussianKernel",
    "Kernel",
    "check_bandwidth",
    "gaussian_jitter",
    "mixture_kernel",
    "optimal_bandwidth",
]
