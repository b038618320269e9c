"""Checks of the numbers and points a user hands in: one clear ValueError naming the value."""

from __future__ import annotations

import math
from typing import Any

import numpy as np


def finite_number(name: str, value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise ValueError(f"{name} must be a number, got {value!r}")
    if not math.isfinite(value):
        raise ValueError(f"{name} must be finite, got {value}")
    return float(value)


def as_point(name: str, value: Any) -> tuple[float, float]:
    try:
        x, y = value
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a pair (x, y), got {value!r}") from None
    return finite_number(f"{name} x", x), finite_number(f"{name} y", y)


def step_number(name: str, value: Any) -> int:
    """A whole step number >= 1, or a clear ValueError."""
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
        raise ValueError(f"{name} must be a step number >= 1, got {value!r}")
    return int(value)


def as_points(name: str, value: Any) -> np.ndarray:
    """An (N, 2) float array of finite points with N >= 1, or a clear ValueError."""
    try:
        points = np.array(value, dtype=float)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a list of (x, y) pairs") from None
    if points.ndim != 2 or points.shape[1] != 2 or len(points) == 0:
        raise ValueError(f"{name} must be a non-empty list of (x, y) pairs, got shape {points.shape}")
    if not np.isfinite(points).all():
        raise ValueError(f"{name} contains a value that is not finite")
    return points


__all__ = [
    "as_point",
    "as_points",
    "finite_number",
    "step_number",
]
