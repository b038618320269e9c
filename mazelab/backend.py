"""Which implementation of the hot parts a particle filter runs on, and on how many threads.

"numpy" (mazelab.numpy_ops.NumpyKernels) is the reference, always there: the lab's code as it always
was, bit for bit. "compiled" (mazelab.kernels.compiled.CompiledKernels: numba, the `fast` extra) does
the same arithmetic but for the sums' order, the last bit of cos and sin and its own random streams, so
a seed repeats a run on each and the two agree statistically. Both offer the operations the model and
the weights call, so the step (mazelab.smc) does not know which runs. A filter takes the backend chosen
when it is made (`chosen_backend`, its `backend`); every result and record says which ran. The compiled
backend's threads (`shared_threads`) change how soon a run ends, never its numbers (mazelab.kernels).
"""

from __future__ import annotations

import importlib.metadata
import os
from collections import Counter
from collections.abc import Iterator
from contextlib import contextmanager
from contextvars import ContextVar
from functools import cache
from typing import Any

from mazelab.numpy_ops import NumpyKernels

BACKENDS = ("numpy", "compiled")
ENVIRONMENT_VARIABLE = "MAZELAB_BACKEND"
THREADS_VARIABLE = "MAZELAB_THREADS"  # the compiled backend's threads for a large call (--threads sets it)
INSTALL_HINT = 'the compiled backend needs numba: pip install -e ".[fast]" (uv sync installs it)'
# What the compiled backend costs and saves, CPU seconds (docs/speed.md): a one-run study on each backend (a 2-core
# Xeon), and numpy's step less the compiled one's (a 2-core AMD EPYC; mazelab.bench's filter_stepper; SIR, APF and
# RPF, one run of N = 100 and 10,000, 30 runs of 1,500 together).
STARTUP_SECONDS = 0.2  # numba's import and its kernels loaded from numba's cache: a process's extra CPU
SAVED_PER_STEP = 60e-6  # a filter step's saving whatever its particles (fewer Python calls): 65-110 us at N = 100
SAVED_PER_PARTICLE = 15e-9  # and per particle the step moves (R runs together: R x N): 9-30 ns
_WORK_CHOICE: ContextVar[str | None] = ContextVar("mazelab_work_backend", default=None)  # backend_by_work's


@cache
def numba_available() -> bool:
    """Whether numba can be imported here (it is the `fast` extra), asked once per process.

    Returns
    -------
    bool
    """
    try:
        import numba  # noqa: F401
    except Exception:  # none, or a numba that does not import with this numpy or Python
        return False
    return True


def check_backend(name: Any, source: str = "backend") -> str:
    """A backend's name, lower case, or one line naming the choices (and the extra for "compiled").

    Parameters
    ----------
    name : str
        "numpy" or "compiled".
    source : str
        What gave the name, for the message (an option, the environment variable).

    Returns
    -------
    str
    """
    chosen = name.strip().lower() if isinstance(name, str) else name
    if chosen not in BACKENDS:
        raise ValueError(f"{source} must be one of {', '.join(BACKENDS)}, got {name!r}")
    if chosen == "compiled" and not numba_available():
        raise ValueError(f"{source} {chosen}: {INSTALL_HINT}")
    return chosen


def chosen_backend() -> str:
    """The backend a filter made now runs on, the first of: MAZELAB_BACKEND (--backend and `use_backend`
    set it, so that a study's worker processes inherit it; checked), the enclosing `backend_by_work`'s
    choice, "compiled" where numba imports, "numpy".

    Returns
    -------
    str
    """
    value = os.environ.get(ENVIRONMENT_VARIABLE, "")
    if value.strip():
        return check_backend(value, ENVIRONMENT_VARIABLE)
    return _WORK_CHOICE.get() or ("compiled" if numba_available() else "numpy")


def backend_for_work(particle_steps: float, steps: float, processes: int = 1) -> str:
    """The backend for this much work: a choice already made stands (`chosen_backend`'s first two), else
    the compiled one where its faster steps pay back its start-up in each process (STARTUP_SECONDS),
    else "numpy", numba then never imported. A command runs inside `use_backend(backend_for_work(...))`,
    library code inside `backend_by_work`.

    Parameters
    ----------
    particle_steps : float
        The particles moved over the whole work: the sum over its filter steps of the particles each
        moves (N for one run, R x N for R runs advanced together).
    steps : float
        The filter steps (calls of `step`: R runs advanced together take one call a step).
    processes : int
        The processes the work is spread over (each pays the start-up).

    Returns
    -------
    str
        "numpy" or "compiled".
    """
    chosen = os.environ.get(ENVIRONMENT_VARIABLE, "").strip() or _WORK_CHOICE.get() is not None
    saved = steps * SAVED_PER_STEP + particle_steps * SAVED_PER_PARTICLE
    return chosen_backend() if chosen or saved > processes * STARTUP_SECONDS else "numpy"


@contextmanager
def backend_by_work(particle_steps: float, steps: float) -> Iterator[str]:
    """The filters made inside (in this thread) run on `backend_for_work`'s choice, without touching the
    environment (a library call such as `simulate` may run in a thread beside others).

    Parameters
    ----------
    particle_steps, steps : float
        The work (see backend_for_work).

    Yields
    ------
    str
        The backend chosen.
    """
    token = _WORK_CHOICE.set(backend_for_work(particle_steps, steps))
    try:
        yield chosen_backend()
    finally:
        _WORK_CHOICE.reset(token)


def cores() -> int:
    """The cores this process may run on (its CPU affinity where the system says, else the count).

    Returns
    -------
    int
    """
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1


def check_threads(value: Any, source: str = "threads") -> int:
    """A thread count from 1 to this machine's cores, or one line naming the range.

    Parameters
    ----------
    value : int or str
    source : str
        What gave it, for the message (an option, the environment variable).

    Returns
    -------
    int
    """
    try:
        count = int(str(value).strip())
    except ValueError:
        count = 0
    if not 1 <= count <= cores():
        raise ValueError(f"{source} must be a whole number from 1 to {cores()} (this machine's cores), got {value!r}")
    return count


def shared_threads(runs: int = 1, client: Any = None) -> int:
    """The threads each run takes for its large calls (mazelab.kernels.THREADED_FROM particles and more)
    where `runs` run at once on this machine (a filter made now: 1; a study: its local worker processes,
    or with `client` the most task threads one host of its Dask cluster has): MAZELAB_THREADS when set
    (--threads, `use_threads`; checked), else this machine's cores shared by them (at least 1 each: runs
    x threads <= cores). A study's units run inside `use_threads` of it.

    Parameters
    ----------
    runs : int
        The runs at once on this machine.
    client : distributed.Client, optional
        A Dask cluster's client (then `runs` is read from its hosts).

    Returns
    -------
    int
    """
    if client is not None:
        hosts: Counter[str] = Counter()
        for worker in client.scheduler_info(n_workers=-1)["workers"].values():
            hosts[worker["host"]] += worker["nthreads"]
        runs = max(hosts.values(), default=1)
    value = os.environ.get(THREADS_VARIABLE, "")
    return check_threads(value, THREADS_VARIABLE) if value.strip() else max(1, cores() // max(1, runs))


@contextmanager
def _environment(variable: str, value: str) -> Iterator[str]:
    """`variable` set to `value` in the environment for the time (processes started inside inherit it)."""
    before = os.environ.get(variable)
    os.environ[variable] = value
    try:
        yield value
    finally:
        if before is None:
            os.environ.pop(variable, None)
        else:
            os.environ[variable] = before


def use_backend(name: str) -> Any:
    """Make the filters created inside, and the processes started inside, run on the backend `name`.

    Parameters
    ----------
    name : str
        "numpy" or "compiled".

    Returns
    -------
    context manager
        Yields the backend's checked name.
    """
    return _environment(ENVIRONMENT_VARIABLE, check_backend(name))


def use_threads(count: int) -> Any:
    """Make the filters created inside, and the processes started inside, run their large calls on
    `count` threads.

    Parameters
    ----------
    count : int
        From 1 to this machine's cores (checked).

    Returns
    -------
    context manager
        Yields the count as a string.
    """
    return _environment(THREADS_VARIABLE, str(check_threads(count)))


def backend_versions() -> dict[str, str | None]:
    """What a record says of the backend: the chosen one's name, and numba's installed version (None
    without it; read from the package's metadata, so that a numpy run does not import numba).

    Returns
    -------
    dict
        {"backend": name, "numba": version or None}.
    """
    try:
        version = importlib.metadata.version("numba")
    except importlib.metadata.PackageNotFoundError:
        version = None
    return {"backend": chosen_backend(), "numba": version}


def backend_of(filt: Any) -> str:
    """The backend a filter ran on: its `backend` for the particle filters, "numpy" for any other (the
    grid filter, the EKF and plug-ins use numpy directly).

    Parameters
    ----------
    filt : a filter

    Returns
    -------
    str
    """
    name = getattr(filt, "backend", None)
    return name if name in BACKENDS else "numpy"


def kernels_for(world: Any) -> Any:
    """The operations of a filter made now on `world`: the numpy ones, or a new CompiledKernels on
    `shared_threads()` threads (`chosen_backend`'s choice).

    Parameters
    ----------
    world : Maze
        The filter's maze (the compiled likelihood reads its lookup tables).

    Returns
    -------
    NumpyKernels or mazelab.kernels.compiled.CompiledKernels
    """
    if chosen_backend() == "numpy":
        return NUMPY_KERNELS
    from mazelab.kernels.compiled import CompiledKernels  # imports numba: only when it runs

    return CompiledKernels(world, threads=shared_threads())


NUMPY_KERNELS = NumpyKernels()
