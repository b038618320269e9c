"""Start-up apart from the time per step: the one-off costs of a process (importing numba and loading the
compiled kernels, numpy's and the filters' first calls, lazily imported modules) are paid here, before
any timed step, so that a filter's ms/step is the same whichever order the filters run in and whether
or not it is the first run of a worker. Each filter is warmed once per process, backend and set of
options (a different option can reach different kernels), by a few untimed steps on a walk of its own
(its numbers are thrown away; no seed of the study is drawn from). The time spent is kept as the
process's start-up (`take_startup_seconds`), which the study and compare report apart, once.

A maze's nearest-station table is built before the timed steps too (`Maze.prepare`): a run on a new
maze (a generated one) would otherwise charge it to the first filter's first step."""

from __future__ import annotations

import os
import socket
import time
import warnings
from collections.abc import Callable, Hashable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

from mazelab.backend import chosen_backend
from mazelab.declaration import options_of
from mazelab.experiments.record import dependency_versions
from mazelab.maze import Maze
from mazelab.registry import resolve_filter
from mazelab.robot import Robot
from mazelab.seeding import start_place
from mazelab.simulation import simulate

WARM_UP_STEPS = 3  # untimed steps per filter: the first loads the kernels, the next ones reach the resampling
# (a filter that resamples when N_eff < threshold N is warmed again with threshold 1, which resamples at once)
WARM_UP_SEED = 0  # the warm-up walk's seed (its numbers are discarded)
REPORTED_PACKAGES = ("numpy", "numba", "llvmlite")  # the versions a worker reports with its backend

_warmed: set[Hashable] = set()  # what this process has warmed: (filter, backend, options, shape)
_startup_seconds = [0.0]  # start-up spent in this process and not yet reported


def warm_once(key: Hashable, warm: Callable[[], Any]) -> None:
    """Run `warm()` the first time this process sees `key` (with the chosen backend), its time kept
    as start-up; the warnings it raises are dropped (the study or compare shows its own)."""
    key = (key, chosen_backend())
    if key in _warmed:
        return
    started = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        warm()
    _warmed.add(key)
    _startup_seconds[0] += time.perf_counter() - started


def options_key(filter_class: type, options: Mapping[str, Any]) -> str:
    """A filter's options as part of a warm-up key: those that differ from their declared default (a
    filter given its defaults runs the same code as one given nothing)."""
    declared = options_of(filter_class)
    return repr(sorted((k, v) for k, v in options.items() if k not in declared or declared[k].default != v))


def warm_up_options(filter_class: type, options: Mapping[str, Any]) -> list[dict[str, Any]]:
    """The options to warm a filter with: its own, and, for one that resamples only when N_eff falls below
    threshold N (the RPF's 0.2 N: a few steps may not reach it), the same with threshold 1, so that its
    resampling's code (the RPF's covariance and jitter) is loaded before the timed steps too."""
    declared = options_of(filter_class).get("threshold")
    own = dict(options)
    if declared is None or own.get("threshold", declared.default) >= 1:
        return [own]
    return [own, {**own, "threshold": 1.0}]


def warm_up_filters(
    world: Maze,
    sigma: float,
    delta: float,
    filter_names: Sequence[str],
    particle_count: int | None,
    options: Mapping[str, Mapping[str, Any]],
) -> None:
    """Before a run's timed steps: the maze's table built, and each filter (with its options) warmed
    once per process by WARM_UP_STEPS steps on a walk of its own (mazelab.simulation.simulate)."""
    world.prepare()
    for name in filter_names:
        own = dict(options.get(name, {}))

        filter_class = resolve_filter(name)

        def warm(name: str = name, filter_class: type = filter_class, own: dict[str, Any] = own) -> None:
            for warmed in warm_up_options(filter_class, own):
                robot = Robot(sigma, delta, start_place(world, WARM_UP_SEED))
                simulate(robot, world, sigma, delta, particle_count, WARM_UP_STEPS, None, name, seed=WARM_UP_SEED,
                         **warmed)  # fmt: skip

        warm_once(("single", filter_class, options_key(filter_class, own)), warm)


def take_startup_seconds() -> float:
    """The start-up this process spent since it was last taken (then 0 until more is spent)."""
    seconds, _startup_seconds[0] = _startup_seconds[0], 0.0
    return seconds


@dataclass
class WorkerReport:
    """What a process that ran a study's runs says of itself with its results: where it ran, its
    backend and package versions (a study refuses workers that disagree), and the start-up it spent."""

    worker: str  # host:pid
    backend: str
    packages: dict[str, str | None] = field(default_factory=dict)
    startup_seconds: float = 0.0

    def describe(self) -> str:
        versions = ", ".join(f"{name} {v or 'none'}" for name, v in self.packages.items())
        return f"{self.worker}: backend {self.backend} ({versions})"


def worker_report(startup_seconds: float = 0.0) -> WorkerReport:
    """This process's report (mazelab.backend.chosen_backend, the installed versions)."""
    return WorkerReport(
        f"{socket.gethostname()}:{os.getpid()}",
        chosen_backend(),
        dependency_versions(REPORTED_PACKAGES),
        startup_seconds,
    )
