"""Shared hypothesis strategies and independent helpers for the ringtrack test suite.

Everything here is written from docs/algorithms.md, not from the code under test, so that the tests can
catch the code disagreeing with it:

* ``convex_vertices``: random strictly convex polygons (CCW vertex arrays), either points on a rotated
  ellipse at sorted random angles or the convex hull of random points, with near-degenerate ones
  (tiny edges, almost straight corners, slivers) rejected;
* ``regions`` / ``region_with_points``: a validated :class:`ConvexRegion` plus interior points (a random
  convex combination of the vertices, pulled towards the vertex centroid);
* ``ring_angles``: N angles (radians) in strict CCW cyclic order;
* ``scenario_from``: a :class:`world.scenario.Scenario` built from TOML text, as a user would write it.
"""

from __future__ import annotations

import math

import numpy as np
from hypothesis import assume
from hypothesis import strategies as st

from ringtrack.world.geometry import ConvexRegion
from ringtrack.world.scenario import Scenario, parse_scenario, resolve

TWO_PI = 2.0 * math.pi

# Authors' polygon and target (docs/algorithms.md sections 10, 11, 13).
AUTHORS_VERTICES = [[3.0, 7.0], [8.0, 17.0], [5.0, 26.0], [1.0, 22.0]]
AUTHORS_TARGET = (4.0, 20.0)
PAPER_ANGLES_DEG = [69.8979, 75.0730, 83.1024, 108.1016, 170.1016, 303.8982]


# ---------------------------------------------------------------------------- polygons
def polygon_quality_ok(vertices: np.ndarray) -> bool:
    """Reject polygons that are valid but numerically degenerate for the oracles' tolerances."""
    vertices = np.asarray(vertices, dtype=float)
    if len(vertices) < 3:
        return False
    edges = np.roll(vertices, -1, axis=0) - vertices
    lengths = np.hypot(edges[:, 0], edges[:, 1])
    diameter = np.max(np.linalg.norm(vertices[:, None] - vertices[None], axis=-1))
    if lengths.min() < 0.02 * diameter:
        return False
    incoming = np.roll(edges, 1, axis=0)
    cross = incoming[:, 0] * edges[:, 1] - incoming[:, 1] * edges[:, 0]
    turn = np.arctan2(cross, np.einsum("kd,kd->k", incoming, edges))
    if turn.min() < 0.03:  # every corner must turn left by a visible angle (strictly convex, CCW)
        return False
    area = 0.5 * np.sum(vertices[:, 0] * np.roll(vertices[:, 1], -1) - np.roll(vertices[:, 0], -1) * vertices[:, 1])
    return area > 0.03 * diameter**2


@st.composite
def ellipse_vertices(draw: st.DrawFn) -> np.ndarray:
    count = draw(st.integers(3, 12))
    gaps = np.array(draw(st.lists(st.floats(0.2, 1.0), min_size=count, max_size=count)))
    start = draw(st.floats(0.0, TWO_PI))
    angles = start + TWO_PI * np.cumsum(gaps) / gaps.sum()
    a = draw(st.floats(0.5, 30.0))
    b = a * draw(st.floats(0.25, 1.0))
    tilt = draw(st.floats(0.0, math.pi))
    centre = np.array([draw(st.floats(-20.0, 20.0)), draw(st.floats(-20.0, 20.0))])
    local = np.stack([a * np.cos(angles), b * np.sin(angles)], axis=1)
    rotation = np.array([[math.cos(tilt), -math.sin(tilt)], [math.sin(tilt), math.cos(tilt)]])
    return centre + local @ rotation.T


@st.composite
def hull_vertices(draw: st.DrawFn) -> np.ndarray:
    from scipy.spatial import ConvexHull

    count = draw(st.integers(3, 14))
    scale = draw(st.floats(0.5, 30.0))
    coordinate = st.floats(-1.0, 1.0)
    points = np.array(draw(st.lists(st.tuples(coordinate, coordinate), min_size=count, max_size=count)))
    assume(np.linalg.matrix_rank(points - points.mean(axis=0), tol=1e-3) == 2)
    hull = ConvexHull(points)
    vertices = points[hull.vertices] * scale  # CCW in 2-D
    shift = draw(st.integers(0, len(vertices) - 1))
    offset = np.array([draw(st.floats(-20.0, 20.0)), draw(st.floats(-20.0, 20.0))])
    return np.roll(vertices, shift, axis=0) + offset


def convex_vertices() -> st.SearchStrategy[np.ndarray]:
    """CCW vertex arrays of non-degenerate strictly convex polygons."""
    return st.one_of(ellipse_vertices(), hull_vertices()).filter(polygon_quality_ok)


def regions() -> st.SearchStrategy[ConvexRegion]:
    return convex_vertices().map(ConvexRegion.from_vertices)


def interior_point(draw: st.DrawFn, vertices: np.ndarray, pull_max: float = 0.95) -> np.ndarray:
    """A convex combination of the vertices, pulled towards the vertex centroid: strictly interior."""
    weights = np.array(draw(st.lists(st.floats(0.0, 1.0), min_size=len(vertices), max_size=len(vertices))))
    weights = weights + 1e-3
    point = weights @ vertices / weights.sum()
    centroid = vertices.mean(axis=0)
    pull = draw(st.floats(0.0, pull_max))
    return centroid + pull * (point - centroid)


@st.composite
def region_with_points(draw: st.DrawFn, count: int = 1, pull_max: float = 0.95) -> tuple[ConvexRegion, list[np.ndarray]]:
    region = draw(regions())
    return region, [interior_point(draw, region.vertices, pull_max) for _ in range(count)]


# ---------------------------------------------------------------------------- rings
@st.composite
def ring_angles(draw: st.DrawFn, min_robots: int = 3, max_robots: int = 30, min_weight: float = 1e-3) -> np.ndarray:
    """Angles (radians) of N robots in strict CCW order, starting anywhere: random positive gaps
    summing to 2 pi, the smallest at least ``min_weight / max weight`` of the largest."""
    robots = draw(st.integers(min_robots, max_robots))
    weights = np.array(draw(st.lists(st.floats(min_weight, 1.0), min_size=robots, max_size=robots)))
    start = draw(st.floats(-math.pi, math.pi))
    gaps = TWO_PI * weights / weights.sum()
    return start + np.concatenate([[0.0], np.cumsum(gaps[:-1])])


def lyapunov(angles: np.ndarray) -> np.ndarray:
    """H = (1/12) sum_i (d_i^+)^3 over the last axis (docs/algorithms.md section 6), gaps computed here
    independently."""
    angles = np.asarray(angles, dtype=float)
    gaps = np.mod(np.roll(angles, -1, axis=-1) - angles, TWO_PI)
    return np.sum(gaps**3, axis=-1) / 12.0


def ccw_gaps(angles: np.ndarray) -> np.ndarray:
    angles = np.asarray(angles, dtype=float)
    return np.mod(np.roll(angles, -1, axis=-1) - angles, TWO_PI)


def midpoint_offsets(angles: np.ndarray) -> np.ndarray:
    """e_i = V_i - theta_i = (d_i^+ - d_i^-)/4 (docs/algorithms.md section 2), computed independently."""
    gaps = ccw_gaps(angles)
    return (gaps - np.roll(gaps, 1, axis=-1)) / 4.0


# ---------------------------------------------------------------------------- independent geometry
def boundary_at(vertices: np.ndarray, s: np.ndarray) -> np.ndarray:
    """Point at arc length s (CCW from vertex 0) of the closed polygon, written independently."""
    vertices = np.asarray(vertices, dtype=float)
    edges = np.roll(vertices, -1, axis=0) - vertices
    lengths = np.hypot(edges[:, 0], edges[:, 1])
    cumulative = np.concatenate([[0.0], np.cumsum(lengths)])
    s = np.mod(np.asarray(s, dtype=float), cumulative[-1])
    edge = np.clip(np.searchsorted(cumulative, s, side="right") - 1, 0, len(vertices) - 1)
    fraction = (s - cumulative[edge]) / lengths[edge]
    return vertices[edge] + fraction[..., None] * edges[edge]


def sweep_omega(vertices: np.ndarray, centre: np.ndarray, d_max: float, dt: float, samples: int = 200_000) -> float:
    """(1/dt) min_s wrap(theta(s + d_max) - theta(s)), docs/algorithms.md section 10, on a fine grid plus the
    vertex-aligned windows."""
    vertices = np.asarray(vertices, dtype=float)
    lengths = np.hypot(*(np.roll(vertices, -1, axis=0) - vertices).T)
    perimeter = lengths.sum()
    vertex_s = np.concatenate([[0.0], np.cumsum(lengths)[:-1]])
    s = np.concatenate([np.linspace(0.0, perimeter, samples, endpoint=False), vertex_s, vertex_s - d_max])
    a = boundary_at(vertices, s) - centre
    b = boundary_at(vertices, s + d_max) - centre
    swept = np.mod(np.arctan2(b[:, 1], b[:, 0]) - np.arctan2(a[:, 1], a[:, 0]), TWO_PI)
    return float(swept.min() / dt)


def circular_distance(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """|a - b| on the circle (radians), in [0, pi]."""
    return np.abs(np.mod(np.asarray(a) - np.asarray(b) + math.pi, TWO_PI) - math.pi)


# ---------------------------------------------------------------------------- scenarios
def _toml_value(value: object) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        return f'"{value}"'
    if isinstance(value, (list, tuple, np.ndarray)):
        return "[" + ", ".join(_toml_value(item) for item in value) + "]"
    if isinstance(value, (float, np.floating)):
        return repr(float(value))
    return str(value)


def scenario_toml(vertices, target, robots: int, angles_deg=None, **control: object) -> str:
    """A scenario file as a user would write it."""
    lines = [
        'name = "test"',
        "seed = 0",
        "[region]",
        f"vertices = {_toml_value([[float(x), float(y)] for x, y in np.asarray(vertices, dtype=float)])}",
        "[target]",
        f"position = {_toml_value([float(c) for c in target])}",
        "[team]",
        f"robots = {robots}",
    ]
    if angles_deg is not None:
        lines.append(f"angles_deg = {_toml_value([float(a) for a in angles_deg])}")
    lines.append("[control]")
    lines += [f"{key} = {_toml_value(value)}" for key, value in control.items()]
    return "\n".join(lines) + "\n"


def scenario_from(vertices, target, robots: int, angles_deg=None, **control: object) -> Scenario:
    return resolve(parse_scenario(scenario_toml(vertices, target, robots, angles_deg, **control), "test.toml"), "test.toml")
