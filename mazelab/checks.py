"""Every guard of what a user hands in, checked up front: one clear ValueError naming the value.

Numbers and points: finite, within the bounds below (angles, places, sigma, the RPF's bandwidth, the
grid's cells, KLD-sampling's numbers, seeds). Memory: particle counts, step counts and maze sizes that
would not fit (more than MEMORY_SHARE of `memory_budget`) are refused in one line before anything is allocated.
"""

from __future__ import annotations

import math
import os
import stat
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from mazelab.constants import DEFAULT_PARTICLE_COUNT

try:
    import resource
except ImportError:  # not on Windows: no process limits there
    resource = None  # type: ignore[assignment]

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


def is_whole(value: Any) -> bool:
    """Whether a value is a whole number: a Python or numpy integer, not True or False."""
    return isinstance(value, (int, np.integer)) and not isinstance(value, bool)


def step_number(name: str, value: Any, what: str = "a step number") -> int:
    """A whole number >= 1 (a step number, a count: `what`, for the message), or a clear ValueError."""
    if not is_whole(value) or value < 1:
        raise ValueError(f"{name} must be {what} >= 1, got {value!r}")
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
    if not is_whole(value):
        raise ValueError(f"{name} must be a whole number >= 0, got {value!r}")
    if not 0 <= value < MAX_SEED:
        shown = f"{value}" if abs(value) < 10**40 else "a number of more than 40 digits"
        raise ValueError(f"{name} must be a whole number in [0, 2**128), got {shown}")
    return int(value)


def read_text_file(
    path: Path, kind: str, contents: str, error: type[ValueError], *, limit: int | None = None, per_byte: int = 0
) -> str:
    """The text of a `kind` file (a maze, a scenario), refusing at once and in one line (`error`) anything
    that is not a regular file (a folder, a device such as /dev/zero, a pipe, a socket), a file beyond `limit` bytes
    or whose parsing (`per_byte` bytes of memory per byte) would not fit, an unreadable or binary one.
    FileNotFoundError passes through: the caller says what to try instead."""
    try:
        status = path.stat()
        if stat.S_ISDIR(status.st_mode):
            raise error(f"{path}: is a folder, not a {kind} file")
        if not stat.S_ISREG(status.st_mode):
            raise error(f"{path}: not a regular file (a device, pipe or socket); a {kind} is a {contents} file")
        size = status.st_size
        if limit is not None and size > limit:
            raise error(f"{path}: {size} bytes is too large for a {kind} file (limit {limit})")
        check_memory(f"{path}: a {kind} file of {size} bytes", size * per_byte)  # 0 without `per_byte`: not checked
        with path.open("rb") as file:
            data = file.read(-1 if limit is None else limit + 1)  # at most one byte past the limit, whatever stat said
    except (FileNotFoundError, error):
        raise
    except MemoryLimitError as problem:  # too large to parse
        raise error(str(problem)) from None
    except PermissionError:
        raise error(f"{path}: not readable (permission denied)") from None
    except OSError as problem:
        raise error(f"{path}: cannot be read ({problem.strerror or problem})") from None
    if limit is not None and len(data) > limit:
        raise error(f"{path}: too large for a {kind} file (more than {limit} bytes)")
    try:
        return data.decode("utf-8-sig")  # a byte-order mark (some editors write one) is fine
    except UnicodeDecodeError as problem:
        where = f"not UTF-8 at byte {problem.start}"
        raise error(f"{path}: not a text file ({where}; a {kind} is a {contents} file)") from None


# -- memory ----------------------------------------------------------------------------------------
MEMORY_SHARE = 0.8  # refuse a request that needs more than this share of the budget
MEMORY_CHECKED_BYTES = 2**20  # a need up to this is never refused: no process runs on less (and /proc is not read)
BYTES_PER_PARTICLE = 400  # arrays a particle needs during a step, temporaries included (generous)
BYTES_PER_STEP = 1000  # a run's per-step arrays, the robot's path and the saved scenario (about 400 measured)
BYTES_PER_MAZE_CELL = 100  # a maze's grid, its lists and the generator's index arrays (generous)
BYTES_PER_LOOKUP_CELL = 250  # the nearest-station table per lookup cell, while it is built (about 170 measured)
BYTES_PER_STUDY_RUN = 1000  # a study's task per run (about 600 measured)
BYTES_PER_STUDY_RECORD = 1500  # a study's result row per run and filter, and its CSV line
# A run drawn into Rerun: its stream, threads and in-memory recording. Under an address-space limit
# (ulimit -v) Rerun's threads reserve most of what is left (measured: about 700 MiB of 800 MiB), so
# it needs far more there than the RAM it really uses (about 100 MiB).
RECORDING_ADDRESS_SPACE_BYTES = 576 * 2**20
RECORDING_RAM_BYTES = 160 * 2**20
BYTES_PER_DRAWN_PARTICLE = 24  # per drawn particle and step in the recording (position, colour, radius)
BYTES_PER_VIEWED_PARTICLE = 40  # per particle and step while the view picks what to draw (weights, indices)
ADDRESS_SPACE_SOURCE = "the address-space limit, ulimit -v"
_UNLIMITED = 2**60  # cgroup v1 writes "no limit" as a huge number near 2**63

CGROUP_ROOT = Path("/sys/fs/cgroup")
# a memory cgroup's limit, usage and reclaimable cache (a key of memory.stat), v2 (True) and v1 (False)
CGROUP_FILES = {
    True: ("memory.max", "memory.current", "inactive_file"),
    False: ("memory.limit_in_bytes", "memory.usage_in_bytes", "total_inactive_file"),
}
PROC_SELF = Path("/proc/self")


class MemoryLimitError(ValueError):
    """A request that does not fit in the memory budget; the message says what, how much and why."""


@dataclass(frozen=True)
class MemoryBudget:
    """Bytes this process may still allocate, and which limit says so (for the message)."""

    available: int
    source: str


def check_memory(what: str, needed: int, budget: MemoryBudget | None = None) -> None:
    """Refuse `what` (e.g. "particle_count 10**11") when its `needed` bytes exceed MEMORY_SHARE of the budget
    (the current one unless given); nothing happens where no limit is known or for MEMORY_CHECKED_BYTES or less."""
    if needed <= MEMORY_CHECKED_BYTES:
        return
    budget = memory_budget() if budget is None else budget
    if budget is not None and needed > MEMORY_SHARE * budget.available:
        raise MemoryLimitError(
            f"{what} needs about {_gib(needed)} GiB, but only {_gib(budget.available)} GiB of memory is available "
            f"({budget.source})"
        )


def particle_count(value: Any, source: str = "particle_count", given: int | None = None) -> int:
    """A run's particle count, checked once on its way to the filter: a whole number >= 1 (the count of
    the initial particles `given`, if any), whose arrays fit in memory; else one line naming `source`
    (an argument, or the command line's --particles).

    Parameters
    ----------
    value : int, or None (the given particles' count, else DEFAULT_PARTICLE_COUNT)
    source : str
    given : int, optional
        The number of initial particles handed in.
    """
    if value is None:
        value = DEFAULT_PARTICLE_COUNT if given is None else given
    value = step_number(source, value, "a whole number")
    if given is not None and value != given:
        raise ValueError(f"{source} is {value!r} but {given} initial particles are given")
    check_memory(f"particle_count {value}", value * BYTES_PER_PARTICLE)  # its arrays fit
    return value


def check_recording(particles: int, steps: int, max_drawn: int, budget: MemoryBudget | None = None) -> None:
    """Refuse a drawn run (--rrd, the viewer) whose particles and recording would not fit together:
    Rerun's own share (more under ulimit -v, see above), the drawn particles of every step kept in
    the recording, and the view's arrays over all particles."""
    budget = memory_budget() if budget is None else budget
    if budget is None:
        return
    rerun = RECORDING_ADDRESS_SPACE_BYTES if budget.source == ADDRESS_SPACE_SOURCE else RECORDING_RAM_BYTES
    needed = (
        particles * (BYTES_PER_PARTICLE + BYTES_PER_VIEWED_PARTICLE)
        + steps * min(particles, max_drawn) * BYTES_PER_DRAWN_PARTICLE
        + rerun
    )
    check_memory(f"particle_count {particles} with a recording of {steps} steps", needed, budget)


def check_steps(steps: Any) -> int:
    """A run's step count: a whole number >= 1 whose per-step results fit in memory, else one line."""
    steps = step_number("steps", steps, "a whole number")
    check_memory(f"steps {steps}", steps * BYTES_PER_STEP)
    return steps


def check_study(runs: int, filters: int) -> None:
    """Refuse a study whose tasks and result rows (`runs` runs in all, each with `filters` filters)
    would not fit, before the first task is made."""
    check_memory(f"a study of {runs} runs", runs * (BYTES_PER_STUDY_RUN + filters * BYTES_PER_STUDY_RECORD))


def memory_budget() -> MemoryBudget | None:
    """The least of the available RAM, the process limits and the cgroup limits; None if none is known."""
    known = [budget for budget in (available_ram(), *process_limits(), *cgroup_limits()) if budget is not None]
    return min(known, key=lambda budget: budget.available, default=None)


def available_ram(proc: Path = Path("/proc")) -> MemoryBudget | None:
    """MemAvailable of /proc/meminfo (free memory plus reclaimable cache), else the free pages."""
    available = _numbers_in(proc / "meminfo").get("MemAvailable")
    if available is not None:
        return MemoryBudget(available, "available RAM")
    try:
        return MemoryBudget(os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE"), "available RAM")
    except (AttributeError, ValueError, OSError):
        return None


def process_limits(proc_self: Path = PROC_SELF) -> list[MemoryBudget]:
    """What RLIMIT_AS (ulimit -v) and RLIMIT_DATA (ulimit -d), each one set, leave beyond this process's use."""
    if resource is None:
        return []
    sizes = _numbers_in(proc_self / "status")  # VmSize and VmData
    budgets = []
    for limit, used_key, source in (
        (resource.RLIMIT_AS, "VmSize", ADDRESS_SPACE_SOURCE),
        (resource.RLIMIT_DATA, "VmData", "the data-size limit, ulimit -d"),
    ):
        soft, _ = resource.getrlimit(limit)
        if soft != resource.RLIM_INFINITY:
            budgets.append(MemoryBudget(max(0, soft - sizes.get(used_key, 0)), source))
    return budgets


def _numbers_in(path: Path) -> dict[str, int]:
    """The numbers of a /proc or cgroup file of `key: value` or `key value` lines (meminfo, status,
    memory.stat), in bytes where the line says kB, a one-value file's (memory.max) under the key "";
    empty where the file cannot be read ("max", no limit, is no number)."""
    numbers = {}
    try:
        for line in path.read_text().splitlines():
            words = ["", *line.split()] if line.strip().isdigit() else line.replace(":", " ", 1).split()
            if len(words) > 1 and words[1].isdigit():
                numbers[words[0]] = int(words[1]) * (1024 if words[-1] == "kB" else 1)
    except OSError:
        pass
    return numbers


def cgroup_limits(root: Path = CGROUP_ROOT, proc_self: Path = PROC_SELF) -> list[MemoryBudget]:
    """What the cgroup memory limits leave, for this process's group and each ancestor that sets one:
    limit less usage (usage less inactive file cache, which the kernel reclaims first)."""
    budgets = []
    for folder, v2 in _cgroup_folders(root, proc_self):
        names = CGROUP_FILES[v2]
        limit = _numbers_in(folder / names[0]).get("")
        if limit is None or limit >= _UNLIMITED:
            continue
        used = _numbers_in(folder / names[1]).get("", 0) - _numbers_in(folder / "memory.stat").get(names[2], 0)
        source = f"the cgroup memory limit, {folder / names[0]}"
        budgets.append(MemoryBudget(max(0, limit - max(used, 0)), source))
    return budgets


def _cgroup_folders(root: Path, proc_self: Path) -> list[tuple[Path, bool]]:
    """The memory cgroup folders that may hold a limit on this process: (folder, is v2), its own group
    and its ancestors, and the mount's top (inside a container the group's path is often not mounted)."""
    try:
        lines = (proc_self / "cgroup").read_text().splitlines()
    except OSError:
        lines = []
    folders: list[tuple[Path, bool]] = []
    for line in lines:
        fields = line.split(":", 2)
        if len(fields) != 3:
            continue
        controllers, path = fields[1], fields[2]
        if controllers == "" and path:  # v2: "0::/path"
            base, v2 = root, True
        elif "memory" in controllers.split(","):  # v1: "N:memory:/path"
            base, v2 = root / "memory", False
        else:
            continue
        parts = [part for part in path.strip().split("/") if part]
        for depth in range(len(parts), -1, -1):
            folder = base.joinpath(*parts[:depth])
            if (folder, v2) not in folders:
                folders.append((folder, v2))
    return folders


def _gib(size: float) -> str:
    """Bytes in GiB for a message: one decimal, or two below 1 GiB."""
    return f"{size / 2**30:.1f}" if size >= 2**30 else f"{size / 2**30:.2f}"
