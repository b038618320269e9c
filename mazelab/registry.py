"""Every filter by name, one entry each: its class, short name, label, colour, one-line help, and what it
can do (take particles, run R runs together). The command line's choices and hints, the figures' labels
and colours (the same in Rerun and in the PNGs), `mazelab --help` and a study's columns read it.

A filter of the package is one entry in `SHIPPED`; a student's own, `path/to/file.py:ClassName`, gets an
entry when it is loaded (mazelab.plugins), with its file's sha256 so that a saved run names it exactly.

    entry = filter_entry("rpf")          # also "RegularizedParticleFilter", "Regularized Particle Filter"
    entry.filter_class, entry.label      # RegularizedParticleFilter, "RPF"
"""

from __future__ import annotations

import difflib
from dataclasses import dataclass

from mazelab.declaration import Options, options_of
from mazelab.filters import AuxiliaryParticleFilter, RegularizedParticleFilter, SIRParticleFilter
from mazelab.grid_filter import GridBayesFilter
from mazelab.kalman import ExtendedKalmanFilter
from mazelab.plugins import (
    PluginReference,
    check_declared_defaults,
    is_plugin_spec,
    load_plugin,
    loaded_plugin,
    plugin_reference,
)

Colour = tuple[int, int, int]
# colours for filters in order (matplotlib's tab10, which the PNGs use too): the shipped filters take
# the first five, plug-ins the next free one (in turn once all are taken)
PALETTE: tuple[Colour, ...] = (
    (214, 39, 40),
    (31, 119, 180),
    (255, 127, 14),
    (44, 160, 44),
    (148, 103, 189),
    (140, 86, 75),
    (227, 119, 194),
    (127, 127, 127),
    (188, 189, 34),
    (23, 190, 207),
)


@dataclass(frozen=True)
class FilterEntry:
    """A filter as every layer knows it.

    Parameters
    ----------
    filter_class : type
        The class (meeting mazelab.contract).
    short_name : str
        What the command line takes (`--filter sir`).
    label : str
        How figures and tables name it (SIR).
    colour : (int, int, int)
        Its colour, RGB 0-255, in the viewer and the PNGs.
    help : str
        One line for the help and the hints.
    takes_particles : bool
        Whether it is a sample (a particle count changes its results): not the grid filter or the EKF.
    batched : bool
        Whether a study may advance R runs of it together (its step works on the run axis; declared,
        False for a new class until it says so).
    plugin : PluginReference or None
        A plug-in's file, its sha256 and its class; None for a filter of the package.
    evidence : str
        Why its log evidence is not an estimate of p(z_1:K) under the lab's model, said beside every
        such figure (tables, files, figures); empty when it is one (or when it keeps none).
    """

    filter_class: type
    short_name: str
    label: str
    colour: Colour
    help: str
    takes_particles: bool = True
    batched: bool = False
    plugin: PluginReference | None = None
    evidence: str = ""

    @property
    def name(self) -> str:
        """The filter's `name`: how results, records and scenarios name it."""
        return self.filter_class.name

    @property
    def options(self) -> Options:
        """Its declared options (mazelab.declaration)."""
        return options_of(self.filter_class)

    @property
    def reference(self) -> str:
        """What a worker process or a record resolves again: the short name, or a plug-in's path:Class."""
        return self.short_name if self.plugin is None else self.plugin.canonical


# the RPF's log evidence: the kernel's jitter after resampling is a move of the particles that is not the
# model's transition and that its weights leave out, so the product of its mean weights is not p(z_1:K)
RPF_EVIDENCE = (
    "not an estimate of p(z_1:K) under the model: its kernel jitters the particles after resampling, "
    "a move its weights leave out"
)
SHIPPED: tuple[FilterEntry, ...] = (
    FilterEntry(SIRParticleFilter, "sir", "SIR", PALETTE[0], "sampling importance resampling (Algorithm 4)",
                batched=True),
    FilterEntry(AuxiliaryParticleFilter, "apf", "APF", PALETTE[1], "the auxiliary particle filter (Algorithm 5)",
                batched=True),
    FilterEntry(RegularizedParticleFilter, "rpf", "RPF", PALETTE[2], "the regularised particle filter (Algorithm 6)",
                batched=True, evidence=RPF_EVIDENCE),
    FilterEntry(GridBayesFilter, "grid", "grid", PALETTE[3], "the exact Bayes filter on a fine grid (the reference)",
                takes_particles=False),
    FilterEntry(ExtendedKalmanFilter, "ekf", "EKF", PALETTE[4], "an extended Kalman filter (the baseline)",
                takes_particles=False),
)  # fmt: skip
_ENTRIES: list[FilterEntry] = list(SHIPPED)  # SHIPPED, then any registered by a package (`register`)
_BY_CLASS: dict[type, FilterEntry] = {entry.filter_class: entry for entry in SHIPPED}
_BY_NAME: dict[str, FilterEntry] = {entry.name: entry for entry in SHIPPED}


def register(entry: FilterEntry) -> FilterEntry:
    """Add a package's filter to the registry (what SHIPPED's lines do for the lab's own): every command,
    figure and study then knows it by its short name.

    Parameters
    ----------
    entry : FilterEntry

    Returns
    -------
    FilterEntry
        The entry, registered.

    Raises
    ------
    ValueError
        One line for a short name or name that already names a filter (as `filter_entry` reads names:
        "SIR" is sir's; a class registered already has its name), or a short name that is not one
        lower-case word; a constructor that spells a default other than the declared one.
    """
    if not entry.short_name or entry.short_name != "".join(entry.short_name.split()).lower():
        raise ValueError(f"the short name {entry.short_name!r} is not one lower-case word (the command line's)")
    for what, mine in (("short name", entry.short_name), ("name", entry.name)):
        other = shipped_entry(mine)
        if other is not None:
            raise ValueError(f"the {what} {mine!r} is taken by {other.name}: a registry entry needs its own")
    check_declared_defaults(entry.filter_class, entry.short_name)
    _ENTRIES.append(entry)
    _BY_CLASS[entry.filter_class] = entry
    _BY_NAME[entry.name] = entry
    return entry


def entries() -> list[FilterEntry]:
    """Every registered filter: the lab's (SHIPPED), then a package's (`register`).

    Returns
    -------
    list of FilterEntry
    """
    return list(_ENTRIES)


def is_shipped(filter_class: type) -> bool:
    """Whether a class is one of the registry's filters (the lab's, or a package's), not a plug-in or
    a user's own class.

    Parameters
    ----------
    filter_class : type

    Returns
    -------
    bool
    """
    return filter_class in _BY_CLASS


def shipped_entry(name: str) -> FilterEntry | None:
    """The registry's filter of a name (short, class or spaced name, as `filter_entry` reads them), or
    None; never a plug-in, and nothing is imported (what a scenario's loader may ask).

    Parameters
    ----------
    name : str

    Returns
    -------
    FilterEntry or None
    """
    key = "".join(str(name).split()).lower()
    for entry in _ENTRIES:
        full = entry.filter_class.__name__.lower()
        if key in (entry.short_name, full, full.replace("particlefilter", ""), entry.name.lower()):
            return entry
    return None


def filter_entry(name: str | type) -> FilterEntry:
    """The entry of a filter: a short name (sir), a class name (SIRParticleFilter) or the paper's spaced
    name ("SIR Particle Filter"), case-insensitive; a class itself (a user's own gets an entry made
    from its attributes); a plug-in `path/to/file.py:ClassName` (imported once per process); or the
    `name` of a plug-in already loaded in this process.

    Parameters
    ----------
    name : str or type

    Returns
    -------
    FilterEntry

    Raises
    ------
    ValueError
        One line naming the unknown name, the nearest short name (`sri`: did you mean sir?) and the valid ones.
    """
    if isinstance(name, type):
        return _BY_CLASS.get(name) or _entry_of_class(name, None)
    text = str(name).strip()
    if is_plugin_spec(text):  # loaded once per process; one line naming the file, the class and what is wrong
        filter_class = load_plugin(text)
        return _entry_of_class(filter_class, plugin_reference(text, filter_class))
    shipped = shipped_entry(text)
    if shipped is not None:
        return shipped
    loaded = loaded_plugin(text)
    if loaded is not None:
        return filter_entry(loaded)
    names = [entry.short_name for entry in _ENTRIES]
    close = difflib.get_close_matches(text.lower(), names, n=1, cutoff=0.5)
    hint = f"; did you mean {close[0]}?" if close else ""
    raise ValueError(f"unknown filter {text!r}{hint} (choose from {', '.join(names)}, or FILE.py:Class)")


def resolve_filter(name: str | type) -> type:
    """The filter class of a name, a class or a plug-in spec (see `filter_entry`).

    Parameters
    ----------
    name : str or type

    Returns
    -------
    type
    """
    return filter_entry(name).filter_class


_made: dict[type, FilterEntry] = {}


def _entry_of_class(filter_class: type, plugin: PluginReference | None) -> FilterEntry:
    """An entry for a class that is not shipped, from its own attributes: `name`, an optional `label`,
    `takes_particles` (default True), `batched` (declared on the class itself, default False) and
    `evidence` (why its log evidence is not of p(z_1:K), default none)."""
    if filter_class in _made and (plugin is None or _made[filter_class].plugin == plugin):
        return _made[filter_class]
    used = {entry.colour for entry in (*_ENTRIES, *_made.values())}
    # the next free colour; once all are taken, the plug-ins' colours in turn (a shipped one never)
    shipped = {entry.colour for entry in SHIPPED}
    others = [c for c in PALETTE if c not in shipped]
    colour = next((c for c in PALETTE if c not in used), others[len(_made) % len(others)])
    doc = (filter_class.__doc__ or "").strip().splitlines()
    entry = FilterEntry(
        filter_class,
        short_name=filter_class.__name__,
        label=str(getattr(filter_class, "label", None) or filter_class.name),
        colour=colour,
        help=doc[0] if doc else f"{filter_class.__name__}, a filter of your own",
        takes_particles=bool(getattr(filter_class, "takes_particles", True)),
        batched=bool(filter_class.__dict__.get("batched", False)),
        plugin=plugin,
        evidence=str(getattr(filter_class, "evidence", "") or ""),
    )
    _made[filter_class] = entry
    return entry


def described(name: str) -> FilterEntry:
    """The entry of a filter by the `name` results carry (a registered one, or a plug-in loaded here): its
    label, colour and caveat for the tables and figures; for a name this process does not know (a student's
    filter in a record), an entry that names it: the name as its label, the palette's grey, no caveat.

    Parameters
    ----------
    name : str

    Returns
    -------
    FilterEntry
    """
    entry = _BY_NAME.get(name)
    loaded = None if entry is not None else loaded_plugin(name)
    if loaded is not None:
        return filter_entry(loaded)
    return entry or FilterEntry(type(name, (), {"name": name}), name, name, PALETTE[7], "a filter unknown here")


def rgb(colour: Colour) -> tuple[float, float, float]:
    """An RGB 0-255 colour in matplotlib's 0-1 form.

    Parameters
    ----------
    colour : (int, int, int)

    Returns
    -------
    (float, float, float)
    """
    return colour[0] / 255, colour[1] / 255, colour[2] / 255


__all__ = [
    "PALETTE",
    "RPF_EVIDENCE",
    "SHIPPED",
    "FilterEntry",
    "described",
    "entries",
    "filter_entry",
    "is_shipped",
    "register",
    "resolve_filter",
    "rgb",
    "shipped_entry",
]
