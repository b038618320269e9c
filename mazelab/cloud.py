"""The particle filter of the lost robot: the step template (mazelab.engine) on the robot's model
(mazelab.model.LostRobot), with the lab's options; mazelab.filters writes SIR, the APF and the RPF as
its hooks.

A student reads one run: `positions` (N, 2) float32, `weights` (N,), `estimate` (2,), `ess` a float.
Every option is declared once in `options` (mazelab.declaration): the constructor takes its defaults
from there and checks the values there. The same object also advances R runs of one setting together
(a batched study), bit for bit R single runs (mazelab.engine). Recovery from kidnapping and
KLD-sampling are hooks of the resampling here; they vary one run's particles, so they need R = 1.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from types import MappingProxyType
from typing import Any, ClassVar

import numpy as np

from mazelab.backend import kernels_for
from mazelab.checks import check_sigma_within
from mazelab.constants import CONFIDENCE_RADIUS, CONFIDENCE_SHARE, PARTICLE_DTYPE
from mazelab.contract import Particles
from mazelab.declaration import Option, Options, number_in, options_of
from mazelab.engine import SMC
from mazelab.maze import Maze, check_world
from mazelab.model import OUTSIDE_PENALTY_OPTION, SPEED_OPTION, LostRobot
from mazelab.modes import ESTIMATE_OPTION, Mode, find_modes
from mazelab.recovery import RECOVERY_OPTIONS, RecoveryTracker, recovery_options
from mazelab.resampling import (
    KLD_OPTIONS,
    RESAMPLING_OPTION,
    KLDSampling,
    kld_options,
    kld_resample,
    resampling_scheme,
    systematic_resample,
)
from mazelab.run_axis import as_runs, generators

THRESHOLD_OPTION = Option(
    "threshold", 1.0, "resample when ESS < threshold * N (adaptive resampling); 1: every step (the paper's)",
    check=number_in("threshold", 0.0, 1.0, what=" (a share of N)"), flag="--threshold",
)  # fmt: skip


class ParticleFilter(SMC):
    """Weighted particles {x_i, W_i} approximating the posterior p(x_k | z_1:k), stepped by the template
    (mazelab.engine.SMC: resample when it is time, move, reweight) on the lost robot's model.

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
    rather than writing into them; to change them, assign new arrays (the estimate and the confidence
    are computed once per assignment and cached).

    The hot parts (the move, the likelihood, systematic resampling, the normalisation and the reads, the
    RPF's jitter) run on `ops`, numpy's or the compiled kernels (mazelab.backend: `backend` names the
    one chosen when the filter was made). The compiled kernels reuse their arrays once nothing else
    holds them, so an array kept from an earlier step is never written over.
    """

    name: ClassVar[str] = "ParticleFilter"
    options: ClassVar[Options] = Options(
        THRESHOLD_OPTION,
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
        self.model = LostRobot(self.world, sigma, delta, self.ops, settings["speed"], settings["outside_penalty"])
        self.threshold = settings["threshold"]
        self.estimate_rule = settings["estimate"]
        self.scheme_name = settings["resampling"]
        self.scheme = resampling_scheme(self.scheme_name)
        runs_particles = as_runs(particles)  # (R, N, 2), float64 (checked; the given array where it is one)
        runs, self.count = runs_particles.shape[:2]
        self.positions = np.asfortranarray(runs_particles.reshape(-1, 2), dtype=PARTICLE_DTYPE)  # (R*N, 2)
        del runs_particles  # a float64 copy goes before the filter's arrays are made (a million particles: 16 MB)
        self.headings = np.zeros(len(self.positions), dtype=PARTICLE_DTYPE)  # each particle's last motion angle
        self.start_runs(generators(rng, runs))
        self._reads_of: tuple[np.ndarray, Any] | None = None  # the arrays _reads describe
        self._reads: dict[str, Any] = {}
        # the parts beyond the paper, off by default
        recovering = recovery_options(settings["recovery"], settings["alpha_slow"], settings["alpha_fast"])
        self.recovery = None if recovering is None else RecoveryTracker(recovering, world, sigma)
        self.kld: KLDSampling | None = kld_options(settings["kld"], settings["kld_epsilon"], settings["kld_z"])
        self.max_count = self.count if self.kld is None or self.kld.max_count is None else self.kld.max_count
        if self.runs > 1 and (self.recovery is not None or self.kld is not None):
            raise ValueError("recovery and KLD-sampling vary one run's particles: they run one run at a time")
        self._injected: np.ndarray | None = None
        self._kld_moved: list[np.ndarray] | None = None  # KLD-sampling: the moves made as the ancestors were drawn
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

    @property
    def diagnostics(self) -> dict[str, Any]:
        """This step's figures of the filter's own, by name (recorded per step in RunResult.extras and a
        study's traces): recovery's injection probability when recovery is on."""
        return {} if self.recovery is None else {"injection_probability": self.injection_probability}

    # -- the model, for the runs the engine serves now -------------------------------------------------
    def transition(self, points: np.ndarray, ancestors: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """x_k ~ p(x_k | x_{k-1}), equation (1), of `points` (or of points[ancestors]).

        Parameters
        ----------
        points : array (R*N, 2)
        ancestors : int array, optional

        Returns
        -------
        (positions, headings)
        """
        selected = self._selected
        if selected is None:  # every run
            return self.model.transition(points, self.compass_angles, self.rngs, ancestors)
        rngs = [self.rngs[r] for r in selected]
        return self.model.transition(points, self.compass_angles[selected], rngs, ancestors)

    def log_likelihood(self, points: np.ndarray) -> np.ndarray:
        """log p(z_k | x), equation (3) with the outside penalty.

        Parameters
        ----------
        points : array (R*N, 2)

        Returns
        -------
        array (R, N)
        """
        return self.model.log_likelihood(self.selected_rows(self.measurements), points)

    def ancestors(self, W: np.ndarray) -> np.ndarray:
        """RESAMPLE: a^i ~ W, N ancestors of each row by the scheme the `resampling` option names:
        mazelab.resampling.systematic_resample by default (the textbook: u ~ U[0, 1), the points
        (u + arange(N)) / N, the inverse CDF), run on the backend in its counting form (the same
        ancestors); with KLD-sampling as many as Fox's bound asks, each drawn with its move.

        Parameters
        ----------
        W : array (R, N)
            The normalised first-stage weights of every run (the served ones are resampled).

        Returns
        -------
        int array
            Indices into `positions`.
        """
        if self.kld is not None:
            return self.kld_ancestors(self.selected_rows(W))
        return self.scheme_ancestors(self.scheme, self.selected_rows(W))  # scheme: resampling.systematic_resample

    def scheme_ancestors(self, scheme: Callable[..., np.ndarray], weights: np.ndarray) -> np.ndarray:
        """`scheme` (weights, rng) -> ancestors applied to each served run's row with its own Generator;
        systematic_resample as its counting form on the backend, all runs at once (the same ancestors).

        Parameters
        ----------
        scheme : callable
            A scheme of mazelab.resampling.
        weights : array (R, N)
            The normalised weights of the runs served now, one row each.

        Returns
        -------
        int array
            Indices into `positions`.
        """
        runs = self.selected_runs
        if scheme is systematic_resample:  # one offset per run, the counting done for all runs at once
            rngs = self.rngs if self._selected is None else [self.rngs[run] for run in runs]
            uniforms = rngs[0].random(1) if len(rngs) == 1 else np.array([rng.random() for rng in rngs])
            ancestors = self.ops.systematic(weights, uniforms, None, self.count)
            if self._selected is not None:  # block b is run runs[b]'s
                ancestors += np.repeat(self.count * (runs - np.arange(len(runs))), self.count).astype(ancestors.dtype)
            return ancestors
        rows = zip(runs, weights, strict=True)
        return np.concatenate([scheme(w, self.rngs[run]) + run * self.count for run, w in rows])

    def normal_draws(self, count: int) -> np.ndarray:
        """eps ~ N(0, I_2), (count, 2) in PARTICLE_DTYPE, each run's block from its own Generator.

        Parameters
        ----------
        count : int
            The draws of all the runs served now.

        Returns
        -------
        array (count, 2)
        """
        runs = self.selected_runs
        size = count // len(runs)
        eps = self.ops.buffer("eps", (count, 2), PARTICLE_DTYPE)
        for block, run in enumerate(runs):
            self.rngs[run].standard_normal(dtype=PARTICLE_DTYPE, out=eps[block * size : (block + 1) * size])
        return eps

    # -- KLD-sampling and recovery: hooks of the resampling (one run) --------------------------------
    def kld_ancestors(self, weights: np.ndarray) -> np.ndarray:
        """KLD-sampling (one run): as many ancestors as Fox's bound asks, each batch moved as it is drawn
        (`move_after_resampling`), the moves kept for `moved_after_resampling`.

        Parameters
        ----------
        weights : array (1, N)

        Returns
        -------
        int array (n,)
        """
        ancestors, *self._kld_moved = kld_resample(
            weights[0], self.move_after_resampling, self.kld, self.scheme, self.rngs[0], self.max_count
        )
        return ancestors

    def moved_after_resampling(self, ancestors: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """`move_after_resampling` (with KLD-sampling: the moves made as the ancestors were drawn); with
        recovery, then each particle replaced with the injection probability by an injected point.

        Parameters
        ----------
        ancestors : int array

        Returns
        -------
        (positions, headings)
        """
        if self.kld is None:
            positions, headings = super().moved_after_resampling(ancestors)
        else:  # one run (R = 1)
            (positions, headings), self._kld_moved = self._kld_moved, None
        self._injected, self._injected_step = None, self.steps_done + 1
        if self.recovery is not None:  # one run (R = 1); the injection writes into the headings (the RPF's read-only)
            headings = np.require(headings, requirements="W")
            self._injected = self.recovery.inject(positions, headings, self.move_injected, self.rngs[0])
        return positions, headings

    def move_injected(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Recovery's injected points as the resampled ones move: by the transition, or (when every
        particle takes the transition after, the RPF) unmoved, with zero headings."""
        return self.transition(points) if self.moved_by_resampling else _unmoved(points)

    def between_resamplings(self) -> None:
        """Recovery between resamplings: replace particles with the injection probability, each injected
        point keeping the weight of the particle it replaces (the selection ignores the weights, so the
        set represents the same mixture (1 - p) belief + p injection as injecting at a resampling); the
        transition follows."""
        if self.injection_probability > 0:
            positions, headings = self.positions.copy(order="F"), self.headings.copy()
            self._injected = self.recovery.inject(positions, headings, _unmoved, self.rngs[0])
            self._injected_step = self.steps_done + 1
            self.positions, self.headings = positions, headings

    def after_reweighting(self, increments: np.ndarray) -> None:
        """Hand recovery this step's w_avg, the estimate of p(z_k | z_1:k-1) (one run)."""
        if self.recovery is not None:
            self.track_likelihood(increments[0], self.measurements[0])

    def restart_count(self) -> int:
        """The particles a restarted run takes: N, or with KLD-sampling the most (the prior is as
        spread as a belief gets)."""
        return self.count if self.kld is None else self.max_count

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

    def replace_runs(self, positions: np.ndarray, headings: np.ndarray, runs: np.ndarray) -> None:
        """The engine's replacement of the runs' particles; the reads kept for the old ones go with them
        (so that the compiled backend may reuse their arrays within the step: the RPF's move)."""
        self._reads_of, self._reads = None, {}
        super().replace_runs(positions, headings, runs)

    # -- the weights' arithmetic on the backend --------------------------------------------------------
    def normalise_rows(self, log_w: np.ndarray, positions: np.ndarray) -> tuple[np.ndarray, Any, Any]:
        """The backend's normalisation (the compiled one reads W, ESS, mean and confidence in its passes)."""
        self._reads_of, self._reads = None, {}  # the compiled backend may reuse the last step's arrays
        return self.ops.normalise(log_w, positions)

    def normalised(
        self, log_a: np.ndarray, log_b: np.ndarray, shifts: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """The backend's W ∝ exp(log_a - shifts + log_b) per run, and the log totals (the APF's first stage)."""
        return self.ops.normalised(log_a, log_b, shifts)

    def reweighted(self, log_a: np.ndarray, log_lik: np.ndarray, shifts: np.ndarray | None = None) -> np.ndarray:
        """The backend's log W_{k-1} + log p(z_k | x_k) (the compiled one float32, into log_lik's array)."""
        return self.ops.reweighted(log_a, log_lik, shifts)

    def kept_reads(self, reads: Any, restarted: np.ndarray, log_weights: np.ndarray | None) -> tuple[Any, Any]:
        """Keep the reads the compiled normalisation made (weights, ESS, mean, and the confidence share
        around the mean, the estimate unless the estimate is the heaviest mode) for this step's reads;
        the restarted runs' are made from their new weights as a run of their own makes them, so that R
        runs together stay R single runs."""
        if reads is None or len(restarted) == self.runs:
            return None, None
        weights, ess, mean, share = reads["weights"], reads["ess"], reads["mean"], reads["share"]
        if len(restarted):  # read from float64 W, as a run alone derives its W (and its reads) from log W
            fresh = np.exp(log_weights[restarted])
            weights[restarted] = fresh
            points = np.concatenate([self.run_positions(run) for run in restarted])
            ess[restarted] = self.ops.effective_sample_size(fresh)
            mean[restarted] = self.ops.weighted_mean(fresh, points)
            share[restarted] = self.ops.mass_within(fresh, points, mean[restarted], CONFIDENCE_RADIUS)
        self._kept = {"mean": mean} if self.estimate_rule == "mode" else {"mean": mean, "confident": share}
        return weights, ess

    def normalise(
        self, log_w: np.ndarray | list[np.ndarray], fresh: tuple[np.ndarray, Any] | None = None
    ) -> np.ndarray:
        """The engine's normalisation (restarts included), the reads the backend made kept for this step."""
        self._kept: dict[str, Any] = {}
        totals = super().normalise(log_w, fresh)
        if self._kept:
            self._reads_of, self._reads = (self.positions, self.weights_value), self._kept
        return totals

    # -- the weighted posterior: what the estimate and the drawing read ---------------------------------
    @property
    def run_weights(self) -> np.ndarray:
        """W_i per run, shape (R, N)."""
        return self.weights_value.W

    @property
    def mean(self) -> np.ndarray:
        """The posterior mean sum_i W_i x_i: (2,) for one run, (R, 2) for R runs."""
        return self._one(self._means()).copy()

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
        return bool(share[0] >= CONFIDENCE_SHARE) if self.runs == 1 else share >= CONFIDENCE_SHARE

    def belief(self) -> Particles:
        """What the viewer draws: the particles (one run).

        Returns
        -------
        Particles
        """
        return Particles(self.positions, self.weights, self.headings, self.injected, self.modes, self.kld is not None)

    def _means(self) -> np.ndarray:
        """The posterior mean of each run, (R, 2) float64."""
        return self._cached("mean", lambda: self.ops.weighted_mean(self.run_weights, self.positions))

    def _estimates(self) -> np.ndarray:
        """The estimate of each run, (R, 2) float64."""
        if self.estimate_rule == "mode":
            return np.stack(
                [m[0].mean if m else mean for m, mean in zip(self._run_modes(), self._means(), strict=True)]
            )
        return self._means()

    def _run_modes(self) -> list[list[Mode]]:
        """Each run's modes, heaviest first."""
        return self._cached(
            "modes", lambda: [find_modes(self.run_positions(r), w) for r, w in enumerate(self.run_weights)]
        )

    def _cached(self, name: str, compute: Callable[[], Any]) -> Any:
        """`compute()`, remembered until `positions` or the weights are assigned anew."""
        described = self._reads_of
        if described is None or described[0] is not self.positions or described[1] is not self.weights_value:
            self._reads_of, self._reads = (self.positions, self.weights_value), {}
        if name not in self._reads:
            self._reads[name] = compute()
        return self._reads[name]


def _unmoved(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Injected points as they are (the step's transition moves them next), with zero headings."""
    return points, np.zeros(len(points), dtype=PARTICLE_DTYPE)


def _check_parts(values: Mapping[str, Any]) -> None:
    """The options that build a part together (recovery and its rates, KLD-sampling and its numbers),
    checked as the constructor builds them: alpha_slow above alpha_fast is refused here, in one line, and
    so is a rate or number given while the part it tunes is off (it would be silently unused)."""
    tuned = {"recovery": ("alpha_slow", "alpha_fast"), "kld": ("kld_epsilon", "kld_z")}
    for part, numbers in tuned.items():
        changed = [n for n in numbers if values[n] != ParticleFilter.options[n].default]
        if values[part] in (None, False) and changed:
            on, off = (ParticleFilter.options[n].flag or f"--option {n}=..." for n in (part, changed[0]))
            raise ValueError(f"{changed[0]} tunes {part}, which is off: give {on} too (or leave out {off})")
    recovery_options(values["recovery"], values["alpha_slow"], values["alpha_fast"])
    kld_options(values["kld"], values["kld_epsilon"], values["kld_z"])


__all__ = ["THRESHOLD_OPTION", "ParticleFilter"]
