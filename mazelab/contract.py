"""The filter contract: what every filter of the lab is, so that run, compare, study, accuracy and the
viewer take any class that meets it (the shipped ones, the exact grid filter, the EKF, a student's own).

A filter is a class built as `cls(world, sigma, delta, particles, rng, **options)` whose objects have:

    step(compass_angle, z)   advance one step: predict with the compass angle th0_k, update with z_k
    estimate                 the point estimate, shape (2,), finite
    ess                      the effective sample size, or NaN when the belief is not a sample
    is_confident             the paper's green circle: 95% of the belief within distance 1 of the estimate
    count                    particles (or cells, or 1 for a Gaussian) this step, a whole number >= 1
    reinitialised_at         the steps at which it restarted from the prior (no hypothesis explained z)
    belief()                 what the viewer draws: Particles, Density or Gaussian (below)
    diagnostics (optional)   a dict of this step's figures of its own, recorded per step
    log_evidence (optional)  log p(z_1:k), its estimate of the log evidence so far, recorded per step

and class attributes `name` (how results and the viewer label it) and `options`, every keyword option
the constructor takes, declared once (mazelab.declaration says how). The contract is checked on the
object before the first step (`check_filter`) and each step's values where they are read
(`check_step_values`): a missing part or a bad value is one line naming it.

A new filter, worked through (SIR that resamples every `period` steps: one option declared once, one
hook overridden), and the other hooks a particle filter may override: docs/architecture.md, "A new
filter". mazelab.exercise.StudentFilter is the gentler start: four parts to write, the rest wired.
"""

from __future__ import annotations

import math
import numbers
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from mazelab.checks import is_whole
from mazelab.declaration import options_of

# -- what a filter has to draw ---------------------------------------------------------------------


@dataclass(frozen=True)
class Particles:
    """A weighted sample: positions (N, 2), normalised weights (N,), headings (N,) or None; `injected`,
    the particles recovery put in this step (bool (N,)) or None; `modes`, the cloud's modes or None;
    `count_varies`, whether N changes from step to step (KLD-sampling: the viewer plots it)."""

    positions: np.ndarray
    weights: np.ndarray
    headings: np.ndarray | None = None
    injected: np.ndarray | None = None
    modes: Sequence[Any] | None = None
    count_varies: bool = False


@dataclass(frozen=True)
class Density:
    """A density on grid cells: the cell centres (M, 2) and their masses (M,); `modes` or None."""

    positions: np.ndarray
    weights: np.ndarray
    modes: Sequence[Any] | None = None


@dataclass(frozen=True)
class Gaussian:
    """A Gaussian belief: mean (2,) and covariance (2, 2)."""

    mean: np.ndarray
    covariance: np.ndarray


class NullView:
    """A view that draws nothing: what a run without drawing uses (a view is anything with `log_step`
    and `close`, and may have `expect_kidnapping(step, position)`, told of the robot's planned jump;
    mazelab.viz.views' draw into Rerun)."""

    def log_step(self, step: int, robot_position: Sequence[float], robot_heading: float | None, state: Any) -> None:
        """Draw step `step`: the robot and the filter `state`.

        Parameters
        ----------
        step : int
            k, from 1.
        robot_position : (x, y)
        robot_heading : float or None
            Radians.
        state : a filter
            Its belief, estimate, ESS and confidence.
        """

    def close(self) -> None:
        """Finish drawing (flush and close the recording)."""


def missing_parts(filter_class: type) -> list[str]:
    """The parts of the contract a class lacks (empty when it meets it), by name.

    Parameters
    ----------
    filter_class : type

    Returns
    -------
    list of str
        E.g. ["class attribute 'name'", "method step()"]; the attributes its objects set in __init__
        (count, reinitialised_at) cannot be seen on the class and are checked by `check_filter`.
    """
    missing = [f"class attribute {a!r}" for a in ("name", "options") if not hasattr(filter_class, a)]
    if hasattr(filter_class, "name") and not isinstance(filter_class.name, str):
        missing.append("'name' as a string")
    if hasattr(filter_class, "options"):
        try:
            options_of(filter_class)
        except (TypeError, ValueError):
            missing.append("'options' as a mapping of option names to defaults (or mazelab.declaration.Options)")
    missing += [f"method {m}()" for m in ("step", "belief") if not callable(getattr(filter_class, m, None))]
    return missing


class ContractError(TypeError, ValueError):
    """A filter object that misses part of the contract or hands back a bad value: one line naming it."""


def check_filter(filt: Any) -> None:
    """Refuse an object that misses part of the contract or has a mistyped part, naming it.

    Parameters
    ----------
    filt : object
        A filter just built, before its first step: its parts are there and `reinitialised_at` is a
        list of step numbers (estimate, ess, is_confident and count are checked where they are read,
        after each step: `check_step_values`).

    Raises
    ------
    ContractError
        One line: the filter, then what is missing or mistyped.
    """
    name = getattr(type(filt), "name", type(filt).__name__)
    missing = missing_parts(type(filt))
    for attribute in ("estimate", "ess", "is_confident", "count", "reinitialised_at"):  # set by __init__ or properties
        try:  # a property's code is not run (a student's `estimate` is read after the first step: errors name it)
            if not isinstance(getattr(type(filt), attribute, None), property):
                getattr(filt, attribute)
        except AttributeError:
            missing.append(f"attribute {attribute!r}")
    if missing:
        raise ContractError(f"{name} does not meet the filter contract: it has no {', '.join(missing)}")
    restarts = filt.reinitialised_at
    if not isinstance(restarts, (list, tuple)) or not all(is_whole(s) for s in restarts):
        raise ContractError(
            f"{name}.reinitialised_at must be a list of step numbers (whole numbers), got {_shown(restarts)}"
        )


def check_step_values(
    filter_class: type, values: tuple[Any, Any, Any, Any], runs: int | None = None
) -> tuple[np.ndarray, Any, Any, int]:
    """A step's values (estimate, ess, is_confident, count) as read from a filter, each checked.

    Parameters
    ----------
    filter_class : type
        The filter's class, for the messages.
    values : (estimate, ess, is_confident, count)
    runs : int, optional
        R for a filter advancing R runs together: estimate (R, 2), ess and is_confident (R,).

    Returns
    -------
    (estimate, ess, is_confident, count)
        estimate float64 (2,) or (R, 2); ess a float (NaN: not a sample) or (R,); is_confident bool or (R,).

    Raises
    ------
    ContractError
        One line naming the part and the value: an estimate that is not finite or not (2,), an ess that
        is no number, a confidence that is not True or False, a count that is not a whole number >= 1.
    """
    raw_estimate, ess, confident, count = values
    name = getattr(filter_class, "name", filter_class.__name__)
    shape = (2,) if runs is None else (runs, 2)
    try:
        estimate = np.asarray(raw_estimate, dtype=float)
    except (TypeError, ValueError):
        raise ContractError(f"{name}.estimate must be a point (x, y), got {_shown(raw_estimate)}") from None
    if estimate.shape != shape:
        raise ContractError(f"{name}.estimate must have shape {shape}, got {estimate.shape}")
    if not np.isfinite(estimate).all():
        raise ContractError(f"{name}.estimate must be finite, got {_shown(estimate)}")
    if runs is None:
        if isinstance(ess, (bool, np.bool_)) or not isinstance(ess, numbers.Real) or not (math.isnan(ess) or ess >= 0):
            raise ContractError(f"{name}.ess must be a number >= 0 (or NaN when not a sample), got {_shown(ess)}")
        ess = float(ess)
        if not isinstance(confident, (bool, np.bool_)):
            raise ContractError(f"{name}.is_confident must be True or False, got {_shown(confident)}")
    if not is_whole(count) or count < 1:
        raise ContractError(f"{name}.count must be a whole number >= 1, got {_shown(count)}")
    return estimate, ess, confident, int(count)


def _shown(value: Any) -> str:
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


__all__ = [
    "ContractError",
    "Density",
    "Gaussian",
    "NullView",
    "Particles",
    "check_filter",
    "check_step_values",
    "missing_parts",
]
