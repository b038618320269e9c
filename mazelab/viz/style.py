"""How the lab is drawn: colours, sizes and entity paths shared by every view."""

from __future__ import annotations

import re

DEFAULT_MAX_DRAWN = 5000  # particles drawn per step at most; the filter keeps all of them
VIEWER_PORT = 9876  # the native viewer's gRPC port, rerun's default: later runs reuse its window


APPLICATION_ID = "maze_particle_filter_lab"
MAP = "/map"  # everything drawn in the map frame lives under this entity
FREE_COLOR, WALL_COLOR = (255, 255, 255), (0, 0, 0)
STATION_COLOR, ROBOT_COLOR = (0, 200, 255), (0, 170, 0)
ESTIMATE_COLOR, CONFIDENT_COLOR = (128, 128, 128), (0, 200, 0)
INJECTED_COLOR = (255, 190, 0)  # particles injected by recovery this step (weights are drawn blue..red)
KIDNAP_COLOR = (230, 0, 200)  # the jump of a kidnapped robot
PARTICLE_ARROW_LENGTH, ROBOT_ARROW_LENGTH = 0.15, 0.5  # map units
STATION_RADIUS, ROBOT_RADIUS, PARTICLE_ARROW_RADIUS, CELL_DOT_RADIUS = 0.08, 0.12, 0.008, 0.03
COVARIANCE_SIGMAS, COVARIANCE_LINE_RADIUS = 2.0, 0.02  # the EKF's ellipse: 2-sigma (86% of a 2-D Gaussian)
MODE_DRAWN_SHARE = 0.05  # modes holding more than this share of the weight are drawn, each a labelled circle
MODE_MIN_RADIUS, MODE_LINE_RADIUS = 0.25, 0.02  # a mode's circle: its spread, at least this (map units)
SERIES = ("error", "ess", "confident")  # the time series under /metrics/<series>/<filter>


def entity_name(filter_name: str) -> str:
    """A filter's name as an entity-path part: "SIRParticleFilter" -> "sir_particle_filter"."""
    spaced = re.sub(r"(?<=[a-z0-9])(?=[A-Z])|(?<=[A-Z])(?=[A-Z][a-z])", "_", str(filter_name).strip())
    return re.sub(r"[^a-z0-9]+", "_", spaced.lower()).strip("_") or "filter"


__all__ = [
    "APPLICATION_ID",
    "CELL_DOT_RADIUS",
    "CONFIDENT_COLOR",
    "COVARIANCE_LINE_RADIUS",
    "COVARIANCE_SIGMAS",
    "DEFAULT_MAX_DRAWN",
    "ESTIMATE_COLOR",
    "FREE_COLOR",
    "INJECTED_COLOR",
    "KIDNAP_COLOR",
    "MAP",
    "MODE_DRAWN_SHARE",
    "MODE_LINE_RADIUS",
    "MODE_MIN_RADIUS",
    "PARTICLE_ARROW_LENGTH",
    "PARTICLE_ARROW_RADIUS",
    "ROBOT_ARROW_LENGTH",
    "ROBOT_COLOR",
    "ROBOT_RADIUS",
    "SERIES",
    "STATION_COLOR",
    "STATION_RADIUS",
    "VIEWER_PORT",
    "WALL_COLOR",
    "entity_name",
]
