"""world/ranges.py against docs/algorithms.md section 11 and oracles 19, 20."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from ringtrack.world.geometry import ConvexRegion, angle_of
from ringtrack.world.ranges import link_lengths, range_bounds, uniform_link_requirement, uniform_ring
from tests.helpers import (
    AUTHORS_TARGET,
    AUTHORS_VERTICES,
    TWO_PI,
    circular_distance,
    examples,
    region_with_points,
    regions,
)

UNIT_SQUARE = ConvexRegion.from_vertices([[0, 0], [1, 0], [1, 1], [0, 1]])


def brute_force_link_requirement(region: ConvexRegion, centre, robots: int, samples: int = 10_000) -> float:
    """min over rotations of the longest link of the angle-uniform ring, with an independent ring
    builder (angles -> boundary points -> successor distances)."""
    rotations = np.linspace(0.0, TWO_PI / robots, samples, endpoint=False)
    angles = rotations[:, None] + TWO_PI * np.arange(robots) / robots
    points = region.boundary_point(angles, centre)
    links = np.linalg.norm(np.roll(points, -1, axis=1) - points, axis=-1)
    return float(links.max(axis=1).min())


# ---------------------------------------------------------------------------- uniform rings
@given(region_with_points(1), st.integers(3, 12), st.floats(-10.0, 10.0))
def test_uniform_ring_is_angle_uniform_on_the_boundary(case, robots, rotation):
    region, (centre,) = case
    ring = uniform_ring(region, centre, robots, rotation)
    assert ring.shape == (robots, 2)
    expected = rotation + TWO_PI * np.arange(robots) / robots
    assert circular_distance(angle_of(ring, centre), expected).max() <= 1e-12
    slack = ring @ region.normals.T - region.offsets
    assert np.abs(slack).min(axis=-1).max() <= 1e-9 * region.outer_diameter
    batch = uniform_ring(region, centre, robots, np.array([rotation, rotation + 0.1]))
    assert batch.shape == (2, robots, 2)
    np.testing.assert_array_equal(batch[0], ring)


def test_link_lengths_by_hand():
    points = np.array([[0.0, 0.0], [3.0, 0.0], [3.0, 4.0]])
    np.testing.assert_allclose(link_lengths(points), [3.0, 4.0, 5.0])
    np.testing.assert_allclose(link_lengths(np.stack([points, 2 * points])), [[3, 4, 5], [6, 8, 10]])


# ---------------------------------------------------------------------------- oracle 19
@settings(max_examples=examples(60))
@given(regions(), st.integers(3, 10), st.lists(st.floats(-math.pi, math.pi), min_size=1, max_size=20))
def test_oracle19_incentre_uniform_rings_respect_the_necessary_bound(region, robots, rotations):
    centre, _ = region.chebyshev_centre
    links = link_lengths(uniform_ring(region, centre, robots, np.array(rotations)))
    bound = region.inner_diameter * math.sin(math.pi / robots)
    assert links.min() >= bound * (1 - 1e-6)


def test_oracle19_equality_at_incircle_tangency_points():
    """Square of side 2 about its centre, N = 4 at the edge midpoints: links are exactly D_in sin(pi/4)."""
    square = ConvexRegion.from_vertices([[0, 0], [2, 0], [2, 2], [0, 2]])
    links = link_lengths(uniform_ring(square, (1.0, 1.0), 4, 0.0))
    np.testing.assert_allclose(links, 2.0 * math.sin(math.pi / 4), rtol=1e-12)


# ---------------------------------------------------------------------------- oracle 20
def test_oracle20_paper_sufficient_condition_counterexample():
    required, rotation = uniform_link_requirement(UNIT_SQUARE, (0.2, 0.2), 6)
    assert required == pytest.approx(0.828, abs=0.005)
    assert required > 4.0 / 6.0
    assert 0.0 <= rotation < TWO_PI / 6
    # the reported rotation really achieves it
    assert link_lengths(uniform_ring(UNIT_SQUARE, (0.2, 0.2), 6, rotation)).max() == pytest.approx(required, rel=1e-12)
    bounds = range_bounds(UNIT_SQUARE, (0.2, 0.2), 6)
    assert bounds.paper_communication == pytest.approx(4.0 / 6.0, rel=1e-12)
    assert bounds.safe_communication == pytest.approx(required, rel=1e-12)
    assert bounds.safe_communication > bounds.paper_communication


def test_oracle20_second_counterexample_target_near_corner():
    required, _ = uniform_link_requirement(UNIT_SQUARE, (0.05, 0.05), 6)
    assert required == pytest.approx(0.984, abs=0.005)


@settings(max_examples=examples(12))
@given(region_with_points(1), st.integers(3, 9))
def test_uniform_link_requirement_matches_brute_force(case, robots):
    region, (centre,) = case
    required, rotation = uniform_link_requirement(region, centre, robots)
    brute = brute_force_link_requirement(region, centre, robots)
    # both are sampled minima over rotations (each overestimates the true one slightly)
    assert required == pytest.approx(brute, rel=2e-3)
    assert link_lengths(uniform_ring(region, centre, robots, rotation)).max() == pytest.approx(required, rel=1e-12)
    assert required <= region.outer_diameter * (1 + 1e-12)


# ---------------------------------------------------------------------------- range_bounds (sections 10 and 11)
def test_range_bounds_authors_polygon():
    region = ConvexRegion.from_vertices(AUTHORS_VERTICES)
    bounds = range_bounds(region, AUTHORS_TARGET, 6)
    assert bounds.perimeter == pytest.approx(41.45677, abs=1e-5)
    assert bounds.inner_diameter == pytest.approx(2 * 3.04738, abs=2e-5)
    assert bounds.outer_diameter == pytest.approx(19.10497, abs=1e-5)
    assert bounds.necessary_communication == pytest.approx(2 * 3.04738 * math.sin(math.pi / 6), abs=2e-5)
    assert bounds.necessary_sensing == pytest.approx(3.04738, abs=1e-5)
    assert bounds.paper_communication == pytest.approx(41.45677 / 6, abs=1e-5)
    assert bounds.safe_sensing == pytest.approx(19.10497, abs=1e-5)
    assert bounds.safe_communication == pytest.approx(brute_force_link_requirement(region, AUTHORS_TARGET, 6), rel=1e-3)
    assert bounds.necessary_communication <= bounds.safe_communication <= bounds.safe_sensing


def test_range_bounds_square_and_triangle():
    square = ConvexRegion.from_vertices([[0, 0], [2, 0], [2, 2], [0, 2]])
    bounds = range_bounds(square, (1.0, 1.0), 4)
    assert bounds.inner_diameter == pytest.approx(2.0, abs=1e-9)
    assert bounds.outer_diameter == pytest.approx(2 * math.sqrt(2), abs=1e-12)
    assert bounds.perimeter == pytest.approx(8.0, abs=1e-12)
    assert bounds.necessary_communication == pytest.approx(2 * math.sin(math.pi / 4), abs=1e-9)
    assert bounds.necessary_sensing == pytest.approx(1.0, abs=1e-9)
    assert bounds.paper_communication == pytest.approx(2.0, abs=1e-12)
    # centred square, N = 4: best rotation puts robots on the edge midpoints, links sqrt(2)
    assert bounds.safe_communication == pytest.approx(math.sqrt(2), rel=1e-9)
    triangle = range_bounds(ConvexRegion.from_vertices([[0, 0], [4, 0], [0, 3]]), (1.0, 1.0), 3)
    assert (triangle.inner_diameter, triangle.outer_diameter, triangle.perimeter) == pytest.approx((2.0, 5.0, 12.0), abs=1e-9)
    assert triangle.necessary_communication == pytest.approx(2.0 * math.sin(math.pi / 3), abs=1e-9)


# ---------------------------------------------------------------------------- the world's ring links
@settings(max_examples=examples(40), deadline=None)
@given(st.integers(3, 12), st.data())
def test_world_ring_links_equal_each_link_alone_to_the_bit(robots, data):
    """A world computes every ring link of a step in one call (WorldState.ring_links); each robot's
    (neighbour, metres) must equal link_distance of that one pair, to the bit, for robots in the ring
    and outside it, before and after robots leave and the team moves."""
    from ringtrack.world.ranges import link_distance
    from ringtrack.world.ring import neighbours_in_ring
    from ringtrack.world.scenario import load_scenario
    from ringtrack.world.state import WorldState

    world = WorldState(load_scenario("paper-stationary", robots=robots), data.draw(st.integers(0, 2**16)), 1, 10)

    def one_at_a_time(robot: int) -> list[tuple[int, float]]:
        neighbours = sorted(set(neighbours_in_ring(robot, world.ring)) - {robot})
        return [(other, float(link_distance(world.positions[robot], world.positions[other]))) for other in neighbours]

    for _ in range(3):
        assert [world.neighbour_distances(robot) for robot in range(robots)] == \
            [one_at_a_time(robot) for robot in range(robots)]
        leaving = data.draw(st.sets(st.sampled_from(sorted(world.live)), max_size=max(0, len(world.live) - 1)))
        for robot in leaving:
            world.leave(robot)
        assert [world.neighbour_distances(robot) for robot in range(robots)] == \
            [one_at_a_time(robot) for robot in range(robots)]
        world.goals = world.scenario.region.boundary_point(
            np.asarray(data.draw(st.lists(st.floats(-np.pi, np.pi), min_size=robots, max_size=robots))),
            world.scenario.target)
        world.advance()
