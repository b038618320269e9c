"""The weighted particle cloud that the paper's three filters share (mazelab.filters writes their steps).

A student reads one run: `positions` (N, 2) float32, `weights` (N,), `estimate` (2,), `ess` a float,
and the public steps a filter is made of: `propagate` (the transition), `likelihood` (equation (3)),
`draw_particles` (RESAMPLE, then move), `normalise` (the weights, with a restart from the prior when no
particle explains z) and `set_uniform_weights`. Every option is declared once in `options`
(mazelab.declaration): the constructor takes its defaults from there and checks the values there.

The same object also advances R runs of one setting together (a batched study): run r's particles are
rows r*N..(r+1)*N of `positions` (R*N, 2), its log weights row r of `run_log_weights` (R, N), and its
draws come from its own Generator `rngs[r]`, in the order a filter of that run alone would draw them,
so R runs are bit for bit R single runs. The run axis shows only where a step passes `runs` (the runs a
draw is for: None means all); the helpers for it sit at the end of the class and in mazelab.run_axis.
Recovery from kidnapping and KLD-sampling vary one run's particles, so they need R = 1.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from types import MappingProxyType
from typing import Any, ClassVar

import numpy as np

from mazelab.backend import kernels_for
from mazelab.checks import check_sigma_within
from mazelab.contract import Particles
from mazelab.declaration import Options, options_of
from mazelab.maze import Maze, check_world
from mazelab.model import (
    CONFIDENCE_RADIUS,
    CONFIDENCE_SHARE,
    LOG_UNDERFLOW,
    OUTSIDE_PENALTY_OPTION,
    PARTICLE_DTYPE,
    SPEED_OPTION,
    log_likelihood,
)
from mazelab.modes import ESTIMATE_OPTION, Mode, find_modes
from mazelab.recovery import RECOVERY_OPTIONS, RecoveryTracker, recovery_options
from mazelab.resampling import (
    KLD_OPTIONS,
    RESAMPLING_OPTION,
    KLDSampling,
    Move,
    kld_options,
    kld_resample,
    resampling_scheme,
    systematic_resample,
)
from mazelab.run_axis import as_runs, generators, per_run, replace_blocks
from mazelab.weights import log_sum_exp


class ParticleFilter:
    """Weighted particles {x_i, W_i} approximating the posterior p(x_k | z_1:k).

    Arulampalam's algorithms end each step by resampling; here each step starts by resampling the
    previous posterior, the same sequence of operations, so that between steps the filter holds the
    weighted posterior that the estimate, the ESS and the drawing read.

    Parameters
    ----------
    world : Maze
        The map: free area and stations (read-only: a filter cannot change it for the others).
    sigma, delta : float
        The measurement noise's standard deviation (map units) and the compass error's width (radians).
    particles : array (N, 2), or (R, N, 2) for R runs together
        The initial particles (the prior's sample).
    rng : numpy.random.Generator, or a sequence of R of them
        Every random draw of the filter (each run's from its own); None: a fresh unseeded one.
    **options
        The declared options (`options`; `mazelab filters sir` lists them); `settings`: the values it runs with.

    Notes
    -----
    `positions` are float32 (PARTICLE_DTYPE), log weights float64. The filter replaces these arrays
    rather than writing into them; to change them, assign new arrays (the weights, estimate, ESS and
    confidence are computed once per assignment and cached).

    The hot parts (the move, the likelihood, systematic resampling, the normalisation and the reads, the
    RPF's jitter) run on `ops`, numpy's or the compiled kernels (mazelab.backend: `backend` names the
    one chosen when the filter was made). The compiled kernels reuse their arrays once nothing else
    holds them, so an array kept from an earlier step is never written over.
    """

    name: ClassVar[str] = "ParticleFilter"
    options: ClassVar[Options] = Options(
        RESAMPLING_OPTION,
        OUTSIDE_PENALTY_OPTION,
        SPEED_OPTION,
        *RECOVERY_OPTIONS,
        *KLD_OPTIONS,
        ESTIMATE_OPTION,
        check=lambda values: _check_parts(values),
    )
    ONE_RUN_OPTIONS: ClassVar[tuple[str, ...]] = ("recovery", "kld")  # options that need R = 1

    def __init_subclass__(cls, **kwargs: Any) -> None:
        """A subclass is named after itself unless it sets `name` (results and the viewer label it so),
        and its `options` are Options (a plain mapping read by `options_of`)."""
        super().__init_subclass__(**kwargs)
        if "name" not in cls.__dict__:
            cls.name = cls.__name__
        cls.options = options_of(cls)

    def __init__(
        self,
        world: Maze,
        sigma: float,
        delta: float,
        particles: np.ndarray,
        rng: np.random.Generator | Sequence[np.random.Generator] | None = None,
        **options: Any,
    ):
        settings = type(self).options.resolve(options, self.name)  # defaults filled in, each value checked
        self.settings: Mapping[str, Any] = MappingProxyType(settings)
        self.world, self.sigma, self.delta = check_world(world), sigma, delta
        check_sigma_within(sigma, world.width, world.height)
        self.ops = kernels_for(self.world)  # the hot operations: numpy's or compiled (mazelab.backend)
        self.backend: str = self.ops.name
        self.estimate_rule = settings["estimate"]
        self.scheme_name = settings["resampling"]
        self.scheme = resampling_scheme(self.scheme_name)
        self.outside_penalty, self.speed = settings["outside_penalty"], settings["speed"]
        runs_particles = as_runs(particles)  # (R, N, 2)
        self.runs, self.count = runs_particles.shape[:2]
        self.rngs = generators(rng, self.runs)
        self.positions = np.asfortranarray(runs_particles.reshape(-1, 2), dtype=PARTICLE_DTYPE)  # (R*N, 2)
        self.headings = np.zeros(len(self.positions), dtype=PARTICLE_DTYPE)  # each particle's last motion angle
        self._log_w = np.full((self.runs, self.count), -math.log(self.count))
        self._summary_of: tuple[np.ndarray, np.ndarray] | None = None  # the arrays _summary describes
        self._summary: dict[str, Any] = {}
        self.steps_done = 0
        self._reinitialised: list[list[int]] = [[] for _ in range(self.runs)]
        # the parts beyond the paper, off by default
        recovering = recovery_options(settings["recovery"], settings["alpha_slow"], settings["alpha_fast"])
        self.recovery = None if recovering is None else RecoveryTracker(recovering, world, sigma)
        self.kld: KLDSampling | None = kld_options(settings["kld"], settings["kld_epsilon"], settings["kld_z"])
        self.max_count = self.count if self.kld is None or self.kld.max_count is None else self.kld.max_count
        if self.runs > 1 and (self.recovery is not None or self.kld is not None):
            raise ValueError("recovery and KLD-sampling vary one run's particles: they run one run at a time")
        self._injected: np.ndarray | None = None
        self._injected_step = 0

    @classmethod
    def runs_together(cls, options: Mapping[str, Any]) -> bool:
        """Whether several runs with these options can advance together (R > 1): not with recovery or
        KLD-sampling, which vary one run's particles (such runs go one at a time).

        Parameters
        ----------
        options : mapping
            The filter's options by name.

        Returns
        -------
        bool
        """
        return not any(options.get(name) not in (None, False, "none") for name in cls.ONE_RUN_OPTIONS)

    def step(self, compass_angle: float | np.ndarray, z: float | np.ndarray) -> None:
        """Advance one step: predict with the compass angle th0_k (radians), update with z_k.

        Parameters
        ----------
        compass_angle, z : float, or arrays (R,) for R runs
        """
        raise NotImplementedError

    @property
    def diagnostics(self) -> dict[str, Any]:
        """This step's figures of the filter's own, by name (recorded per step in RunResult.extras and a
        study's traces): recovery's injection probability when recovery is on."""
        return {} if self.recovery is None else {"injection_probability": self.injection_probability}

    # -- the model: transition and likelihood ----------------------------------------------------------
    def propagate(
        self,
        positions: np.ndarray,
        compass_angle: np.ndarray,
        runs: np.ndarray | None = None,
        ancestors: np.ndarray | None = None,
    ) -> tuple[np.ndarray, np.ndarray]:
        """Draw x_k ~ p(x_k | x_{k-1}): uniform on the arc of radius L around th0 (headings too).

        Parameters
        ----------
        positions : array (N, 2), or the blocks of the given runs one after another
        compass_angle : array (R,)
            th0_k of every run (`per_run` makes it from a number).
        runs : array of run indices, optional
            The runs whose blocks `positions` holds (None: every run).
        ancestors : int array, optional
            Move positions[ancestors] (the resampled particles, gathered in the same pass), not positions.

        Returns
        -------
        (moved positions, headings) : arrays (M, 2) and (M,) in the positions' dtype
        """
        rngs = self.rngs if runs is None else [self.rngs[run] for run in runs]
        dtype = positions.dtype  # PARTICLE_DTYPE, or float64 for injected draws from the free area
        moved = len(positions) if ancestors is None else len(ancestors)
        uniforms = self.ops.buffer("uniforms", (len(rngs), moved // len(rngs)), dtype)
        for row, rng in enumerate(rngs):
            rng.random(dtype=dtype, out=uniforms[row])
        angles = (compass_angle if runs is None else compass_angle[runs]).astype(dtype)
        return self.ops.move(positions, ancestors, uniforms, angles, self.delta, self.speed)

    def motion(self, compass_angle: np.ndarray) -> tuple[Callable[..., Any], Move]:
        """This step's transition, for resampled ancestors and for injected points (draw_particles).

        Parameters
        ----------
        compass_angle : array (R,)
            th0_k of every run.

        Returns
        -------
        (move_ancestors, move_injected)
            (ancestors, runs) -> the ancestors' particles moved, and points -> the points moved, each
            as (positions, headings).
        """

        def ancestors_moved(ancestors: np.ndarray, runs: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
            return self.propagate(self.positions, compass_angle, runs, ancestors)

        return ancestors_moved, lambda points: self.propagate(points, compass_angle)

    def likelihood(self, z: np.ndarray, positions: np.ndarray) -> np.ndarray:
        """log p(z_k | x) of equation (3) with the outside penalty.

        Parameters
        ----------
        z : array (R,)
            z_k of each run whose block `positions` holds.
        positions : array (R*N, 2)

        Returns
        -------
        array (R, N)
        """
        return self.ops.log_likelihood(z, positions, self.world, self.sigma, self.outside_penalty)

    # -- resampling, and the parts that change it ------------------------------------------------------
    def resample(self, weights: np.ndarray, runs: np.ndarray | None = None) -> np.ndarray:
        """Ancestors drawn by the weights with the resampling scheme.

        Parameters
        ----------
        weights : array (R, N)
            Normalised weights of the given runs (one row per run).
        runs : array of run indices, optional
            The runs to resample (None: every run).

        Returns
        -------
        array (len(runs) * N,)
            Indices into `positions`, N per run.
        """
        chosen = range(self.runs) if runs is None else runs
        if self.scheme is systematic_resample:  # one offset per run, the counting done for all runs at once
            uniforms = np.array([self.rngs[run].random() for run in chosen])
            return self.ops.systematic(weights, uniforms, runs, self.count)
        return np.concatenate([self.scheme(weights[run], self.rngs[run]) + run * self.count for run in chosen])

    def draw_particles(
        self, weights: np.ndarray, move_ancestors: Callable[..., Any], move_injected: Move, runs: np.ndarray | None
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None]:
        """RESAMPLE by the weights (R, N) and `move_ancestors` the ancestors; with KLD-sampling, as many
        as Fox's bound asks; with recovery, then replace each particle with the injection probability by
        an injected point passed through `move_injected`.

        Parameters
        ----------
        weights : array (R, N)
            Every run's normalised weights.
        move_ancestors : callable
            (ancestors, runs) -> (positions, headings), the transition of the resampled particles.
        move_injected : callable
            points -> (positions, headings), the transition of recovery's injected points.
        runs : int array, or None
            The runs to draw for (None: every run).

        Returns
        -------
        (positions, headings, ancestors, injected mask or None) of the given runs (None: every run).
        """
        if self.kld is None:
            ancestors = self.resample(weights, runs)
            positions, headings = move_ancestors(ancestors, runs)
        else:  # one run (R = 1)
            ancestors, positions, headings = kld_resample(
                weights[0], lambda a: move_ancestors(a, runs), self.kld, self.scheme, self.rngs[0], self.max_count
            )
        injected = None
        if self.recovery is not None:  # one run (R = 1)
            injected = self.recovery.inject(positions, headings, move_injected, self.rngs[0])
        self._injected, self._injected_step = injected, self.steps_done + 1
        return positions, headings, ancestors, injected

    def inject_without_resampling(self, move_injected: Move) -> None:
        """Recovery between resamplings: replace particles with the injection probability, each injected
        point keeping the weight of the particle it replaces (the selection ignores the weights, so the
        set represents the same mixture (1 - p) belief + p injection as injecting at a resampling).

        Parameters
        ----------
        move_injected : callable
            points -> (positions, headings), applied to the injected points.
        """
        positions, headings = self.positions.copy(order="F"), self.headings.copy()
        self._injected = self.recovery.inject(positions, headings, move_injected, self.rngs[0])
        self._injected_step = self.steps_done + 1
        self.positions, self.headings = positions, headings

    @property
    def injected(self) -> np.ndarray | None:
        """Which particles this step's recovery replaced by injected draws (bool, (N,)), or None."""
        return self._injected if self._injected_step == self.steps_done else None

    @property
    def injection_probability(self) -> float:
        """The recovery's injection probability now (0 without recovery)."""
        return 0.0 if self.recovery is None else self.recovery.injection_probability

    def track_likelihood(self, log_w_avg: np.ndarray | float, z: np.ndarray | float) -> None:
        """Hand recovery this step's w_avg, log p(z_k | z_1:k-1) estimated (one run).

        Parameters
        ----------
        log_w_avg : float or array of one
            log w_avg.
        z : float or array of one
            z_k.
        """
        if self.recovery is not None:
            self.recovery.track(float(np.asarray(log_w_avg).item()), float(np.asarray(z).item()))

    # -- the weights ---------------------------------------------------------------------------------
    def normalise(self, log_w: np.ndarray, z: np.ndarray, lost: np.ndarray | None = None) -> None:
        """W_i ∝ exp(log w_i): normalise each run's log weights (R, N) and keep them; a run whose total
        underflows (no particle explains z_k), or that is `lost` (bool (R,)), starts again from the prior
        (uniform over the free area), weighted by its own z_k (`reinitialised_at` lists the step).

        The compiled backend reads the step's weights, ESS, mean and confidence in the same passes;
        they are kept for the reads of this step.

        Parameters
        ----------
        log_w : array (R, N)
            Unnormalised log weights of the particles in `positions`.
        z : array (R,)
            z_k of each run (a restarted run is weighted by it).
        lost : bool array (R,), optional
            Runs to restart whatever their weights.
        """
        # the last step's weights and reads go first (the new ones replace them), so that the compiled
        # backend writes the new ones into their arrays, unless something else still holds them
        self._summary_of, self._summary, self._log_w = None, {}, None
        totals, log_weights, reads = self.ops.normalise(log_w, self.positions)
        explained = totals >= LOG_UNDERFLOW  # False for an underflow and for NaN
        if lost is not None:
            explained &= ~lost
        restarted = np.flatnonzero(~explained)
        if len(restarted):
            log_weights = self._reinitialise(restarted, z, log_weights)
        self._log_w = log_weights
        if reads is not None and len(restarted) < self.runs:
            self._keep_reads(reads, restarted)

    def normalised(self, log_a: np.ndarray, log_b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """W_i ∝ exp(log a_i + log b_i) per run, and log sum_i exp(log a_i + log b_i) (the APF's first
        stage, W_{k-1} p(z_k | mu_k), and its total F), without changing the filter's weights.

        Parameters
        ----------
        log_a, log_b : arrays (R, N)

        Returns
        -------
        (W (R, N), log totals (R,)); a run whose total is -inf gets NaN weights
        """
        return self.ops.normalised(log_a, log_b)

    def set_uniform_weights(self, runs: np.ndarray | None = None) -> None:
        """W_i = 1 / N for the given runs (None: every run): the weights after a resampling.

        Parameters
        ----------
        runs : int array, optional
        """
        log_weights = np.empty((self.runs, self.count)) if runs is None else self._log_w.copy()
        log_weights[slice(None) if runs is None else runs] = -math.log(self.count)
        self._log_w = log_weights

    @property
    def log_weights(self) -> np.ndarray:
        """log W_i, normalised: (N,) for one run, (R, N) for R runs."""
        return self._log_w[0] if self.runs == 1 else self._log_w

    @log_weights.setter
    def log_weights(self, values: np.ndarray) -> None:
        self._log_w = np.asarray(values, dtype=float).reshape(self.runs, -1)

    @property
    def run_log_weights(self) -> np.ndarray:
        """log W_i per run, shape (R, N) (for one run: one row), normalised."""
        return self._log_w

    @property
    def run_weights(self) -> np.ndarray:
        """W_i = exp(log W_i) per run, shape (R, N)."""
        return self._cached("weights", lambda: np.exp(self._log_w))

    @property
    def weights(self) -> np.ndarray:
        """The normalised weights W_i: (N,) for one run, (R, N) for R runs."""
        return self._one(self.run_weights)

    # -- the weighted posterior: what the estimate, the ESS and the drawing read ------------------------
    @property
    def run_ess(self) -> np.ndarray:
        """N_eff = 1 / sum_i W_i^2 per run, shape (R,)."""
        return self._cached("ess", lambda: self.ops.effective_sample_size(self.run_weights))

    @property
    def ess(self) -> float | np.ndarray:
        """N_eff = 1 / sum_i W_i^2: a float for one run, (R,) for R runs."""
        return float(self.run_ess[0]) if self.runs == 1 else self.run_ess

    @property
    def mean(self) -> np.ndarray:
        """The posterior mean sum_i W_i x_i: (2,) for one run, (R, 2) for R runs."""
        return self._one(self._cached("mean", lambda: self.ops.weighted_mean(self.run_weights, self.positions))).copy()

    @property
    def modes(self) -> list[Mode] | list[list[Mode]]:
        """The cloud's modes (connected occupied bins, mazelab.modes), heaviest first; a list per run for R runs."""
        return self._one(self._run_modes())

    @property
    def estimate(self) -> np.ndarray:
        """The posterior mean (the paper's), or the heaviest mode's mean: (2,), or (R, 2) for R runs."""
        return self._one(self._estimates()).copy()

    @property
    def is_confident(self) -> bool | np.ndarray:
        """At least 95% of the weight lies within distance 1 of the estimate (the paper's green circle)."""
        share = self._cached(
            "confident",
            lambda: self.ops.mass_within(self.run_weights, self.positions, self._estimates(), CONFIDENCE_RADIUS),
        )
        confident = share >= CONFIDENCE_SHARE
        return bool(confident[0]) if self.runs == 1 else confident

    @property
    def reinitialised_at(self) -> list[int] | list[list[int]]:
        """The steps at which no particle explained z and the filter restarted (a list per run for R runs)."""
        return self._one(self._reinitialised)

    def belief(self) -> Particles:
        """What the viewer draws: the particles (one run).

        Returns
        -------
        Particles
        """
        return Particles(self.positions, self.weights, self.headings, self.injected, self.modes, self.kld is not None)

    # -- R runs together: the blocks of the run axis ------------------------------------------------------
    def run_positions(self, run: int) -> np.ndarray:
        """Run `run`'s particles.

        Parameters
        ----------
        run : int

        Returns
        -------
        array (N, 2), a view of `positions`
        """
        return self.positions[run * self.count : (run + 1) * self.count]

    def replace_runs(self, x: np.ndarray, headings: np.ndarray, runs: np.ndarray | None = None) -> None:
        """New particles (len(runs) * N, 2) and headings for the given runs (None: every run); the other
        runs keep theirs.

        Parameters
        ----------
        x : array (len(runs) * N, 2)
        headings : array (len(runs) * N,)
        runs : int array, optional
        """
        if runs is None:
            self.positions, self.headings, self.count = x, headings, len(x) // self.runs
            return
        self.positions = replace_blocks(self.positions, x, runs, self.count)
        self.headings = replace_blocks(self.headings, headings, runs, self.count)

    def all_runs(self, log_w: np.ndarray | None, runs: np.ndarray | None) -> np.ndarray:
        """Log weights (R, N) with the given runs' rows from `log_w` (None: every run's; the other runs
        restart: zeros).

        Parameters
        ----------
        log_w : array (len(runs), N), or None
        runs : int array, or None

        Returns
        -------
        array (R, N)
        """
        if runs is None:
            return log_w
        full = np.zeros((self.runs, self.count), dtype=np.float32 if log_w is None else log_w.dtype)
        if log_w is not None:
            full[runs] = log_w
        return full

    def _estimates(self) -> np.ndarray:
        """The estimate of each run, (R, 2) float64."""
        if self.estimate_rule == "mode":
            means = self._cached("mean", lambda: self.ops.weighted_mean(self.run_weights, self.positions))
            return np.stack([m[0].mean if m else mean for m, mean in zip(self._run_modes(), means, strict=True)])
        return self._cached("mean", lambda: self.ops.weighted_mean(self.run_weights, self.positions))

    def _run_modes(self) -> list[list[Mode]]:
        """Each run's modes, heaviest first."""
        return self._cached(
            "modes", lambda: [find_modes(self.run_positions(r), w) for r, w in enumerate(self.run_weights)]
        )

    def _one(self, per_run: Any) -> Any:
        """Run 0's value for one run (the paper's shapes), all runs' otherwise."""
        return per_run[0] if self.runs == 1 else per_run

    def _keep_reads(self, reads: dict[str, np.ndarray], restarted: np.ndarray) -> None:
        """Keep the reads the compiled normalisation made (weights, ESS, mean, and the confidence share
        around the mean, the estimate unless the estimate is the heaviest mode) for this step's reads;
        the restarted runs' are made from their new weights as a run of their own makes them, so that R
        runs together stay R single runs."""
        weights, ess, mean, share = reads["weights"], reads["ess"], reads["mean"], reads["share"]
        if len(restarted):
            weights[restarted] = np.exp(self._log_w[restarted])
            points = np.concatenate([self.run_positions(run) for run in restarted])
            ess[restarted] = self.ops.effective_sample_size(weights[restarted])
            mean[restarted] = self.ops.weighted_mean(weights[restarted], points)
            share[restarted] = self.ops.mass_within(weights[restarted], points, mean[restarted], CONFIDENCE_RADIUS)
        self._summary_of = (self.positions, self._log_w)
        self._summary = {"weights": weights, "ess": ess, "mean": mean}
        if self.estimate_rule != "mode":
            self._summary["confident"] = share

    def _cached(self, name: str, compute: Callable[[], Any]) -> Any:
        """`compute()`, remembered until `positions` or the log weights are assigned a new array."""
        described = self._summary_of
        if described is None or described[0] is not self.positions or described[1] is not self._log_w:
            self._summary_of, self._summary = (self.positions, self._log_w), {}
        if name not in self._summary:
            self._summary[name] = compute()
        return self._summary[name]

    def _reinitialise(self, runs: np.ndarray, z: np.ndarray, log_weights: np.ndarray) -> np.ndarray:
        """The given runs start again from the prior (uniform over the free area), weighted by their z;
        returns the log weights with theirs replaced."""
        if self.kld is not None:  # the prior is as spread as a belief gets: the most particles (R = 1)
            self.count = self.max_count
            self.positions = np.empty((self.count, 2), dtype=PARTICLE_DTYPE, order="F")
            self.headings = np.zeros(self.count, dtype=PARTICLE_DTYPE)
            log_weights = np.empty((1, self.count))
        else:
            self.positions = self.positions.copy(order="F")
        for run in runs:
            self._reinitialised[run].append(self.steps_done + 1)
            rows = slice(run * self.count, (run + 1) * self.count)
            self.positions[rows] = self.world.random_free_places(self.count, self.rngs[run])
            log_w = log_likelihood(float(z[run]), self.positions[rows], self.world, self.sigma, self.outside_penalty)
            total = log_sum_exp(log_w)
            uniform = total < LOG_UNDERFLOW
            log_weights[run] = -math.log(self.count) if uniform else np.subtract(log_w, total, dtype=float)
        return log_weights


def _check_parts(values: Mapping[str, Any]) -> None:
    """The options that build a part together (recovery and its rates, KLD-sampling and its numbers),
    checked as the constructor builds them: alpha_slow above alpha_fast is refused here, in one line."""
    recovery_options(values["recovery"], values["alpha_slow"], values["alpha_fast"])
    kld_options(values["kld"], values["kld_epsilon"], values["kld_z"])


__all__ = ["ParticleFilter", "per_run"]
