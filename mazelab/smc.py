"""The step every particle filter of the lab runs: nchopin/particles' `SMC.__next__` over R runs at once.

    observe th0_k, z_k; the first stage W_{k-1} eta_k (the APF's; eta = 1 otherwise); due = the runs
    whose time it is to RESAMPLE; A = their ancestors (identity in the other runs); x_k = the move of
    x_{k-1}^A; the due runs' weights reset; reweight by log G_k = log p(z_k | x_k); the runs nothing
    explains restart from the prior M0; the log mean increment added to the evidence.

`SMC.step` is those lines. What differs between the filters are the hooks below it (`log_eta`,
`time_to_resample`, `ancestors`, `move`, `reweight_resampled`); what the model provides is the model
object a subclass hands in (`M0`, `M`, `logG`: mazelab.model.LostRobot for the lab's filters, the
student's parts for mazelab.exercise.StudentFilter), and the resampling scheme is the subclass's
`resample` ((W (N,), rng) -> ancestors (N,)).

Every array has the run axis first, always: x (R, N, 2), W (R, N), A (R, N), the `due` mask (R,), with
R = 1 for one run. Run r draws from its own Generator `rngs[r]`, in the order a filter of that run
alone would draw, so R runs are bit for bit R single runs: rows not due get identity ancestors and
keep their weights; only the due rows draw a resampling (and the RPF's jitter); every row draws its
move, but for a run nothing explained at the first stage (`lost`), which draws nothing before its
restart. What a hook returns is checked once, where the step receives it (`HookError`: one line
naming the hook and what came).

This module imports numpy, mazelab.checks, mazelab.constants and mazelab.weights only: the grading
sandbox ships it with StudentFilter, and no implementation of the model or of a resampling scheme
comes with it.
"""

from __future__ import annotations

import inspect
import math
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from mazelab.checks import as_points
from mazelab.constants import LOG_UNDERFLOW, PARTICLE_DTYPE
from mazelab.weights import Weights, read_only

# mazelab 0.2's hooks that are gone, and how each is written now (a plug-in overriding one gets this line)
PORTED = {
    "move_after_resampling": "move_resampled(self, x, A, due) -> (positions, headings), x (R, N, 2), A (R, M)",
    "moved_after_resampling": "move(self, x, A, due)",
    "resampled": "move_resampled(self, x, A, due) (ParticleFilter's) or move(self, x, A, due)",
    "between_resamplings": "move(self, x, A, due), which gets A None when no run resamples",
    "after_reweighting": "step: call super().step(...), then read self.log_evidence_increment (R,)",
    "first_stage": "log_eta(self) -> log eta (R, N), or None",
}


class HookError(ValueError):
    """What a hook returned cannot be used: one line naming the hook and what came."""


class SMC:
    """The step (Arulampalam et al. Algorithms 4-6 as one algorithm with hooks) over R runs.

    Parameters
    ----------
    model : object
        The state-space model (particles' FeynmanKac): `M0(N, rng)` the prior's (N, 2) draws, `M(x, A,
        th0, rngs)` the transition of x^A (R, N, 2) -> (x_k, headings (R, N)), `logG(x, z)` log p(z_k |
        x_k) (R, N). A Generator of None in `rngs` is a run that does not move (it draws nothing).
    particles : array (N, 2), or (R, N, 2) for R runs
        The prior's sample each run starts from.
    rng : numpy.random.Generator, or a sequence of R of them
        Every draw of run r comes from rngs[r]; None: a fresh unseeded one per run.
    weights : type
        The Weights class of the backend (mazelab.weights.Weights: numpy's).
    dtype : numpy dtype, optional
        The particles' (default: float32, PARTICLE_DTYPE).
    """

    threshold: float = 1.0  # RESAMPLE when N_eff < threshold * N; 1: every step (Algorithms 4 and 5)
    resample: Callable[[np.ndarray, np.random.Generator], np.ndarray]  # the scheme: W (N,), rng -> a (N,)

    def __init__(self, model: Any, particles: Any, rng: Any = None, weights: type = Weights, dtype: Any = None):
        runs, self.rngs = runs_of(particles, rng)  # (R, N, 2) float64, checked; a Generator each
        self.model, self.weights_class = model, weights
        self.runs = len(runs)  # R
        self.all_due = np.ones(len(runs), dtype=bool)  # every run due: the mask of threshold 1 (never written into)
        self.all_due.flags.writeable = False
        self.x = particles_array(runs, PARTICLE_DTYPE if dtype is None else dtype)
        self.headings = np.zeros(self.x.shape[:2], dtype=self.x.dtype)  # each particle's last motion angle
        self.W = weights.uniform(*self.x.shape[:2])
        self.steps_done = 0
        self.resampled_now = np.zeros(len(runs), dtype=bool)
        self._ancestors: np.ndarray | None = None  # this step's A, None: no run resampled
        self.run_log_evidence = np.zeros(len(runs))
        self._reinitialised: list[list[int]] = [[] for _ in runs]

    def __init_subclass__(cls, **kwargs: Any) -> None:
        """A plug-in written for mazelab 0.2's hooks runs, or gets one line on how to port the hook that changed."""
        super().__init_subclass__(**kwargs)
        for old, new in PORTED.items():
            if old in cls.__dict__:
                raise TypeError(
                    f"{cls.__name__}.{old} is a hook of mazelab 0.2; port it to {new} (docs/architecture.md)"
                )
        hook = cls.__dict__.get("time_to_resample")
        if callable(hook) and len(inspect.signature(hook).parameters) == 1:  # 0.2's time_to_resample(self)
            cls.time_to_resample = lambda self, W, _old=hook: _old(self)
        hook = cls.__dict__.get("ancestors")
        if callable(hook) and len(inspect.signature(hook).parameters) == 2:  # 0.2's ancestors(self, W)
            raise TypeError(
                f"{cls.__name__}.ancestors(W) is a hook of mazelab 0.2; port it to ancestors(self, W, due) -> A "
                "(R, N), or write the scheme as resample(W (N,), rng) -> a (N,) (docs/architecture.md)"
            )

    # -- the step --------------------------------------------------------------------------------------
    def step(self, compass_angle: float | np.ndarray, z: float | np.ndarray) -> None:
        """One step: resample the runs it is time for, move, reweight (Algorithms 4, 5 and 6 as one).

        Parameters
        ----------
        compass_angle : float, or array (R,)
            th0_k, the heading the compass reports for this step (radians), of each run.
        z : float, or array (R,)
            z_k, the measured distance to the nearest station (map units), of each run.
        """
        self._observe(compass_angle, z)  # th0_k and z_k of each run
        W, eta = self.W, log_weights_of("log_eta", self.log_eta(), self.runs)  # the APF's eta; None: eta = 1
        Wf = W if eta is None else W.add(eta, self.x)  # W_{k-1} eta_k, normalised (the APF's first stage)
        lost = None if eta is None else self._lost_at_first_stage(Wf, eta)  # nothing explains z_k: no draws
        due = due_of("time_to_resample", self.time_to_resample(W), self, lost)  # RESAMPLE now? (R,)
        A = ancestors_of("ancestors", self.ancestors(Wf, due), self) if due is self.all_due or due.any() else None
        x, headings = moved_of("move", self.move(self.x, A, due), self.runs)  # x_k^i ~ p(x_k | x_{k-1}^{a^i})
        log_g = log_weights_of("log_likelihood", self.log_likelihood(x), self.runs)  # log G_k(x_k^i)
        reset = None if A is None else reset_of("reweight_resampled", self.reweight_resampled(log_g, A), self.runs)
        self.x, self.headings, self.resampled_now, self._ancestors = x, headings, due, A
        self.W, increment = self._reweighted(W, log_g, due, reset)  # w_k = W_{k-1} G_k, or the due rows' reset
        if lost is not None or not settled(self.W.log_total):  # a hook's NaN, or nothing explains z_k: M0 again
            suspects = ("move", x), ("log_likelihood", log_g), ("reweight_resampled", reset and reset[0])
            self._received_totals(self.W, *suspects)
            increment = self._restart(self.W.lost if lost is None else self.W.lost | lost, lost, increment, Wf)
        self.log_evidence_increment = increment  # log p(z_k | z_1:k-1) of each run
        self.run_log_evidence = self.run_log_evidence + increment
        self.steps_done += 1

    # -- the hooks: what differs between the filters ---------------------------------------------------
    def log_eta(self) -> np.ndarray | None:
        """log eta_k^i, the first-stage factor of each particle (the APF's); None: eta = 1.

        Returns
        -------
        float array (R, N), or None
        """
        return None

    def time_to_resample(self, W: Weights) -> np.ndarray:
        """Which runs RESAMPLE now: N_eff < threshold * N of W_{k-1} (every step for threshold 1, the
        paper's SIR and APF; the RPF's N_T = 0.2 N).

        Parameters
        ----------
        W : Weights
            W_{k-1}, (R, N).

        Returns
        -------
        bool array (R,) (one bool: every run)
        """
        if self.threshold >= 1:
            return self.all_due
        return W.ess < self.threshold * self.x.shape[1]

    def ancestors(self, W: Weights, due: np.ndarray) -> np.ndarray:
        """RESAMPLE: a^i ~ W in each due run by the scheme (`resample`, or `resample_rows` for several
        runs at once), identity in the others.

        Parameters
        ----------
        W : Weights
            The first-stage weights W_{k-1} eta_k, (R, N).
        due : bool array (R,)

        Returns
        -------
        int array (R, M): indices into each run's own particles
        """
        if len(due) == 1:  # the scheme: mazelab.resampling.systematic_resample by default
            return self.resample(W.W[0], self.rngs[0])[None]
        if self._every(due):
            return self.resample_rows(W.W, self.rngs)
        rows = np.flatnonzero(due)
        A = identity(*W.W.shape)
        A[rows] = self.resample_rows(W.W[rows], [self.rngs[r] for r in rows.tolist()])
        return A

    def resample_rows(self, W: np.ndarray, rngs: Sequence[np.random.Generator]) -> np.ndarray:
        """The scheme over the due runs: `resample` ((W (N,), rng) -> a (M,)) run by run, each with its own
        Generator (a scheme that takes the rows at once, as mazelab.resampling's do, stands in for this).

        Parameters
        ----------
        W : array (D, N)
            The due runs' normalised weights.
        rngs : sequence of D Generators

        Returns
        -------
        int array (D, M)
        """
        return np.array([self.resample(w, rng) for w, rng in zip(W, rngs, strict=True)])

    def move(self, x: np.ndarray, A: np.ndarray | None, due: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """x_k^i ~ p(x_k | x_{k-1}^{a^i}), the transition of the ancestors.

        Parameters
        ----------
        x : array (R, N, 2)
            x_{k-1}.
        A : int array (R, M), or None (no run resampled)
        due : bool array (R,)

        Returns
        -------
        (positions (R, M, 2), headings (R, M))
        """
        return self.transition(x, A)

    def reweight_resampled(self, log_g: np.ndarray, A: np.ndarray) -> tuple[np.ndarray, Any]:
        """The log weights of the due runs after resampling: w_k^i = G_k(x_k^i) (their W is 1/N), and
        the log of what their mean lacks to estimate p(z_k | z_1:k-1) (the APF's first-stage total),
        0.0, or None when their log total is that estimate. Rows not due are not read.

        Parameters
        ----------
        log_g : array (R, M)
            log G_k = log p(z_k | x_k^i).
        A : int array (R, M)

        Returns
        -------
        (log w (R, M), log factor: array (R,), a float, or None)
        """
        return log_g, 0.0

    # -- the model (the object the subclass hands in) --------------------------------------------------
    def transition(self, x: np.ndarray, A: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """The model's M: x^A moved, each run by its own Generator (a lost run by none).

        Parameters
        ----------
        x : array (R, N, 2)
        A : int array (R, M), optional

        Returns
        -------
        (positions (R, M, 2), headings (R, M))
        """
        return self.model.M(x, A, self.th0, self.movers)

    def log_likelihood(self, x: np.ndarray) -> np.ndarray:
        """The model's log G_k = log p(z_k | x).

        Parameters
        ----------
        x : array (R, N, 2)

        Returns
        -------
        float array (R, N)
        """
        return self.model.logG(x, self.z)

    # -- the step's parts ------------------------------------------------------------------------------
    def _observe(self, compass_angle: float | np.ndarray, z: float | np.ndarray) -> None:
        """Keep this step's th0_k and z_k, float64 (R,), one per run."""
        runs = len(self.rngs)
        self.th0, self.z = per_run(compass_angle, runs), per_run(z, runs)
        self.movers: Sequence[np.random.Generator | None] = self.rngs

    def _lost_at_first_stage(self, Wf: Weights, eta: np.ndarray) -> np.ndarray | None:
        """The runs whose first-stage total underflows (bool (R,), or None: none): they draw nothing this
        step and restart."""
        if settled(Wf.log_total):
            return None
        self._received_totals(Wf, ("log_eta", eta))
        lost = Wf.lost
        self.movers = [None if gone else g for g, gone in zip(self.rngs, lost.tolist(), strict=True)]
        return lost

    def _reweighted(
        self, W: Weights, log_g: np.ndarray, due: np.ndarray, reset: tuple[np.ndarray, Any] | None
    ) -> tuple[Weights, np.ndarray]:
        """w_k = W_{k-1} G_k normalised per run, the due runs' from their reset log w; and each run's
        log mean increment, log sum_i W_{k-1}^i G_k^i (the due runs': their log total less log N plus
        the factor, or their log total when the factor is None): (weights, increments (R,))."""
        if reset is None:
            new = W.add(log_g, self.x)
            return new, new.log_total
        log_w, factor = reset
        every = self._every(due)
        fresh = self.weights_class.from_log(*((log_w, self.x) if every else (log_w[due], self.x[due])))
        if isinstance(factor, np.ndarray) and factor.ndim and not every:
            factor = factor[due]
        increment = fresh.log_total if factor is None else fresh.log_total - math.log(log_w.shape[1])
        if factor is not None and not (isinstance(factor, float) and factor == 0):  # x + 0.0 is x
            increment = increment + factor
        if every:
            return fresh, increment
        kept = W.add(log_g, self.x)
        increments = kept.log_total.copy()
        increments[due] = increment
        return kept.reset(due, fresh, self.x), increments

    def _restart(self, rows: np.ndarray, lost: np.ndarray | None, increment: np.ndarray, Wf: Weights) -> np.ndarray:
        """The runs nothing explains (and the lost ones) start again from the prior M0, weighted by their
        z_k (uniformly where even the prior's sample explains nothing); a lost run's increment is its
        first stage's total. Returns the increments."""
        count = self.restart_count()
        same = count == self.count
        x = particles_array(self.x if same else np.zeros((self.runs, count, 2)), self.x.dtype)
        for r in np.flatnonzero(rows).tolist():
            self._reinitialised[r].append(self.steps_done + 1)
            x[r] = self.model.M0(count, self.rngs[r])
        log_g = log_weights_of("log_likelihood", self.log_likelihood(x), self.runs)
        every = bool(rows.all())
        restarted = (log_g, x) if every else (log_g[rows], x[rows])  # the restarted runs' log G and particles
        fresh = self.weights_class.from_log(*restarted)
        self._received_totals(fresh, ("log_likelihood", log_g))
        fresh = fresh.reset(fresh.lost, self.weights_class.uniform(int(fresh.lost.sum()), count), restarted[1])
        self.x = x
        if not same:
            self.headings = np.zeros((self.runs, count), dtype=x.dtype)
        self.W = fresh if every else self.W.reset(rows, fresh, x)
        return increment if lost is None else np.where(lost, Wf.log_total, increment)

    def restart_count(self) -> int:
        """The particles a restarted run draws from the prior: N.

        Returns
        -------
        int
        """
        return self.x.shape[1]

    def _every(self, due: np.ndarray) -> bool:
        """Whether every run is due."""
        return due is self.all_due or bool(due.all())

    # -- the boundary: what a hook returns, checked once where the step receives it --------------------
    def _received_totals(self, W: Weights, *suspects: tuple[str, np.ndarray | None]) -> None:
        """A NaN or +inf log total (one check per run, fused into the normalisation; the step asks once
        its totals are not all settled): HookError naming the first of the hooks (hook, what it
        returned) whose values hold a NaN or +inf."""
        bad = ~(W.log_total < math.inf)  # True for NaN and +inf
        if bad.any():
            hook = next(
                (name for name, v in suspects if v is not None and (np.isnan(v).any() or np.isposinf(v).any())),
                suspects[-1][0],
            )
            said = "the move returned NaN positions" if hook == "move" else f"{hook} returned NaN or +inf"
            raise HookError(f"{said} (run {int(np.flatnonzero(bad)[0])}); expected finite values")

    # -- what the step leaves: the paper's shapes for one run, one value per run for R runs -------------
    @property
    def count(self) -> int:
        """N, the particles of each run now."""
        return self.x.shape[1]

    @property
    def positions(self) -> np.ndarray:
        """The particles x_i: (N, 2) for one run, (R, N, 2) for R runs."""
        return self._one(self.x)

    @positions.setter
    def positions(self, values: np.ndarray) -> None:
        self.x = particles_array(np.asarray(values).reshape(self.runs, -1, 2), self.x.dtype)

    @property
    def weights(self) -> np.ndarray:
        """The normalised weights W_i: (N,) for one run, (R, N) for R runs (read-only)."""
        return self._one(self.W.W)

    @property
    def log_weights(self) -> np.ndarray:
        """log W_i, normalised: (N,) for one run, (R, N) for R runs (read-only)."""
        return self._one(self.W.lw)

    @log_weights.setter
    def log_weights(self, values: np.ndarray) -> None:
        self.W = self.weights_class.from_log(np.asarray(values, dtype=float).reshape(self.runs, -1), self.x)

    @property
    def ess(self) -> float | np.ndarray:
        """N_eff = 1 / sum_i W_i^2: a float for one run, (R,) for R runs."""
        ess = self.W.ess
        return float(ess[0]) if len(ess) == 1 else ess

    @property
    def log_evidence(self) -> float | np.ndarray:
        """log p(z_1:k), the running estimate (particles' logLt): a float for one run, (R,) for R runs.
        A step that no particle explains adds the filter's (underflowing) estimate before its restart."""
        return float(self.run_log_evidence[0]) if self.runs == 1 else self.run_log_evidence.copy()

    @property
    def ancestry(self) -> tuple[np.ndarray, np.ndarray] | None:
        """This step's genealogy (A, due), read-only, or None before the first step.

        A, int (R, M): the index in x_{k-1} of the particle each particle of x_k descends from (identity in
        the runs not due); due, bool (R,): the runs that resampled. A run restarted from the prior
        (`reinitialised_at`) and recovery's injected particles (`injected`) have no ancestor, whatever A
        says. Nothing is kept past the step: a recorder of the genealogy keeps each step's pair."""
        if not self.steps_done:
            return None
        A = identity(self.runs, self.count) if self._ancestors is None else self._ancestors
        return read_only(A.view()), read_only(self.resampled_now.view())

    @property
    def reinitialised_at(self) -> list[int] | list[list[int]]:
        """The steps at which no particle explained z and the filter restarted (a list per run for R runs)."""
        return self._one(self._reinitialised)

    def _one(self, per_run: Any) -> Any:
        """Run 0's value for one run (the paper's shapes), all runs' otherwise."""
        return per_run[0] if self.runs == 1 else per_run


UNSIGNED = {1: np.uint8, 2: np.uint16, 4: np.uint32, 8: np.uint64}  # ints viewed as unsigned, by size


def settled(totals: np.ndarray) -> bool:
    """Whether every log total (R,) lies in [LOG_UNDERFLOW, inf): no run to restart or to refuse (the
    common step's one check; one run's a compare of floats)."""
    if len(totals) == 1:
        return LOG_UNDERFLOW <= float(totals[0]) < math.inf
    return bool(((totals >= LOG_UNDERFLOW) & (totals < math.inf)).all())


# -- the run axis -----------------------------------------------------------------------------------------
def runs_of(particles: Any, rng: Any) -> tuple[np.ndarray, list[np.random.Generator]]:
    """The runs a filter starts: initial particles as (R, N, 2) float64, checked ((N, 2) is one run),
    and one Generator per run (`rng` itself for one run, the sequence of R given, None: fresh ones).

    Parameters
    ----------
    particles : array-like (N, 2) or (R, N, 2)
    rng : numpy.random.Generator, a sequence of R of them, or None

    Returns
    -------
    (array (R, N, 2), list of R numpy.random.Generator)
    """
    array = np.asarray(particles)
    if array.ndim == 3:
        if array.shape[2] != 2 or array.shape[1] < 1:
            raise ValueError(f"particles of R runs must have shape (R, N, 2), got {array.shape}")
        array = np.stack([as_points("particles", run) for run in array])
    else:
        array = as_points("particles", particles)[None]
    runs = len(array)
    if rng is None:
        return array, [np.random.default_rng() for _ in range(runs)]
    rngs = [rng] if isinstance(rng, np.random.Generator) else list(rng)
    if len(rngs) != runs or not all(isinstance(g, np.random.Generator) for g in rngs):
        raise ValueError(f"{runs} runs need {runs} numpy Generators, one each, got {len(rngs)}")
    return array, rngs


def particles_array(values: np.ndarray, dtype: Any) -> np.ndarray:
    """(R, N, 2) particles stored x column then y column ((2, R, N) in memory), so that x[..., 0] is
    contiguous and x.reshape(-1, 2) an (R*N, 2) order-F view, the kernels' layout.

    Parameters
    ----------
    values : array (R, N, 2)
    dtype : numpy dtype

    Returns
    -------
    array (R, N, 2), a new one
    """
    stored = new_particles(*values.shape[:2], dtype)
    stored[..., 0], stored[..., 1] = values[..., 0], values[..., 1]
    return stored


def new_particles(runs: int, count: int, dtype: Any) -> np.ndarray:
    """An empty (R, N, 2) array of particles in their layout (`particles_array`).

    Parameters
    ----------
    runs, count : int
    dtype : numpy dtype

    Returns
    -------
    array (R, N, 2)
    """
    return np.empty((2, runs, count), dtype=dtype).transpose(1, 2, 0)


def identity(runs: int, count: int) -> np.ndarray:
    """Identity ancestors (R, N): each particle its own."""
    return np.broadcast_to(np.arange(count), (runs, count)).copy()


def per_run(value: Any, runs: int) -> np.ndarray:
    """A step's compass angle or measurement as float64, one per run: (R,), or (R, k) for a reading of
    k numbers (a model with several sensors), given once for every run or with the run axis first."""
    if not isinstance(value, (np.ndarray, list, tuple)):
        return np.array([float(value)] * runs)
    value = np.asarray(value).astype(float, copy=False)
    if value.ndim and len(value) == runs:
        return read_only(value.view())  # read-only as broadcast_to's view, without its cost
    return np.broadcast_to(value, (runs, *value.shape) if value.size > 1 else (runs,))


def describe(value: Any) -> str:
    """What a hook returned, in a few words: its type, dtype and shape."""
    if isinstance(value, np.ndarray):
        return f"a {value.dtype} array of shape {value.shape}"
    return f"{type(value).__name__} {str(value)[:40]}"


def log_weights_of(hook: str, value: Any, runs: int) -> np.ndarray | None:
    """A hook's float (R, N) log weights (None passes), or HookError."""
    if value is None or (
        isinstance(value, np.ndarray) and value.dtype.kind == "f" and value.ndim == 2 and len(value) == runs
    ):
        return value
    raise HookError(f"{hook} returned {describe(value)}; expected float (R, N) with R = {runs}")


def due_of(hook: str, value: Any, filt: SMC, lost: np.ndarray | None) -> np.ndarray:
    """A hook's bool (R,) mask (one bool stands for every run) less the lost runs, or HookError."""
    if value is filt.all_due and lost is None:
        return value
    due, runs = np.asarray(value), filt.runs
    if due.dtype != bool or due.shape not in ((), (runs,)):
        raise HookError(f"{hook} returned {describe(value)}; expected bool (R,) with R = {runs}")
    due = np.broadcast_to(due, (runs,)) if due.shape == () else due
    return due if lost is None else due & ~lost


def ancestors_of(hook: str, value: Any, filt: SMC) -> np.ndarray:
    """A hook's ancestors, int (R, M) within [0, N), or HookError (so that no kernel reads outside its arrays)."""
    runs, count = filt.x.shape[:2]
    if not (isinstance(value, np.ndarray) and value.dtype.kind in "iu" and value.ndim == 2 and len(value) == runs):
        raise HookError(f"{hook} returned {describe(value)}; expected int (R, M) indices with R = {runs}")
    if value.size and np.maximum.reduce(value.view(UNSIGNED[value.itemsize]), None) >= count:  # -1: a large unsigned
        raise HookError(f"{hook} returned an index outside [0, {count}): {value.min()}..{value.max()}")
    return value


def moved_of(hook: str, value: Any, runs: int) -> tuple[np.ndarray, np.ndarray]:
    """A hook's (positions float (R, M, 2), headings (R, M)), or HookError."""
    if not (isinstance(value, tuple) and len(value) == 2):
        raise HookError(f"{hook} returned {describe(value)}; expected (positions (R, N, 2), headings (R, N))")
    x, headings = value
    if not (isinstance(x, np.ndarray) and x.dtype.kind == "f" and x.ndim == 3 and len(x) == runs and x.shape[2] == 2):
        raise HookError(f"{hook} returned positions {describe(x)}; expected float (R, N, 2) with R = {runs}")
    if not (isinstance(headings, np.ndarray) and headings.shape == x.shape[:2]):
        raise HookError(f"{hook} returned headings {describe(headings)}; expected (R, N) = {x.shape[:2]}")
    return x, headings


def reset_of(hook: str, value: Any, runs: int) -> tuple[np.ndarray, Any]:
    """A hook's (log w (R, N), log factor), or HookError."""
    if not (isinstance(value, tuple) and len(value) == 2):
        raise HookError(f"{hook} returned {describe(value)}; expected (log w (R, N), log factor or None)")
    return log_weights_of(hook, value[0], runs), value[1]


__all__ = ["PORTED", "SMC", "HookError", "new_particles", "particles_array", "runs_of"]
