"""The whole filter against the exact posterior: on the seed's scenarios, the distance between the
student's estimates and the exact grid filter's posterior means, beside the shipped SIR's (run by the
grader, `References`); judged by the sign and the magnitude tests of docs/exercise.md ("What each
check promises"), which fail a filter that is the SIR in distribution with probability at most 0.0042.
"""

from __future__ import annotations

import math
import queue
import threading
import warnings
from collections.abc import Callable
from concurrent.futures import Executor, Future
from dataclasses import dataclass
from typing import Any

import numpy as np

from mazelab.exercise.child import Message
from mazelab.exercise.inputs import SCENARIO_COUNT, ScenarioInputs
from mazelab.exercise.parts import FAIL, PASS, Row, error_of, take
from mazelab.simulation import convergence_step, simulate

GRID_RESOLUTION = 0.05  # the exact filter's cells: fine next to L = 0.2, coarse enough to be quick
WORSE_LIMIT = 11  # fail when farther than the SIR from the exact mean on this many of the 12 scenarios
MAGNITUDE_ALPHA = 0.001  # the magnitude test's level (its p-value is a multiple of 1/4096)
NAN_HINT = "the estimate must be a number at every step: check the weights (all 0 or NaN?) and estimate"


def sign_test_alpha(limit: int = WORSE_LIMIT, scenarios: int = SCENARIO_COUNT) -> float:
    """P(Binomial(scenarios, 1/2) >= limit): the whole-filter check's false-alarm rate."""
    return sum(math.comb(scenarios, k) for k in range(limit, scenarios + 1)) / 2**scenarios


def expected_text(scheme: str = "systematic") -> str:
    return (
        f"no worse than SIR ({scheme}): farther on < {WORSE_LIMIT} of {SCENARIO_COUNT} (alpha "
        f"{sign_test_alpha():.4f}), distance ratio p > {MAGNITUDE_ALPHA:g}"
    )


def magnitude_p(distances: np.ndarray, sir_distances: np.ndarray) -> tuple[float, float]:
    """(the geometric mean of the distance ratios, the randomization test's p-value): the share of the
    2^n sign patterns of the log ratios whose sum reaches theirs (exact given the ratios' sizes)."""
    ratios = np.log((np.asarray(distances) + 1e-12) / (np.asarray(sir_distances) + 1e-12))
    n = len(ratios)
    signs = ((np.arange(2**n)[:, None] >> np.arange(n)) & 1) * 2 - 1
    sums = signs @ np.abs(ratios)
    return float(np.exp(ratios.mean())), float(np.mean(sums >= ratios.sum() - 1e-9))


# -- the grader's own runs ------------------------------------------------------------------------
def reference_run(scenario: ScenarioInputs, filter_name: str, **options: object) -> np.ndarray:
    """A shipped filter's estimates (steps, 2) on the scenario: the exact grid filter's posterior means
    ("grid"), or the SIR's ("sir", resampling with the student's scheme)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        result = simulate(
            scenario.robot(),
            scenario.world,
            scenario.sigma,
            scenario.delta,
            None,
            len(scenario.measurements),
            scenario.particles,
            filter_name,
            seed=scenario.seed,
            **options,
        )
    return result.estimates


_memo: dict[tuple, Future] = {}
_memo_lock = threading.Lock()


class Background(Executor):
    """One daemon thread working through what is submitted: a check that ends early does not wait
    for the reference runs it no longer needs (nor count them as threads left running)."""

    def __init__(self) -> None:
        self._queue: queue.SimpleQueue = queue.SimpleQueue()
        threading.Thread(target=self._work, name="mazelab-references", daemon=True).start()

    def submit(self, function: Callable[..., Any], /, *args: Any, **kwargs: Any) -> Future:
        future: Future = Future()
        self._queue.put((future, function, args, kwargs))
        return future

    def _work(self) -> None:
        while True:
            future, function, args, kwargs = self._queue.get()
            if not future.set_running_or_notify_cancel():
                continue
            try:
                future.set_result(function(*args, **kwargs))
            except BaseException as error:  # the future carries it to whoever waits
                future.set_exception(error)


_background: Background | None = None


class References:
    """The exact and the SIR runs of scenarios, each computed once per process (a memo of futures
    shared by every References), on `executor` (default: one background thread)."""

    def __init__(self, executor: Executor | None = None):
        self.executor = executor

    def _submit(self, key: tuple, scenario: ScenarioInputs, filter_name: str, **options: object) -> Future:
        global _background
        with _memo_lock:
            future = _memo.get(key)
            if future is not None and not (future.done() and (future.cancelled() or future.exception())):
                return future
            if self.executor is None and _background is None:
                _background = Background()
            future = (self.executor or _background).submit(reference_run, scenario, filter_name, **options)
            _memo[key] = future
            return future

    def exact(self, scenario: ScenarioInputs) -> Future:
        return self._submit(("exact", scenario.key), scenario, "grid", resolution=GRID_RESOLUTION)

    def sir(self, scenario: ScenarioInputs, scheme: str) -> Future:
        return self._submit(("sir", scheme, scenario.key), scenario, "sir", resampling=scheme)


# -- the verdict ------------------------------------------------------------------------------------
@dataclass
class ScenarioFigures:
    """One scenario: the student's and the SIR's distance to the exact mean (second half) and convergence."""

    maze: str
    seed: int
    sigma: float
    delta: float
    particles: int
    distance: float
    sir_distance: float
    converged: bool
    sir_converged: bool


FIGURE_COLUMNS = (  # the per-scenario table: each column's heading and its cell
    ("maze", lambda f: f.maze),
    ("sigma", lambda f: f"{f.sigma:.2f}"),
    ("delta", lambda f: f"{f.delta:.2f}"),
    ("N", lambda f: str(f.particles)),
    ("to exact", lambda f: f"{f.distance:.3f}"),
    ("SIR's", lambda f: f"{f.sir_distance:.3f}"),
    ("converged", lambda f: "yes" if f.converged else "no"),
    ("SIR's", lambda f: "yes" if f.sir_converged else "no"),
)


def distance_to_exact(estimates: np.ndarray, exact: np.ndarray) -> float:
    """Mean distance between a run's estimates and the exact posterior means over the second half."""
    window = slice(len(exact) // 2, None)
    return float(np.hypot(*(estimates - exact)[window].T).mean())


def converged(estimates: np.ndarray, truth: np.ndarray) -> bool:
    return convergence_step(np.hypot(*(estimates - truth).T)) is not None


def whole_answer(scenarios: list[ScenarioInputs], answer: Message, scheme: str) -> Row | list[np.ndarray]:
    """The student's estimates per scenario, or the failing row when there are none to compare: an
    error (naming the scenario) or an estimate that is not a number (naming the step)."""
    expected, error = expected_text(scheme), error_of(answer)
    if error:
        where = answer.meta.get("scenario")
        prefix = f"scenario {where + 1}: " if isinstance(where, int) and not isinstance(where, bool) else ""
        hint = NAN_HINT if "not finite" in error["text"] else "fix the error first"
        return Row("whole filter", FAIL, expected, prefix + error["text"], hint)
    estimates = []
    for i, scenario in enumerate(scenarios):
        mine = take(answer, f"estimates/{i}", (len(scenario.measurements), 2))
        if not np.isfinite(mine).all():
            step = int(np.argmin(np.isfinite(mine).all(axis=1))) + 1
            got = f"scenario {i + 1}: the estimate is {mine[step - 1].tolist()} at step {step}"
            return Row("whole filter", FAIL, expected, got, NAN_HINT)
        estimates.append(mine)
    return estimates


def judge_whole(
    scenarios: list[ScenarioInputs],
    estimates: list[np.ndarray],
    exact: list[np.ndarray],
    sir: list[np.ndarray],
    scheme: str,
) -> tuple[Row, list[ScenarioFigures]]:
    """The whole filter's row (the sign and magnitude tests against the SIR) and the figures per scenario."""
    figures = [
        ScenarioFigures(
            s.maze,
            s.seed,
            s.sigma,
            s.delta,
            len(s.particles),
            distance_to_exact(mine, exact[i]),
            distance_to_exact(sir[i], exact[i]),
            converged(mine, s.true_positions),
            converged(sir[i], s.true_positions),
        )
        for i, (s, mine) in enumerate(zip(scenarios, estimates, strict=True))
    ]
    worse = sum(not f.distance <= f.sir_distance for f in figures)  # NaN counts as worse
    mean, sir_mean = np.mean([f.distance for f in figures]), np.mean([f.sir_distance for f in figures])
    ratio, p = magnitude_p(np.array([f.distance for f in figures]), np.array([f.sir_distance for f in figures]))
    got = (
        f"farther on {worse} of {len(figures)}; to exact {mean:.3f} (SIR {sir_mean:.3f}); "
        f"converged {sum(f.converged for f in figures)}/{len(figures)} (SIR {sum(f.sir_converged for f in figures)}); "
        f"distance ratio {ratio:.2f} (p {p:.2g})"
    )
    if worse < WORSE_LIMIT and p > MAGNITUDE_ALPHA:
        return Row("whole filter", PASS, expected_text(scheme), got), figures
    hint = "the parts pass alone but not together: check what weigh and predict assume of each other"
    return Row("whole filter", FAIL, expected_text(scheme), got, hint), figures
