"""A filter's options, declared once: `Option(name, default, help, parse, check)` in the filter's class.

Every layer reads the declaration: the constructor takes its defaults from it and validates there
(`Options.resolve`), the command line turns `--option NAME=VALUE` (and the paper's named flags, which
are spellings of the same options) into values with `parse`, and scenarios, records and replays store
values in their JSON form (`Options.to_json`, `Options.from_json`).

    options = ParticleFilter.options.extend(
        Option("spread", 0.1, "the jitter's std, map units", check=number_in("spread", 0.0, 1.0)),
    )

A plug-in may declare its options as a plain mapping of names to defaults (`{"spread": 0.1}`, see `options_of`).
"""

from __future__ import annotations

import ast
import dataclasses
import math
import re
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from mazelab.checks import finite_number

Parse = Callable[[str], Any]
Check = Callable[[Any], Any]


# -- how a value is written and read --------------------------------------------------------------
def to_plain_json(value: Any) -> Any:
    """A value's JSON form: a dataclass as a dict of its fields, a numpy number as a Python one.

    Parameters
    ----------
    value : Any
        An option's value: a number, a word, a flag, None, a sequence, or a dataclass (Recovery, KLDSampling).

    Returns
    -------
    Any
        Plain JSON (dict, list, str, int, float, bool, None).

    Raises
    ------
    ValueError
        For a value with no JSON form (an infinite number, an arbitrary object).
    """
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return {f.name: to_plain_json(getattr(value, f.name)) for f in dataclasses.fields(value)}
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, (list, tuple, np.ndarray)):
        return [to_plain_json(v) for v in value]
    if isinstance(value, float) and not math.isfinite(value):
        raise ValueError(f"option value {value} has no JSON form")
    if value is None or isinstance(value, (bool, int, float, str)):
        return value
    raise ValueError(f"option value {value!r} ({type(value).__name__}) has no JSON form")


def show_value(value: Any) -> str:
    """A value in a few words (tables, labels, messages): 0.05, multimodal, none.

    Parameters
    ----------
    value : Any

    Returns
    -------
    str
        Floats by `:g`, None as "none", a dataclass as `Name(field value, ...)`.
    """
    if value is None:
        return "none"
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        fields_ = ", ".join(f"{f.name} {show_value(getattr(value, f.name))}" for f in dataclasses.fields(value))
        return f"{type(value).__name__}({fields_})"
    if isinstance(value, float):
        return f"{value:g}"
    return str(value)


def _parse_literal(text: str) -> Any:
    """Command-line text as the value it spells: a number, true/false, none, or the word itself; a
    number that is not finite (1e999) is a ValueError."""
    stripped = text.strip()
    lowered = stripped.lower()
    if lowered in ("true", "false"):
        return lowered == "true"
    if lowered in ("none", "null"):
        return None
    try:
        value = ast.literal_eval(stripped)
    except (ValueError, SyntaxError, MemoryError, RecursionError):
        return stripped
    if isinstance(value, float) and not math.isfinite(value):
        raise ValueError(f"expected a finite number, got {text!r}")
    return value if isinstance(value, (int, float)) and not isinstance(value, bool) else stripped


def parse_flag(text: str) -> bool:
    """true/false (also yes/no, on/off, 1/0).

    Parameters
    ----------
    text : str

    Returns
    -------
    bool
    """
    lowered = text.strip().lower()
    if lowered in ("true", "yes", "on", "1"):
        return True
    if lowered in ("false", "no", "off", "0"):
        return False
    raise ValueError(f"expected true or false, got {text!r}")


def decimal_comma(text: str) -> str | None:
    """'0,3' -> '0.3': the number that text written with a decimal comma means, else None (the one
    reading of a decimal comma for every hint: an option's value, a typer number, a study's list)."""
    match = re.fullmatch(r"\s*(-?\d+),(\d+)\s*", text)
    return None if match is None else f"{match[1]}.{match[2]}"


def _parse_number(text: str, kind: type = float) -> Any:
    """A finite number: "0.3", "1e-3" (NaN and infinities are refused, and "0,3" says to write 0.3); with
    `kind` int, a whole number: "3"."""
    try:
        number = kind(text)
    except ValueError:
        decimal = decimal_comma(text) if kind is float else None
        hint = f" (write {decimal})" if decimal is not None else ""
        raise ValueError(f"expected a {'whole ' if kind is int else ''}number, got {text!r}{hint}") from None
    if not math.isfinite(number):
        raise ValueError(f"expected a finite number, got {text!r}")
    return number


# -- checks: value -> the value the filter uses, or a ValueError of one line -------------------------
def choice(name: str, choices: tuple[str, ...]) -> Check:
    """A check that takes a word among `choices`.

    Parameters
    ----------
    name : str
        The option's name, for the message.
    choices : tuple of str

    Returns
    -------
    callable
        value -> the word, or a ValueError naming the choices.
    """

    def check(value: Any) -> str:
        if not isinstance(value, str) or value not in choices:
            raise ValueError(f"{name} must be one of {', '.join(choices)}, got {value!r}")
        return value

    return check


def number_in(name: str, low: float, high: float, *, low_open: bool = True, what: str = "") -> Check:
    """A check that takes a finite number in (low, high] (or [low, high] with low_open=False).

    Parameters
    ----------
    name : str
        The option's name, for the message.
    low, high : float
        The bounds.
    low_open : bool
        Whether `low` itself is refused.
    what : str
        Words after the interval in the message (its units, what the number is).

    Returns
    -------
    callable
        value -> float, or a ValueError of one line naming the option and the interval.
    """

    def check(value: Any) -> float:
        number = finite_number(name, value)
        inside = (low < number if low_open else low <= number) and number <= high
        if not inside:
            bracket = "(" if low_open else "["
            raise ValueError(f"{name} must be in {bracket}{low:g}, {high:g}]{what}, got {value!r}")
        return number

    return check


# -- the declaration ------------------------------------------------------------------------------
def _as_given(value: Any) -> Any:
    """The check of an option declared without one: any value, as it is."""
    return value


@dataclass(frozen=True)
class Option:
    """One keyword option of a filter.

    Parameters
    ----------
    name : str
        The keyword the constructor takes (`--option NAME=VALUE` on the command line).
    default : Any
        The value when none is given: the paper's where the paper has one.
    help : str
        One line: what the option does, with units.
    parse : callable, optional
        Command-line text -> value (default: by the default's type: a flag, a whole
        number or a finite number, else any literal).
    check : callable, optional
        Value -> the value the filter uses, raising ValueError of one line for a bad one (default:
        any value, as it is): the one place the option is validated (`Options.resolve`).
    flag : str, optional
        The paper's named flag that spells this option too (e.g. "--bandwidth"), for the messages.
    stored_as : dataclass, optional
        The class of an option whose value may be an object (Recovery, KLDSampling): `to_plain_json`
        writes it as its fields and a stored dict of them becomes `stored_as(**fields)` (default: as stored).
    derived : bool
        Handed in by the run itself (the EKF's `start`): never on the command line, never stored.
    """

    name: str
    default: Any
    help: str
    parse: Parse | None = None
    check: Check = _as_given
    flag: str | None = None
    stored_as: type | None = None
    derived: bool = False

    def parse_text(self, text: str) -> Any:
        """The value that command-line `text` spells (not yet checked: `check` does that).

        Parameters
        ----------
        text : str
            What follows `--option NAME=`, or a named flag's text.

        Returns
        -------
        Any

        Raises
        ------
        ValueError
            One line naming the option: text it cannot read, or a control character (a newline
            would print as a line of its own wherever the value is shown).
        """
        # undeclared: by the default's type (a flag, a whole number, a number), else any literal (None, text)
        by_type = ((bool, parse_flag), (int, lambda text: _parse_number(text, int)), (float, _parse_number))
        parse = self.parse or next((p for kind, p in by_type if isinstance(self.default, kind)), _parse_literal)
        try:
            if not text.isprintable():
                raise ValueError(f"a value cannot hold a control character (a newline, a tab), got {text!r}")
            return parse(text)
        except ValueError as error:
            raise ValueError(f"option {self.name}: {error}") from None


class Options(Mapping[str, Option]):
    """A filter's options by name, in declaration order (`extend` makes a new declaration).

    Parameters
    ----------
    *options : Option
    check : callable, optional
        Sees every resolved value together and refuses a combination (recovery's alpha_slow below its
        alpha_fast) in one line (default: any combination); `extend` keeps it.
    """

    def __init__(self, *options: Option, check: Callable[[dict[str, Any]], Any] = _as_given):
        names = [o.name for o in options]
        repeated = sorted({n for n in names if names.count(n) > 1})
        if repeated:
            raise ValueError(f"option {repeated[0]!r} is declared twice")
        self.declared = tuple(options)
        self.check = check
        self._by_name = {o.name: o for o in options}

    def __repr__(self) -> str:
        return f"Options({', '.join(self._by_name)})"

    def __getitem__(self, name: str) -> Option:
        return self._by_name[name]

    def __iter__(self) -> Iterator[str]:
        return iter(self._by_name)

    def __len__(self) -> int:
        return len(self.declared)

    def extend(self, *options: Option) -> Options:
        """These options and more (an option of the same name replaces the inherited one in place).

        Parameters
        ----------
        *options : Option

        Returns
        -------
        Options
            A new declaration (this one is unchanged); the combined check is kept.
        """
        new = {o.name: o for o in options}
        kept = [new.pop(o.name, o) for o in self.declared]
        return Options(*kept, *new.values(), check=self.check)

    def defaults(self) -> dict[str, Any]:
        """Every option's default, by name.

        Returns
        -------
        dict
        """
        return {o.name: o.default for o in self.declared}

    def settable(self) -> list[Option]:
        """The options a user sets (the derived ones left out).

        Returns
        -------
        list of Option
        """
        return [o for o in self.declared if not o.derived]

    def resolve(self, given: Mapping[str, Any], owner: str) -> dict[str, Any]:
        """Every option's value: the given ones checked, the rest their defaults.

        Parameters
        ----------
        given : mapping
            The options handed to the constructor (or typed on the command line).
        owner : str
            The filter's name, for the messages.

        Returns
        -------
        dict
            Every declared option's value, in declaration order.

        Raises
        ------
        ValueError
            One line: an undeclared option, a bad value, or a combination the declaration's `check` refuses.
        """
        for name in given:
            if name not in self._by_name:
                raise ValueError(f"{owner} does not take the option {name} (it takes: {_taken(self)})")
        values = {o.name: o.check(given[o.name]) if o.name in given else o.default for o in self.declared}
        self.check(values)
        return values

    def to_json(self, values: Mapping[str, Any]) -> dict[str, Any]:
        """Values in their JSON form, in declaration order (derived options and undeclared names left out).

        Parameters
        ----------
        values : mapping
            Option values by name.

        Returns
        -------
        dict
            What a scenario or a record stores.

        Raises
        ------
        ValueError
            One line naming the option whose value has no JSON form (an infinite number, an object).
        """
        stored = {}
        for o in self.declared:
            if o.name in values and not o.derived:
                try:
                    stored[o.name] = to_plain_json(values[o.name])
                except ValueError as error:
                    raise ValueError(f"option {o.name}: {error}") from None
        return stored

    def from_json(self, stored: Mapping[str, Any], owner: str) -> dict[str, Any]:
        """Stored JSON values back as the filter's keyword options, each checked and all checked together;
        the derived ones are never taken from a file.

        Parameters
        ----------
        stored : mapping
            What a scenario stores (`filter_options`).
        owner : str
            The filter's name, for the messages.

        Returns
        -------
        dict
            Keyword options for the constructor.

        Raises
        ------
        ValueError
            One line naming the option and the problem.
        """
        values = {}
        for name, value in stored.items():
            option = self._by_name.get(name, Option(name, None, "undeclared"))  # refused by `resolve` below
            if option.derived:
                raise ValueError(f"{owner} option {name} is handed in by the run itself, not stored")
            try:
                if isinstance(value, dict) and option.stored_as is not None:  # an object stored as its fields
                    known = {f.name for f in dataclasses.fields(option.stored_as)}
                    unknown = sorted(set(value) - known)
                    if unknown:
                        raise ValueError(f"has no field {unknown[0]!r} (it has: {', '.join(sorted(known))})")
                    value = option.stored_as(**value)
                values[name] = value
            except (TypeError, ValueError) as error:
                raise ValueError(f"{owner} option {name}: {error}") from None
        self.resolve(values, owner)  # names, values and their combination checked as the constructor checks them
        return values


def _taken(options: Options) -> str:
    """The options a user sets, named for the messages: "resolution, margin", or "no options"."""
    return ", ".join(o.name for o in options.settable()) or "no options"


def scoped(key: str) -> tuple[str | None, str]:
    """An option's key as a study or a command sets it, split into its filter and its name.

    Parameters
    ----------
    key : str
        'threshold' (every filter that declares it) or 'rpf.threshold' (that filter alone; a short name,
        a class name or a plug-in's FILE.py:Class before the last dot).

    Returns
    -------
    (str or None, str)
        ('rpf', 'threshold'), or (None, 'threshold') for an option of every filter.
    """
    scope, dot, name = key.rpartition(".")
    return (scope, name) if dot and scope and name.isidentifier() else (None, key)


def options_of(filter_class: type) -> Options:
    """A filter class's declared options as Options: its `options` as they are, or a plain mapping read
    as a declaration.

    In a mapping, a name whose value is an Option takes that Option (`{**SIRParticleFilter.options, ...}`);
    a name that a base class declares keeps the base's Option, the value its new default (checked as a
    given value is); a new name is declared by its default alone (parsed by the default's type, not
    checked). What the nearest base that declares options declares and the mapping leaves out is kept, with
    its combined check: a subclass runs the base's constructor, which needs every option.

    Parameters
    ----------
    filter_class : type

    Returns
    -------
    Options

    Raises
    ------
    TypeError
        When `options` is neither Options nor a mapping.
    ValueError
        When a name of the mapping holds an Option of another name, or a new default its check refuses.
    """
    declared = getattr(filter_class, "options", None)
    if isinstance(declared, Options):
        return declared
    if not isinstance(declared, Mapping):
        raise TypeError(f"{getattr(filter_class, '__name__', filter_class)!r}.options is not a mapping of options")
    base = next((base for base in getattr(filter_class, "__mro__", ())[1:] if "options" in vars(base)), None)
    inherited = Options() if base is None else options_of(base)
    return inherited.extend(*(_declared_by(str(name), value, inherited) for name, value in declared.items()))


def _declared_by(name: str, value: Any, inherited: Options) -> Option:
    """The Option that `name: value` of a plain mapping declares (see `options_of`)."""
    if isinstance(value, Option):
        if value.name != name:
            raise ValueError(f"options: the name {name!r} holds the option {value.name!r}")
        return value
    if name in inherited:  # a new default, checked as a given value would be
        return replace(inherited[name], default=inherited[name].check(value))
    return Option(name, value, "(declared by its default)")


def not_taken(filter_classes: Sequence[type], spelled: str) -> str:
    """The line for an option that none of the filters declares: 'GridBayesFilter does not take
    --recovery (it takes: resolution, margin, ...)', each filter's options named for several.

    Parameters
    ----------
    filter_classes : sequence of type
    spelled : str
        The option as the user wrote it.

    Returns
    -------
    str
    """

    if len(filter_classes) == 1:
        return f"{filter_classes[0].name} does not take {spelled} (it takes: {_taken(options_of(filter_classes[0]))})"
    names = " and ".join(cls.name for cls in filter_classes)
    each = "; ".join(f"{cls.name}: {_taken(options_of(cls))}" for cls in filter_classes)
    return f"{names} do not take {spelled} ({each})"


__all__ = [
    "Option",
    "Options",
    "choice",
    "not_taken",
    "number_in",
    "options_of",
    "parse_flag",
    "scoped",
    "show_value",
    "to_plain_json",
]
