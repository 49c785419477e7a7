"""world/geometry.py against docs/algorithms.md sections 1, 10, 11 and oracles 1, 2, 17, 18."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from ringtrack.world.geometry import ConvexRegion, RegionError, angle_of
from tests.helpers import (
    AUTHORS_TARGET,
    AUTHORS_VERTICES,
    TWO_PI,
    circular_distance,
    examples,
    region_with_points,
    regions,
    sweep_omega,
)

AUTHORS = ConvexRegion.from_vertices(AUTHORS_VERTICES)


def arc_fractions(count: int):
    return st.lists(st.floats(0.0, 1.0, exclude_max=True), min_size=1, max_size=count)


# ---------------------------------------------------------------------------- oracle 1
@given(region_with_points(1), arc_fractions(40))
def test_oracle1_inverse_map_recovers_boundary_points(case, fractions):
    region, (centre,) = case
    s = np.concatenate([np.array(fractions) * region.perimeter, region.vertex_arc[:-1]])
    points = region.point_at(s)
    recovered = region.boundary_point(angle_of(points, centre), centre)
    error = np.linalg.norm(recovered - points, axis=-1).max()
    assert error <= 1e-9 * region.outer_diameter


@given(region_with_points(1), st.lists(st.floats(-20.0, 20.0), min_size=1, max_size=40))
def test_oracle1_phi_of_inverse_is_identity_mod_two_pi(case, thetas):
    region, (centre,) = case
    theta = np.array(thetas)
    points = region.boundary_point(theta, centre)
    assert points.shape == (len(thetas), 2)
    assert circular_distance(angle_of(points, centre), theta).max() <= 1e-12


@given(region_with_points(1), st.lists(st.floats(-20.0, 20.0), min_size=1, max_size=40))
def test_oracle1_inverse_map_lands_on_the_boundary(case, thetas):
    region, (centre,) = case
    points = region.boundary_point(np.array(thetas), centre)
    slack = points @ region.normals.T - region.offsets  # n_k.p - c_k, <= 0 inside
    assert np.all(slack <= 1e-9)
    assert np.abs(slack).min(axis=-1).max() <= 1e-9 * region.outer_diameter


def test_oracle1_inverse_map_on_unit_square_by_hand():
    square = ConvexRegion.from_vertices([[0, 0], [2, 0], [2, 2], [0, 2]])
    points = square.boundary_point(np.array([0.0, math.pi / 4, math.pi / 2, math.pi, -math.pi / 2]), (1.0, 1.0))
    np.testing.assert_allclose(points, [[2, 1], [2, 2], [1, 2], [0, 1], [1, 0]], atol=1e-15)
    # broadcasting: several centres, one angle each
    centres = np.array([[0.5, 0.5], [1.5, 1.0]])
    np.testing.assert_allclose(square.boundary_point(np.array([0.0, math.pi]), centres), [[2, 0.5], [0, 1.0]], atol=1e-15)


@given(region_with_points(1, pull_max=0.8), st.floats(-math.pi, math.pi))
def test_section1_boundary_speed_is_r_squared_over_h(case, theta):
    """|dp/dtheta| = r^2 / h_k on edge k (docs/algorithms.md section 1), by central differences."""
    region, (centre,) = case
    point = region.boundary_point(theta, centre)
    assume(np.linalg.norm(region.vertices - point, axis=-1).min() > 1e-3 * region.outer_diameter)
    edge = int(np.argmin(np.abs(point @ region.normals.T - region.offsets)))
    step = 1e-6
    derivative = np.linalg.norm(region.boundary_point(theta + step, centre) - region.boundary_point(theta - step, centre)) / (2 * step)
    r = np.linalg.norm(point - centre)
    assert derivative == pytest.approx(r**2 / region.heights(centre)[edge], rel=1e-5)


# ---------------------------------------------------------------------------- oracle 2
@given(region_with_points(2), arc_fractions(30))
def test_oracle2_boundary_order_is_the_same_for_every_centre(case, fractions):
    region, (first, second) = case
    s = np.array(fractions) * region.perimeter
    s_sorted = np.sort(s)
    assume(len(s) >= 2 and np.min(np.diff(np.concatenate([s_sorted, [s_sorted[0] + region.perimeter]]))) > 1e-6 * region.perimeter)
    points = region.point_at(s)
    orders = []
    for centre in (first, second):
        theta = angle_of(points, centre)
        orders.append(np.argsort(np.mod(theta - theta[0], TWO_PI), kind="stable"))
    np.testing.assert_array_equal(orders[0], orders[1])
    # ... and both equal the order along the boundary (theta(s) strictly increasing mod 2 pi)
    np.testing.assert_array_equal(orders[0], np.argsort(np.mod(s - s[0], region.perimeter), kind="stable"))
    for centre in (first, second):
        theta = angle_of(region.point_at(s_sorted), centre)
        gaps = np.mod(np.roll(theta, -1) - theta, TWO_PI)
        assert np.all(gaps > 0)
        assert gaps.sum() == pytest.approx(TWO_PI, abs=1e-9)


# ---------------------------------------------------------------------------- region validation
SQUARE = [[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]]
PENTAGRAM = [[math.cos(math.pi / 2 + 4 * math.pi * k / 5), math.sin(math.pi / 2 + 4 * math.pi * k / 5)] for k in range(5)]


@pytest.mark.parametrize(
    ("vertices", "message"),
    [
        pytest.param([[0, 0], [1, 0]], "region.vertices has 2 vertices; a polygon needs at least 3", id="two-vertices"),
        pytest.param(
            [[0, 0], [1, 0], [math.nan, 1]],
            "region.vertices contains NaN or infinity; give finite coordinates",
            id="nan",
        ),
        pytest.param(
            [[0, 0], [1, 0], [math.inf, 1]],
            "region.vertices contains NaN or infinity; give finite coordinates",
            id="infinity",
        ),
        pytest.param(
            [[0, 0], [1, 0], [1, 0], [0, 1]],
            "region.vertices 1 and 2 coincide; remove the repeated vertex",
            id="repeated-vertex",
        ),
        pytest.param(
            [[0, 0], [1, 0], [0, 1], [0, 0]],
            "region.vertices 0 and 3 coincide; remove the repeated vertex",
            id="closing-vertex-repeated",
        ),
        pytest.param(
            [[0, 0], [1, 1], [2, 2]],
            "region.vertices enclose zero area; give a polygon with an interior",
            id="zero-area",
        ),
        pytest.param(
            [[0, 0], [1, 0], [2, 0], [2, 2], [0, 2]],
            "region.vertices 0, 1, 2 are collinear; remove vertex 1",
            id="collinear",
        ),
        pytest.param(
            [[0, 0], [4, 0], [1, 1], [0, 4]],
            "region is not convex at vertex 2 [1.0, 1.0]; give a convex polygon",
            id="non-convex",
        ),
        pytest.param(
            PENTAGRAM,
            "region edges 0 and 2 cross (self-intersecting); list the corners in order",
            id="pentagram",
        ),
        pytest.param(
            SQUARE + SQUARE,
            "region.vertices 0 and 4 coincide; remove the repeated vertex",
            id="square-twice",
        ),
        pytest.param([[0, 0, 0], [1, 0, 0], [0, 1, 0]], "region.vertices must be a list of [x, y] number pairs", id="3d"),
        pytest.param([["a", 0], [1, 0], [0, 1]], "region.vertices must be a list of [x, y] number pairs", id="text"),
    ],
)
def test_region_validation_messages(vertices, message):
    with pytest.raises(RegionError) as raised:
        ConvexRegion.from_vertices(vertices)
    assert str(raised.value) == message
    assert "\n" not in str(raised.value)


def test_region_validation_clockwise_pentagram_is_refused_too():
    with pytest.raises(RegionError, match="self-intersecting"):
        ConvexRegion.from_vertices(PENTAGRAM[::-1])


def test_clockwise_vertices_are_reordered_ccw_keeping_vertex_0_first():
    region = ConvexRegion.from_vertices([[0, 0], [0, 1], [1, 1], [1, 0]])
    np.testing.assert_array_equal(region.vertices, [[0, 0], [1, 0], [1, 1], [0, 1]])
    # outward normals and offsets of the reordered square
    np.testing.assert_allclose(region.normals, [[0, -1], [1, 0], [0, 1], [-1, 0]], atol=1e-15)
    np.testing.assert_allclose(region.offsets, [0, 1, 1, 0], atol=1e-15)
    assert region.perimeter == 4.0


@given(regions())
def test_clockwise_random_polygon_gives_the_same_region(region):
    ccw = region.vertices
    clockwise = np.concatenate([ccw[:1], ccw[:0:-1]])
    again = ConvexRegion.from_vertices(clockwise)
    np.testing.assert_array_equal(again.vertices, ccw)


def test_authors_polygon_heights_and_interior():
    np.testing.assert_allclose(AUTHORS.heights(AUTHORS_TARGET), [4.919, 2.846, 3.536, 2.709], atol=5e-4)
    assert AUTHORS.is_interior(AUTHORS_TARGET)
    assert not AUTHORS.is_interior((3.0, 7.0))  # a vertex is not interior
    with pytest.raises(RegionError) as raised:
        AUTHORS.require_interior([40.0, 20.0], "target.position")
    assert str(raised.value) == "target.position [40.0, 20.0] is not inside the region; move it inside the polygon"


# ---------------------------------------------------------------------------- arc length
@given(regions(), st.lists(st.floats(-3.0, 3.0), min_size=1, max_size=30))
def test_arc_length_and_point_at_round_trip(region, fractions):
    s = np.array(fractions) * region.perimeter
    points = region.point_at(s)
    back = region.arc_length(points)
    assert np.all((back >= 0) & (back < region.perimeter))
    gap = np.abs(np.mod(back - s + region.perimeter / 2, region.perimeter) - region.perimeter / 2)
    assert gap.max() <= 1e-9 * region.perimeter
    np.testing.assert_allclose(region.point_at(back), points, rtol=0, atol=1e-9 * region.outer_diameter)


def test_arc_length_on_square_by_hand():
    square = ConvexRegion.from_vertices(SQUARE)
    np.testing.assert_allclose(square.arc_length(np.array([[0, 0], [0.5, 0], [1, 0.25], [0.5, 1], [0, 0.5]])), [0, 0.5, 1.25, 2.5, 3.5])
    np.testing.assert_allclose(square.point_at(np.array([0.0, 1.0, 3.5, 4.0, -0.5, 9.25])), [[0, 0], [1, 0], [0, 0.5], [0, 0], [0, 0.5], [1.0, 0.25]])


# ---------------------------------------------------------------------------- move_along
@given(regions(), st.floats(0.0, 1.0, exclude_max=True), st.floats(0.0, 1.0, exclude_max=True), st.floats(0.0, 0.6))
def test_move_along_caps_distance_and_returns_goal_when_reachable(region, a, b, cap_fraction):
    L = region.perimeter
    start, goal = region.point_at(a * L), region.point_at(b * L)
    s_start, s_goal = region.arc_length(start), region.arc_length(goal)
    shift = np.mod(s_goal - s_start + L / 2, L) - L / 2  # signed shorter arc
    assume(abs(abs(shift) - L / 2) > 1e-6 * L)
    cap = cap_fraction * L
    assume(abs(abs(shift) - cap) > 1e-9 * L)
    moved = region.move_along(start, goal, cap)
    if abs(shift) <= cap:
        np.testing.assert_array_equal(moved, goal)
    else:
        travelled = np.mod(region.arc_length(moved) - s_start + L / 2, L) - L / 2
        assert travelled == pytest.approx(math.copysign(cap, shift), abs=1e-9 * L)
        slack = moved @ region.normals.T - region.offsets
        assert np.abs(slack).min() <= 1e-9 * region.outer_diameter
    np.testing.assert_array_equal(region.move_along(start, goal, None), goal)


def test_move_along_on_square_by_hand():
    square = ConvexRegion.from_vertices(SQUARE)
    # from (0.5, 0) to (0, 0.5): shorter way is clockwise through the corner (0, 0), 1 m long
    np.testing.assert_allclose(square.move_along([0.5, 0.0], [0.0, 0.5], 0.25), [0.25, 0.0])
    np.testing.assert_allclose(square.move_along([0.5, 0.0], [0.0, 0.5], 0.75), [0.0, 0.25])
    np.testing.assert_array_equal(square.move_along([0.5, 0.0], [0.0, 0.5], 1.0), [0.0, 0.5])
    # batch of starts/goals
    moved = square.move_along(np.array([[0.5, 0.0], [1.0, 0.5]]), np.array([[1.0, 0.5], [1.0, 0.75]]), 0.5)
    np.testing.assert_allclose(moved, [[1.0, 0.0], [1.0, 0.75]])


# ---------------------------------------------------------------------------- clamp_interior
@given(region_with_points(1), st.floats(0.0, TWO_PI), st.floats(1.01, 50.0), st.floats(1e-6, 0.9))
def test_clamp_interior_pulls_outside_points_margin_inside(case, direction, reach, margin_fraction):
    region, (inside,) = case
    centre, radius = region.chebyshev_centre
    margin = margin_fraction * radius
    outside = centre + reach * region.outer_diameter * np.array([math.cos(direction), math.sin(direction)])
    assert not region.is_interior(outside)
    clamped = region.clamp_interior(outside, margin)
    assert region.heights(clamped).min() >= margin - 1e-9 * region.outer_diameter
    # it moved along the segment towards the Chebyshev centre and stopped on the shrunk boundary
    assert region.heights(clamped).min() <= margin + 1e-9 * region.outer_diameter
    a, b = clamped - centre, outside - centre
    cross = a[0] * b[1] - a[1] * b[0]
    assert abs(cross) <= 1e-9 * region.outer_diameter * np.linalg.norm(outside - centre)


@given(region_with_points(1), st.floats(0.0, 0.9))
def test_clamp_interior_leaves_deep_points_unchanged(case, margin_fraction):
    region, (point,) = case
    margin = margin_fraction * region.heights(point).min()
    assume(margin < region.chebyshev_centre[1])
    clamped = region.clamp_interior(point, margin)
    np.testing.assert_allclose(clamped, point, rtol=0, atol=1e-12 * (1 + np.abs(point).max()))


def test_clamp_interior_refuses_margin_beyond_inscribed_radius():
    square = ConvexRegion.from_vertices([[0, 0], [2, 0], [2, 2], [0, 2]])
    with pytest.raises(RegionError) as raised:
        square.clamp_interior([5.0, 5.0], 1.0)
    assert str(raised.value) == "clamp margin 1.0 m exceeds the inscribed radius 1 m"
    np.testing.assert_allclose(square.clamp_interior([5.0, 1.0], 0.1), [1.9, 1.0])


# ---------------------------------------------------------------------------- oracle 17 (omega_max)
def test_oracle17_authors_polygon_omega_max():
    assert AUTHORS.omega_max(1.0, 0.1, AUTHORS_TARGET) == pytest.approx(0.016059, rel=1e-3)
    assert math.degrees(AUTHORS.omega_max(1.0, 0.1, AUTHORS_TARGET)) == pytest.approx(0.920, rel=1e-3)
    assert AUTHORS.omega_max(0.2, 0.1, AUTHORS_TARGET) == pytest.approx(0.003193, rel=1e-3)


def test_oracle17_authors_polygon_bounds():
    o = np.array(AUTHORS_TARGET)
    v = AUTHORS.vertices
    h = AUTHORS.heights(o)
    far = np.maximum(np.linalg.norm(v - o, axis=1), np.linalg.norm(np.roll(v, -1, axis=0) - o, axis=1))
    lower, upper = np.min(h / far**2), 1.0 / h.min()
    assert lower == pytest.approx(0.015937, rel=1e-4)
    assert upper == pytest.approx(0.369091, rel=1e-5)
    assert lower <= AUTHORS.omega_max(1.0, 0.1, o) <= upper


@pytest.mark.slow
@settings(max_examples=examples(30))
@given(region_with_points(1), st.floats(0.1, 5.0), st.floats(0.01, 1.0), st.floats(1e-3, 0.5))
def test_oracle17_omega_max_within_bounds_and_matches_sweep(case, v_max, dt, fraction):
    region, (centre,) = case
    dt = fraction * region.perimeter / v_max  # d_max = v_max dt = fraction of L
    omega = region.omega_max(v_max, dt, centre)
    h = region.heights(centre)
    v = region.vertices
    far = np.maximum(np.linalg.norm(v - centre, axis=1), np.linalg.norm(np.roll(v, -1, axis=0) - centre, axis=1))
    assert omega >= v_max * np.min(h / far**2) * (1 - 1e-9)
    assert omega <= v_max / h.min() * (1 + 1e-9)  # dist(o, boundary) = min_k h_k for convex Q
    assert omega == pytest.approx(sweep_omega(region.vertices, centre, v_max * dt, dt), rel=1e-3)


def test_oracle17_omega_max_refuses_step_longer_than_perimeter():
    square = ConvexRegion.from_vertices(SQUARE)
    with pytest.raises(RegionError, match="at least the perimeter"):
        square.omega_max(50.0, 0.1, (0.5, 0.5))


# ---------------------------------------------------------------------------- oracle 18 (sizes)
def test_oracle18_square():
    square = ConvexRegion.from_vertices([[0, 0], [2, 0], [2, 2], [0, 2]])
    centre, radius = square.chebyshev_centre
    assert (square.inner_diameter, square.outer_diameter, square.perimeter) == pytest.approx((2.0, 2.0 * math.sqrt(2.0), 8.0), abs=1e-9)
    np.testing.assert_allclose(centre, [1.0, 1.0], atol=1e-9)
    assert radius == pytest.approx(1.0, abs=1e-9)


def test_oracle18_345_triangle():
    triangle = ConvexRegion.from_vertices([[0, 0], [4, 0], [0, 3]])
    centre, radius = triangle.chebyshev_centre
    assert triangle.inner_diameter == pytest.approx(2.0, abs=1e-9)
    np.testing.assert_allclose(centre, [1.0, 1.0], atol=1e-9)
    assert triangle.outer_diameter == pytest.approx(5.0, abs=1e-12)
    assert triangle.perimeter == pytest.approx(12.0, abs=1e-12)


def test_oracle18_authors_polygon_sizes():
    centre, radius = AUTHORS.chebyshev_centre
    assert radius == pytest.approx(3.04738, abs=1e-5)
    np.testing.assert_allclose(centre, [4.70984, 17.23382], atol=1e-5)
    assert AUTHORS.outer_diameter == pytest.approx(19.10497, abs=1e-5)
    assert AUTHORS.perimeter == pytest.approx(41.45677, abs=1e-5)


@given(regions())
def test_oracle18_chebyshev_centre_is_feasible_with_two_active_edges(region):
    centre, radius = region.chebyshev_centre
    slack = region.offsets - region.normals @ centre - radius  # >= 0 (feasible), 0 where active
    assert radius > 0
    assert slack.min() >= -1e-9
    assert np.sum(slack <= 1e-7 * region.outer_diameter) >= 2
    # sizes against independent formulas
    v = region.vertices
    assert region.perimeter == pytest.approx(np.sum(np.linalg.norm(np.roll(v, -1, axis=0) - v, axis=1)), rel=1e-12)
    assert region.outer_diameter == pytest.approx(max(np.linalg.norm(a - b) for a in v for b in v), rel=1e-12)
    assert region.inner_diameter <= region.outer_diameter


@given(regions(), st.floats(0.0, 1.0, exclude_max=True), st.floats(-4.0, 4.0), st.floats(-4.0, 4.0))
def test_one_point_is_on_the_boundary_exactly_when_the_array_check_says_so(region, fraction, dx, dy):
    """A goal as a message carries it (a tuple of floats, checked in plain floats) and the same point
    as an array get the same answer, on the boundary and up to four tolerances off it."""
    x, y = (float(value) for value in region.point_at(fraction * region.perimeter))
    tolerance = 1e-6 * region.outer_diameter
    moved = (x + dx * tolerance, y + dy * tolerance)
    assert region.on_boundary((x, y), tolerance)
    assert bool(region.on_boundary(moved, tolerance)) == bool(region.on_boundary(np.array(moved), tolerance))
    heights = region.heights(np.array(moved))
    assert bool(region.on_boundary(moved, tolerance)) == (heights.min() >= -tolerance and abs(heights).min() <= tolerance)
