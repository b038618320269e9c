"""The paper's particle filters: SIR, APF and RPF (Arulampalam, Maskell, Gordon, Clapp 2002,
Algorithms 4, 5 and 6) with the paper's refinements, weights in the log domain.

Each is the step (mazelab.smc.SMC.step: resample the runs it is time for, move, reweight) on the lost
robot's model (mazelab.model.LostRobot) with its own hooks: SIR is the step's defaults (Algorithm 4);
the APF adds the first stage (`log_eta`) and the second-stage weights (`reweight_resampled`, Algorithm
5); the RPF resamples when N_eff < N_T and jitters the resampled particles (`move_resampled`) before
every particle takes the transition (Algorithm 6). `ParticleFilter`, their base, holds what they share:
the options, the backend, the resampling scheme, the estimate and the green circle, and KLD-sampling
(a scheme that draws as many ancestors as Fox's bound asks) and recovery from kidnapping (an override
of the move), one run each (R = 1).

A student reads one run: `positions` (N, 2) float32, `weights` (N,), `estimate` (2,), `ess` a float;
the same object advances R runs of one setting together (a batched study), bit for bit R single runs.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable, Mapping
from types import MappingProxyType
from typing import Any, ClassVar

import numpy as np

from mazelab.backend import kernels_for
from mazelab.checks import check_sigma_within
from mazelab.constants import CONFIDENCE_RADIUS, CONFIDENCE_SHARE, PARTICLE_DTYPE, RPF_THRESHOLD
from mazelab.contract import Particles
from mazelab.declaration import Option, Options, number_in, options_of
from mazelab.maze import Maze, check_world
from mazelab.model import MODEL_OPTIONS, LostRobot
from mazelab.modes import ESTIMATE_OPTION, Mode, find_modes
from mazelab.numpy_ops import keep_freed_memory
from mazelab.recovery import RECOVERY_OPTIONS, RecoveryTracker, recovery_options
from mazelab.regularisation import BANDWIDTH_OPTION, GaussianKernel, Kernel, mixture_kernel, optimal_bandwidth
from mazelab.resampling import KLD_OPTIONS, RESAMPLING_OPTION, RESAMPLING_SCHEMES, kld_options, kld_resample
from mazelab.smc import SMC, particles_array
from mazelab.weights import Weights, weighted_covariance


class ParticleFilter(SMC):
    """Weighted particles {x_i, W_i} approximating the posterior p(x_k | z_1:k), stepped by
    mazelab.smc.SMC on the lost robot's model.

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
    `positions` are float32 (PARTICLE_DTYPE), log weights float64 on the numpy backend. The hot parts
    (the move, the likelihood, the weights and their reads, the RPF's jitter) run on `ops`, numpy's or
    the compiled kernels (mazelab.backend: `backend` names the one chosen when the filter was made).
    """

    name: ClassVar[str] = "ParticleFilter"
    options: ClassVar[Options] = Options(
        Option(
            "threshold",
            1.0,
            "resample when ESS < threshold * N (adaptive resampling); 1: every step (the paper's)",
            check=number_in("threshold", 0.0, 1.0, what=" (a share of N)"),
            flag="--threshold",
        ),
        RESAMPLING_OPTION,
        *MODEL_OPTIONS,
        *RECOVERY_OPTIONS,
        *KLD_OPTIONS,
        ESTIMATE_OPTION,
        check=lambda values: _check_parts(values),
    )
    ONE_RUN_OPTIONS: ClassVar[tuple[str, ...]] = ("recovery", "kld")  # options that need R = 1
    moved_by_resampling: ClassVar[bool] = True  # the resampled particles take the transition as they are drawn

    def __init_subclass__(cls, **kwargs: Any) -> None:
        """A subclass is named after itself unless it sets `name` (results and the viewer label it so),
        and its `options` are Options (a plain mapping read by `options_of`)."""
        super().__init_subclass__(**kwargs)
        if "name" not in cls.__dict__:
            cls.name = cls.__name__
        cls.options = options_of(cls)

    def __init__(self, world: Maze, sigma: float, delta: float, particles: np.ndarray, rng: Any = None, **options: Any):
        settings = type(self).options.resolve(options, self.name)  # defaults filled in, each value checked
        self.settings: Mapping[str, Any] = MappingProxyType(settings)
        self.world, self.sigma, self.delta = check_world(world), sigma, delta
        check_sigma_within(sigma, world.width, world.height)
        self.ops = kernels_for(self.world)  # the hot operations: numpy's or compiled (mazelab.backend)
        keep_freed_memory()  # a step's freed arrays reused, not given back and faulted in again
        self.backend: str = self.ops.name
        model = LostRobot.of_settings(self.world, sigma, delta, self.ops, settings)
        self.threshold = settings["threshold"]
        self.kld = kld_options(settings["kld"], settings["kld_epsilon"], settings["kld_z"])
        # the scheme: mazelab.resampling's textbook function, or the backend's faster form of it
        scheme = self.ops.schemes.get(settings["resampling"]) or RESAMPLING_SCHEMES[settings["resampling"]]
        if not hasattr(type(self), "resample"):  # a plug-in's own `resample` is its scheme
            self.resample = scheme if self.kld is None else functools.partial(self.kld_resample, scheme)
            if self.kld is None:  # mazelab.resampling's schemes and the backend's draw every due run in one call
                self.resample_rows = scheme
        super().__init__(model, particles, rng, self.ops.Weights)
        recovering = recovery_options(settings["recovery"], settings["alpha_slow"], settings["alpha_fast"])
        self.recovery = None if recovering is None else RecoveryTracker(recovering, world, model.sensor)
        self.max_count = self.count if self.kld is None or self.kld.max_count is None else self.kld.max_count
        if self.runs > 1 and not self.runs_together(settings):
            raise ValueError("recovery and KLD-sampling vary one run's particles: they run one run at a time")
        self._injected: tuple[int, np.ndarray | None] = (0, None)  # (the step, recovery's injected particles)
        self._resampled: list[np.ndarray] = []  # each step's due mask (resampled_at)
        self._reads: tuple[Any, dict[str, Any]] = (None, {})  # (the x and W read, the reads)

    @classmethod
    def runs_together(cls, options: Mapping[str, Any]) -> bool:
        """Whether several runs with these options can advance together (R > 1): not with recovery or
        KLD-sampling, which vary one run's particles (such runs go one at a time)."""
        return not any(options.get(name) not in (None, False, "none") for name in cls.ONE_RUN_OPTIONS)

    @property
    def diagnostics(self) -> dict[str, Any]:
        """This step's figures of the filter's own, by name (recorded per step in RunResult.extras and a
        study's traces): recovery's injection probability when recovery is on."""
        return {} if self.recovery is None else {"injection_probability": self.recovery.injection_probability}

    def step(self, compass_angle: float | np.ndarray, z: float | np.ndarray) -> None:
        """SMC.step; its due mask kept (`resampled_at`); recovery then tracks w_avg, this step's estimate
        of p(z_k | z_1:k-1) (one run).

        Parameters
        ----------
        compass_angle, z : float, or arrays (R,)
        """
        super().step(compass_angle, z)
        self._resampled.append(self.resampled_now)
        if self.recovery is not None:
            self.recovery.track(float(self.log_evidence_increment[0]), self.z[0])  # run 0's reading, as it came

    # -- the ancestors and the move: KLD-sampling and recovery (one run) ---------------------------------
    def kld_resample(self, scheme: Callable[..., np.ndarray], W: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """KLD-sampling's scheme (one run): as many ancestors as Fox's bound asks, drawn by `scheme` in
        batches, each batch moved as it is drawn (the moves kept for `move`).

        Parameters
        ----------
        scheme : callable
            The `resampling` option's scheme.
        W : array (N,)
        rng : numpy.random.Generator

        Returns
        -------
        int array (M,)
        """
        A, *moved = kld_resample(W, self._move_one, self.kld, scheme, rng, self.max_count)
        self._kld_moved = tuple(values[None] for values in moved)
        return A

    def _move_one(self, A: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """KLD-sampling's batch of one run's ancestors (M,) moved: (positions (M, 2), headings (M,))."""
        x, headings = self.move_resampled(self.x, A[None], np.ones(1, dtype=bool))
        return x[0], headings[0]

    def move(self, x: np.ndarray, A: np.ndarray | None, due: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The resampled particles by `move_resampled` (with KLD-sampling: as they were drawn); with
        recovery, each particle then replaced with the injection probability by an injected point;
        then the transition for those that have not taken it (the RPF's: every particle)."""
        if A is None:  # no run resamples: recovery injects before the move (one run, unless it is lost)
            if self.recovery is not None and self.recovery.injection_probability > 0 and self.movers is self.rngs:
                x, headings = particles_array(x, x.dtype), self.headings.copy()
                self._inject(x, headings, moved=False)
            return self.transition(x)
        if self.kld is not None:
            x, headings = self._kld_moved
        else:
            x, headings = self.move_resampled(x, A, due)
        if self.recovery is not None:
            headings = np.require(headings, requirements="W")
            self._inject(x, headings, moved=self.moved_by_resampling)
        return (x, headings) if self.moved_by_resampling else self.transition(x)

    def move_resampled(self, x: np.ndarray, A: np.ndarray, due: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The resampled particles: x_k^i ~ p(x_k | x_{k-1}^{a^i}), the transition as they are drawn."""
        return self.transition(x, A)

    def _inject(self, x: np.ndarray, headings: np.ndarray, moved: bool) -> None:
        """Recovery (one run): particles replaced in place, each with the injection probability, by
        draws from the free area (moved by the transition when the resampled ones were)."""
        move = self._transition_one if moved else _unmoved
        self._injected = (self.steps_done + 1, self.recovery.inject(x[0], headings[0], move, self.rngs[0]))

    def _transition_one(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Recovery's injected points (M, 2) through the transition: (positions (M, 2), headings (M,))."""
        x, headings = self.transition(points[None])
        return x[0], headings[0]

    def restart_count(self) -> int:
        """The particles a restarted run takes: N, or with KLD-sampling the most (the prior is as
        spread as a belief gets)."""
        return self.count if self.kld is None else self.max_count

    @property
    def resampled_at(self) -> list[int] | list[list[int]]:
        """The steps after which the filter resampled (a list per run for R runs)."""
        runs = np.array(self._resampled, dtype=bool).reshape(-1, self.runs).T  # (R, steps)
        return self._one([np.flatnonzero(row).tolist() for row in runs])

    @property
    def injected(self) -> np.ndarray | None:
        """Which particles this step's recovery replaced by injected draws (bool, (N,)), or None."""
        step, injected = self._injected
        return injected if step == self.steps_done else None

    # -- the weighted posterior: what the estimate and the drawing read ---------------------------------
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
            "confident", lambda: self.ops.mass_within(self.W, self.x, self._estimates(), CONFIDENCE_RADIUS)
        )
        return bool(share[0] >= CONFIDENCE_SHARE) if self.runs == 1 else share >= CONFIDENCE_SHARE

    def belief(self) -> Particles:
        """What the viewer draws: the particles (one run)."""
        return Particles(
            self.positions, self.weights, self.headings[0], self.injected, self.modes, self.kld is not None
        )

    def _means(self) -> np.ndarray:
        """The posterior mean of each run, (R, 2) float64."""
        return self._cached("mean", lambda: self.ops.weighted_mean(self.W, self.x))

    def _estimates(self) -> np.ndarray:
        """The estimate of each run, (R, 2) float64."""
        if self.settings["estimate"] == "mode":
            return np.stack(
                [m[0].mean if m else mean for m, mean in zip(self._run_modes(), self._means(), strict=True)]
            )
        return self._means()

    def _run_modes(self) -> list[list[Mode]]:
        """Each run's modes, heaviest first."""
        return self._cached("modes", lambda: [find_modes(self.x[r], w) for r, w in enumerate(self.W.W)])

    def _cached(self, name: str, compute: Callable[[], Any]) -> Any:
        """`compute()`, remembered while the particles and the weights stay the same objects."""
        of, reads = self._reads
        if of is None or of[0] is not self.x or of[1] is not self.W:
            self._reads = of, reads = (self.x, self.W), {}
        if name not in reads:
            reads[name] = compute()
        return reads[name]


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


class SIRParticleFilter(ParticleFilter):
    """Sampling importance resampling (bootstrap filter), Arulampalam et al. Algorithm 4: the step's
    defaults (mazelab.smc.SMC.step): RESAMPLE, x_k^i ~ p(x_k | x_{k-1}^i), w_k^i = p(z_k | x_k^i)."""

    name = "SIRParticleFilter"


class AuxiliaryParticleFilter(ParticleFilter):
    """Auxiliary particle filter, Arulampalam et al. Algorithm 5, with refinement 2: the auxiliary
    point mu_i is one draw from the transition p(x_k | x_{k-1}^i).

    With threshold < 1 it decides whether to resample on the ESS of W_{k-1}, before the first stage
    (nchopin/particles' APF decides on the first-stage weights' ESS instead)."""

    name = "AuxiliaryParticleFilter"

    def log_eta(self) -> np.ndarray:
        """The first stage's factor: log p(z_k | mu_k^i), mu_k^i ~ p(x_k | x_{k-1}^i) (refinement 2), (R, N)."""
        mu, _ = self.transition(self.x)  # mu_k^i ~ p(x_k | x_{k-1}^i)
        self.log_mu = self.log_likelihood(mu)  # p(z_k | mu_k^i)
        return self.log_mu

    def ancestors(self, W: Weights, due: np.ndarray) -> np.ndarray:
        """ParticleFilter.ancestors of the first-stage weights W_{k-1} eta_k, whose log total F is kept."""
        self.log_F = W.log_total  # log F = log sum_i W_{k-1}^i p(z_k | mu_k^i)
        return super().ancestors(W, due)

    def reweight_resampled(self, log_g: np.ndarray, A: np.ndarray) -> tuple[np.ndarray, Any]:
        """The second stage: w_k^j = p(z_k | x_k^j) / p(z_k | mu_k^{i^j}); its mean times the first
        stage's total F = sum_i W_{k-1}^i p(z_k | mu_k^i) estimates p(z_k | z_1:k-1) (Pitt and Shephard).

        Returns
        -------
        (log w (R, N), log F (R,), or 0.0 when the weights carry F already: recovery's)
        """
        second_stage = self.ops.second_stage(log_g, self.log_mu, A)  # log p(z|x^j) - log p(z|mu^{i^j})
        if self.recovery is None:
            return second_stage, self.log_F
        # recovery's w_avg reads them on the scale of p(z_k | z_1:k-1): F p(z|x^j) / p(z|mu^{i^j}), whose mean
        # is Pitt and Shephard's estimate (normalised: the second stage again); an injected particle has no
        # ancestor and carries p(z|x^j)
        log_w = second_stage + self.log_F.astype(second_stage.dtype)[:, None]
        step, injected = self._injected
        return (log_w if injected is None or step <= self.steps_done else np.where(injected, log_g, log_w)), 0.0


class RegularizedParticleFilter(ParticleFilter):
    """Regularised particle filter, Arulampalam et al. Algorithm 6, with refinements 3-5: the prior
    as proposal, a 2-D Gaussian kernel, and regularisation when N_eff < N_T = threshold * N_S.

    `threshold`: N_T / N_S (the paper's 0.2). `bandwidth`: "optimal" (the paper's h_opt with the whole
    cloud's covariance), "multimodal" (one kernel per mode, beyond the paper) or a number h; see
    mazelab.regularisation. The other options are ParticleFilter's; `resampled_at` lists the steps after
    which it regularised."""

    name = "RegularizedParticleFilter"
    options: ClassVar[Options] = ParticleFilter.options.extend(
        Option(
            "threshold",
            RPF_THRESHOLD,
            "N_T / N_S: regularise when the ESS falls below N_T (refinement 5: 0.2)",
            check=number_in("the RPF threshold", 0.0, 1.0, what=" (N_T = threshold * N_S)"),
            flag="--threshold",
        ),
        BANDWIDTH_OPTION,
    )
    moved_by_resampling = False  # the jittered particles take the transition with the rest

    @property
    def bandwidth(self) -> float:
        """h of the whole-cloud kernel: h_opt = A N^(-1/(n+4)), A = (4/(n+2))^(1/(n+4)) in n = 2
        dimensions, or the number given (with "multimodal" each mode has its own h_opt(n_c))."""
        rule = self.settings["bandwidth"]  # checked by its declaration (check_bandwidth)
        return rule if isinstance(rule, float) else optimal_bandwidth(self.count)

    @property
    def diagnostics(self) -> dict[str, Any]:
        """ParticleFilter's, and whether this step began by regularising (bool, or (R,) for R runs)."""
        now = bool(self.resampled_now[0]) if self.runs == 1 else self.resampled_now.copy()
        return {**super().diagnostics, "regularised": now}

    def move_resampled(self, x: np.ndarray, A: np.ndarray, due: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """IF N_eff < N_T: x^i = x^{a^i} + h D eps, eps ~ N(0, I_2), D D^T = S of the weighted cloud
        (the kernel K_h), in the due runs; the transition of every particle follows.

        Returns
        -------
        (positions (R, M, 2), headings: zeros (the transition that follows sets them))
        """
        rows = np.flatnonzero(due)
        kernels = self.kernels(self.W.W[rows], x[rows])
        jittered = self.ops.jitter(x, A, due, self.rngs, kernels)  # eps ~ N(0, I_2) from each due run's rng
        return jittered, np.zeros(jittered.shape[:2], dtype=x.dtype)

    def reweight_resampled(self, log_g: np.ndarray, A: np.ndarray) -> tuple[np.ndarray, None]:
        """W^i = 1 / N after resampling: w_k^i ∝ W^i p(z_k | x_k^i), whose total estimates p(z_k | z_1:k-1)."""
        return self.ops.equal_weighted(log_g, -math.log(log_g.shape[1])), None  # log W^i + log p(z_k | x_k^i)

    def kernels(self, weights: np.ndarray, clouds: np.ndarray) -> list[Kernel]:
        """Each run's kernel: h D_k with its whole cloud's S_k, or one per mode (multimodal).

        Parameters
        ----------
        weights : array (R, N)
            The runs' normalised weights.
        clouds : array (R, N, 2)
            Their particles.

        Returns
        -------
        list of Kernel, one per run
        """
        if self.settings["bandwidth"] == "multimodal":
            return [mixture_kernel] * len(weights)
        covariance = weighted_covariance(weights, clouds.reshape(-1, 2))  # S_k per run, the weighted covariance
        D = np.linalg.cholesky(covariance + 1e-12 * np.eye(2))  # D_k D_k^T = S_k (tiny ridge: S may be 0)
        return [GaussianKernel(scale) for scale in self.bandwidth * D]


__all__ = [
    "AuxiliaryParticleFilter",
    "ParticleFilter",
    "RegularizedParticleFilter",
    "SIRParticleFilter",
]
