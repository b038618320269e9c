"""Filter options from the command line, read from the filter contract (mazelab.contract).

A flag the user gives sets one filter option. Each filter takes the options it declares; a flag that
no filter of the command declares is refused in one line naming the flag and the filter(s), so
`run --filter grid --recovery` and `study --filters sir --bandwidth multimodal` stop before any work.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

from mazelab.cli.options import UserError
from mazelab.contract import options_for
from mazelab.registry import resolve_filter

# the flag that sets each filter option (what the user typed, for the messages)
FLAGS: Mapping[str, str] = {
    "resampling": "--resampling",
    "recovery": "--recovery/--sensor-resetting",
    "kld": "--kld",
    "threshold": "--threshold",
    "bandwidth": "--bandwidth",
    "estimate": "--estimate",
    "init": "--init",
}


def options_per_filter(filter_names: Sequence[str | type], given: Mapping[str, Any]) -> dict[str, dict[str, Any]]:
    """Per filter (by class name), the given options (None: not given) that it declares; `given` holds
    every filter option the command has a flag for. Raises UserError for an option that no filter of
    the command declares, naming its flag, the filters and the flags they take."""
    try:
        return options_for([resolve_filter(name) for name in filter_names], given, spelled=FLAGS)
    except ValueError as error:
        raise UserError(str(error)) from None


__all__ = ["FLAGS", "options_per_filter"]
