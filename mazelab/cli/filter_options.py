"""Filter options from the command line, read from each filter's declaration (mazelab.declaration).

One generic `--option NAME=VALUE` (repeatable) sets any declared option of any filter, a plug-in's
included; the paper's named flags (`--bandwidth`, `--resampling`, ...) are spellings of the same
options: `--bandwidth 0.05` and `--option bandwidth=0.05` give the same value, parsed and checked by
the same declaration. An option that no filter of the command declares is refused in one line naming
it and what the filters take, before any work; so is a value the declaration refuses.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Annotated, Any

import typer

from mazelab.cli.options import UserError
from mazelab.contract import not_taken, options_for
from mazelab.declaration import Option
from mazelab.modes import ESTIMATE_OPTION
from mazelab.recovery import RECOVERY_OPTIONS
from mazelab.registry import entries, filter_entry
from mazelab.regularisation import BANDWIDTH_OPTION
from mazelab.resampling import KLD_OPTIONS, RESAMPLING_OPTION

# -- the paper's named flags: spellings of declared options (their help is the declaration's) -----------
ResamplingFlag = Annotated[
    str | None, typer.Option("--resampling", metavar="SCHEME", help=RESAMPLING_OPTION.help, show_default=False)
]
RecoveryFlag = Annotated[bool, typer.Option("--recovery", help="recovery: augmented MCL, injects when lost")]
SensorResettingFlag = Annotated[
    bool, typer.Option("--sensor-resetting", help="recovery: sensor resetting, injects what matches z")
]
KldFlag = Annotated[bool, typer.Option("--kld", help="KLD-sampling: N adapts, --particles the most")]
# the parts' tuning: --option alpha_slow=... spells them too (hidden: `mazelab filters` lists them)
AlphaSlowFlag = Annotated[float | None, typer.Option("--alpha-slow", hidden=True, help=RECOVERY_OPTIONS[1].help)]
AlphaFastFlag = Annotated[float | None, typer.Option("--alpha-fast", hidden=True, help=RECOVERY_OPTIONS[2].help)]
KldEpsilonFlag = Annotated[float | None, typer.Option("--kld-epsilon", hidden=True, help=KLD_OPTIONS[1].help)]
KldZFlag = Annotated[float | None, typer.Option("--kld-z", hidden=True, help=KLD_OPTIONS[2].help)]
BandwidthFlag = Annotated[
    str | None, typer.Option("--bandwidth", metavar="KERNEL", help=BANDWIDTH_OPTION.help, show_default=False)
]
EstimateFlag = Annotated[
    str | None, typer.Option("--estimate", metavar="mean|mode", help=ESTIMATE_OPTION.help, show_default=False)
]


def recovery_value(recovery: bool, sensor_resetting: bool) -> str | None:
    """--recovery and --sensor-resetting as the recovery option's value (None: neither)."""
    if recovery and sensor_resetting:
        raise UserError("choose one of --recovery and --sensor-resetting")
    return "sensor" if sensor_resetting else "augmented" if recovery else None


def named_values(named: Mapping[str, Any], filter_names: Sequence[str | type]) -> dict[str, Any]:
    """The named flags' values as options (None: not given), a flag's text parsed by the declaration
    as `--option NAME=TEXT` would be."""
    values = {}
    for name, value in named.items():
        if value is None:
            continue
        declared = declared_by(filter_names, name)
        if isinstance(value, str) and declared:
            value = read_value(declared[0], value, declared[0].flag or f"--{name}")
        values[name] = value
    return values


def read_value(option: Option, text: str, spelled: str) -> Any:
    """One value of `option` from command-line text, read by its declaration; a value with a comma
    that it refuses, when each part alone is one it takes, says that lists are the study's."""
    try:
        value = option.parse_text(text)
        if "," in text:
            option.validate(value)  # refused here, where the hint can say where lists go
        return value
    except ValueError as error:
        message = str(error).removeprefix(f"option {option.name}: ")
        raise UserError(f"{spelled}: {message}{_list_hint(option, text)}") from None


def _list_hint(option: Option, text: str) -> str:
    """'; ...' when `text` reads as a list of values of `option` (V1,V2), else nothing."""
    try:
        for part in text.split(","):
            option.validate(option.parse_text(part))
    except ValueError:
        return ""
    return f"; a list of values is for mazelab study (study --option {option.name}={text})" if "," in text else ""


OptionFlag = Annotated[
    list[str] | None,
    typer.Option(
        "--option",
        metavar="NAME=VALUE",
        help="any filter option, repeatable (mazelab filters lists them)",
        show_default=False,
    ),
]
StudyOptionFlag = Annotated[
    list[str] | None,
    typer.Option(
        "--option",
        metavar="NAME=V1,V2",
        help="a filter option, values varied (mazelab filters)",
        show_default=False,
    ),
]


def declared_by(filter_names: Sequence[str | type], name: str) -> list[Option]:
    """The declarations of option `name` among the filters (first the first filter's)."""
    return [entry.options[name] for entry in map(filter_entry, filter_names) if name in entry.options]


def parse_option_texts(
    texts: Sequence[str] | None, filter_names: Sequence[str | type], *, lists: bool = False
) -> dict[str, Any]:
    """`--option NAME=VALUE` texts as {name: value} (with `lists`, {name: [values]} from NAME=V1,V2),
    each value parsed by the declaration of the first filter that declares the option.

    Raises
    ------
    UserError
        One line: a text without '=', an option none of the filters declares (naming what they take),
        an option given twice, or a value its declaration cannot read.
    """
    parsed: dict[str, Any] = {}
    for text in texts or ():
        if not text.isprintable():  # a newline would print as a line of its own in the messages
            raise UserError(f"--option {text!r}: an option cannot hold a control character (a newline, a tab)")
        name, equals, value = text.partition("=")
        name = name.strip()
        if not equals or not name:
            raise UserError(f"--option {text!r}: write NAME=VALUE, e.g. --option bandwidth=multimodal")
        declared = declared_by(filter_names, name)
        if not declared or declared[0].derived:
            raise UserError(refusal(filter_names, name, f"--option {name}"))
        if name in parsed:
            raise UserError(f"--option {name} is given twice; give each option once")
        spelled = f"--option {name}={value}"
        if not lists:
            parsed[name] = read_value(declared[0], value, spelled)
            continue
        parts = [part for part in value.split(",") if part.strip()]
        if not parts:
            raise UserError(f"{spelled}: no values (write NAME=V1,V2)")
        parsed[name] = list(dict.fromkeys(read_value(declared[0], part, spelled) for part in parts))
    return parsed


def refusal(filter_names: Sequence[str | type], name: str, spelled: str) -> str:
    """The line for an option none of the filters declares: what each filter takes instead."""
    return not_taken([filter_entry(f).filter_class for f in filter_names], spelled)


class GivenOptions(dict):
    """Options given on the command line, by name, with how the user spelled each (`spelled`: the
    named flag, or --option NAME), for the messages."""

    spelled: dict[str, str]


def merge_named(named: Mapping[str, Any], generic: Mapping[str, Any]) -> GivenOptions:
    """The named flags' values (None: not given) and the generic --option ones together; one option
    given both ways with different values is refused in one line."""
    merged = GivenOptions(generic)
    merged.spelled = {name: f"--option {name}" for name in generic}
    for name, value in named.items():
        if value is None:
            continue
        if name in merged and merged[name] != value:
            raise UserError(f"{name} is given twice, as its flag and as --option {name}; give it once")
        merged[name] = value
        declared = declared_option_anywhere(name)
        merged.spelled[name] = declared.flag if declared is not None and declared.flag else f"--{name}"
    return merged


def declared_option_anywhere(name: str) -> Option | None:
    """The declaration of an option among the lab's filters (for its named flag), or None."""
    return next((entry.options[name] for entry in entries() if name in entry.options), None)


def options_per_filter(
    filter_names: Sequence[str | type],
    given: Mapping[str, Any],
    *,
    flags: Mapping[str, str] | None = None,
    check: bool = True,
) -> dict[str, dict[str, Any]]:
    """Per filter (by `name`), the given options it declares (None: not given); an option that none of
    them declares is refused in one line naming how the user spelled it (`flags`: option -> flag,
    default the declaration's named flag) and what they take. With `check`, each filter's options
    are checked by its declaration as its constructor will check them (a value out of range, a
    tuning option whose part is off), in one line."""
    entries = [filter_entry(name) for name in filter_names]
    classes = [entry.filter_class for entry in entries]
    spelled = {name: spelling(entries, name, {**getattr(given, "spelled", {}), **(flags or {})}) for name in given}
    try:
        per_filter = options_for(classes, given, spelled=spelled)
        if check:
            for entry in entries:
                entry.options.resolve(per_filter[entry.name], entry.name)
    except ValueError as error:
        raise UserError(str(error)) from None
    return per_filter


def spelling(entries: Sequence[Any], name: str, flags: Mapping[str, str] | None = None) -> str:
    """How a command spells option `name`: its own flag (`flags`), the declaration's named flag, or
    --option NAME=..."""
    if flags and name in flags:
        return flags[name]
    declared = next((e.options[name] for e in entries if name in e.options), None)
    return declared.flag if declared is not None and declared.flag else f"--option {name}=..."


__all__ = [
    "AlphaFastFlag",
    "AlphaSlowFlag",
    "BandwidthFlag",
    "EstimateFlag",
    "GivenOptions",
    "KldEpsilonFlag",
    "KldFlag",
    "KldZFlag",
    "OptionFlag",
    "RecoveryFlag",
    "ResamplingFlag",
    "SensorResettingFlag",
    "StudyOptionFlag",
    "declared_by",
    "declared_option_anywhere",
    "merge_named",
    "named_values",
    "options_per_filter",
    "parse_option_texts",
    "read_value",
    "recovery_value",
    "refusal",
    "spelling",
]
