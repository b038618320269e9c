"""Filter options from the command line, read from the filter contract (mazelab.contract).

A flag the user gives sets one filter option. Each filter takes the options it declares; a flag that
no filter of the command declares is refused in one line naming the flag and the filter(s), so
`run --filter grid --recovery` and `study --filters sir --bandwidth multimodal` stop before any work.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

from mazelab.cli.options import UserError
from mazelab.contract import takes
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
    """Per filter (by class name), the given options (None: not given) that it declares.

    Raises UserError for an option that no filter of the command declares, naming its flag and the
    filters."""
    classes = [resolve_filter(name) for name in filter_names]
    chosen = {name: value for name, value in given.items() if value is not None}
    for option in chosen:
        if not any(takes(cls, option) for cls in classes):
            flag = FLAGS.get(option, option)
            names = " and ".join(cls.name for cls in classes)
            flags = [FLAGS[o] for o in FLAGS if any(takes(cls, o) for cls in classes)]
            takes_list = f"; {'they take' if len(classes) > 1 else 'it takes'} {', '.join(flags)}" if flags else ""
            raise UserError(f"{names} {'do' if len(classes) > 1 else 'does'} not take {flag}{takes_list}")
    return {cls.name: {o: v for o, v in chosen.items() if takes(cls, o)} for cls in classes}


__all__ = ["FLAGS", "options_per_filter"]
