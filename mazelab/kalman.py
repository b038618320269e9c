"""An extended Kalman filter on the lab's model: the baseline the particle filters are measured
against, in the tradition of the Kalman filters this lab grew from.

One Gaussian N(m, P) over the position (x, y) holds the belief. Prediction moves the mean by the
arc's mean displacement and adds the arc's covariance Q (both exact for the uniform compass error);
the update linearises the range to the station nearest the predicted mean. It tracks well from a
known start and fails at global localisation: one Gaussian cannot hold a belief with several modes,
the nearest-station data association picks the wrong station when the estimate is wrong, and walls
are not in a Gaussian.
"""

from __future__ import annotations

import math
from typing import Any, ClassVar

import numpy as np

from mazelab.checks import MAP_MARGIN
from mazelab.contract import Gaussian
from mazelab.declaration import Option, Options, choice, number_in
from mazelab.maze import Maze
from mazelab.model import CONFIDENCE_RADIUS, CONFIDENCE_SHARE, ROBOT_SPEED, SPEED_OPTION, ModelFilter
from mazelab.modes import ESTIMATE_OPTION

START_STD = 0.05  # std of each coordinate of init="start"'s covariance, map units: the start is known
# `gaussian_mass_within`'s midpoint nodes psi on a quarter turn, as cos^2 psi and sin^2 psi: 256 reach
# rounding level (64 already agree to 1e-9 for eigenvalues 5 and 1e-3; the integrand flattens where thin)
_PSI = (np.arange(256) + 0.5) * (math.pi / 2 / 256)
_COS2, _SIN2 = np.cos(_PSI) ** 2, np.sin(_PSI) ** 2


class ExtendedKalmanFilter(ModelFilter):
    """The EKF of the lab's model: state (x, y), mean `mean` (2,) and covariance `covariance` (2, 2).

    `init="prior"` (default) starts from the free area's exact mean and covariance (global
    localisation, the lab's problem); `init="start"` from the robot's true start `start` with
    covariance START_STD^2 I (position tracking). simulate hands every filter class that declares
    the option `start` the robot's start. A Kalman filter never restarts (`reinitialised_at` stays empty).
    """

    name: ClassVar[str] = "ExtendedKalmanFilter"
    count = 1  # one Gaussian
    options: ClassVar[Options] = Options(
        Option(
            "init",
            "prior",
            "prior (global localisation, the lab's problem) or start (tracking the start)",
            parse=str.strip,
            check=choice("init", ("prior", "start")),
            flag="--init",
        ),
        Option("start", None, "the robot's start (x, y), handed in by the run", derived=True),
        Option(
            "start_std",
            START_STD,
            "init=start: each coordinate's std, map units",
            check=number_in("start_std", 0.0, MAP_MARGIN, what=" map units"),
        ),
        SPEED_OPTION,
        ESTIMATE_OPTION,
    )

    def __init__(self, *args: Any, **options: Any):
        super().__init__(*args, **options)
        init, start, start_std = self.settings["init"], self.settings["start"], self.settings["start_std"]
        if init == "prior":
            self.mean, self.covariance = free_area_moments(self.world)
        else:  # "start"
            if start is None:
                raise ValueError('init="start" needs the robot\'s start: give start=(x, y)')
            self.mean = np.array(start, dtype=float).reshape(2)
            self.covariance = start_std**2 * np.eye(2)
        self.innovation = math.nan  # z_k less the reading expected at the predicted mean, map units

    def advance(self, compass_angle: float) -> None:
        """The prediction, m <- m + E[displacement], P <- P + Q: the exact first two moments of equation (1)."""
        displacement, q = self.per_angle(compass_angle, lambda angle: arc_moments(angle, self.delta, self.speed))
        self.mean = self.mean + displacement
        self.covariance = self.covariance + q

    def update(self, z: float) -> None:
        """The EKF update with the model's sensor linearised at the predicted mean (`Sensor.linearised`:
        the range to the nearest station), in Joseph form; none where its gradient is undefined."""
        expected, h = self.sensor.linearised(self.world, self.mean)
        self.innovation = math.nan if h is None else float(z) - expected
        if h is not None:
            self.mean, self.covariance = kalman_update(self.mean, self.covariance, h, self.innovation, self.sigma**2)

    def belief(self) -> Gaussian:
        """What the viewer draws: the Gaussian's mean and covariance."""
        return Gaussian(self.mean, self.covariance)

    # the read interface simulate and the viewer use
    @property
    def estimate(self) -> np.ndarray:
        """The mean m, shape (2,)."""
        return self.mean.copy()

    @property
    def is_confident(self) -> bool:
        """At least CONFIDENCE_SHARE (95%) of the Gaussian's mass lies within CONFIDENCE_RADIUS of the
        mean (the particle filters' rule, with the exact Gaussian mass)."""
        return gaussian_mass_within(self.covariance, CONFIDENCE_RADIUS) >= CONFIDENCE_SHARE


def arc_moments(compass_angle: float, delta: float, speed: float = ROBOT_SPEED) -> tuple[np.ndarray, np.ndarray]:
    """Mean (2,) and covariance Q (2, 2) of the displacement L (cos th, sin th), th ~ U(th0 +- Delta/2).

    With phi = th - th0 ~ U(-Delta/2, Delta/2): E[cos phi] = sin(Delta/2) / (Delta/2) = s,
    E[sin phi] = 0, E[cos^2 phi] = (1 + c) / 2 and E[sin^2 phi] = (1 - c) / 2 with c = sin(Delta) / Delta.
    So the mean is L s (cos th0, sin th0), and Q, in the frame along and across th0, is diagonal:
    L^2 diag((1 + c) / 2 - s^2, (1 - c) / 2), rotated by th0.
    """
    s = math.sin(delta / 2) / (delta / 2) if delta != 0 else 1.0  # sinc, 1 at 0
    c = math.sin(delta) / delta if delta != 0 else 1.0
    along = max((1 + c) / 2 - s * s, 0.0)  # ~ Delta^4 / 720: tiny, and rounding must not make it negative
    across = (1 - c) / 2  # ~ Delta^2 / 12
    cos, sin = math.cos(compass_angle), math.sin(compass_angle)
    rotation = np.array([[cos, -sin], [sin, cos]])
    mean = speed * s * np.array([cos, sin])
    q = speed**2 * (rotation * [along, across]) @ rotation.T
    return mean, q


def kalman_update(
    mean: np.ndarray, covariance: np.ndarray, h: np.ndarray, innovation: float, r: float
) -> tuple[np.ndarray, np.ndarray]:
    """One EKF update with a scalar reading of gradient H = `h` (2,), noise variance r and innovation
    z - h(m): (mean, covariance).

    S = H P H^T + r, K = P H^T / S, m <- m + K (z - h(m)), P <- (I - K H) P (I - K H)^T + K r K^T
    (Joseph form: symmetric and positive semi-definite whatever the rounding).
    """
    s = float(h @ covariance @ h) + r
    gain = covariance @ h / s  # (2,)
    i_kh = np.eye(2) - np.outer(gain, h)
    covariance = i_kh @ covariance @ i_kh.T + r * np.outer(gain, gain)
    return mean + gain * innovation, covariance


def free_area_moments(world: Maze) -> tuple[np.ndarray, np.ndarray]:
    """Mean (2,) and covariance (2, 2) of the uniform distribution over the free area, exactly.

    Every free cell is a unit square of equal area, so the law is an equal mixture of uniforms on the
    cells: mean = the mean of the cell centres; covariance = the centres' covariance (over the cells,
    divided by their count) plus each unit square's own covariance, I / 12.
    """
    centres = world.free_cells + 0.5  # (F, 2)
    mean = centres.mean(axis=0)
    centred = centres - mean
    return mean, centred.T @ centred / len(centres) + np.eye(2) / 12


def gaussian_mass_within(covariance: np.ndarray, radius: float) -> float:
    """P(|x| <= radius) for x ~ N(0, covariance), 2-D.

    With eigenvalues l1, l2 and x = (sqrt(l1) rho cos psi, sqrt(l2) rho sin psi), rho^2 ~ chi^2_2:
    P = (1 / 2 pi) int_0^2pi 1 - exp(-radius^2 / (2 (l1 cos^2 psi + l2 sin^2 psi))) dpsi, a smooth
    periodic integrand: the midpoint rule on a quarter turn (the rest by symmetry) is exact to rounding
    unless the Gaussian is extremely thin.
    """
    # l1, l2 in closed form, (a + d) / 2 +- sqrt(((a - d) / 2)^2 + b^2), clipped at 0, in plain floats: a few
    # times quicker than numpy's eigvalsh on 2 x 2
    (a, b), (_, d) = covariance.tolist()
    centre, half_gap = (a + d) / 2, math.hypot((a - d) / 2, b)
    l1, l2 = max(centre + half_gap, 0.0), max(centre - half_gap, 0.0)
    spread = l1 * _COS2 + l2 * _SIN2
    with np.errstate(divide="ignore"):
        inside = -np.expm1(-(radius**2) / (2 * spread))
    return float(inside.mean())


def covariance_ellipse(mean: np.ndarray, covariance: np.ndarray, scale: float = 2.0, points: int = 64) -> np.ndarray:
    """The `scale`-sigma ellipse {m + scale P^(1/2) u : |u| = 1} as a closed polygon, shape (points + 1, 2)."""
    values, vectors = np.linalg.eigh(covariance)
    angles = np.linspace(0.0, 2 * math.pi, points + 1)
    circle = np.column_stack([np.cos(angles), np.sin(angles)])
    return mean + scale * (circle * np.sqrt(np.maximum(values, 0.0))) @ vectors.T


__all__ = [
    "START_STD",
    "ExtendedKalmanFilter",
    "arc_moments",
    "covariance_ellipse",
    "free_area_moments",
    "gaussian_mass_within",
    "kalman_update",
]
