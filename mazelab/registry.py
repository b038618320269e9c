"""Every filter by name: class names, short names (sir, apf, rpf, grid, ekf), the paper's spaced names,
and a student's own as `path/to/file.py:ClassName` (mazelab.plugins)."""

from __future__ import annotations

from mazelab.filters import AuxiliaryParticleFilter, RegularizedParticleFilter, SIRParticleFilter
from mazelab.grid_filter import GridBayesFilter
from mazelab.kalman import ExtendedKalmanFilter
from mazelab.plugins import is_plugin_spec, load_plugin, loaded_plugin

FILTERS: dict[str, type] = {
    "SIRParticleFilter": SIRParticleFilter,
    "AuxiliaryParticleFilter": AuxiliaryParticleFilter,
    "RegularizedParticleFilter": RegularizedParticleFilter,
    "GridBayesFilter": GridBayesFilter,
    "ExtendedKalmanFilter": ExtendedKalmanFilter,
}
SHORT_NAMES = {
    "sir": "SIRParticleFilter",
    "apf": "AuxiliaryParticleFilter",
    "rpf": "RegularizedParticleFilter",
    "grid": "GridBayesFilter",
    "ekf": "ExtendedKalmanFilter",
}


def resolve_filter(name: str | type) -> type:
    """The filter class for a class name, a short name (sir/apf/rpf/grid/ekf) or the paper's spaced name
    ("SIR Particle Filter"), case-insensitive; a class itself; or a plug-in `path/to/file.py:ClassName`
    (imported once per process; a class loaded so is also found by its `name`)."""
    if isinstance(name, type):
        return name
    if is_plugin_spec(str(name)):
        return load_plugin(str(name))
    key = "".join(str(name).split()).lower()
    for full in FILTERS:
        if key in (full.lower(), full.lower().replace("particlefilter", "")):
            return FILTERS[full]
    if key in SHORT_NAMES:
        return FILTERS[SHORT_NAMES[key]]
    plugin = loaded_plugin(str(name).strip())
    if plugin is not None:
        return plugin
    valid = ", ".join([*FILTERS, *SHORT_NAMES])
    raise ValueError(f"unknown filtering algorithm {name!r}; valid names: {valid}, or path/to/file.py:ClassName")


__all__ = [
    "FILTERS",
    "SHORT_NAMES",
    "resolve_filter",
]
