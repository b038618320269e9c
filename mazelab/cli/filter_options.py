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


# flags that tune a filter option rather than set it: refused, by their own name, where the option is
TUNING_FLAGS: Mapping[str, tuple[str, str]] = {
    "alpha_slow": ("recovery", "--alpha-slow"),
    "alpha_fast": ("recovery", "--alpha-fast"),
    "kld_epsilon": ("kld", "--kld-epsilon"),
    "kld_z": ("kld", "--kld-z"),
}


def options_per_filter(
    filter_names: Sequence[str | type],
    given: Mapping[str, Any],
    *,
    tuning: Sequence[str] = (),
    flags: Mapping[str, str] | None = None,
) -> dict[str, dict[str, Any]]:
    """Per filter (by class name), the given options (None: not given) that it declares; `given` holds
    every filter option the command has a flag for. Raises UserError for an option that no filter of
    the command declares, naming its flag, the filters and the flags they take; likewise for each
    flag in `tuning` (TUNING_FLAGS the user typed, e.g. "alpha_fast") whose option none of them
    declares. `flags` overrides how a command spells an option's flag (FLAGS by default)."""
    classes = [resolve_filter(name) for name in filter_names]
    spelled = {**FLAGS, **(flags or {})}
    try:
        for parameter in tuning:
            option, flag = TUNING_FLAGS[parameter]
            options_for(classes, {**dict.fromkeys(given), option: True}, spelled={**spelled, option: flag})
        return options_for(classes, given, spelled=spelled)
    except ValueError as error:
        raise UserError(str(error)) from None


__all__ = ["FLAGS", "TUNING_FLAGS", "options_per_filter"]
