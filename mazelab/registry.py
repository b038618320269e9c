"""Every filter by name, one entry each (`FilterEntry`): its class, short name, label, colour, one-line
help, and what it can do. The command line's choices and hints, the figures' labels and colours (the
same in Rerun and in the PNGs), `mazelab --help` and a study's columns read it. A filter of the package
is one entry in `SHIPPED`; a student's own, `path/to/file.py:ClassName` wherever a filter name goes,
gets one when it is loaded (`load_plugin`), named in a saved run by its `PluginReference` and carried by
a study with its code (`plugin_codes`). The student's code failing during a run is mazelab.stops.StudentCodeError.

    entry = filter_entry("rpf")          # also "RegularizedParticleFilter", "Regularized Particle Filter"
    entry.filter_class, entry.label      # RegularizedParticleFilter, "RPF"
"""

from __future__ import annotations

import difflib
import hashlib
import importlib.util
import inspect
import re
import sys
import tempfile
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from types import ModuleType
from typing import Any

from mazelab.atomic import write_atomically
from mazelab.contract import missing_parts
from mazelab.declaration import Options, options_of
from mazelab.filters import AuxiliaryParticleFilter, RegularizedParticleFilter, SIRParticleFilter
from mazelab.grid_filter import GridBayesFilter
from mazelab.kalman import ExtendedKalmanFilter
from mazelab.stops import describe_exit, is_users_stop, student_line, working_folder_kept

# -- a student's own filter as a plug-in: `path/to/my_filter.py:MyFilter` wherever a filter name goes
_by_name: dict[str, type] = {}  # the loaded plug-ins by their `name`, for the names results carry


def is_plugin_spec(text: str) -> bool:
    """Whether `text` names a file's class (`file.py:Class`) or a file (`file.py`), not a shipped filter."""
    return str(split_spec(text)[0]).strip().endswith(".py")


def split_spec(spec: str) -> tuple[Path, str | None]:
    """`file.py:Class` -> (Path("file.py"), "Class"); `file.py` -> (Path("file.py"), None)."""
    spec = spec.strip()
    if spec.endswith(".py"):
        return Path(spec), None
    path, _, class_name = spec.rpartition(":")
    return Path(path), class_name.strip() or None


@dataclass(frozen=True)
class PluginReference:
    """One plug-in file: its spec (as the user wrote it; a study's runs name it by its absolute path,
    `/abs/file.py:Class`), the sha256 of its bytes and its class; `path` the file's absolute path when it
    was loaded, and `source` its bytes when a study carries them (`plugin_codes`), read once when the
    study is planned so that a worker process, or a Dask worker on another machine, runs the very code
    the study was planned with (only its file travels). A scenario stores the reference (`as_json`, read
    back by `from_json`) and never imports it; a replay needs the user to name the plug-in again."""

    spec: str
    sha256: str
    class_name: str
    path: Path | None = None
    source: bytes = b""

    def as_json(self) -> dict[str, str]:
        """What a scenario stores (the absolute path is the machine's, so it is left out)."""
        return {"spec": self.spec, "sha256": self.sha256, "class": self.class_name}

    def describe(self) -> str:
        """'my_filter.py:MyFilter (sha256 1a2b3c4d...)'."""
        return f"{self.spec} (sha256 {self.sha256[:12]}...)"

    def spec_here(self) -> str:
        """The spec that imports a study's plug-in (`plugin_codes`) in this process: its file itself when
        it holds the study's bytes, else a copy written beside the other shipped plug-ins. Raises
        ValueError (one line) when the bytes do not have the recorded sha256."""
        path = split_spec(self.spec)[0]
        if hashlib.sha256(self.source).hexdigest() != self.sha256:
            raise ValueError(f"{path.name}: the plug-in's code arrived damaged (its sha256 differs)")
        try:
            if file_sha256(path) == self.sha256:
                return self.spec
        except OSError:  # not on this machine
            pass
        copy = Path(tempfile.gettempdir()) / CODE_FOLDER / self.sha256 / path.name
        if not copy.is_file():
            copy.parent.mkdir(parents=True, exist_ok=True)
            write_atomically(copy, self.source)
        return f"{copy}:{self.class_name}"

    @classmethod
    def from_json(cls, stored: Any) -> PluginReference:
        """A stored reference, checked: the spec is one printable line naming a .py file and this class
        (`file.py:Class`, as `as_json` writes it), since it is printed in messages and commands, where a
        newline would forge a line. Raises ValueError of one line."""
        if not isinstance(stored, dict) or sorted(stored) != ["class", "sha256", "spec"]:
            raise ValueError('must be {"spec": "FILE.py:Class", "sha256": "...", "class": "Class"}')
        spec, sha256, class_name = (stored[key] for key in ("spec", "sha256", "class"))
        if not isinstance(sha256, str) or not re.fullmatch("[0-9a-f]{64}", sha256):
            raise ValueError(f"sha256 must be 64 hexadecimal digits, got {str(sha256)[:70]!r}")
        if not isinstance(class_name, str) or not class_name.isidentifier() or len(class_name) > 256:
            raise ValueError(f"class must be a Python class name, got {str(class_name)[:60]!r}")
        if not isinstance(spec, str) or not spec.isprintable() or len(spec) > 4096:
            raise ValueError(f"spec must be one printable line, got {str(spec)[:60]!r}")
        path, _, named = spec.rpartition(":")
        if not path.strip().endswith(".py") or named != class_name:
            raise ValueError(
                f"spec must name a .py file and the class {class_name} (FILE.py:{class_name}), got {spec[:60]!r}"
            )
        return cls(spec, sha256, class_name)


def file_sha256(path: str | Path) -> str:
    """The sha256 of a file's bytes, hex (what `sha256sum FILE` prints)."""
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def load_plugin(spec: str) -> type:
    """The class of a plug-in spec `path/to/file.py:ClassName` (or `file.py` holding one filter class),
    the file imported under a module name of its own, so that two files that both define `MyFilter`
    never clash, with its folder importable while it loads, as `python my_filter.py` has it.

    Raises
    ------
    ValueError
        One line naming the file, the class and what is missing: no such file, an import that fails,
        no such class, or a class that misses part of the filter contract (mazelab.contract).
    """
    path, class_name = split_spec(spec)
    shown = f"{path}:{class_name}" if class_name else str(path)
    if not path.is_file():
        raise ValueError(f"{shown}: no such file {path}" + ("" if path.exists() else " (check the path)"))
    module = _import_file(path.resolve(), path)  # imported once per version of the file
    own = {n: c for n, c in vars(module).items() if isinstance(c, type) and c.__module__ == module.__name__}
    defined = ", ".join(own) or "no classes"
    if class_name is None:
        classes = [c for c in own.values() if not missing_parts(c)]
        if len(classes) != 1:
            found = ", ".join(c.__name__ for c in classes) or "none"
            raise ValueError(f"{path}: name the filter class as {path}:ClassName (filter classes found: {found})")
        class_name = classes[0].__name__
        shown = f"{path}:{class_name}"
    cls = getattr(module, class_name, None)
    if not isinstance(cls, type):
        raise ValueError(f"{shown}: {path} has no class {class_name!r} (it defines: {defined})")
    if cls.__module__ != module.__name__ and is_lab_class(cls):
        raise ValueError(
            f"{shown}: {class_name} is the lab's own class, which {path.name} imports; name the class you wrote "
            f"(it defines: {defined})"
        )
    missing = missing_parts(cls)
    if missing:
        raise ValueError(
            f"{shown}: class {class_name} does not meet the filter contract: it has no {', '.join(missing)}"
        )
    check_declared_defaults(cls, shown)
    _by_name[cls.name] = cls
    return cls


def check_declared_defaults(cls: type, shown: str) -> None:
    """A constructor that spells an option's default itself must spell the declared one (else the run
    would use one value and the scenario store another); one line naming the option."""
    try:
        parameters = inspect.signature(cls.__init__).parameters
        declared = options_of(cls)
    except (TypeError, ValueError) as error:
        raise ValueError(f"{shown}: {error}") from None
    for name, parameter in parameters.items():
        spelled = name in declared and parameter.default is not inspect.Parameter.empty
        if spelled and parameter.default != declared[name].default:
            raise ValueError(
                f"{shown}: the constructor's default {name}={parameter.default!r} is not the declared "
                f"default {declared[name].default!r}: take the default from the declaration (options)"
            )


def is_lab_class(cls: type) -> bool:
    """Whether a class is the lab's own (defined in mazelab/ or a face of the repo), not the student's."""
    module = getattr(cls, "__module__", "") or ""
    return module.split(".")[0] in ("mazelab", "particle_filter", "draw")


def loaded_plugin(name: str) -> type | None:
    """A plug-in already loaded in this process, by its `name` (what results and tables carry)."""
    return _by_name.get(name)


def _import_file(resolved: Path, shown: Path) -> ModuleType:
    """Import the file as module `mazelab_plugin_<hash of its path>_<mtime>`: unique per file (and per
    version of it, so an edited file is read again), registered in sys.modules (pickle, dataclasses)."""
    stamp = resolved.stat().st_mtime_ns
    digest = hashlib.sha1(str(resolved).encode()).hexdigest()[:12]
    module_name = f"mazelab_plugin_{digest}_{stamp}"
    if module_name in sys.modules:
        return sys.modules[module_name]
    spec = importlib.util.spec_from_file_location(module_name, resolved)
    if spec is None or spec.loader is None:
        raise ValueError(f"{shown}: cannot be imported as a Python module")
    module = importlib.util.module_from_spec(spec)
    sys.modules[module_name] = module
    folder = str(resolved.parent)
    added = folder not in sys.path
    if added:
        sys.path.insert(0, folder)  # its helper modules import, as with `python file.py`
    try:
        with working_folder_kept(shown.name):
            spec.loader.exec_module(module)
    except (Exception, SystemExit, KeyboardInterrupt) as error:
        del sys.modules[module_name]
        if is_users_stop(error):
            raise
        exited = isinstance(error, (SystemExit, KeyboardInterrupt))  # sys.exit() in the file, say
        what = f"it {describe_exit(error)} while being imported" if exited else f"{type(error).__name__}: {error}"
        raise ValueError(f"{shown} does not import: {what}{student_line(error.__traceback__, error)}") from None
    finally:
        if added and folder in sys.path:
            sys.path.remove(folder)
    return module


# -- a plug-in's code, sent with a study's runs ------------------------------------------------------
CODE_FOLDER = "mazelab-plugins"  # under the system's temporary folder: the shipped plug-ins, by sha256


def plugin_codes(filters: Sequence[object]) -> tuple[PluginReference, ...]:
    """Every plug-in among a study's filters with its code, read now (names and specs, each spec with an
    absolute path, runs.filter_key; classes from Python are sent as they are)."""
    codes = []
    for spec in dict.fromkeys(f for f in filters if isinstance(f, str) and is_plugin_spec(f)):
        path, class_name = split_spec(spec)
        source = path.read_bytes()
        codes.append(PluginReference(spec, hashlib.sha256(source).hexdigest(), class_name or "", path, source))
    return tuple(codes)


def filters_here(filters: Sequence[str], codes: Sequence[PluginReference]) -> tuple[str, ...]:
    """A run's filter names with each plug-in's spec replaced by the one that imports its shipped code
    in this process (`PluginReference.spec_here`)."""
    here = {code.spec: code.spec_here() for code in codes}
    return tuple(here.get(name, name) for name in filters)


# -- every filter by name ---------------------------------------------------------------------------
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
        """What a worker process or a record resolves again: the short name, or a plug-in's /abs/file.py:Class."""
        return self.short_name if self.plugin is None else f"{self.plugin.path}:{self.plugin.class_name}"


# the RPF's log evidence: the kernel's jitter after resampling is a move of the particles that is not the
# model's transition and that its weights leave out, so the product of its mean weights is not p(z_1:K)
RPF_EVIDENCE = (
    "not an estimate of p(z_1:K) under the model: its kernel jitters the particles after resampling, "
    "a move its weights leave out"
)
SHIPPED: tuple[FilterEntry, ...] = (
    FilterEntry(
        SIRParticleFilter, "sir", "SIR", PALETTE[0], "sampling importance resampling (Algorithm 4)", batched=True
    ),
    FilterEntry(
        AuxiliaryParticleFilter, "apf", "APF", PALETTE[1], "the auxiliary particle filter (Algorithm 5)", batched=True
    ),
    FilterEntry(
        RegularizedParticleFilter,
        "rpf",
        "RPF",
        PALETTE[2],
        "the regularised particle filter (Algorithm 6)",
        batched=True,
        evidence=RPF_EVIDENCE,
    ),
    FilterEntry(
        GridBayesFilter,
        "grid",
        "grid",
        PALETTE[3],
        "the exact Bayes filter on a fine grid (the reference)",
        takes_particles=False,
    ),
    FilterEntry(
        ExtendedKalmanFilter,
        "ekf",
        "EKF",
        PALETTE[4],
        "an extended Kalman filter (the baseline)",
        takes_particles=False,
    ),
)
_ENTRIES: list[FilterEntry] = list(SHIPPED)  # SHIPPED, then any registered by a package (`register`)


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
    return entry


def entries() -> list[FilterEntry]:
    """Every registered filter: the lab's (SHIPPED), then a package's (`register`).

    Returns
    -------
    list of FilterEntry
    """
    return list(_ENTRIES)


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
        return next((e for e in _ENTRIES if e.filter_class is name), None) or _entry_of_class(name, None)
    text = str(name).strip()
    if is_plugin_spec(text):  # loaded once per process; one line naming the file, the class and what is wrong
        filter_class = load_plugin(text)
        class_name, path = filter_class.__name__, Path(inspect.getfile(filter_class)).resolve()
        plugin = PluginReference(f"{split_spec(text)[0]}:{class_name}", file_sha256(path), class_name, path)
        return _entry_of_class(filter_class, plugin)
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
    loaded = loaded_plugin(name)
    entry = next((e for e in _ENTRIES if e.name == name), None) or (loaded and filter_entry(loaded))
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
    "register",
    "resolve_filter",
    "rgb",
    "shipped_entry",
]
