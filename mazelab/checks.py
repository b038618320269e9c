"""Checks of the numbers and points a user hands in: one clear ValueError naming the value."""

from __future__ import annotations

import math
import stat
from pathlib import Path
from typing import Any

import numpy as np

# Angles are radians. A heading is periodic, so any real one lies within a few turns of zero; beyond
# MAX_ANGLE a float32 particle heading (spacing 2**-10 rad at 1e4, 50 times finer than the lab's least
# delta) would lose the compass's precision, and at 1e20 or so nothing of it is left: refused.
MAX_ANGLE = 1e4
# Map units. Coordinates and measured distances beyond this are no place on any maze (a maze has at
# most 4000 cells a side, mazelab.maze.MAX_MAZE_SIDE); they would overflow float32 particles (1e39).
MAX_COORDINATE = 1e6
# Map units: particles may lie this far beyond the map's border (they are penalised there, equation
# (3)); farther out they are a typo, not a belief about the robot.
MAP_MARGIN = 10.0


def finite_number(name: str, value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise ValueError(f"{name} must be a number, got {value!r}")
    if not math.isfinite(value):
        raise ValueError(f"{name} must be finite, got {value}")
    return float(value)


def bounded_number(name: str, value: Any, bound: float, unit: str) -> float:
    """A finite number with |value| <= bound, or a ValueError naming the value and the bound."""
    value = finite_number(name, value)
    if abs(value) > bound:
        raise ValueError(f"{name} must lie within [-{bound:g}, {bound:g}] {unit}, got {value:g}")
    return value


def check_all_within(name: str, values: Any, bound: float, unit: str) -> None:
    """`bounded_number` for a whole array at numpy speed (a scenario holds a pair per particle), naming
    the first value out of bounds by its index, e.g. init_particles_pos[3][0]."""
    array = np.asarray(values, dtype=float)
    bad = np.argwhere(~(np.abs(array) <= bound))  # NaN is caught too
    if len(bad):
        index = tuple(int(i) for i in bad[0])
        bounded_number(name + "".join(f"[{i}]" for i in index), float(array[index]), bound, unit)


def angle(name: str, value: Any) -> float:
    """An angle in radians, finite and within MAX_ANGLE of zero."""
    return bounded_number(name, value, MAX_ANGLE, "radians")


def coordinate(name: str, value: Any) -> float:
    """A map coordinate or a measured distance, finite and within MAX_COORDINATE map units of zero."""
    return bounded_number(name, value, MAX_COORDINATE, "map units")


def as_point(name: str, value: Any) -> tuple[float, float]:
    try:
        x, y = value
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a pair (x, y), got {value!r}") from None
    return coordinate(f"{name} x", x), coordinate(f"{name} y", y)


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


def check_within_map(name: str, points: Any, width: float, height: float, margin: float = MAP_MARGIN) -> None:
    """Refuse points (N, 2) lying more than `margin` map units beyond a width x height map, naming the
    first one (a particle at [1e39, 1] is a typo that would overflow float32)."""
    points = np.asarray(points, dtype=float).reshape(-1, 2)
    x, y = points[:, 0], points[:, 1]
    beyond = np.flatnonzero(~((x >= -margin) & (x <= width + margin) & (y >= -margin) & (y <= height + margin)))
    if len(beyond):
        i = int(beyond[0])
        raise ValueError(
            f"{name}[{i}] = ({x[i]:g}, {y[i]:g}) lies more than {margin:g} map units beyond the "
            f"{width:g} x {height:g} map ({len(beyond)} such point(s))"
        )


__all__ = [
    "MAP_MARGIN",
    "MAX_ANGLE",
    "MAX_COORDINATE",
    "angle",
    "as_point",
    "as_points",
    "bounded_number",
    "check_all_within",
    "check_within_map",
    "coordinate",
    "finite_number",
    "step_number",
]


def regular_file_size(path: Path, kind: str, contents: str) -> int:
    """The size in bytes of `path`, which must be a regular file: a folder, device (/dev/zero), pipe or
    socket is refused with a ValueError naming it. OSError (a missing file, no permission) passes through."""
    status = path.stat()
    if stat.S_ISDIR(status.st_mode):
        raise ValueError(f"{path}: is a folder, not a {kind} file")
    if not stat.S_ISREG(status.st_mode):
        raise ValueError(f"{path}: not a regular file (a device, pipe or socket); a {kind} is a {contents} file")
    return status.st_size
