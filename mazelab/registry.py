"""Every filter by name: class names, short names (sir, apf, rpf, grid, ekf) and the paper's spaced names."""

from __future__ import annotations

from mazelab.filters import AuxiliaryParticleFilter, RegularizedParticleFilter, SIRParticleFilter
from mazelab.grid_filter import GridBayesFilter
from mazelab.kalman import ExtendedKalmanFilter

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
    ("SIR Particle Filter"), case-insensitive."""
    if isinstance(name, type):
        return name
    key = "".join(str(name).split()).lower()
    for full in FILTERS:
        if key in (full.lower(), full.lower().replace("particlefilter", "")):
            return FILTERS[full]
    if key in SHORT_NAMES:
        return FILTERS[SHORT_NAMES[key]]
    valid = ", ".join([*FILTERS, *SHORT_NAMES])
    raise ValueError(f"unknown filtering algorithm {name!r}; valid names: {valid}")


__all__ = [
    "FILTERS",
    "SHORT_NAMES",
    "resolve_filter",
]
