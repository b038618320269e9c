"""The R runs that a filter of the lab advances together, as the step template (mazelab.engine.SMC)
keeps them: run r's particles are rows r*N..(r+1)*N of `positions`, its log weights row r of the
Weights value. `RunBlocks`, SMC's base, holds the runs a hook serves now (while a hook runs for some of
them, those that resample this step) and what the step leaves: one value per run for R runs, the
paper's shapes for one.

This module imports numpy and mazelab.weights only: the grading sandbox ships it with the engine.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from mazelab.weights import Weights


class RunBlocks:
    """The R runs of a filter (SMC's base): the runs a hook serves and what the step leaves.

    The step template (mazelab.engine.SMC, from `start_runs` on) sets what these read: `runs` (R),
    `count` (N), `positions` (R*N, 2), `headings` (R*N,), `weights_value` (the Weights of the R runs),
    `run_log_evidence` (R,), the steps each run restarted and resampled at (`_reinitialised`,
    `_resampled_at`), and the runs a hook serves now (`_selected`; None: every run, `_every_run`).
    """

    # -- the runs a hook serves ------------------------------------------------------------------------
    @property
    def selected_runs(self) -> np.ndarray:
        """The runs the present hook serves (every run outside the hooks)."""
        return self._every_run if self._selected is None else self._selected

    def selected_rows(self, values: np.ndarray) -> np.ndarray:
        """The rows of an (R, ...) array that belong to the runs served now."""
        return values if self._selected is None else values[self._selected]

    def selected_points(self) -> np.ndarray:
        """The particles of the runs served now (R'*N, 2)."""
        if self._selected is None:
            return self.positions
        return np.concatenate([self.run_positions(run) for run in self._selected])

    def run_positions(self, run: int) -> np.ndarray:
        """Run `run`'s particles, a view (N, 2) of `positions`.

        Parameters
        ----------
        run : int

        Returns
        -------
        array (N, 2)
        """
        return self.positions[run * self.count : (run + 1) * self.count]

    def replace_runs(self, positions: np.ndarray, headings: np.ndarray, runs: np.ndarray) -> None:
        """New particles and headings for the given runs (their blocks, in order); the others keep theirs.

        Parameters
        ----------
        positions : array (len(runs) * N, 2)
        headings : array (len(runs) * N,)
        runs : int array
        """
        if len(runs) == self.runs:
            self.positions, self.headings, self.count = positions, headings, len(positions) // self.runs
            return
        self.positions = _replace_blocks(self.positions, positions, runs, self.count)
        self.headings = _replace_blocks(self.headings, headings, runs, self.count)

    # -- what the step leaves: one value per run for R runs, the paper's shapes for one -----------------
    @property
    def weights(self) -> np.ndarray:
        """The normalised weights W_i: (N,) for one run, (R, N) for R runs (float64; float32 as the compiled
        backend's normalisation writes them, every sum over them in float64)."""
        return self._one(self.weights_value.W)

    @property
    def log_weights(self) -> np.ndarray:
        """log W_i, normalised: (N,) for one run, (R, N) for R runs."""
        return self._one(self.weights_value.lw)

    @log_weights.setter
    def log_weights(self, values: np.ndarray) -> None:
        self.weights_value = Weights(np.asarray(values, dtype=float).reshape(self.runs, -1))

    @property
    def ess(self) -> float | np.ndarray:
        """N_eff = 1 / sum_i W_i^2: a float for one run, (R,) for R runs."""
        ess = self.weights_value.ess
        return float(ess[0]) if self.runs == 1 else ess

    @property
    def log_evidence(self) -> float | np.ndarray:
        """log p(z_1:k), the running estimate (particles' logLt): a float for one run, (R,) for R runs.
        A step that no particle explains adds the filter's (underflowing) estimate before its restart."""
        return float(self.run_log_evidence[0]) if self.runs == 1 else self.run_log_evidence.copy()

    @property
    def reinitialised_at(self) -> list[int] | list[list[int]]:
        """The steps at which no particle explained z and the filter restarted (a list per run for R runs)."""
        return self._one(self._reinitialised)

    @property
    def resampled_at(self) -> list[int] | list[list[int]]:
        """The steps after which the filter resampled (a list per run for R runs)."""
        return self._one(self._resampled_at)

    def _one(self, per_run: Any) -> Any:
        """Run 0's value for one run (the paper's shapes), all runs' otherwise."""
        return per_run[0] if self.runs == 1 else per_run


def _replace_blocks(values: np.ndarray, new: np.ndarray, runs: np.ndarray, size: int) -> np.ndarray:
    """A copy of `values` whose blocks of the given runs are the blocks of `new`, in order."""
    replaced = values.copy(order="F" if values.ndim > 1 else "C")
    for block, run in enumerate(runs):
        replaced[run * size : (run + 1) * size] = new[block * size : (block + 1) * size]
    return replaced


__all__ = ["RunBlocks"]
