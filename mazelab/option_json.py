"""A filter's options as JSON and back: what a scenario stores so that a replay repeats the run that
made it (`run --scenario`), and what a study's record lists.

Plain values (numbers, strings, booleans, None) stay as they are; the options that are objects have a
JSON form: a `Recovery` is {"mode", "alpha_slow", "alpha_fast", "reset_level"}, a `KLDSampling` is
{"epsilon", "z", "bin_size", "min_count", "max_count"}. `options_from_json` builds them again and
checks them as the filter would (one line naming the option).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from typing import Any

import numpy as np

from mazelab.recovery import Recovery
from mazelab.resampling import KLDSampling

OBJECT_OPTIONS: dict[str, type] = {"recovery": Recovery, "kld": KLDSampling}  # option -> the class of its object form
DERIVED_OPTIONS = ("start",)  # handed in by simulate from the run itself (the EKF's start), never stored


def option_to_json(value: Any) -> Any:
    """One option's JSON form: a dataclass as a dict of its fields, a numpy number as a Python one."""
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return {f.name: option_to_json(getattr(value, f.name)) for f in dataclasses.fields(value)}
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, (list, tuple, np.ndarray)):
        return [option_to_json(v) for v in value]
    if isinstance(value, float) and not math.isfinite(value):
        raise ValueError(f"option value {value} has no JSON form")
    if value is None or isinstance(value, (bool, int, float, str)):
        return value
    raise ValueError(f"option value {value!r} ({type(value).__name__}) has no JSON form")


def options_to_json(options: Mapping[str, Any]) -> dict[str, Any]:
    """Every option of a run in JSON form, in a stable order (the options simulate derives left out)."""
    return {name: option_to_json(options[name]) for name in sorted(options) if name not in DERIVED_OPTIONS}


def options_from_json(options: Mapping[str, Any]) -> dict[str, Any]:
    """The filter's keyword options from their JSON form: a dict for `recovery` or `kld` becomes a
    Recovery or KLDSampling (checked as the filter checks it); a ValueError names a bad one."""
    built: dict[str, Any] = {}
    for name, value in options.items():
        kind = OBJECT_OPTIONS.get(name)
        if kind is not None and isinstance(value, Mapping):
            known = {f.name for f in dataclasses.fields(kind)}
            unknown = sorted(set(value) - known)
            if unknown:
                fields = ", ".join(sorted(known))
                raise ValueError(f"filter option {name} has no field {unknown[0]!r} (it has: {fields})")
            try:
                built[name] = kind(**value)
            except (TypeError, ValueError) as error:
                raise ValueError(f"filter option {name}: {error}") from None
        else:
            built[name] = value
    return built


def describe_option(value: Any) -> str:
    """An option's value in a few words, for the line that says what a replay changed."""
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        fields = ", ".join(f"{f.name} {getattr(value, f.name)}" for f in dataclasses.fields(value))
        return f"{type(value).__name__}({fields})"
    return f"{value:g}" if isinstance(value, float) else str(value)


__all__ = [
    "DERIVED_OPTIONS",
    "OBJECT_OPTIONS",
    "describe_option",
    "option_to_json",
    "options_from_json",
    "options_to_json",
]
