"""Which sigma and delta explain a walk's measurements: the exact parameter posterior on a grid of values,
and particle marginal Metropolis-Hastings (PMMH, Andrieu, Doucet and Holenstein 2010) beside it.

The stated prior is uniform on a box of (sigma, delta), by default the lab's ranges sigma in [0.2, 0.8],
delta in [0.05, 0.6]. Then

    p(sigma, delta | z_1:K) ∝ p(z_1:K | sigma, delta)   inside the box, 0 outside.

The exact posterior (`exact_parameter_posterior`) takes the grid filter's exact evidence at each cell's
centre of a ParameterGrid (`grid_log_evidence`, a function of one cell that an executor maps). PMMH
(`pmmh`) uses a particle filter's estimate of p(z_1:K) in place of the evidence: it targets the exact
posterior whenever that estimate is unbiased (Del Moral 2004; `evidence_filter`, docs/smoothing.md).
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from mazelab.checks import check_seed, finite_number, step_number
from mazelab.checks import particle_count as checked_particle_count
from mazelab.grid_filter import GridBayesFilter, check_grid_memory
from mazelab.maze import Maze
from mazelab.model import LAB_DELTA_RANGE, LAB_SIGMA_RANGE, check_model_parameters
from mazelab.registry import FilterEntry, filter_entry
from mazelab.smoothing import check_walk

INTERVAL_LEVEL = 0.9  # the equal-tailed credible interval reported beside the posterior mean


@dataclass(frozen=True)
class ParameterGrid:
    """Equal cells over a box of (sigma, delta), the support of the uniform prior: each cell carries
    prior mass 1 / (S D). Row i, column j is the cell of the i-th sigma and the j-th delta.

    Parameters
    ----------
    sigma_range : (low, high)
        Map units, within the model's bounds (mazelab.model.check_model_parameters).
    delta_range : (low, high)
        Radians, within [0, 2 pi].
    cells : (S, D)
        The cells along sigma and along delta.
    """

    sigma_range: tuple[float, float] = LAB_SIGMA_RANGE
    delta_range: tuple[float, float] = LAB_DELTA_RANGE
    cells: tuple[int, int] = (12, 12)

    def __post_init__(self) -> None:
        for name, (low, high) in (("sigma", self.sigma_range), ("delta", self.delta_range)):
            if not finite_number(f"{name} range low", low) < finite_number(f"{name} range high", high):
                raise ValueError(f"the {name} range must be (low, high) with low < high, got ({low:g}, {high:g})")
        check_model_parameters(self.sigma_range[0], self.delta_range[0])  # the box's corners within the model's bounds
        check_model_parameters(self.sigma_range[1], self.delta_range[1])
        for name, count in zip(("sigma", "delta"), self.cells, strict=True):
            step_number(f"the {name} cells", count)

    @property
    def edges(self) -> tuple[np.ndarray, np.ndarray]:
        """The cells' edges along sigma (S + 1,) and along delta (D + 1,)."""
        return tuple(
            np.linspace(low, high, count + 1)
            for (low, high), count in zip((self.sigma_range, self.delta_range), self.cells, strict=True)
        )

    @property
    def centres(self) -> tuple[np.ndarray, np.ndarray]:
        """The cells' centres along sigma (S,) and along delta (D,)."""
        return tuple((e[1:] + e[:-1]) / 2 for e in self.edges)

    @property
    def values(self) -> tuple[list[float], list[float]]:
        """The sigma and the delta of every cell, row by row, two lists of S D floats: what an executor maps."""
        sigmas, deltas = np.meshgrid(*self.centres, indexing="ij")
        return sigmas.ravel().tolist(), deltas.ravel().tolist()

    def __contains__(self, point: Sequence[float]) -> bool:
        """Whether `point`, (sigma, delta), lies in the box, where the prior is positive."""
        sigma, delta = point
        return (
            self.sigma_range[0] <= sigma <= self.sigma_range[1] and self.delta_range[0] <= delta <= self.delta_range[1]
        )


def grid_log_evidence(
    world: Maze,
    compass_angles: Sequence[float],
    measurements: Sequence[float],
    sigma: float,
    delta: float,
    **grid_options: Any,
) -> float:
    """log p(z_1:K | sigma, delta): the grid filter's exact evidence of the walk (one cell of a
    ParameterGrid; plain values in and out, so that an executor can map it).

    Parameters
    ----------
    world : Maze
    compass_angles, measurements : sequences of K floats
        The walk's th0_k (radians) and z_k (map units).
    sigma, delta : float
        The model's parameters at the cell.
    **grid_options
        GridBayesFilter's options (resolution, margin, outside_penalty, speed).

    Returns
    -------
    float
        -inf where no cell of the grid explains a measurement (the filter restarted: the model gives
        the walk no density).
    """
    grid = GridBayesFilter(world, sigma, delta, **grid_options)
    for compass_angle, z in zip(compass_angles, measurements, strict=True):
        grid.step(compass_angle, z)
    return -math.inf if grid.reinitialised_at else float(grid.log_evidence)


@dataclass(frozen=True)
class ParameterPosterior:
    """p(sigma, delta | z_1:K) on a ParameterGrid, its density constant within each cell.

    Attributes
    ----------
    grid : ParameterGrid
    log_evidence : array (S, D)
        log p(z_1:K | sigma, delta) at each cell's centre.
    """

    grid: ParameterGrid
    log_evidence: np.ndarray

    @property
    def mass(self) -> np.ndarray:
        """The posterior mass of each cell (S, D): the evidence times the uniform prior, normalised."""
        finite = self.log_evidence[np.isfinite(self.log_evidence)]
        if len(finite) == 0:
            raise ValueError("no (sigma, delta) of the grid explains the measurements: the posterior is undefined")
        mass = np.exp(self.log_evidence - finite.max())
        return mass / mass.sum()

    @property
    def marginals(self) -> tuple[np.ndarray, np.ndarray]:
        """The marginal posteriors: sigma's masses (S,) and delta's (D,)."""
        mass = self.mass
        return mass.sum(axis=1), mass.sum(axis=0)

    @property
    def mean(self) -> np.ndarray:
        """E[(sigma, delta) | z_1:K], (2,): exact for the density constant on each cell."""
        return np.array([m @ c for m, c in zip(self.marginals, self.grid.centres, strict=True)])

    def interval(self, level: float = INTERVAL_LEVEL) -> np.ndarray:
        """The equal-tailed credible interval of sigma and of delta: each marginal's CDF is linear
        within a cell, so its quantiles are interpolated between the edges.

        Parameters
        ----------
        level : float
            The interval's posterior probability.

        Returns
        -------
        array (2, 2)
            Row 0 sigma's (low, high), row 1 delta's.
        """
        tails = np.array([(1 - level) / 2, (1 + level) / 2])
        rows = []
        for mass, edges in zip(self.marginals, self.grid.edges, strict=True):
            cdf = np.concatenate([[0.0], np.cumsum(mass)])
            rows.append(np.interp(tails, cdf / cdf[-1], edges))
        return np.array(rows)


def exact_parameter_posterior(
    world: Maze,
    compass_angles: Sequence[float],
    measurements: Sequence[float],
    grid: ParameterGrid | None = None,
    mapper: Callable[..., Iterable[float]] = map,
    **grid_options: Any,
) -> ParameterPosterior:
    """The exact parameter posterior of a walk on a ParameterGrid (the lab's ranges, 12 x 12 cells, by
    default): `grid_log_evidence` at every cell.

    Parameters
    ----------
    world : Maze
    compass_angles, measurements : sequences of K floats
        The walk's th0_k and z_k.
    grid : ParameterGrid, optional
    mapper : callable
        map(function, sigmas, deltas), the built-in by default (one cell after another); an executor's
        map spreads the cells over processes.
    **grid_options
        GridBayesFilter's options (resolution, margin, outside_penalty, speed).

    Returns
    -------
    ParameterPosterior
    """
    grid = ParameterGrid() if grid is None else grid
    angles, zs = check_walk(compass_angles, measurements)
    resolved = GridBayesFilter.options.resolve(grid_options, "GridBayesFilter")  # checked here, not in each cell
    check_grid_memory(world.width, world.height, resolved["resolution"], resolved["margin"])
    cell = functools.partial(grid_log_evidence, world, angles.tolist(), zs.tolist(), **grid_options)
    log_evidence = np.array(list(mapper(cell, *grid.values)), dtype=float)
    return ParameterPosterior(grid, log_evidence.reshape(grid.cells))


def evidence_filter(name: str | type, options: dict[str, Any] | None = None) -> FilterEntry:
    """The registry's entry of a filter whose log evidence estimates p(z_1:K) without bias with these
    options: one whose declaration carries no caveat (FilterEntry.evidence: the RPF's has one) and runs
    without recovery; else a one-line ValueError saying why. (The grid filter's is the exact value on the
    grid: PMMH with it is plain Metropolis-Hastings.)

    Parameters
    ----------
    name : str or class
        What mazelab.registry.filter_entry takes (sir, SIRParticleFilter, ...).
    options : dict, optional
        The filter's options, each checked by its declaration (a one-line ValueError).

    Returns
    -------
    FilterEntry
    """
    entry = filter_entry(name)
    if entry.evidence:
        raise ValueError(f"PMMH needs a filter whose evidence estimates p(z_1:K): {entry.label}'s is {entry.evidence}")
    if (options or {}).get("recovery") not in (None, False, "none"):
        raise ValueError(
            "PMMH needs a filter whose evidence estimates p(z_1:K): with recovery it does not (its injected "
            "particles come from no proposal the weights account for); leave recovery out"
        )
    entry.options.resolve(options or {}, entry.name)  # each option checked once, before the first run
    return entry


def estimated_log_evidence(
    world: Maze,
    compass_angles: np.ndarray,
    measurements: np.ndarray,
    entry: FilterEntry,
    particle_count: int,
    options: dict[str, Any],
    sigma: float,
    delta: float,
    rng: np.random.Generator,
) -> float:
    """log p_hat(z_1:K | sigma, delta) by one fresh run of a filter (`evidence_filter`'s entry, with its
    options) over the walk: its particle_count particles drawn from the model's prior (uniform over the free
    area) and its own draws, both from Generators spawned from `rng`; -inf where it is not a number."""
    particles_rng, filter_rng = rng.spawn(2)
    particles = world.random_free_places(particle_count, particles_rng) if entry.takes_particles else None
    filt = entry.filter_class(world, sigma, delta, particles, filter_rng, **options)
    for compass_angle, z in zip(compass_angles, measurements, strict=True):
        filt.step(float(compass_angle), float(z))
    if not hasattr(filt, "log_evidence"):  # optional in the contract (mazelab.contract)
        raise ValueError(f"PMMH needs a filter whose evidence estimates p(z_1:K): {entry.label} keeps none")
    log_z = float(filt.log_evidence)
    return log_z if not math.isnan(log_z) else -math.inf


@dataclass(frozen=True)
class Chain:
    """A PMMH chain on (sigma, delta): its states after each iteration and what they rest on.

    Attributes
    ----------
    samples : array (iterations, 2)
        (sigma, delta) after each iteration; the first `burn_in` are not part of its estimates.
    log_evidence : array (iterations,)
        The estimate of log p(z_1:K | sigma, delta) the chain held after each iteration.
    accepted : int
        The proposals accepted (burn-in included).
    burn_in : int
    """

    samples: np.ndarray
    log_evidence: np.ndarray
    accepted: int
    burn_in: int

    @property
    def kept(self) -> np.ndarray:
        """The samples after the burn-in, (n, 2)."""
        return self.samples[self.burn_in :]

    @property
    def acceptance_rate(self) -> float:
        return self.accepted / len(self.samples)

    @property
    def ess(self) -> np.ndarray:
        """The effective sample size of sigma's and of delta's kept samples (`chain_ess`), (2,)."""
        return np.array([chain_ess(column) for column in self.kept.T])

    @property
    def mean(self) -> np.ndarray:
        """The chain's posterior mean of (sigma, delta), (2,)."""
        return self.kept.mean(axis=0)

    @property
    def mean_error(self) -> np.ndarray:
        """The Monte Carlo standard error of `mean`, sd / sqrt(ESS), (2,)."""
        return self.kept.std(axis=0, ddof=1) / np.sqrt(self.ess)

    def interval(self, level: float = INTERVAL_LEVEL) -> np.ndarray:
        """The equal-tailed credible interval of sigma and of delta, from the kept samples' quantiles.

        Parameters
        ----------
        level : float

        Returns
        -------
        array (2, 2)
            Row 0 sigma's (low, high), row 1 delta's.
        """
        return np.quantile(self.kept, [(1 - level) / 2, (1 + level) / 2], axis=0).T

    def interval_error(self, level: float = INTERVAL_LEVEL) -> np.ndarray:
        """The Monte Carlo standard error of each end of `interval` (`quantile_error`).

        Parameters
        ----------
        level : float

        Returns
        -------
        array (2, 2)
        """
        tails = ((1 - level) / 2, (1 + level) / 2)
        return np.array([[quantile_error(column, p) for p in tails] for column in self.kept.T])


def pmmh(
    world: Maze,
    compass_angles: Sequence[float],
    measurements: Sequence[float],
    iterations: int,
    *,
    filter_name: str | type = "sir",
    particle_count: int = 1000,
    prior: ParameterGrid | None = None,
    start: tuple[float, float] | None = None,
    proposal_scale: tuple[float, float] = (0.08, 0.3),
    burn_in: int = 0,
    seed: int = 0,
    **filter_options: Any,
) -> Chain:
    """Particle marginal Metropolis-Hastings on (sigma, delta) under the uniform prior on `prior`'s box.

    Each iteration proposes (sigma', delta') = (sigma, delta) + proposal_scale * N(0, I); one inside the
    box is accepted with probability min(1, Z_hat' / Z_hat), Z_hat' a fresh run's estimate of p(z_1:K),
    Z_hat the one kept with the current state (never re-estimated: that keeps the exact posterior the
    chain's target); one outside the box is rejected without a run.

    Parameters
    ----------
    world : Maze
    compass_angles, measurements : sequences of K floats
        The walk's th0_k and z_k.
    iterations, burn_in : int
        The chain's iterations, and the first of them left out of its estimates.
    filter_name : str or class
        A filter whose evidence estimates p(z_1:K) (`evidence_filter`: the RPF, or recovery, is refused
        in one line), run with `particle_count` particles and its `**filter_options`.
    prior, start : ParameterGrid and (sigma, delta), optional
        The uniform prior's box (the lab's ranges by default) and the chain's first state (its centre by default).
    proposal_scale : (float, float)
        The random walk's standard deviations along sigma (map units) and delta (radians): the
        defaults suit walks of a few dozen steps, whose posterior of delta is nearly the prior's (about
        a quarter of the proposals are accepted).
    seed : int
        Seeds the proposals, the acceptances and every run's particles and draws.

    Returns
    -------
    Chain
    """
    entry = evidence_filter(filter_name, filter_options)
    walk = (world, *check_walk(compass_angles, measurements), entry, checked_particle_count(particle_count))
    estimate = functools.partial(estimated_log_evidence, *walk, filter_options)
    return random_walk(estimate, prior, start, proposal_scale, iterations, burn_in, seed)


def random_walk(
    estimate: Callable[[float, float, np.random.Generator], float],
    prior: ParameterGrid | None,
    start: tuple[float, float] | None,
    proposal_scale: tuple[float, float],
    iterations: int,
    burn_in: int,
    seed: int,
) -> Chain:
    """PMMH's chain (`pmmh`), `estimate(sigma, delta, rng)` a run's log p_hat(z_1:K), `rng` the Generator
    of `seed`, from `start` (else the prior's centre; the prior the lab's box by default), once its settings
    are checked: a one-line ValueError for a start outside the prior's box, a count or seed that is not a
    whole number, a burn-in outside [0, iterations)."""
    prior = ParameterGrid() if prior is None else prior
    state = np.array(start if start is not None else [np.mean(prior.sigma_range), np.mean(prior.delta_range)])
    iterations = step_number("iterations", iterations)
    if not 0 <= burn_in < iterations:
        raise ValueError(f"burn_in must lie in [0, iterations), got {burn_in!r}")
    if state not in prior:
        raise ValueError(f"the chain's start {tuple(state)} lies outside the prior's box")
    scale = np.array([finite_number("proposal scale", s) for s in proposal_scale])
    rng = np.random.default_rng(check_seed("seed", seed))
    log_z = estimate(*state, rng)
    samples, log_evidence, accepted = np.empty((iterations, 2)), np.empty(iterations), 0
    for i in range(iterations):
        proposal = state + scale * rng.standard_normal(2)
        if proposal in prior:
            proposed_log_z = estimate(*proposal, rng)
            if math.log(rng.random()) < proposed_log_z - log_z:  # the prior is flat on the box
                state, log_z, accepted = proposal, proposed_log_z, accepted + 1
        samples[i], log_evidence[i] = state, log_z
    return Chain(samples, log_evidence, accepted, burn_in)


def chain_ess(x: np.ndarray) -> float:
    """The effective sample size n / tau of a chain's values, tau = 1 + 2 sum_t rho_t its integrated
    autocorrelation time by Geyer's initial monotone sequence: the sums of pairs rho_2m + rho_2m+1 while they stay
    positive, made non-increasing (Geyer 1992).

    Parameters
    ----------
    x : array (n,)

    Returns
    -------
    float
        At most n log10(n) (an antithetic chain's tau may fall below 1); 1 for a chain that never moved.
    """
    x = np.asarray(x, dtype=float)
    n = len(x)
    centred = x - x.mean()
    if n < 4 or not np.any(centred):
        return 1.0
    spectrum = np.fft.rfft(centred, 2 * n)
    autocovariance = np.fft.irfft(spectrum * spectrum.conj(), 2 * n)[:n]
    rho = autocovariance / autocovariance[0]
    pairs = rho[: n - n % 2].reshape(-1, 2).sum(axis=1)
    negative = np.flatnonzero(pairs <= 0)
    pairs = np.minimum.accumulate(pairs[: negative[0] if len(negative) else len(pairs)])
    tau = max(-1.0 + 2.0 * pairs.sum(), 1.0 / math.log10(n))  # tau's floor keeps the ESS <= n log10(n)
    return float(n / tau)


def quantile_error(x: np.ndarray, p: float) -> float:
    """The Monte Carlo standard error of a chain's p-quantile (Vehtari et al. 2021): the indicator
    1{x <= q_p} has variance p (1 - p) / ESS of its mean, and the chain's quantiles at p -/+ one such
    standard deviation span two standard errors of q_p.

    Parameters
    ----------
    x : array (n,)
        The chain's values.
    p : float
        The quantile's probability, in (0, 1).

    Returns
    -------
    float
    """
    q = np.quantile(x, p)
    spread = math.sqrt(p * (1 - p) / chain_ess(x <= q))
    low, high = np.quantile(x, [max(0.0, p - spread), min(1.0, p + spread)])
    return float((high - low) / 2)


__all__ = [
    "INTERVAL_LEVEL",
    "Chain",
    "ParameterGrid",
    "ParameterPosterior",
    "chain_ess",
    "evidence_filter",
    "exact_parameter_posterior",
    "grid_log_evidence",
    "pmmh",
    "quantile_error",
]
