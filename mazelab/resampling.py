"""Resampling schemes as plain functions, normalised weights W (N,) -> ancestor indices (M,), and
KLD-sampling (Fox 2003), which chooses M as it resamples."""

from __future__ import annotations

import warnings
from collections.abc import Callable
from dataclasses import dataclass
from statistics import NormalDist
from typing import Any

import numpy as np

from mazelab.checks import check_kld_numbers, finite_number, step_number
from mazelab.declaration import Option, parse_flag


# Every scheme is `scheme(weights, rng, count=None) -> ancestors`: weights (N,), normalised; rng a
# numpy Generator; count M (default N); ancestors int (M,), indices into the particles. Each also takes
# R runs' weights (R, N) with R Generators, one each, and returns (R, M): row r is what it returns for
# W[r] and rngs[r] alone, to the bit (the engine draws every due run in one call).
def uniforms(rng: Any, size: int | None = None) -> float | np.ndarray:
    """U[0, 1) draws: rng.random(size) of one Generator, or of R Generators one row each, (R, size)
    (size None: one draw, a float; (R, 1) for R runs)."""
    if hasattr(rng, "random"):
        return rng.random() if size is None else rng.random(size)
    return np.array([[g.random()] if size is None else g.random(size) for g in rng])  # random(): random(1)'s


def _inverse_cdf(sorted_uniforms: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Indices i with cumsum(W)[i-1] <= u < cumsum(W)[i] for sorted uniforms u in [0, 1), row by row.
    One search per run: searching R runs' rows as one array (each offset by its row) takes longer."""
    cumulative = np.cumsum(weights, axis=-1)
    cumulative[..., -1] = 1.0  # guard against round-off leaving the last bin short of 1
    if cumulative.ndim == 1:
        return cumulative.searchsorted(sorted_uniforms, side="right")
    out = np.empty(sorted_uniforms.shape, dtype=np.intp)
    for row, bins, points in zip(out, cumulative, sorted_uniforms, strict=True):
        row[:] = bins.searchsorted(points, side="right")
    return out


def multinomial_resample(weights: np.ndarray, rng: Any, count: int | None = None) -> np.ndarray:
    """M independent draws from the categorical distribution W (sorted ancestors)."""
    count = weights.shape[-1] if count is None else count
    return _inverse_cdf(np.sort(uniforms(rng, count), axis=-1), weights)


def stratified_resample(weights: np.ndarray, rng: Any, count: int | None = None) -> np.ndarray:
    """One uniform draw in each of the M strata [m/M, (m+1)/M) (sorted ancestors)."""
    count = weights.shape[-1] if count is None else count
    return _inverse_cdf((np.arange(count) + uniforms(rng, count)) / count, weights)


def systematic_resample(weights: np.ndarray, rng: Any, count: int | None = None) -> np.ndarray:
    """Systematic resampling (Kitagawa 1996), the lowest-variance scheme and the default: one uniform
    offset u ~ U[0, 1) shared by the M points u_m = (u + m) / M, each taken to the particle whose
    cumulative weight first exceeds it (the inverse CDF; sorted ancestors).

    The numpy backend runs this; the compiled one its counting form (mazelab.kernels.weights), which
    gives the same ancestors in O(N).
    """
    count = weights.shape[-1] if count is None else count
    u = uniforms(rng)  # u ~ U[0, 1): a float, or (R, 1) for R runs
    return _inverse_cdf((u + np.arange(count)) / count, weights)


def residual_resample(weights: np.ndarray, rng: Any, count: int | None = None) -> np.ndarray:
    """floor(M W_i) copies of each particle, the remaining draws multinomial on the remainders."""
    if weights.ndim == 2:
        return np.array([residual_resample(w, g, count) for w, g in zip(weights, rng, strict=True)])
    count = len(weights) if count is None else count
    copies = np.floor(count * weights).astype(np.int64)
    deterministic = np.repeat(np.arange(len(weights)), copies)
    left = count - len(deterministic)
    if left == 0:
        return deterministic
    remainder = count * weights - copies
    return np.concatenate([deterministic, multinomial_resample(remainder / remainder.sum(), rng, left)])


RESAMPLING_SCHEMES: dict[str, Callable[..., np.ndarray]] = {
    "systematic": systematic_resample,
    "stratified": stratified_resample,
    "multinomial": multinomial_resample,
    "residual": residual_resample,
}


def check_scheme(name: Any) -> str:
    """A resampling scheme's name, lower case, or one line naming the schemes.

    Parameters
    ----------
    name : str
        Any case.

    Returns
    -------
    str
    """
    if not isinstance(name, str) or name.lower() not in RESAMPLING_SCHEMES:
        raise ValueError(f"unknown resampling scheme {name!r}; choose one of {', '.join(RESAMPLING_SCHEMES)}")
    return name.lower()


RESAMPLING_OPTION = Option(
    "resampling",
    "systematic",
    f"the resampling scheme: {', '.join(RESAMPLING_SCHEMES)}",
    parse=str.strip,
    check=check_scheme,
    flag="--resampling",
)


KLD_BIN_SIZE = 0.25  # KLD-sampling counts occupied squares of this side (map units)
KLD_EPSILON = 0.05  # epsilon: the bound on the KL distance between the sample and the binned posterior
KLD_QUANTILE = NormalDist().inv_cdf(0.99)  # z_{1-delta}, the upper normal quantile for delta = 0.01: 2.326
KLD_MIN_COUNT = 100


def kld_sample_size(bins: Any, epsilon: float = KLD_EPSILON, z: float = KLD_QUANTILE) -> np.ndarray:
    """Fox (2003), eq. 13: the sample size that keeps the KL distance between the sample's binned
    estimate and the binned posterior below epsilon with probability 1 - delta, for k occupied bins:
        n = (k-1)/(2 eps) (1 - 2/(9(k-1)) + sqrt(2/(9(k-1))) z_{1-delta})^3   (0 for k <= 1).

    Parameters
    ----------
    bins : int or array of int
        k, the occupied bins.
    epsilon : float
        The KL bound.
    z : float
        The normal quantile z_{1-delta}.

    Returns
    -------
    float array, the shape of `bins`
    """
    k_minus_1 = np.asarray(bins, dtype=float) - 1
    safe = np.maximum(k_minus_1, 1.0)
    c = 2 / (9 * safe)
    return np.where(k_minus_1 >= 1, safe / (2 * epsilon) * (1 - c + np.sqrt(c) * z) ** 3, 0.0)


@dataclass(frozen=True)
class KLDSampling:
    """KLD-sampling options (Fox 2003): resample until the count n reaches the bound of `kld_sample_size`
    for the k bins (squares of side `bin_size`) the new particles occupy, within [min_count, max_count].
    `z` is the normal quantile z_{1-delta} (2.326 for delta = 0.01), not the probability 1 - delta;
    max_count None means the filter's initial particle count."""

    epsilon: float = KLD_EPSILON
    z: float = KLD_QUANTILE
    bin_size: float = KLD_BIN_SIZE
    min_count: int = KLD_MIN_COUNT
    max_count: int | None = None

    def __post_init__(self) -> None:
        check_kld_numbers(self.epsilon, self.z)  # epsilon and z within ranges that keep the count finite
        if not finite_number("KLD bin_size", self.bin_size) > 0:
            raise ValueError(f"KLD bin_size must be > 0, got {self.bin_size}")
        if self.z < 1:
            warnings.warn(
                f"KLD z = {self.z} looks like a probability; z is the normal quantile z_(1-delta), "
                f"e.g. {KLD_QUANTILE:.3f} for delta = 0.01",
                stacklevel=3,
            )
        step_number("KLD min_count", self.min_count)
        if self.max_count is not None and step_number("KLD max_count", self.max_count) < self.min_count:
            raise ValueError(f"KLD max_count {self.max_count} is below min_count {self.min_count}")

    def required_count(self, bins: Any) -> np.ndarray:
        """max(min_count, ceil(n_chi(k))): Fox's stopping count for k occupied bins (`kld_sample_size`'s
        `bins`, with these epsilon and z), an int64 array of their shape."""
        return np.maximum(self.min_count, np.ceil(kld_sample_size(bins, self.epsilon, self.z))).astype(np.int64)


def kld_options(
    kld: bool | KLDSampling | None, epsilon: float = KLD_EPSILON, z: float = KLD_QUANTILE
) -> KLDSampling | None:
    """The KLDSampling a filter option asks for: None (off), True (with `epsilon` and `z`), or a
    KLDSampling (its own numbers).

    Parameters
    ----------
    kld : bool, KLDSampling or None
        The option's value as its declaration checked it (`check_kld`).
    epsilon, z : float
        KLD-sampling's numbers when `kld` is True.

    Returns
    -------
    KLDSampling or None
    """
    return KLDSampling(epsilon=epsilon, z=z) if kld is True else kld


def check_kld(kld: Any) -> bool | KLDSampling | None:
    """The kld option: None/False (off), True, or a KLDSampling; True, the KLDSampling or None."""
    if kld is None or isinstance(kld, (bool, KLDSampling)):
        return None if kld is False else kld
    raise ValueError(f"kld must be true, false or a KLDSampling, got {kld!r}")


def _kld_number(name: str) -> Any:
    """The check of KLD-sampling's `epsilon` or `z` (the other at its default): the value as a float."""
    return lambda value: check_kld_numbers(**{"epsilon": KLD_EPSILON, "z": KLD_QUANTILE, name: value})[name == "z"]


KLD_OPTIONS = (
    Option(
        "kld",
        None,
        "KLD-sampling (Fox 2003): the particle count adapts, the given count the most",
        parse=parse_flag,
        check=check_kld,
        stored_as=KLDSampling,
        flag="--kld",
    ),
    Option(
        "kld_epsilon",
        KLD_EPSILON,
        "KLD-sampling's error bound epsilon",
        check=_kld_number("epsilon"),
        flag="--kld-epsilon",
    ),
    Option(
        "kld_z",
        KLD_QUANTILE,
        "KLD-sampling's normal quantile z_(1-delta) (2.326: delta 0.01)",
        check=_kld_number("z"),
        flag="--kld-z",
    ),
)


Move = Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]]  # ancestors or points -> (positions, headings)


def kld_resample(
    weights: np.ndarray,
    move: Move,
    options: KLDSampling,
    resample: Callable[..., np.ndarray],
    rng: np.random.Generator,
    max_count: int,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """KLD-sampling (Fox 2003, Table 1) in batches: draw ancestors from W, move them, and stop at the first
    sample n with n >= required_count(k), k the bins occupied by samples 1..n, or at max_count.
    Each batch is shuffled so that cutting a stratified or systematic batch short still keeps every
    ancestor with the same probability.

    Parameters
    ----------
    weights : array (N,)
        Normalised weights (one run).
    move : callable
        Ancestors -> (positions, headings): the transition of the drawn particles.
    options : KLDSampling
    resample : callable
        The resampling scheme, (weights, rng, count) -> ancestors.
    rng : numpy.random.Generator
    max_count : int
        The most particles to draw.

    Returns
    -------
    (ancestors (n,), positions (n, 2), headings (n,))
    """
    least = min(options.min_count, max_count)
    occupied = np.empty(0, dtype=np.int64)  # sorted keys of the occupied bins
    parts, drawn, target = [], 0, least
    while True:
        batch = min(max(target - drawn, drawn, 64), max_count - drawn)  # at least doubles: O(log n) batches
        ancestors = rng.permutation(resample(weights, rng, batch))
        positions, headings = move(ancestors)
        enough, keys = _enough(positions, occupied, drawn, least, options)
        stop = int(np.argmax(enough)) + 1 if enough.any() else batch
        parts.append((ancestors[:stop], positions[:stop], headings[:stop]))
        drawn += stop
        if enough.any() or drawn >= max_count:
            break
        occupied = np.union1d(occupied, keys)
        target = int(options.required_count(len(occupied)))
    ancestors, positions, headings = (np.concatenate(part) for part in zip(*parts, strict=True))
    return ancestors, positions, headings


def _enough(
    positions: np.ndarray, occupied: np.ndarray, drawn: int, least: int, options: KLDSampling
) -> tuple[np.ndarray, np.ndarray]:
    """Whether the sample reaches KLD-sampling's bound after each point of a batch (n >= least and n >=
    required_count(k), k the bins occupied by then, `occupied` before the batch), bool (batch,); and the
    sorted keys of the bins the batch occupies."""
    cells = np.floor(positions / options.bin_size).astype(np.int64)  # each point's bin, the square holding it
    keys, first = np.unique(cells[:, 0] * (1 << 32) + cells[:, 1], return_index=True)  # one int64 key a bin
    new = np.zeros(len(positions), dtype=bool)
    new[first[~np.isin(keys, occupied, assume_unique=True)]] = True
    bins = len(occupied) + np.cumsum(new)  # occupied bins after each point of the batch
    return drawn + np.arange(1, len(positions) + 1) >= np.maximum(least, options.required_count(bins)), keys


__all__ = [
    "KLD_BIN_SIZE",
    "KLD_EPSILON",
    "KLD_MIN_COUNT",
    "KLD_OPTIONS",
    "KLD_QUANTILE",
    "RESAMPLING_OPTION",
    "RESAMPLING_SCHEMES",
    "KLDSampling",
    "Move",
    "check_kld",
    "check_scheme",
    "kld_options",
    "kld_resample",
    "kld_sample_size",
    "multinomial_resample",
    "residual_resample",
    "stratified_resample",
    "systematic_resample",
]
