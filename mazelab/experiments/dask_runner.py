"""A study's runs on an existing Dask cluster (`study --dask ADDRESS`), through dask.distributed's
Client: the optional extra `pip install -e ".[dask]"`. The workers run the same functions on the
same seeded tasks as the local pool, so every run's figures are the same bit for bit."""

from __future__ import annotations

import contextlib
import logging
from collections.abc import Callable, Sequence
from typing import Any

from mazelab.experiments.study import RunFailure, RunTask
from mazelab.experiments.units import run_unit_timed

CONNECT_SECONDS = 3  # a scheduler that does not answer within this is reported unreachable


def connect(address: str, timeout: float = CONNECT_SECONDS) -> Any:
    """A dask.distributed Client of the scheduler at `address` (e.g. tcp://10.0.0.5:8786), or a
    ValueError of one line: dask missing, or the scheduler unreachable within `timeout` seconds."""
    try:
        from distributed import Client
    except ImportError:
        raise ValueError('--dask needs dask.distributed: pip install -e ".[dask]"') from None
    from distributed.comm import parse_address
    from distributed.comm.addressing import parse_host_port

    try:  # a malformed address is refused here: a Client that fails to parse it lingers at exit
        scheme, location = parse_address(address)
        if scheme in ("tcp", "tls"):
            parse_host_port(location)
    except (ValueError, TypeError) as error:
        raise ValueError(f"--dask {address!r} is not a scheduler address like tcp://HOST:8786 ({error})") from None
    logging.getLogger("distributed").setLevel(logging.CRITICAL)  # its retry warnings, one per attempt
    try:
        return Client(address, timeout=timeout, set_as_default=False)
    except Exception as error:  # OSError, TimeoutError, ValueError (a malformed address), ...
        reason = str(error).splitlines()[0] if str(error) else type(error).__name__
        raise ValueError(f"cannot reach the Dask scheduler at {address!r}: {reason}") from None


def close_client(client: Any) -> None:
    """Close the connection (the cluster itself goes on)."""
    with contextlib.suppress(Exception):
        client.close(timeout=CONNECT_SECONDS)


def run_on_dask(
    client: Any,
    units: Sequence[tuple[RunTask, ...]],
    run_here: Callable[[], None],
    collect: Callable[[list], None],
    advance: Callable[..., None],
) -> None:
    """Submit every unit, run `run_here` (the drawn run) meanwhile, and collect the units as they
    finish. On Ctrl-C (or SIGTERM/SIGHUP), cancel the remaining units, keep the finished ones and
    raise the stop again."""
    from distributed import as_completed

    futures = dict(zip(client.map(run_unit_timed, units, pure=False), units, strict=True))
    taken: set[Any] = set()

    def take(future: Any) -> None:
        taken.add(future)
        unit = futures[future]
        try:
            collect(future.result())
        except Exception as error:  # the unit failed on the worker (e.g. mazelab missing there)
            collect([RunFailure(task, f"on the Dask cluster: {type(error).__name__}: {error}") for task in unit])
        advance(len(unit))

    try:
        run_here()
        for future in as_completed(list(futures), loop=client.loop):
            take(future)
    except KeyboardInterrupt:
        with contextlib.suppress(Exception):
            client.cancel([f for f in futures if f not in taken])
        for future in futures:
            if future not in taken and future.status == "finished":
                take(future)
        raise


__all__ = [
    "CONNECT_SECONDS",
    "close_client",
    "connect",
    "run_on_dask",
]
