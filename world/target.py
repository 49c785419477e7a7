"""Target motion models, which are also the ``[target]`` section of a scenario (tagged by ``motion``).

Where the target is at each step (metres; step k at time ``(k - 1) dt``):

* ``stationary``: ``o(k) = position``;
* ``circle``: centre ``c``, linear speed ``v`` (m/s), angular speed ``w`` (rad/s, CCW positive),
  radius ``v / |w|``, ``o(k) = c + r (cos(phi0 + w t), sin(phi0 + w t))``, ``phi0`` = ``phase_deg``;
* ``random_walk``: ``o(k+1) = o(k) + N(0, (speed_std dt)^2 I)`` from a seeded stream; a step that
  would leave the region is redrawn, so the walk stays inside by construction (and its steps near
  the boundary are not exactly Gaussian: :meth:`RandomWalk.step_covariance` is the free walk's);
* ``waypoints``: along the polyline at ``speed`` (m/s), back to the first waypoint if ``loop``.

Paths are computed for the whole run at once, so the engine and the world process read the same
array. A circle or waypoints that leave the region are refused with a :class:`RegionError`.
"""

from __future__ import annotations

import math
from typing import Annotated

import msgspec
import numpy as np

from ringtrack.world.geometry import ConvexRegion, FloatArray, RegionError
from ringtrack.world.schema import Finite, NonNegative, Point, Positive, Spec

TARGET_STREAM = 2  # random-walk draws: numpy.random.default_rng([seed, TARGET_STREAM])
REDRAWS = 100


class Stationary(Spec, tag_field="motion", tag="stationary", frozen=True):
    position: Point

    def path(self, steps: int, dt: float, region: ConvexRegion, seed: int, margin: float) -> FloatArray:
        return np.tile(np.asarray(self.position, dtype=float), (steps, 1))

    def check(self, region: ConvexRegion, margin: float) -> None:
        _require_inside(region, self.position, "target.position", margin)


class Circle(Spec, tag_field="motion", tag="circle", frozen=True):
    centre: Point
    speed: Positive
    angular_speed: Finite  # rad/s, counter-clockwise positive
    phase_deg: Finite = 0.0

    @property
    def radius(self) -> float:
        return self.speed / abs(self.angular_speed)

    def path(self, steps: int, dt: float, region: ConvexRegion, seed: int, margin: float) -> FloatArray:
        angle = math.radians(self.phase_deg) + self.angular_speed * dt * np.arange(steps)
        return np.asarray(self.centre) + self.radius * np.stack([np.cos(angle), np.sin(angle)], axis=1)

    def check(self, region: ConvexRegion, margin: float) -> None:
        if self.angular_speed == 0:
            raise RegionError("target.angular_speed is 0 (an infinite circle); give a nonzero rad/s")
        _require_inside(region, self.centre, "target.centre", margin)
        room = float(region.heights(self.centre).min())
        if room - self.radius <= margin:
            raise RegionError(
                f"target circle of radius {self.radius:.4g} m (speed / angular_speed) about {list(self.centre)} "
                f"leaves the region ({room:.4g} m of room); lower target.speed or raise the size of "
                "target.angular_speed"
            )


class RandomWalk(Spec, tag_field="motion", tag="random_walk", frozen=True):
    position: Point
    speed_std: NonNegative  # m/s

    def path(self, steps: int, dt: float, region: ConvexRegion, seed: int, margin: float) -> FloatArray:
        rng = np.random.default_rng([seed, TARGET_STREAM])
        points = np.empty((steps, 2))
        points[0] = self.position
        scale = self.speed_std * dt
        for k in range(1, steps):
            candidate = points[k - 1]  # boxed in: stay
            for _ in range(REDRAWS):
                step = points[k - 1] + rng.normal(0.0, scale, 2)
                if region.is_interior(step, margin):
                    candidate = step
                    break
            points[k] = candidate
        return points

    def check(self, region: ConvexRegion, margin: float) -> None:
        _require_inside(region, self.position, "target.position", margin)

    def step_covariance(self, dt: float) -> float:
        """The variance (m^2, per axis) of a step of ``dt`` seconds, ``(speed_std dt)^2``: ``Q = q I``.
        Exact for the free walk; a step redrawn because it would leave the region is drawn from
        the Gaussian truncated to the region, whose covariance is smaller (ignored)."""
        return (self.speed_std * dt) ** 2


class Waypoints(Spec, tag_field="motion", tag="waypoints", frozen=True):
    waypoints: Annotated[list[Point], msgspec.Meta(min_length=2)]
    speed: Positive
    loop: bool = True

    def path(self, steps: int, dt: float, region: ConvexRegion, seed: int, margin: float) -> FloatArray:
        corners = np.asarray(self.waypoints, dtype=float)
        if self.loop:
            corners = np.vstack([corners, corners[:1]])
        along = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(corners, axis=0), axis=1))])
        travelled = self.speed * dt * np.arange(steps)
        travelled = np.mod(travelled, along[-1]) if self.loop and along[-1] > 0 else np.minimum(travelled, along[-1])
        return np.stack([np.interp(travelled, along, corners[:, axis]) for axis in (0, 1)], axis=1)

    def check(self, region: ConvexRegion, margin: float) -> None:
        for index, point in enumerate(self.waypoints):  # convex region: the legs stay inside too
            _require_inside(region, point, f"target.waypoints[{index}]", margin)


TargetSpec = Stationary | Circle | RandomWalk | Waypoints


def matched_process_noise(target: TargetSpec, dt: float, robots: int, range_sigma: float) -> float:
    """The random-walk filters' ``q`` (m^2 per step, ``Q = q I``) that fits ``target``'s motion,
    from the scenario's own models (``process_noise = "auto"``).

    * a random walk: its own step variance, ``(speed_std dt)^2`` (the model is then exact);
    * a target moving at ``speed`` ``v`` along a circle or waypoints: a walk tracking a drift of
      ``d = v dt`` metres a step with ``J = N / (2 sigma_z^2)`` per axis of information a step (N
      ranges, m^-2) settles at ``P ~ sqrt(q / J)`` per axis with a lag ``d / sqrt(q J)``; the total
      squared error ``2 sqrt(q / J) + d^2 / (q J)`` is least at ``q = d^(4/3) J^(-1/3)``;
    * a stationary target: 0.
    """
    if isinstance(target, RandomWalk):
        return target.step_covariance(dt)
    if isinstance(target, Stationary):
        return 0.0
    drift = target.speed * dt
    return float(drift ** (4.0 / 3.0) * ring_information(robots, range_sigma) ** (-1.0 / 3.0))


def ring_information(robots: int, range_sigma: float) -> float:
    """``J = N / (2 sigma_z^2)`` (m^-2 per axis): the information a step's ranges (``range_sigma``
    metres each) of ``robots`` robots spread uniformly around the target give along any axis (the
    sum of ``u u^T / sigma_z^2`` over N unit bearings spread evenly is ``N / (2 sigma_z^2) I``)."""
    return robots / (2.0 * range_sigma**2)


def steady_variance(robots: int, range_sigma: float, process_noise: float) -> float:
    """The per-axis variance (m^2) a random-walk filter (``q = process_noise`` m^2 per step and
    axis) settles to when it takes every step the ranges of ``robots`` robots spread uniformly
    around the target: the fixed point of ``P = (P + q) / (1 + J (P + q))`` with ``J`` of
    :func:`ring_information`, ``P = (sqrt(q^2 + 4 q / J) - q) / 2`` (0 for a stationary target's
    ``q = 0``): what the centralized filter of a spread team reaches."""
    information = ring_information(robots, range_sigma)
    return (math.sqrt(process_noise**2 + 4.0 * process_noise / information) - process_noise) / 2.0


def _require_inside(region: ConvexRegion, point: Point, field: str, margin: float) -> None:
    if not bool(region.is_interior(point, margin)):
        raise RegionError(f"{field} {list(point)} is not inside the region; move it inside the polygon")
