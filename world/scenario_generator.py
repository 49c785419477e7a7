"""Seeded random scenarios (``ringtrack scenarios generate``): convex regions, teams and moving targets.

Scenario ``index`` of seed ``S`` is drawn from ``numpy.random.default_rng([S, index])`` alone, so it
is the same whatever else is generated beside it (``--count 3`` writes the first three files of
``--count 10``), and the same bytes on every machine (coordinates rounded to millimetres).

* The region: 4-10 vertices on an ellipse with semi-axes ``a`` in [6, 20] m and ``b`` in
  [0.5 a, a], at sorted random angles at least 0.35 rad apart, rotated and placed within 50 m of the
  origin; points of an ellipse are in strictly convex position, so any such polygon is convex.
* The team: robots drawn uniformly from the range asked for (default 4-12), seeded random starts.
* The target: ``motion`` cycles through the motions asked for (scenario ``index`` gets
  ``motions[index % len(motions)]``). Its speed is ``v = f omega_max h``, ``f`` uniform in
  [0.3, 1], ``omega_max`` the robots' angular speed limit (rad/s) and ``h`` (metres) the least
  distance from its path to the boundary: a robot at least ``h`` away from the target sees its
  bearing turn no faster than ``v / h <= omega_max``, so the robots can keep up.

  - ``circle``: about a centre within 0.3 ``r_in`` of the Chebyshev centre (``r_in`` its radius),
    radius a share [0.3, 0.7] of the centre's room ``d`` (distance to the nearest edge), so
    ``h = d - radius``;
  - ``random_walk``: from the same kind of centre, ``speed_std = v / sqrt(pi / 2)`` (its mean step
    speed is then ``v``) with ``h = r_in / 2`` (the walk stays inside by construction, redrawing a
    step that would leave);
  - ``waypoints``: 3-6 points uniform in the region shrunk by half about the Chebyshev centre
    (each at least ``r_in / 2`` from the boundary, so ``h = r_in / 2``), in order of angle about
    it, looped.

The rest is as the shipped moving scenarios: dt = 0.1 s, omega_max = 1 deg/s, sigma = 0.1 deg,
ranges with sigma_z = 0.2 m, decentralized EKFs (prior at the truth, P0 = I), 1500 steps; but the
filters' process noise is fitted to the target's motion (``process_noise = "auto"``,
:func:`world.target.matched_process_noise`), not the authors' 0.2 m^2 a step, and the team runs the
project's decentralized default, the ``relay`` strategy (self-triggered polls with a tolerance from
each robot's estimate, carrying ranges), not the paper's ``self``.
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence

import msgspec
import numpy as np
from numpy.typing import ArrayLike

from ringtrack.world.geometry import ConvexRegion
from ringtrack.world.scenario_schema import ControlSpec, EstimationSpec, RegionSpec, ScenarioSpec, SensingSpec, TeamSpec
from ringtrack.world.target import Circle, RandomWalk, TargetSpec, Waypoints

MOTIONS = ("circle", "random_walk", "waypoints")
ROBOTS = (4, 12)  # the team sizes drawn from, inclusive
VERTICES = (4, 10)
SEMI_AXIS = (6.0, 20.0)  # m
MIN_VERTEX_GAP = 0.35  # rad between the ellipse angles of neighbouring vertices
PLACE = 50.0  # m: the ellipse's centre lies within this of the origin, on each axis
SPEED_SHARE = (0.3, 1.0)  # f: the target's speed over omega_max times its least distance to the boundary
CONTROL = ControlSpec(dt=0.1, omega_max_deg=1.0, sigma_deg=0.1, max_steps=1500)
SENSING = SensingSpec(range_sigma=0.2)
ESTIMATION = EstimationSpec(mode="decentralized", range_sigma=0.2, process_noise="auto", prior="truth",
                            prior_variance=1.0, fusion="ci")
DECIMALS = 3  # coordinates and speeds rounded to millimetres (per second)


def file_name(index: int) -> str:
    """``gen-0007.toml``: the file of scenario ``index``."""
    return f"gen-{index:04d}.toml"


def random_region(rng: np.random.Generator) -> ConvexRegion:
    """A convex polygon of 4-10 vertices on a random ellipse (metres; see the module docstring)."""
    count = int(rng.integers(VERTICES[0], VERTICES[1] + 1))
    slack = 2.0 * math.pi - count * MIN_VERTEX_GAP
    gaps = MIN_VERTEX_GAP + slack * rng.dirichlet(np.ones(count))  # sum to 2 pi, each >= MIN_VERTEX_GAP
    angles = rng.uniform(0.0, 2.0 * math.pi) + np.concatenate([[0.0], np.cumsum(gaps[:-1])])
    a = rng.uniform(*SEMI_AXIS)
    b = a * rng.uniform(0.5, 1.0)
    tilt = rng.uniform(0.0, math.pi)
    local = np.stack([a * np.cos(angles), b * np.sin(angles)], axis=1)
    rotation = np.array([[math.cos(tilt), -math.sin(tilt)], [math.sin(tilt), math.cos(tilt)]])
    vertices = local @ rotation.T + rng.uniform(-PLACE, PLACE, 2)
    return ConvexRegion.from_vertices(np.round(vertices, DECIMALS))


def _point(values: ArrayLike) -> tuple[float, float]:
    values = np.asarray(values, dtype=float)
    return (round(float(values[0]), DECIMALS), round(float(values[1]), DECIMALS))


def _speed(rng: np.random.Generator, clearance: float) -> float:
    """``f omega_max h`` (m/s) for the least distance ``h`` (metres) from the target to the boundary."""
    assert CONTROL.omega_max_deg is not None
    return float(rng.uniform(*SPEED_SHARE) * math.radians(CONTROL.omega_max_deg) * clearance)


def _near_centre(rng: np.random.Generator, region: ConvexRegion) -> np.ndarray:
    centre, radius = region.chebyshev_centre
    angle = rng.uniform(0.0, 2.0 * math.pi)
    return np.asarray(_point(centre + 0.3 * radius * rng.uniform() * np.array([math.cos(angle), math.sin(angle)])))


def random_target(rng: np.random.Generator, motion: str, region: ConvexRegion) -> TargetSpec:
    """A target of ``motion`` (one of :data:`MOTIONS`) that stays inside ``region`` and that the
    robots can keep up with (see the module docstring)."""
    centre, radius = region.chebyshev_centre
    if motion == "circle":
        middle = _near_centre(rng, region)
        room = float(region.heights(middle).min())
        circle = room * rng.uniform(0.3, 0.7)
        speed = round(_speed(rng, room - circle), DECIMALS + 2)
        return Circle(centre=_point(middle), speed=speed, angular_speed=round(speed / circle, DECIMALS + 2),
                      phase_deg=round(float(rng.uniform(0.0, 360.0)), 1))
    if motion == "random_walk":
        start = _near_centre(rng, region)
        return RandomWalk(position=_point(start),
                          speed_std=round(_speed(rng, radius / 2.0) / math.sqrt(math.pi / 2.0), DECIMALS + 2))
    if motion == "waypoints":
        count = int(rng.integers(3, 7))
        low, high = region.vertices.min(axis=0), region.vertices.max(axis=0)
        points: list[np.ndarray] = []
        while len(points) < count:  # uniform in the region, then shrunk by half about its centre
            candidate = rng.uniform(low, high)
            if region.is_interior(candidate):
                points.append(np.asarray(_point(centre + 0.5 * (candidate - centre))))
        points.sort(key=lambda point: math.atan2(point[1] - centre[1], point[0] - centre[0]))
        return Waypoints(waypoints=[_point(point) for point in points], speed=round(_speed(rng, radius / 2.0),
                                                                                      DECIMALS + 2))
    raise ValueError(f"unknown motion {motion!r}; give one of {', '.join(MOTIONS)}")


def random_scenario(seed: int, index: int, motions: Sequence[str] = MOTIONS,
                    robots: tuple[int, int] = ROBOTS) -> ScenarioSpec:
    """Scenario ``index`` of generator seed ``seed``: drawn from ``default_rng([seed, index])``, its
    target of motion ``motions[index % len(motions)]``, ``robots[0]..robots[1]`` robots."""
    rng = np.random.default_rng([seed, index])
    region = random_region(rng)
    team = TeamSpec(robots=int(rng.integers(robots[0], robots[1] + 1)))
    target = random_target(rng, motions[index % len(motions)], region)
    return ScenarioSpec(name=file_name(index).removesuffix(".toml"),
                        region=RegionSpec(vertices=[_point(vertex) for vertex in region.vertices]),
                        target=target, team=team, strategy={"name": "relay"}, control=CONTROL, sensing=SENSING,
                        estimation=ESTIMATION)


def scenario_text(seed: int, index: int, motions: Sequence[str] = MOTIONS, robots: tuple[int, int] = ROBOTS) -> bytes:
    """The TOML file of :func:`random_scenario`, with a comment header saying how it was made."""
    spec = random_scenario(seed, index, motions, robots)
    header = (f"# Generated by: ringtrack scenarios generate --seed {seed} --motion {','.join(motions)} "
              f"--robots {robots[0]}-{robots[1]}\n"
              f"# scenario {index}: numpy.random.default_rng([{seed}, {index}]), a {spec.target.__struct_config__.tag}"
              f" target, {spec.team.robots} robots (ringtrack.world.scenario_generator)\n")
    return (header + compact_toml(msgspec.to_builtins(spec))).encode()


def compact_toml(document: dict[str, object]) -> str:
    """A scenario's plain values as TOML, one line per key and arrays inline (as the shipped files
    are written): the top level's plain keys, then a ``[section]`` per table of plain values."""
    plain = [f"{key} = {_toml_value(value)}" for key, value in document.items() if not isinstance(value, dict)]
    sections = [f"\n[{key}]\n" + "".join(f"{name} = {_toml_value(item)}\n" for name, item in value.items())
                for key, value in document.items() if isinstance(value, dict)]
    return "\n".join(plain) + "\n" + "".join(sections)


def _toml_value(value: object) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int | float):
        return repr(value)
    if isinstance(value, str):
        return json.dumps(value)  # a JSON string is a TOML basic string
    if isinstance(value, list | tuple):
        return "[" + ", ".join(_toml_value(item) for item in value) + "]"
    raise TypeError(f"no TOML value for {value!r}")  # a nested table: not in a generated scenario
