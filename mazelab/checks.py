"""Checks of the numbers and points a user hands in: one clear ValueError naming the value."""

from __future__ import annotations

import math
import stat
from pathlib import Path
from typing import Any

import numpy as np

MAX_MAZE_SIDE = 4000  # rows and columns of a maze, at most (its tables grow with their product)

# Angles are radians. A heading is periodic, so any real one lies within a few turns of zero; beyond
# MAX_ANGLE a float32 particle heading (spacing 2**-10 rad at 1e4, 50 times finer than the lab's least
# delta) would lose the compass's precision, and at 1e20 or so nothing of it is left: refused.
MAX_ANGLE = 1e4
# Map units. Coordinates and measured distances beyond this are no place on any maze (a maze has at
# most 4000 cells a side, mazelab.maze.MAX_MAZE_SIDE); they would overflow float32 particles (1e39).
MAX_COORDINATE = 1e6
# A measurement is z = d + sigma v with v standard normal: float64 draws never exceed NORMAL_TAIL,
# so a sigma up to (MAX_COORDINATE - map diagonal) / NORMAL_TAIL keeps every z a finite distance
# that a scenario can store; and above SIGMA_PER_DIAGONAL map diagonals a measurement says nothing.
NORMAL_TAIL = 10.0
SIGMA_PER_DIAGONAL = 100.0
# Below: the particles' residuals (d - z) / sigma are float32 and squared, so (diagonal / sigma)**2
# must stay below float32's largest number by a wide margin (RESIDUAL_HEADROOM), also in sums over steps.
RESIDUAL_HEADROOM = 1e6
# The RPF's kernel width h multiplies a cloud's spread (at most the map's diagonal) and normal draws:
# beyond MAX_BANDWIDTH the jitter throws every particle off any map; below MIN_BANDWIDTH it is nothing.
MAX_BANDWIDTH = 100.0
MIN_BANDWIDTH = 1e-12
# The grid filter's cell size: at most a maze cell (coarser cells cannot tell a wall from a corridor).
MAX_GRID_RESOLUTION = 1.0
MAX_SEED = 2**128  # seeds are whole numbers in [0, MAX_SEED): numpy's SeedSequence takes them whole
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
    """An (N, 2) float array of finite points with N >= 1, or a clear ValueError (the array itself when
    it is one already: no copy of a million particles; the callers copy or convert what they keep)."""
    try:
        points = np.asarray(value, dtype=float)
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


def map_diagonal(width: float, height: float) -> float:
    """The length of the map's diagonal, in map units."""
    return math.hypot(width, height)


def sigma_range(width: float, height: float) -> tuple[float, float]:
    """The sigmas (map units) that keep a run's arithmetic finite on a width x height map (see above)."""
    diagonal = map_diagonal(width, height)
    low = diagonal * RESIDUAL_HEADROOM / math.sqrt(float(np.finfo(np.float32).max))
    high = min(SIGMA_PER_DIAGONAL * diagonal, (MAX_COORDINATE - diagonal) / NORMAL_TAIL)
    return low, high


def check_sigma_within(sigma: float, width: float | None, height: float | None, name: str = "sigma") -> float:
    """A sigma within sigma_range of the map, or a one-line ValueError naming the range; without a
    map (None), within the widest range of any maze (a 1 x 1 one's least, a largest one's most)."""
    sigma = finite_number(name, sigma)
    if width is None or height is None:
        low, high = sigma_range(1, 1)[0], sigma_range(MAX_MAZE_SIDE, MAX_MAZE_SIDE)[1]
        where = "on any maze"
    else:
        (low, high), where = sigma_range(width, height), f"on a {width:g} x {height:g} map"
    if not low <= sigma <= high:
        raise ValueError(
            f"{name} must lie within [{low:.3g}, {high:.3g}] {where} "
            f"(beyond it the arithmetic overflows or the measurement says nothing), got {sigma:g}"
        )
    return sigma


def check_bandwidth_within(bandwidth: Any, width: float, height: float) -> Any:
    """An RPF bandwidth: a name ("optimal", "multimodal", checked by the engine) or a number h within
    [MIN_BANDWIDTH, MAX_BANDWIDTH]; a numeric string counts as its number. One-line ValueError."""
    if isinstance(bandwidth, str):
        try:
            number = float(bandwidth)
        except ValueError:
            return bandwidth
    else:
        number = bandwidth
    number = finite_number("bandwidth", number)
    if not MIN_BANDWIDTH <= number <= MAX_BANDWIDTH:
        raise ValueError(
            f"bandwidth must be optimal, multimodal or a number h within [{MIN_BANDWIDTH:g}, {MAX_BANDWIDTH:g}] "
            f"(h scales the cloud's spread, at most the {map_diagonal(width, height):.3g}-unit diagonal), "
            f"got {number:g}"
        )
    return bandwidth


def check_grid_resolution(resolution: Any) -> float:
    """The grid filter's cell size: a finite number in (0, MAX_GRID_RESOLUTION] map units (memory is
    checked where the grid is made). For GridBayesFilter(resolution=...)."""
    resolution = finite_number("resolution", resolution)
    if not 0 < resolution <= MAX_GRID_RESOLUTION:
        raise ValueError(
            f"resolution must lie in (0, {MAX_GRID_RESOLUTION:g}] map units (at most a maze cell), got {resolution:g}"
        )
    return resolution


MAX_KLD_QUANTILE = 40.0  # z_(1-delta) beyond this is no probability float64 can tell from 1
MAX_KLD_EPSILON = 1.0  # the KL bound: beyond 1 it bounds nothing a particle count can reach
MIN_KLD_EPSILON = 1e-9  # the count grows as 1/epsilon: below this it is no count at all


def check_kld_numbers(epsilon: Any, z: Any) -> tuple[float, float]:
    """KLD-sampling's error bound epsilon in [MIN_KLD_EPSILON, MAX_KLD_EPSILON] and quantile z in (0, MAX_KLD_QUANTILE]
    (the engine's KLDSampling checks the rest) as floats, or a one-line ValueError."""
    epsilon, z = finite_number("KLD epsilon", epsilon), finite_number("KLD z", z)
    if not MIN_KLD_EPSILON <= epsilon <= MAX_KLD_EPSILON:
        raise ValueError(f"KLD epsilon must lie in [{MIN_KLD_EPSILON:g}, {MAX_KLD_EPSILON:g}], got {epsilon:g}")
    if not 0 < z <= MAX_KLD_QUANTILE:
        raise ValueError(f"KLD z must lie in (0, {MAX_KLD_QUANTILE:g}] (a normal quantile), got {z:g}")
    return epsilon, z


def check_seed(name: str, value: Any) -> int:
    """A seed: a whole number in [0, MAX_SEED) (1.5 or True are refused, not rounded), or a ValueError."""
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        raise ValueError(f"{name} must be a whole number >= 0, got {value!r}")
    if not 0 <= value < MAX_SEED:
        shown = f"{value}" if abs(value) < 10**40 else "a number of more than 40 digits"
        raise ValueError(f"{name} must be a whole number in [0, 2**128), got {shown}")
    return int(value)


__all__ = [
    "MAP_MARGIN",
    "MAX_ANGLE",
    "MAX_BANDWIDTH",
    "MAX_COORDINATE",
    "MAX_GRID_RESOLUTION",
    "MAX_MAZE_SIDE",
    "MAX_SEED",
    "MIN_BANDWIDTH",
    "NORMAL_TAIL",
    "angle",
    "as_point",
    "as_points",
    "bounded_number",
    "check_all_within",
    "check_bandwidth_within",
    "check_grid_resolution",
    "check_kld_numbers",
    "check_seed",
    "check_sigma_within",
    "check_within_map",
    "coordinate",
    "finite_number",
    "map_diagonal",
    "regular_file_size",
    "sigma_range",
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
