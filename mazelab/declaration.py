"""A filter's options, declared once: `Option(name, default, help, parse, check)` in the filter's class.

Every layer reads the declaration: the constructor takes its defaults from it and validates there
(`Options.resolve`), the command line turns `--option NAME=VALUE` (and the paper's named flags, which
are spellings of the same options) into values with `parse`, and scenarios, records, replays and a
study's columns store and show values with `to_json`, `from_json` and `show`.

    options = ParticleFilter.options.extend(
        Option("spread", 0.1, "the jitter's std, map units", check=positive("spread")),
    )

A plug-in may declare its options as a plain mapping of names to defaults (`{"spread": 0.1}`);
`options_of` reads that as Options whose `parse` follows each default's type.
"""

from __future__ import annotations

import ast
import dataclasses
import math
import re
from collections.abc import Callable, Iterator, Mapping
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


def object_from_json(kind: type) -> Callable[[Any], Any]:
    """The `from_json` of an option whose value may be an object given as its fields (Recovery,
    KLDSampling): a dict becomes `kind(**fields)`, an unknown field is one line; anything else stays.

    Parameters
    ----------
    kind : a dataclass

    Returns
    -------
    callable
        stored value -> the option's value.
    """

    def from_json(value: Any) -> Any:
        if not isinstance(value, dict):
            return value
        known = {f.name for f in dataclasses.fields(kind)}
        unknown = sorted(set(value) - known)
        if unknown:
            raise ValueError(f"has no field {unknown[0]!r} (it has: {', '.join(sorted(known))})")
        return kind(**value)

    return from_json


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


def parse_literal(text: str) -> Any:
    """Command-line text as the value it spells: a number, true/false, none, or the word itself.

    Parameters
    ----------
    text : str

    Returns
    -------
    int, float, bool, None or str
    """
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
    return value if isinstance(value, (int, float)) and not isinstance(value, bool) else stripped


def parse_like(default: Any) -> Parse:
    """The parser for an option declared only by its default: the default's type (a float option
    reads "0.3", a whole number "3", a flag "true"), or any literal for None and text.

    Parameters
    ----------
    default : Any

    Returns
    -------
    callable
        text -> value.
    """
    if isinstance(default, bool):
        return parse_flag
    if isinstance(default, int):
        return parse_whole
    if isinstance(default, float):
        return parse_number
    return parse_literal


def parse_number(text: str) -> float:
    """A number: "0.3", "1e-3" (a decimal comma is refused with what to write instead).

    Parameters
    ----------
    text : str

    Returns
    -------
    float

    Raises
    ------
    ValueError
        One line; for "0,3" it says to write 0.3.
    """
    try:
        return float(text)
    except ValueError:
        hint = f" (write {text.replace(',', '.')})" if "," in text else ""
        raise ValueError(f"expected a number, got {text!r}{hint}") from None


def parse_whole(text: str) -> int:
    """A whole number: "3".

    Parameters
    ----------
    text : str

    Returns
    -------
    int
    """
    try:
        return int(text)
    except ValueError:
        raise ValueError(f"expected a whole number, got {text!r}") from None


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
        if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
            raise ValueError(f"{name} must be a number, got {value!r}")
        number = finite_number(name, value)
        inside = (low < number if low_open else low <= number) and number <= high
        if not inside:
            bracket = "(" if low_open else "["
            raise ValueError(f"{name} must be in {bracket}{low:g}, {high:g}]{what}, got {value!r}")
        return number

    return check


# -- the declaration ------------------------------------------------------------------------------
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
        Command-line text -> value (default: by the default's type, `parse_like`).
    check : callable, optional
        Value -> the value the filter uses, raising ValueError of one line for a bad one (default:
        any value). The one place the option is validated: the constructor calls it, and so do the
        command line and the study, early, through `Options.resolve`.
    flag : str, optional
        The paper's named flag that spells this option too (e.g. "--bandwidth"), for the messages.
    to_json, from_json : callable, optional
        The value's JSON form (scenarios, records) and back (default: plain values).
    show : callable, optional
        The value in a few words, for tables, labels and the study's columns.
    tunes : str, optional
        The option this one tunes (alpha_fast tunes recovery): giving it a value other than its
        default while that option is off is refused, rather than silently unused.
    derived : bool
        Handed in by the run itself (the EKF's `start`): never on the command line, never stored.
    """

    name: str
    default: Any
    help: str
    parse: Parse | None = None
    check: Check | None = None
    flag: str | None = None
    to_json: Callable[[Any], Any] = to_plain_json
    from_json: Callable[[Any], Any] = lambda value: value
    show: Callable[[Any], str] = show_value
    tunes: str | None = None
    derived: bool = False

    def parse_text(self, text: str) -> Any:
        """The value that command-line `text` spells (not yet checked: `validate` does that).

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
            One line naming the option.
        """
        parse = self.parse or parse_like(self.default)
        try:
            return parse(text)
        except ValueError as error:
            raise ValueError(f"option {self.name}: {error}") from None

    def validate(self, value: Any) -> Any:
        """The value the filter uses (the declared check applied), or a ValueError naming the option.

        Parameters
        ----------
        value : Any

        Returns
        -------
        Any
        """
        return value if self.check is None else self.check(value)

    @property
    def spelled(self) -> str:
        """How the command line spells it: the named flag, or --option NAME=..."""
        return self.flag or f"--option {self.name}=..."


class Options(Mapping[str, Option]):
    """A filter's options by name, in declaration order: an immutable value (`extend` and
    `with_defaults` make new ones)."""

    __slots__ = ("_by_name", "check", "declared")

    def __init__(self, *options: Option, check: Callable[[dict[str, Any]], None] | None = None):
        """`check`, if given, sees every resolved value together and refuses combinations (recovery's
        alpha_slow below its alpha_fast) in one line; `extend` and `with_defaults` keep it."""
        names = [o.name for o in options]
        repeated = sorted({n for n in names if names.count(n) > 1})
        if repeated:
            raise ValueError(f"option {repeated[0]!r} is declared twice")
        object.__setattr__(self, "declared", tuple(options))
        object.__setattr__(self, "_by_name", {o.name: o for o in options})
        object.__setattr__(self, "check", check)

    def __setattr__(self, name: str, value: Any) -> None:
        raise AttributeError("Options are immutable: extend() or with_defaults() make new ones")

    def __eq__(self, other: object) -> bool:
        return isinstance(other, Options) and self.declared == other.declared

    def __repr__(self) -> str:
        return f"Options({', '.join(self._by_name)})"

    def __getitem__(self, name: str) -> Option:
        return self._by_name[name]

    def __iter__(self) -> Iterator[str]:
        return iter(self._by_name)

    def __len__(self) -> int:
        return len(self.declared)

    def __hash__(self) -> int:
        return hash(self.declared)

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

    def with_defaults(self, **defaults: Any) -> Options:
        """The same options with other defaults (a subclass that changes one).

        Parameters
        ----------
        **defaults
            New defaults by option name.

        Returns
        -------
        Options
            A new declaration (this one is unchanged).
        """
        unknown = sorted(set(defaults) - set(self))
        if unknown:
            raise ValueError(f"no option {unknown[0]!r} to change the default of (declared: {', '.join(self)})")
        return Options(
            *(replace(o, default=defaults[o.name]) if o.name in defaults else o for o in self.declared),
            check=self.check,
        )

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

    def refuse_undeclared(self, given: Mapping[str, Any], owner: str) -> None:
        """Refuse the first option of `given` that is not declared, naming what `owner` takes.

        Parameters
        ----------
        given : mapping
            Option names (and values).
        owner : str
            The filter's name, for the message.
        """
        for name in given:
            if name not in self._by_name:
                takes = ", ".join(o.name for o in self.settable()) or "no options"
                raise ValueError(f"{owner} does not take the option {name} (it takes: {takes})")

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
            One line: an undeclared option, a bad value, a tuning option given while what it tunes is
            off, or a combination the declaration's `check` refuses.
        """
        self.refuse_undeclared(given, owner)
        values = {}
        for option in self.declared:
            value = given.get(option.name, option.default)
            values[option.name] = option.validate(value) if option.name in given else value
        for option in self.declared:
            tuned = self._by_name.get(option.tunes) if option.tunes else None
            changed = option.name in given and values[option.name] != option.default
            if tuned is not None and changed and values[tuned.name] in (None, False):
                raise ValueError(
                    f"{owner}: {option.name} tunes {tuned.name}, which is off: give {tuned.spelled} too "
                    f"(or leave out {option.spelled})"
                )
        if self.check is not None:
            self.check(values)
        return values

    def parse(self, name: str, text: str, owner: str) -> Any:
        """The value of `--option NAME=TEXT` for `owner`'s declared option `name`.

        Parameters
        ----------
        name, text : str
        owner : str
            The filter's name, for the message.

        Returns
        -------
        Any
        """
        self.refuse_undeclared({name: None}, owner)
        return self._by_name[name].parse_text(text)

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
        """
        return {o.name: o.to_json(values[o.name]) for o in self.declared if o.name in values and not o.derived}

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
        self.refuse_undeclared(stored, owner)
        values = {}
        for name, value in stored.items():
            option = self._by_name[name]
            if option.derived:
                raise ValueError(f"{owner} option {name} is handed in by the run itself, not stored")
            try:
                values[name] = option.from_json(value)
            except (TypeError, ValueError) as error:
                raise ValueError(f"{owner} option {name}: {error}") from None
        self.resolve(values, owner)  # each value and their combination, checked as the constructor checks them
        return values

    def numpydoc(self) -> str:
        """The options as a numpydoc section, for the filter's docstring.

        Returns
        -------
        str
        """
        lines = ["Options", "-------"]
        for o in self.settable():
            lines += [f"{o.name} : default {show_value(o.default)}", f"    {o.help}"]
        return "\n".join(lines)


def with_options_section(doc: str | None, options: Options) -> str:
    """A filter class's docstring with its declared options listed (made from the declaration, so the
    list never goes stale): an earlier generated section is replaced.

    Parameters
    ----------
    doc : str or None
        The class's docstring.
    options : Options

    Returns
    -------
    str
    """
    doc = (doc or "").rstrip()
    earlier = re.search(r"\n\n[ \t]*Options\n[ \t]*-------\n", doc)
    if earlier is not None:
        doc = doc[: earlier.start()].rstrip()
    lines = [line for line in doc.splitlines()[1:] if line.strip()]
    indent = " " * min((len(line) - len(line.lstrip()) for line in lines), default=0)
    section = "\n".join(indent + line if line else line for line in options.numpydoc().splitlines())
    return f"{doc}\n\n{section}\n"


def options_of(filter_class: type) -> Options:
    """A filter class's declared options as Options: its `options` as they are, or, for a plain
    mapping of names to defaults (a plug-in's), Options parsed by each default's type.

    Parameters
    ----------
    filter_class : type

    Returns
    -------
    Options

    Raises
    ------
    TypeError
        When `options` is neither.
    """
    declared = getattr(filter_class, "options", None)
    if isinstance(declared, Options):
        return declared
    if isinstance(declared, Mapping):
        return Options(*(Option(str(name), default, "(declared by its default)") for name, default in declared.items()))
    raise TypeError(f"{getattr(filter_class, '__name__', filter_class)!r}.options is not a mapping of options")


__all__ = [
    "Option",
    "Options",
    "choice",
    "number_in",
    "object_from_json",
    "options_of",
    "parse_flag",
    "parse_like",
    "parse_literal",
    "parse_number",
    "parse_whole",
    "show_value",
    "to_plain_json",
    "with_options_section",
]
