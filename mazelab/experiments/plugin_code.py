"""A plug-in filter's code as a study carries it: the file's bytes and their sha256, read once when the
study is planned. Every run takes the code with it, so a worker process or a Dask worker on another
machine runs the very code the study was planned with: it checks the hash, uses the file at the same
path if that file has those bytes, and otherwise writes the bytes to a folder of its own (named by the
hash) and imports them from there. A plug-in that imports modules beside it needs them on the worker
too; only its own file travels."""

from __future__ import annotations

import hashlib
import tempfile
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from mazelab.atomic import write_bytes_atomically
from mazelab.plugins import is_plugin_spec, split_spec

CODE_FOLDER = "mazelab-plugins"  # under the system's temporary folder: the shipped plug-ins, by sha256


@dataclass(frozen=True)
class PluginCode:
    """One plug-in of a study: the spec the runs name it by (`/absolute/path/file.py:Class`), the
    file's bytes and their sha256."""

    spec: str
    source: bytes
    sha256: str

    @classmethod
    def of(cls, spec: str) -> PluginCode:
        """The code of a plug-in spec with an absolute path (runs.filter_key), read now."""
        source = split_spec(spec)[0].read_bytes()
        return cls(spec, source, hashlib.sha256(source).hexdigest())

    @property
    def path(self) -> Path:
        return split_spec(self.spec)[0]

    @property
    def class_name(self) -> str:
        return split_spec(self.spec)[1] or ""

    def spec_here(self) -> str:
        """The spec that imports this code in this process: the file itself when it holds these bytes,
        else a copy written beside the other shipped plug-ins. Raises ValueError (one line) when the
        bytes do not have the recorded sha256."""
        if hashlib.sha256(self.source).hexdigest() != self.sha256:
            raise ValueError(f"{self.path.name}: the plug-in's code arrived damaged (its sha256 differs)")
        try:
            if hashlib.sha256(self.path.read_bytes()).hexdigest() == self.sha256:
                return self.spec
        except OSError:  # not on this machine
            pass
        copy = Path(tempfile.gettempdir()) / CODE_FOLDER / self.sha256 / self.path.name
        if not copy.is_file():
            copy.parent.mkdir(parents=True, exist_ok=True)
            write_bytes_atomically(copy, self.source)
        return f"{copy}:{self.class_name}"


def plugin_codes(filters: Sequence[object]) -> tuple[PluginCode, ...]:
    """The code of every plug-in among a study's filters (names and specs; classes from Python are
    sent as they are)."""
    return tuple(PluginCode.of(f) for f in filters if isinstance(f, str) and is_plugin_spec(f))


def filters_here(filters: Sequence[str], codes: Sequence[PluginCode]) -> tuple[str, ...]:
    """A run's filter names with each plug-in's spec replaced by the one that imports its shipped code
    in this process (`PluginCode.spec_here`)."""
    here = {code.spec: code.spec_here() for code in codes}
    return tuple(here.get(name, name) for name in filters)


__all__ = ["CODE_FOLDER", "PluginCode", "filters_here", "plugin_codes"]
