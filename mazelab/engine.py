"""The step template every particle filter of the lab runs (as nchopin/particles' SMC.__next__):

    RESAMPLE when `time_to_resample()` says so, a^i = `ancestors(W)` (the resampling scheme) by the
    first-stage weights W = W_{k-1} eta_k (eta = 1 but for the APF), then `move_after_resampling` them;
    MOVE by the transition the particles not moved yet; REWEIGHT by the log-likelihood, normalise, and
    add log p(z_k | z_1:k-1), the Weights' log mean increment, to the evidence.

`SMC.step` is those lines; what differs between the filters are its hooks (`log_eta`, `time_to_resample`,
`move_after_resampling`, `reweight_resampled`), and what the model provides (`transition`,
`log_likelihood`, `ancestors`) a subclass supplies: mazelab.cloud.ParticleFilter from the model of the
lost robot and the resampling schemes, mazelab.exercise.StudentFilter from the student's parts.

The engine below the hooks also advances R runs of one setting together (their blocks and what the
step leaves of each: mazelab.run_blocks.RunBlocks, SMC's base): run r's particles are rows r*N..(r+1)*N
of `positions`, its log weights row r of the Weights value, its draws from its own Generator `rngs[r]`
in the order a filter of that run alone would draw them, so R runs are bit for bit R single runs. No
hook names the runs: while a hook runs for some of them (those that resample this step), the engine's
`transition`, `log_likelihood` and draws are those runs'. A run whose weights all underflow (no particle
explains z_k) starts again from the prior, weighted by its z_k.

This module imports numpy, mazelab.weights, mazelab.constants and mazelab.run_blocks only: the grading
sandbox ships it with StudentFilter, and no reference implementation of the model or of resampling may
come with it.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from mazelab.constants import LOG_UNDERFLOW, PARTICLE_DTYPE
from mazelab.run_blocks import RunBlocks
from mazelab.weights import Weights, log_sum_exp, weights_from_logs


class SMC(RunBlocks):
    """The step template (Arulampalam et al. Algorithms 4-6 as one algorithm with hooks).

    A subclass's constructor sets `world` (the map: `random_free_places` is the prior), `positions`
    (R*N, 2), `headings` (R*N,), `count` (N) and `threshold`, then calls `start_runs(rngs)` (one
    Generator per run: the weights start uniform); and the subclass provides the model's parts
    `transition`, `log_likelihood` and `ancestors`.
    """

    threshold: float = 1.0  # RESAMPLE when N_eff < threshold * N; 1: every step (Algorithms 4 and 5)
    moved_by_resampling: bool = True  # the resampled particles take the transition as they are drawn

    # -- the step --------------------------------------------------------------------------------------
    def step(self, compass_angle: float | np.ndarray, z: float | np.ndarray) -> None:
        """One step: resample when it is time, move, reweight (Algorithms 4, 5 and 6 as one).

        Parameters
        ----------
        compass_angle : float, or array (R,)
            th0_k, the heading the compass reports for this step (radians), of each run.
        z : float, or array (R,)
            z_k, the measured distance to the nearest station (map units), of each run.
        """
        self.observe(compass_angle, z)  # th0_k and z_k
        W = self.first_stage(self.log_eta())  # W_{k-1}^i eta_k^i (the APF's; eta = 1 otherwise)
        if self.due(self.time_to_resample()):  # RESAMPLE when it is time
            self.resampled(self.ancestors(W))  # a^i ~ W by the scheme; x^i = move_after_resampling(a^i)
        del W  # spent: the compiled backend may reuse its memory for this step's weights
        self.move()  # x_k^i ~ p(x_k | x_{k-1}^i) for the particles not moved at resampling
        self.reweight(self.log_likelihood(self.positions))  # w_k^i ∝ w^i p(z_k | x_k^i); log p(z_k | z_1:k-1)
        self.steps_done += 1

    # -- the hooks: what differs between the filters ---------------------------------------------------
    def log_eta(self) -> np.ndarray | None:
        """log eta_k^i, the first-stage factor of each particle (the APF's); None: eta = 1 (SIR, RPF).

        Returns
        -------
        array (R, N), or None
        """
        return None

    def time_to_resample(self) -> bool | np.ndarray:
        """Whether to RESAMPLE now: N_eff < threshold * N (every step for threshold 1, the paper's SIR
        and APF; the RPF's N_T = 0.2 N).

        Returns
        -------
        bool, or bool array (R,) for R runs
        """
        return True if self.threshold >= 1 else self.ess < self.threshold * self.count

    def move_after_resampling(self, ancestors: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The resampled particles: x_k^i ~ p(x_k | x_{k-1}^{a^i}), the transition as they are drawn.

        Parameters
        ----------
        ancestors : int array
            a^i, indices into `positions`.

        Returns
        -------
        (positions, headings) of the drawn particles
        """
        return self.transition(self.positions, ancestors)

    def reweight_resampled(self, log_lik: np.ndarray, ancestors: np.ndarray) -> tuple[np.ndarray, Any]:
        """The log weights of resampled particles after the likelihood: w_k^i = p(z_k | x_k^i) (their
        weights are equal after resampling), and the log of what their mean lacks to be the estimate of
        p(z_k | z_1:k-1) (the APF's first-stage total); None when their total is that estimate.

        Parameters
        ----------
        log_lik : array (R, N)
            log p(z_k | x_k^i) of the resampled runs (spent after this hook: it may be written into).
        ancestors : int array
            a^i of those runs' particles.

        Returns
        -------
        (log w (R, N), log factor: 0.0, an array (R,), or None)
        """
        return log_lik, 0.0

    # -- what the model provides (mazelab.cloud from the lost robot's model; StudentFilter from the parts)
    def transition(self, points: np.ndarray, ancestors: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """x_k ~ p(x_k | x_{k-1}) for `points` (or points[ancestors]): (positions, headings)."""
        raise NotImplementedError

    def log_likelihood(self, points: np.ndarray) -> np.ndarray:
        """log p(z_k | x) of `points`, shape (R, N)."""
        raise NotImplementedError

    def ancestors(self, W: np.ndarray) -> np.ndarray:
        """RESAMPLE: a^i ~ W, ancestor indices into `positions`, N per row of the normalised first-stage
        weights W (R, N) that the engine serves now (`selected_rows`)."""
        raise NotImplementedError

    # -- the engine: the steps' parts, for every run ---------------------------------------------------
    def start_runs(self, rngs: Sequence[np.random.Generator]) -> None:
        """The engine's bookkeeping, set by the subclass's constructor after `positions` and `count`.

        Parameters
        ----------
        rngs : sequence of numpy.random.Generator
            One per run.
        """
        self.rngs = list(rngs)
        self.runs = len(self.rngs)
        self.weights_value = Weights.uniform(self.runs, self.count)
        self.steps_done = 0
        self._reinitialised: list[list[int]] = [[] for _ in range(self.runs)]
        self._resampled_at: list[list[int]] = [[] for _ in range(self.runs)]
        self.resampled_now = np.zeros(self.runs, dtype=bool)
        self.run_log_evidence = np.zeros(self.runs)
        self._selected: np.ndarray | None = None  # the runs a hook serves now (None: every run)
        self._every_run = np.arange(self.runs)
        self._no_run = np.zeros(self.runs, dtype=bool)  # never written into
        self._all_runs = np.ones(self.runs, dtype=bool)  # never written into

    def observe(self, compass_angle: float | np.ndarray, z: float | np.ndarray) -> None:
        """Keep the step's th0_k and z_k, one per run (float64 (R,)).

        Parameters
        ----------
        compass_angle, z : float, or arrays (R,)
        """
        self.compass_angles, self.measurements = _per_run(compass_angle, self.runs), _per_run(z, self.runs)
        self._moved = self._lost = self._no_run  # replaced, never written into
        self._resampled: tuple[np.ndarray, np.ndarray] | None = None  # (the runs, their ancestors)
        self._selected = None  # every run (a step cut short by an error leaves none served)

    def first_stage(self, log_eta: np.ndarray | None) -> np.ndarray:
        """W_{k-1}^i eta_k^i normalised per run; a run whose total underflows (no eta explains z_k) is
        lost: it restarts from the prior this step.

        Parameters
        ----------
        log_eta : array (R, N), or None (eta = 1)

        Returns
        -------
        array (R, N), normalised weights
        """
        self._first_stage_totals = None
        if log_eta is None:
            return self.weights_value.W
        log_a, shifts = self.weights_value.log_parts  # log W_{k-1} = log_a - shifts, not made when not held
        weights, log_totals = self.normalised(log_a, log_eta, shifts)
        self._first_stage_totals = log_totals
        if not _all_at_least(log_totals, LOG_UNDERFLOW):  # a run lost (or a NaN total: not lost)
            lost = log_totals < LOG_UNDERFLOW
            self._lost = lost if lost.any() else self._no_run  # none lost: the steps' checks of it are skipped
        return weights

    def due(self, due: bool | np.ndarray) -> bool:
        """Whether any run resamples now: those it is time for (not the lost ones), which the engine's
        parts serve until `resampled`; without any, recovery may inject (`between_resamplings`).

        Parameters
        ----------
        due : bool, or bool array (R,)

        Returns
        -------
        bool
        """
        none_lost = self._lost is self._no_run  # the common step: its checks of the lost runs skipped
        if due is True and none_lost:
            self.resampled_now, self._selected = self._all_runs, None
            return True
        if due is False and none_lost:  # no run resamples (one run's N_eff above N_T)
            self.resampled_now = self._no_run
            self.between_resamplings()
            return False
        if none_lost and isinstance(due, np.ndarray) and due.shape == self._no_run.shape:
            due = due.astype(bool)  # a new array (R,)
        else:
            due = ~self._lost if due is True else np.asarray(due, dtype=bool) & ~self._lost
        self.resampled_now = due
        if not due.any():
            if none_lost or not self._lost.any():
                self.between_resamplings()
            return False
        runs = np.flatnonzero(due)
        self._selected = None if len(runs) == self.runs else runs
        return True

    def resampled(self, ancestors: np.ndarray) -> None:
        """x^i = `move_after_resampling`(a^i) for the runs that resample; the other runs keep their particles.

        Parameters
        ----------
        ancestors : int array
            a^i of the served runs' particles, indices into `positions`.
        """
        runs = self.selected_runs
        if self.moved_by_resampling and len(runs) == self.runs:
            self.headings = None  # every particle moves now: the old headings go first (their memory reused)
        try:
            positions, headings = self.moved_after_resampling(ancestors)
        finally:
            self._selected = None
        self.replace_runs(positions, headings, runs)
        if len(runs) == self.runs:  # every run's weights are spent (the reweighting sets the next): the
            self.weights_value = None  # compiled backend may reuse their arrays (the likelihood's too)
        if self.moved_by_resampling:
            self._moved = self.resampled_now
        self._resampled = (runs, ancestors)
        for run in runs.tolist():
            self._resampled_at[run].append(self.steps_done)

    def moved_after_resampling(self, ancestors: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The resampled particles: `move_after_resampling` (mazelab.cloud adds KLD-sampling and recovery).

        Parameters
        ----------
        ancestors : int array

        Returns
        -------
        (positions, headings) of the served runs
        """
        return self.move_after_resampling(ancestors)

    def between_resamplings(self) -> None:
        """What a step without resampling does first (recovery's injection; nothing by default)."""

    def move(self) -> None:
        """x_k^i ~ p(x_k | x_{k-1}^i) for the runs whose particles the resampling did not move (not the
        lost runs: they restart)."""
        if self._moved is self._no_run and self._lost is self._no_run:
            runs = self._every_run  # no run resampled and none lost: every run moves
        elif self._moved is self._all_runs or self._moved.all():
            return
        else:
            pending = ~self._moved & ~self._lost
            if not pending.any():
                return
            runs = np.flatnonzero(pending)
        self._selected = None if len(runs) == self.runs else runs
        if self._selected is None:
            self.headings = None  # every particle moves now: the old headings go first (their memory reused)
        try:
            positions, headings = self.transition(self.selected_points())
        finally:
            self._selected = None
        self.replace_runs(positions, headings, runs)

    def reweight(self, log_lik: np.ndarray) -> None:
        """log w_k^i = log w^i + log p(z_k | x_k^i) (the resampled runs' by `reweight_resampled`),
        normalised per run; log p(z_k | z_1:k-1) added to each run's evidence; a run that nothing
        explains (or that was lost) restarts from the prior.

        Parameters
        ----------
        log_lik : array (R, N)
            log p(z_k | x_k^i) of every run's particles.
        """
        fresh: np.ndarray | bool = False  # which runs' log w leave out W_{k-1} (True: every run)
        extra: np.ndarray | float = 0.0
        if self._resampled is None:
            log_a, shifts = self.weights_value.log_parts  # log W_{k-1} = log_a - shifts, not made when not held
            log_w: np.ndarray | list[np.ndarray] = self.reweighted(log_a, log_lik, shifts)
        else:
            runs, ancestors = self._resampled
            every_run = len(runs) == self.runs
            self._selected = None if every_run else runs
            try:
                resampled, scale = self.reweight_resampled(self.selected_rows(log_lik), ancestors)
            finally:
                self._selected = None
            if scale is not None and every_run:
                fresh, extra = True, scale
            elif scale is not None:
                fresh, extra = np.zeros(self.runs, dtype=bool), np.zeros(self.runs)
                fresh[runs], extra[runs] = True, scale
            if every_run:
                log_w = resampled
            else:  # some runs resampled: each run's row (rows of two dtypes are normalised apart)
                rows = dict(zip(runs.tolist(), resampled, strict=True))
                log_a, shifts = self.weights_value.log_parts
                kept = self.reweighted(log_a, log_lik, shifts)  # the others': log W_{k-1} + log p(z_k | x_k)
                log_w = [rows[r] if r in rows else kept[r] for r in range(self.runs)]
                del kept, log_a
        self.weights_value = None  # the last step's weights go first (the compiled backend reuses their arrays)
        self.normalise(log_w, (fresh, extra))
        increments = self.weights_value.log_mean_increment  # log p(z_k | z_1:k-1)
        if self._lost is not self._no_run:
            increments = increments.copy()
            increments[self._lost] = self._first_stage_totals[self._lost]
        self.log_evidence_increment = increments
        self.run_log_evidence = self.run_log_evidence + increments  # a new array (R,)
        self.after_reweighting(increments)

    def after_reweighting(self, increments: np.ndarray) -> None:
        """What follows the reweighting (recovery's w_avg; nothing by default).

        Parameters
        ----------
        increments : array (R,)
            log p(z_k | z_1:k-1) estimated, per run.
        """

    # -- the weights ---------------------------------------------------------------------------------
    def normalise(
        self, log_w: np.ndarray | list[np.ndarray], fresh: tuple[np.ndarray | bool, Any] | None = None
    ) -> np.ndarray:
        """W_i ∝ exp(log w_i) of each run (its row); runs whose total underflows (or that are lost)
        restart from the prior, weighted by their z_k. Rows of one dtype are normalised together.

        Parameters
        ----------
        log_w : array (R, N), or a list of R rows (N,)
            Each run's unnormalised log weights.
        fresh : (bool array (R,) or bool, array (R,) or float), optional
            The runs whose log w leave out W_{k-1} = 1/N (resampled; True: every run) and the log factor
            they lack, for the Weights' log mean increment (None: every run's log w carries W_{k-1}).

        Returns
        -------
        array (R,)
            The log totals before any restart.
        """
        if isinstance(log_w, np.ndarray):
            totals, log_weights, reads = self.normalise_rows(log_w, self.positions)
        else:
            log_w, (totals, log_weights, reads) = self._normalise_list(log_w)
        if self._lost is self._no_run and _all_at_least(totals, LOG_UNDERFLOW):
            restarted = _NO_RUNS  # the common step: every run explained, none lost
        else:
            explained = totals >= LOG_UNDERFLOW  # False for an underflow and for NaN
            explained &= ~self._lost
            restarted = np.flatnonzero(~explained)
        if len(restarted):
            log_weights = self._reinitialise(restarted, _log_weights(log_weights, log_w, totals))
        unnormalised = None if log_weights is not None else (log_w, totals)  # log W derived when read
        totals = np.asarray(totals, dtype=float)
        increment = (totals, *((False, 0.0) if fresh is None else fresh), self.count)
        reads = self.kept_reads(reads, restarted, log_weights)
        self.weights_value = Weights(log_weights, *reads, unnormalised, increment)
        return totals

    def _normalise_list(self, rows: list[np.ndarray]) -> tuple[np.ndarray, tuple]:
        """`normalise_rows` of R rows (N,): together when they share a dtype, else by `_normalise_groups`.

        Returns
        -------
        (log w, the array normalised (R, N) or the rows, normalise_rows' results)
        """
        groups: dict[Any, list[int]] = {}
        for run, row in enumerate(rows):
            groups.setdefault(row.dtype, []).append(run)
        if len(groups) > 1:
            return rows, self._normalise_groups(rows, list(groups.values()))
        log_w = np.asarray(rows)
        return log_w, self.normalise_rows(log_w, self.positions)

    def _normalise_groups(
        self, rows: list[np.ndarray], groups: list[list[int]]
    ) -> tuple[np.ndarray, np.ndarray, dict[str, np.ndarray] | None]:
        """`normalise_rows` of each group of runs apart (rows of one dtype), put back in the runs' order."""
        totals, log_weights = np.empty(self.runs), np.empty((self.runs, self.count))
        reads: dict[str, np.ndarray] | None = {}
        for runs in groups:
            points = np.concatenate([self.run_positions(run) for run in runs])
            part_log_w = np.stack([rows[r] for r in runs])
            part_totals, part_log, part_reads = self.normalise_rows(part_log_w, points)
            totals[runs], log_weights[runs] = part_totals, _log_weights(part_log, part_log_w, part_totals)
            if part_reads is None or reads is None:
                reads = None
                continue
            for name, value in part_reads.items():
                reads.setdefault(name, np.empty((self.runs, *value.shape[1:]), value.dtype))[runs] = value
        return totals, log_weights, reads

    def normalise_rows(self, log_w: np.ndarray, positions: np.ndarray) -> tuple[np.ndarray, Any, Any]:
        """log W = log w - log sum exp(log w) per row: (log totals (R,), log W (R, N) float64 or None
        (then derived from log w and the totals when read), reads or None); the compiled backend's also
        reads the step's W, ESS, mean and confidence share, and may leave log W to be derived."""
        totals = np.atleast_1d(log_sum_exp(log_w))
        return totals, np.subtract(log_w, totals[:, None], dtype=float), None

    def normalised(
        self, log_a: np.ndarray, log_b: np.ndarray, shifts: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """W ∝ exp(log_a - shifts + log_b) per row, and its log sum exp (the APF's first stage: log_a -
        shifts is log W_{k-1}, as Weights.log_parts gives it; shifts None: none)."""
        log_w = self.reweighted(log_a, log_b, shifts)
        totals = np.atleast_1d(log_sum_exp(log_w))
        return weights_from_logs(log_w, totals), totals

    def reweighted(self, log_a: np.ndarray, log_lik: np.ndarray, shifts: np.ndarray | None = None) -> np.ndarray:
        """log w = log W_{k-1} + log p(z_k | x_k) per row, log W_{k-1} = log_a - shifts (Weights.log_parts;
        shifts None: log_a is log W_{k-1}): a step that does not resample, and the APF's first stage."""
        if shifts is not None:
            log_a = np.subtract(log_a, shifts[:, None], dtype=float)
        return log_a + log_lik

    def kept_reads(self, reads: Any, restarted: np.ndarray, log_weights: np.ndarray | None) -> tuple[Any, Any]:
        """The W and ESS the normalisation read (None: derived from the log weights when asked)."""
        return None, None

    def _reinitialise(self, runs: np.ndarray, log_weights: np.ndarray) -> np.ndarray:
        """The given runs start again from the prior (uniform over the free area), weighted by their
        z_k; returns the log weights with theirs replaced."""
        count = self.restart_count()
        if count != self.count:  # the restart takes another particle count (KLD-sampling, one run)
            self.count = count
            self.positions = np.empty((count, 2), dtype=PARTICLE_DTYPE, order="F")
            self.headings = np.zeros(count, dtype=PARTICLE_DTYPE)
            log_weights = np.empty((1, count))
        else:
            self.positions = self.positions.copy(order="F")
        for run in runs:
            self._reinitialised[run].append(self.steps_done + 1)
            rows = slice(run * self.count, (run + 1) * self.count)
            self.positions[rows] = self.world.random_free_places(self.count, self.rngs[run])
            self._selected = np.array([run])
            try:
                log_w = self.log_likelihood(self.positions[rows])[0]
            finally:
                self._selected = None
            total = log_sum_exp(log_w)
            uniform = total < LOG_UNDERFLOW
            log_weights[run] = -math.log(self.count) if uniform else np.subtract(log_w, total, dtype=float)
        return log_weights

    def restart_count(self) -> int:
        """The particles a restarted run takes (N)."""
        return self.count

    @property
    def first_stage_log_total(self) -> np.ndarray:
        """log F = log sum_i W_{k-1}^i eta_k^i, the first stage's total (R,) (the APF's)."""
        return self.selected_rows(self._first_stage_totals)


_NO_RUNS = np.empty(0, dtype=np.intp)  # no run restarted (never written into)


def _all_at_least(values: np.ndarray, bound: float) -> bool:
    """Whether every value (R,) is at least `bound` (False for NaN): for one run a compare of floats."""
    return bool(values[0] >= bound) if len(values) == 1 else bool((values >= bound).all())


def _per_run(value: float | np.ndarray, runs: int) -> np.ndarray:
    """A step's compass angle or measurement as one value per run, float64 (R,)."""
    if isinstance(value, np.ndarray):
        return np.broadcast_to(value.astype(float, copy=False), (runs,))
    return np.array([float(value)] * runs)


def _log_weights(log_weights: np.ndarray | None, log_w: np.ndarray, totals: np.ndarray) -> np.ndarray:
    """The normalised log weights a normalisation returned, or log w - log total where it left them out."""
    return np.subtract(log_w, totals[:, None], dtype=float) if log_weights is None else log_weights


__all__ = ["SMC"]
