"""The filter contract: what every filter of the lab is, so that run, compare, study, accuracy and the
viewer take any class that meets it (the shipped ones, the exact grid filter, the EKF, a student's own).

A filter is a class built as `cls(world, sigma, delta, particles, rng, **options)` whose objects have:

    step(compass_angle, z)   advance one step: predict with the compass angle th0_k, update with z_k
    estimate                 the point estimate, shape (2,)
    ess                      the effective sample size, or NaN when the belief is not a sample
    is_confident             the paper's green circle: 95% of the belief within distance 1 of the estimate
    count                    particles (or cells, or 1 for a Gaussian) this step
    reinitialised_at         the steps at which it restarted from the prior (no hypothesis explained z)
    belief()                 what the viewer draws: Particles, Density or Gaussian (below)

and class attributes `name` (how results and the viewer label it) and `options` (every keyword option
the constructor takes, with its default). An option a filter does not declare is refused for it, by
`check_options`, with one line that names the option and the filter.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any, ClassVar, Protocol, runtime_checkable

import numpy as np

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


Belief = Particles | Density | Gaussian


@runtime_checkable
class Filter(Protocol):
    """What every filter provides (see the module's docstring)."""

    name: ClassVar[str]
    options: ClassVar[Mapping[str, Any]]
    count: int
    reinitialised_at: list[int]

    def step(self, compass_angle: float, z: float) -> None:
        """Predict with the compass angle th0_k (radians), then update with the measurement z_k (map units)."""

    @property
    def estimate(self) -> np.ndarray:
        """The point estimate of the position, shape (2,)."""

    @property
    def ess(self) -> float:
        """The effective sample size 1 / sum W_i^2, or NaN when the belief is not a sample."""

    @property
    def is_confident(self) -> bool:
        """At least 95% of the belief lies within distance 1 of the estimate."""

    def belief(self) -> Belief:
        """What the viewer draws this step."""


REQUIRED_METHODS = ("step", "belief")
REQUIRED_ATTRIBUTES = ("estimate", "ess", "is_confident", "count", "reinitialised_at")


def missing_parts(filter_class: type) -> list[str]:
    """The parts of the contract a class lacks (empty when it meets it), by name; the attributes its
    objects set in __init__ (count, reinitialised_at) cannot be seen on the class and are checked on
    an object by `check_filter`."""
    missing = [f"class attribute {a!r}" for a in ("name", "options") if not hasattr(filter_class, a)]
    if hasattr(filter_class, "options") and not isinstance(filter_class.options, Mapping):
        missing.append("'options' as a mapping of option names to defaults")
    missing += [f"method {m}()" for m in REQUIRED_METHODS if not callable(getattr(filter_class, m, None))]
    return missing


def check_filter(filt: Any) -> None:
    """Refuse an object that misses part of the contract, naming what is missing."""
    missing = missing_parts(type(filt))
    missing += [f"attribute {a!r}" for a in REQUIRED_ATTRIBUTES if not hasattr(filt, a)]
    if missing:
        raise TypeError(f"{type(filt).__name__} does not meet the filter contract: it has no {', '.join(missing)}")


def check_options(filter_class: type, options: Mapping[str, Any], *, spelled: Mapping[str, str] | None = None) -> None:
    """Refuse any option that `filter_class` does not declare, in one line naming the option and the
    filter; `spelled` maps an option to how the user wrote it (e.g. "bandwidth" -> "--bandwidth")."""
    declared = filter_class.options
    for option in options:
        if option not in declared:
            shown = (spelled or {}).get(option, option)
            takes = ", ".join(declared) or "no options"
            raise ValueError(f"{filter_class.name} does not take the option {shown} (it takes: {takes})")


def options_for(
    filter_classes: Sequence[type], given: Mapping[str, Any], *, spelled: Mapping[str, str] | None = None
) -> dict[str, dict[str, Any]]:
    """Per filter (by `name`), the given options (None: not given) that it declares; several filters
    share the options given, each taking its own. An option that none of them declares is refused in
    one line naming the option (as the user `spelled` it), the filters and what they take."""
    spelled = spelled or {}
    chosen = {option: value for option, value in given.items() if value is not None}
    for option in chosen:
        if not any(takes(cls, option) for cls in filter_classes):
            names = " and ".join(cls.name for cls in filter_classes)
            offered = [spelled.get(o, o) for o in given if any(takes(cls, o) for cls in filter_classes)]
            they = "they take" if len(filter_classes) > 1 else "it takes"
            take_list = f"; {they} {', '.join(offered)}" if offered else ""
            verb = "do" if len(filter_classes) > 1 else "does"
            raise ValueError(f"{names} {verb} not take {spelled.get(option, option)}{take_list}")
    return {cls.name: {o: v for o, v in chosen.items() if takes(cls, o)} for cls in filter_classes}


def takes(filter_class: type, option: str) -> bool:
    """Whether `filter_class` declares `option`."""
    return option in filter_class.options


__all__ = [
    "Belief",
    "Density",
    "Filter",
    "Gaussian",
    "Particles",
    "check_filter",
    "check_options",
    "missing_parts",
    "options_for",
    "takes",
]
