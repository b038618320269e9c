"""An existing Dask cluster for a study's runs (`study --dask ADDRESS`), through dask.distributed's
Client (the optional extra `pip install -e ".[dask]"`): connecting in one line or refusing, asking
the workers before any run, and saying what is left of a cluster that stopped finishing runs. The
runs themselves go through the Client's executor, as on the local pool (mazelab.experiments.executor),
so every run's figures are the same bit for bit."""

from __future__ import annotations

import contextlib
import logging
import socket
import sys
from typing import Any

from mazelab.experiments.warmup import WorkerReport, worker_report

CONNECT_SECONDS = 3  # a scheduler that does not answer within this is reported unreachable
DASK_TIMEOUT = 300.0  # seconds without any finished run after which a study on Dask gives up (--dask-timeout)
SCHEMES = ("tcp",)  # what --dask takes: tls, ucx and others need a security or transport setup of their own
# The loggers silenced while a study runs on Dask: distributed's configuration gives some of their
# children a level and a handler of their own (distributed.client: warning), so each is set, not
# only the parents.
QUIET_LOGGERS = ("distributed", "tornado", "asyncio", "bokeh")


def connect(address: str, timeout: float = CONNECT_SECONDS) -> Any:
    """A dask.distributed Client of the scheduler at `address` (e.g. tcp://10.0.0.5:8786), or a
    ValueError of one line: dask missing, another scheme than tcp://, or the scheduler unreachable
    within `timeout` seconds (probed with a plain socket first, so no half-made Client lingers)."""
    try:
        from distributed import Client
    except ImportError:
        raise ValueError('--dask needs dask.distributed: pip install -e ".[dask]"') from None
    host, port = parse_scheduler_address(address)
    quiet_distributed()
    try:
        with socket.create_connection((host, port), timeout=timeout):
            pass
    except OSError as error:
        reason = error.strerror or type(error).__name__ if not isinstance(error, TimeoutError) else "no answer"
        raise ValueError(f"cannot reach the Dask scheduler at {address!r}: {reason} within {timeout:g} s") from None
    try:
        return Client(address, timeout=timeout, set_as_default=False)
    except MemoryError:  # something answers there, but not Dask's protocol (a frame of exabytes)
        raise ValueError(f"cannot reach the Dask scheduler at {address!r}: what answers there is not one") from None
    except Exception as error:  # OSError, TimeoutError, ValueError (not a scheduler there), ...
        reason = str(error).splitlines()[0] if str(error) else type(error).__name__
        raise ValueError(f"cannot reach the Dask scheduler at {address!r}: {reason}") from None


def parse_scheduler_address(address: str) -> tuple[str, int]:
    """(host, port) of tcp://HOST:PORT, or a one-line ValueError naming --dask."""
    from distributed.comm import parse_address
    from distributed.comm.addressing import parse_host_port

    usage = f"--dask {address!r} is not a scheduler address like tcp://HOST:8786"
    try:  # a malformed address is refused here: a Client that fails to parse it lingers at exit
        scheme, location = parse_address(address)
        if scheme not in SCHEMES:
            raise ValueError(f"{usage} (only tcp:// is supported, not {scheme}://)")
        host, port = parse_host_port(location)
    except ValueError as error:
        raise ValueError(str(error) if str(error).startswith(usage) else f"{usage} ({error})") from None
    except TypeError as error:
        raise ValueError(f"{usage} ({error})") from None
    if not port or not 0 < int(port) < 65536:
        raise ValueError(f"{usage} (no port)")
    return host, int(port)


def quiet_distributed() -> None:
    """distributed's own logging (retries, lost connections, tracebacks) off, and the noise of a
    Client collected late ("Exception ignored in Client.__del__") dropped: this program says in one
    line what went wrong."""
    names = [n for n in list(logging.Logger.manager.loggerDict) if n.split(".")[0] in QUIET_LOGGERS]
    for name in dict.fromkeys([*QUIET_LOGGERS, *names]):
        logging.getLogger(name).setLevel(logging.CRITICAL + 1)
    previous = sys.unraisablehook
    if getattr(previous, "_mazelab_quiet", False):
        return

    def hook(unraisable: Any) -> None:
        where = " ".join(
            str(getattr(thing, "__module__", "") or "") for thing in (unraisable.object, type(unraisable.object))
        )
        if "distributed" not in where and "tornado" not in where:
            previous(unraisable)

    hook._mazelab_quiet = True  # type: ignore[attr-defined]
    sys.unraisablehook = hook


def check_workers(client: Any, backend: str) -> list[WorkerReport]:
    """Each Dask worker's report (mazelab.experiments.warmup), asked before any run: a worker that cannot
    run the study's `backend` (compiled without numba) or whose package versions differ from the
    others' would make rows that do not belong together, so it is refused in one line naming it."""
    try:
        reports = client.run(worker_report)
    except Exception as error:  # a worker without mazelab, or gone
        reason = str(error).splitlines()[0] if str(error) else type(error).__name__
        raise ValueError(f"the Dask workers cannot say their backend: {reason}") from None
    reports = [reports[address] for address in sorted(reports)]
    for report in reports:
        if backend == "compiled" and report.packages.get("numba") is None:
            raise ValueError(f"the Dask worker {report.describe()} cannot run the compiled backend: install numba "
                             "there, or give --backend numpy")  # fmt: skip
        if report.packages != reports[0].packages:
            raise ValueError(
                f"the Dask workers disagree ({reports[0].describe()}; {report.describe()}): start every worker "
                "with the same packages"
            )
    return reports


def close_client(client: Any) -> None:
    """Close the connection (the cluster itself goes on); quietly, also when the cluster is gone."""
    with contextlib.suppress(Exception):
        client.close(timeout=CONNECT_SECONDS)


def describe_workers(client: Any) -> str:
    """'no worker is left' or 'N worker(s) connected', for the timeout's message."""
    try:
        count = len(client.scheduler_info(n_workers=-1).get("workers", {}))
    except TypeError:  # an older distributed without n_workers
        count = len(client.scheduler_info().get("workers", {}))
    except Exception:
        return "the scheduler does not answer"
    return "no worker is left" if count == 0 else f"{count} worker(s) connected, none finishing"


__all__ = [
    "CONNECT_SECONDS",
    "DASK_TIMEOUT",
    "QUIET_LOGGERS",
    "check_workers",
    "close_client",
    "connect",
    "describe_workers",
    "parse_scheduler_address",
    "quiet_distributed",
]
