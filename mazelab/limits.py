"""How much memory a command may take, checked up front: particle counts, step counts and maze sizes
that would not fit are refused with one line before anything is allocated.

The budget is the least of what is free: the available RAM (MemAvailable), the address-space and
data limits of this process (RLIMIT_AS, `ulimit -v`; RLIMIT_DATA, `ulimit -d`) less what it already
uses, and the cgroup memory limit (v2 memory.max, v1 memory.limit_in_bytes) less the group's usage.
A request is refused when it needs more than MEMORY_SHARE of that budget.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from mazelab.constants import DEFAULT_PARTICLE_COUNT

try:
    import resource
except ImportError:  # not on Windows: no process limits there
    resource = None  # type: ignore[assignment]

MEMORY_SHARE = 0.8  # refuse a request that needs more than this share of the budget
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
PROC_SELF = Path("/proc/self")


class MemoryLimitError(ValueError):
    """A request that does not fit in the memory budget; the message says what, how much and why."""


@dataclass(frozen=True)
class MemoryBudget:
    """Bytes this process may still allocate, and which limit says so (for the message)."""

    available: int
    source: str


def check_memory(what: str, needed: int, budget: MemoryBudget | None = None) -> None:
    """Refuse `what` (e.g. "particle_count 10**11") when its `needed` bytes exceed MEMORY_SHARE of the
    budget (the current one unless given); nothing happens where no limit is known."""
    budget = memory_budget() if budget is None else budget
    if budget is not None and needed > MEMORY_SHARE * budget.available:
        raise MemoryLimitError(
            f"{what} needs about {_gib(needed)} GiB, but only {_gib(budget.available)} GiB of memory is available "
            f"({budget.source})"
        )


def check_particles(count: int) -> None:
    """Refuse a particle count whose arrays would not fit."""
    check_memory(f"particle_count {count}", count * BYTES_PER_PARTICLE)


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

    Returns
    -------
    int
    """
    if value is None:
        value = DEFAULT_PARTICLE_COUNT if given is None else given
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
        raise ValueError(f"{source} must be a whole number >= 1, got {value!r}")
    if given is not None and value != given:
        raise ValueError(f"{source} is {value!r} but {given} initial particles are given")
    check_particles(int(value))
    return int(value)


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


def check_steps(steps: int) -> None:
    """Refuse a step count whose per-step results would not fit."""
    check_memory(f"steps {steps}", steps * BYTES_PER_STEP)


def check_study(runs: int, filters: int) -> None:
    """Refuse a study whose tasks and result rows (`runs` runs in all, each with `filters` filters)
    would not fit, before the first task is made."""
    check_memory(f"a study of {runs} runs", runs * (BYTES_PER_STUDY_RUN + filters * BYTES_PER_STUDY_RECORD))


def memory_budget() -> MemoryBudget | None:
    """The least of the available RAM, the process limits and the cgroup limit; None if none is known."""
    budgets = [available_ram(), process_limit(), cgroup_limit()]
    known = [budget for budget in budgets if budget is not None]
    return min(known, key=lambda budget: budget.available) if known else None


def available_ram(proc: Path = Path("/proc")) -> MemoryBudget | None:
    """MemAvailable of /proc/meminfo (free memory plus reclaimable cache), else the free pages."""
    try:
        for line in (proc / "meminfo").read_text().splitlines():
            if line.startswith("MemAvailable:"):
                return MemoryBudget(int(line.split()[1]) * 1024, "available RAM")
    except (OSError, ValueError, IndexError):
        pass
    try:
        return MemoryBudget(os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE"), "available RAM")
    except (AttributeError, ValueError, OSError):
        return None


def process_limit(proc_self: Path = PROC_SELF) -> MemoryBudget | None:
    """What RLIMIT_AS (ulimit -v) and RLIMIT_DATA (ulimit -d) leave beyond this process's current use."""
    if resource is None:
        return None
    sizes = _process_sizes(proc_self)
    budgets = []
    for limit, used_key, source in (
        (resource.RLIMIT_AS, "VmSize", ADDRESS_SPACE_SOURCE),
        (resource.RLIMIT_DATA, "VmData", "the data-size limit, ulimit -d"),
    ):
        soft, _ = resource.getrlimit(limit)
        if soft != resource.RLIM_INFINITY:
            budgets.append(MemoryBudget(max(0, soft - sizes.get(used_key, 0)), source))
    return min(budgets, key=lambda budget: budget.available) if budgets else None


def _process_sizes(proc_self: Path) -> dict[str, int]:
    """VmSize and VmData of /proc/self/status in bytes (empty where there is no /proc)."""
    sizes = {}
    try:
        for line in (proc_self / "status").read_text().splitlines():
            key, _, value = line.partition(":")
            if key in ("VmSize", "VmData"):
                sizes[key] = int(value.split()[0]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    return sizes


def cgroup_limit(root: Path = CGROUP_ROOT, proc_self: Path = PROC_SELF) -> MemoryBudget | None:
    """What the cgroup memory limit leaves: the least over this process's group and its ancestors of
    limit less usage (usage less inactive file cache, which the kernel reclaims first)."""
    budgets = []
    for folder, v2 in _cgroup_folders(root, proc_self):
        names = (
            ("memory.max", "memory.current", "inactive_file")
            if v2
            else (
                "memory.limit_in_bytes",
                "memory.usage_in_bytes",
                "total_inactive_file",
            )
        )
        limit = _read_number(folder / names[0])
        if limit is None or limit >= _UNLIMITED:
            continue
        used = (_read_number(folder / names[1]) or 0) - _stat_value(folder / "memory.stat", names[2])
        source = f"the cgroup memory limit, {folder / names[0]}"
        budgets.append(MemoryBudget(max(0, limit - max(used, 0)), source))
    return min(budgets, key=lambda budget: budget.available) if budgets else None


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


def _read_number(path: Path) -> int | None:
    """The whole number in a one-value cgroup file; None for "max", a missing or unreadable file."""
    try:
        return int(path.read_text().strip())
    except (OSError, ValueError):
        return None


def _stat_value(path: Path, key: str) -> int:
    """One value of a memory.stat file, 0 if absent."""
    try:
        for line in path.read_text().splitlines():
            name, _, value = line.partition(" ")
            if name == key:
                return int(value)
    except (OSError, ValueError):
        pass
    return 0


def _gib(size: float) -> str:
    """Bytes in GiB for a message: one decimal, or two below 1 GiB."""
    return f"{size / 2**30:.1f}" if size >= 2**30 else f"{size / 2**30:.2f}"
