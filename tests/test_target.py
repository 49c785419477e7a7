"""world/target.py (target motion, the [target] section), world/sensing.py (RangeSensor) and the
scenario rules of [target], [sensing], [estimation] (world/scenario.py), against docs/algorithms.md
sections 7 and 9 and the authors' moving-target setting."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from ringtrack.world.geometry import ConvexRegion, RegionError
from ringtrack.world.scenario import TARGET_MARGIN, load_scenario, parse_scenario, resolve
from ringtrack.world.sensing import RangeSensor
from ringtrack.world.target import Circle, RandomWalk, Stationary, Waypoints
from tests.helpers import AUTHORS_VERTICES, CIRCLE_LINES, MOVING, region_with_points

AUTHORS = ConvexRegion.from_vertices(AUTHORS_VERTICES)
MARGIN = TARGET_MARGIN * AUTHORS.outer_diameter


def polar_angle(points: np.ndarray, centre) -> np.ndarray:
    relative = np.asarray(points) - np.asarray(centre)
    return np.arctan2(relative[..., 1], relative[..., 0])


def wrapped(angle):
    return np.mod(np.asarray(angle) + math.pi, 2.0 * math.pi) - math.pi


# ---------------------------------------------------------------------------- circle
def test_authors_moving_target_is_kf_m():
    """Section 7: o(k) = (3, 20) + (cos((k - 1)/100), sin((k - 1)/100)), k = 1, 2, ..."""
    scenario = load_scenario("authors-moving")
    path = scenario.target_path(0, 1300)
    k = np.arange(1, 1301)
    expected = np.array([3.0, 20.0]) + np.stack([np.cos((k - 1) / 100), np.sin((k - 1) / 100)], axis=1)
    np.testing.assert_allclose(path, expected, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(scenario.target, [4.0, 20.0])  # o(1), where the prior "truth" sits
    assert scenario.moving


def test_gazebo_moving_target_circle():
    """v_o = 1.0 m/s, w_o = 0.6 rad/s: radius v_o / w_o = 5/3 m about the Chebyshev centre, 0.06 rad a step."""
    scenario = load_scenario("gazebo-moving")
    centre = np.array([4.70984, 17.23382])
    path = scenario.target_path(0, 200)
    np.testing.assert_allclose(np.linalg.norm(path - centre, axis=1), 5.0 / 3.0, rtol=1e-12)
    np.testing.assert_allclose(wrapped(np.diff(polar_angle(path, centre))), 0.06, rtol=0, atol=1e-12)
    steps = np.linalg.norm(np.diff(path, axis=0), axis=1)
    np.testing.assert_allclose(steps, 2 * (5.0 / 3.0) * math.sin(0.03), rtol=1e-12)  # chord of 0.06 rad
    assert np.all(scenario.region.is_interior(path))


@given(
    speed=st.floats(0.01, 5.0),
    angular_speed=st.one_of(st.floats(0.05, 3.0), st.floats(-3.0, -0.05)),
    phase_deg=st.floats(-720.0, 720.0),
    dt=st.sampled_from([0.05, 0.1, 0.5]),
)
def test_circle_path_geometry(speed, angular_speed, phase_deg, dt):
    centre = (4.5, 18.0)
    circle = Circle(centre=centre, speed=speed, angular_speed=angular_speed, phase_deg=phase_deg)
    radius = speed / abs(angular_speed)
    assert circle.radius == pytest.approx(radius, rel=1e-15)
    path = circle.path(50, dt, AUTHORS, 0, MARGIN)  # check() is not asked here: geometry only
    np.testing.assert_allclose(np.linalg.norm(path - centre, axis=1), radius, rtol=1e-12)
    start = np.array(centre) + radius * np.array([math.cos(math.radians(phase_deg)), math.sin(math.radians(phase_deg))])
    np.testing.assert_allclose(path[0], start, rtol=0, atol=1e-12 * (1 + radius))
    # the angle advances by w dt a step (CCW for w > 0), so the speed along the circle is |w| r = v
    np.testing.assert_allclose(wrapped(np.diff(polar_angle(path, centre))), angular_speed * dt, rtol=0, atol=1e-9)
    chord = 2.0 * radius * math.sin(abs(angular_speed) * dt / 2.0)
    np.testing.assert_allclose(np.linalg.norm(np.diff(path, axis=0), axis=1), chord, rtol=1e-9)


@pytest.mark.parametrize("angular_speed", [2 * math.pi / 10, -2 * math.pi / 10])
def test_circle_period(angular_speed):
    """Period 2 pi / |w| = 10 s = 100 steps of 0.1 s: back at the start, half way opposite."""
    circle = Circle(centre=(4.5, 18.0), speed=1.0 * abs(angular_speed), angular_speed=angular_speed, phase_deg=90.0)
    path = circle.path(201, 0.1, AUTHORS, 0, MARGIN)
    np.testing.assert_allclose(path[100], path[0], rtol=0, atol=1e-12)
    np.testing.assert_allclose(path[200], path[0], rtol=0, atol=1e-12)
    np.testing.assert_allclose(path[50], [4.5, 17.0], rtol=0, atol=1e-12)  # radius 1, phase 90 + 180 deg
    quarter = path[25] - np.array([4.5, 18.0])
    np.testing.assert_allclose(quarter, [-math.copysign(1.0, angular_speed), 0.0], rtol=0, atol=1e-12)


@given(case=region_with_points(1, pull_max=0.7), fraction=st.floats(0.05, 1.5), angular_speed=st.floats(-2.0, 2.0))
def test_circle_check_accepts_exactly_the_circles_inside(case, fraction, angular_speed):
    region, (centre,) = case
    margin = TARGET_MARGIN * region.outer_diameter
    if angular_speed == 0:
        with pytest.raises(RegionError):
            Circle(centre=tuple(centre), speed=1.0, angular_speed=0.0).check(region, margin)
        return
    room = region.heights(centre).min()
    radius = fraction * room
    circle = Circle(centre=tuple(centre), speed=radius * abs(angular_speed), angular_speed=angular_speed)
    radius = circle.radius  # the circle as built (a subnormal angular speed rounds speed / angular_speed)
    angles = np.linspace(0.0, 2 * math.pi, 4001)
    ring = centre + radius * np.stack([np.cos(angles), np.sin(angles)], axis=1)
    deepest_miss = region.heights(ring).min()  # the circle's closest approach to the boundary
    try:
        circle.check(region, margin)
    except RegionError:
        assert deepest_miss <= margin + 1e-6 * region.outer_diameter
    else:
        assert deepest_miss > margin - 1e-9 * region.outer_diameter
        assert np.all(region.is_interior(circle.path(200, 0.1, region, 0, margin)))


# ---------------------------------------------------------------------------- waypoints
def along_polyline(corners: np.ndarray, s: float) -> np.ndarray:
    """The point at arc length s along the polyline (clamped at its end), walked leg by leg."""
    for start, end in zip(corners[:-1], corners[1:], strict=True):
        leg = float(np.linalg.norm(end - start))
        if s <= leg:
            return start + (s / leg) * (end - start)
        s -= leg
    return corners[-1].copy()


SQUARE = [(3.0, 18.0), (5.0, 18.0), (5.0, 20.0), (3.0, 20.0)]  # 8 m around


@pytest.mark.parametrize("loop", [True, False])
@pytest.mark.parametrize("speed", [1.0, 0.37])
def test_waypoints_constant_speed_along_legs(loop, speed):
    waypoints = [(2.0, 18.0), (6.0, 18.0), (4.0, 22.0), (4.5, 13.0)]
    motion = Waypoints(waypoints=waypoints, speed=speed, loop=loop)
    dt = 0.1
    path = motion.path(600, dt, AUTHORS, 0, MARGIN)
    corners = np.array(waypoints + (waypoints[:1] if loop else []))
    total = float(np.sum(np.linalg.norm(np.diff(corners, axis=0), axis=1)))
    for k in range(600):
        travelled = speed * dt * k
        s = math.fmod(travelled, total) if loop else min(travelled, total)
        np.testing.assert_allclose(path[k], along_polyline(corners, s), rtol=0, atol=1e-9)
    hops = np.linalg.norm(np.diff(path, axis=0), axis=1)
    assert np.all(hops <= speed * dt * (1 + 1e-9))  # never faster than speed
    if loop:
        assert np.mean(np.isclose(hops, speed * dt, rtol=1e-9)) > 0.9  # full speed except at corners
    else:
        end = int(math.ceil(total / (speed * dt)))
        np.testing.assert_array_equal(path[end:], np.tile(corners[-1], (600 - end, 1)))  # parked at the last one
    assert np.all(AUTHORS.is_interior(path))


def test_waypoints_loop_period():
    motion = Waypoints(waypoints=SQUARE, speed=1.0, loop=True)
    path = motion.path(161, 0.1, AUTHORS, 0, MARGIN)  # 8 m at 0.1 m a step: 80 steps a lap
    for lap in (0, 80, 160):
        for corner, step in enumerate((0, 20, 40, 60)):
            if lap + step < len(path):
                np.testing.assert_allclose(path[lap + step], SQUARE[corner], rtol=0, atol=1e-12)
    np.testing.assert_allclose(path[10], [4.0, 18.0], rtol=0, atol=1e-12)
    np.testing.assert_allclose(path[70], [3.0, 19.0], rtol=0, atol=1e-12)  # on the closing leg


# ---------------------------------------------------------------------------- random walk
def test_random_walk_is_seeded():
    walk = RandomWalk(position=(4.0, 20.0), speed_std=1.0)
    first = walk.path(500, 0.1, AUTHORS, 7, MARGIN)
    np.testing.assert_array_equal(first, walk.path(500, 0.1, AUTHORS, 7, MARGIN))
    assert not np.array_equal(first, walk.path(500, 0.1, AUTHORS, 8, MARGIN))
    np.testing.assert_array_equal(first[0], [4.0, 20.0])


@pytest.mark.parametrize("speed_std", [0.5, 20.0, 200.0])
@pytest.mark.parametrize("seed", [0, 1])
def test_random_walk_stays_inside(speed_std, seed):
    """Steps that would leave are redrawn: every point is inside by the margin, even with steps of
    2 m and 20 m std in a region about 5 m across (start near the boundary)."""
    walk = RandomWalk(position=(2.0, 18.0), speed_std=speed_std)
    path = walk.path(2000, 0.1, AUTHORS, seed, MARGIN)
    assert np.all(AUTHORS.heights(path) > MARGIN)
    assert np.all(np.isfinite(path))
    assert len(np.unique(path, axis=0)) > 100  # it does move


def test_random_walk_step_statistics():
    """Away from the boundary the increments are N(0, (speed_std dt)^2 I)."""
    walk = RandomWalk(position=(4.7, 17.2), speed_std=0.05)
    path = walk.path(4001, 0.1, AUTHORS, 3, MARGIN)
    steps = np.diff(path, axis=0)
    assert AUTHORS.heights(path).min() > 0.2  # no redraws could have happened (a 5 mm step std)
    np.testing.assert_allclose(steps.std(axis=0), 0.005, rtol=0.05)
    assert np.all(np.abs(steps.mean(axis=0)) < 4 * 0.005 / math.sqrt(4000))


def test_random_walk_scenario_path_is_per_seed():
    text = MOVING.replace(CIRCLE_LINES, 'motion = "random_walk"\nposition = [4.0, 20.0]\nspeed_std = 1.0\n')
    scenario = resolve(parse_scenario(text, "x.toml"), "x.toml")
    np.testing.assert_array_equal(scenario.target_path(5, 300), scenario.target_path(5, 300))
    assert not np.array_equal(scenario.target_path(5, 300), scenario.target_path(6, 300))
    np.testing.assert_array_equal(scenario.target, [4.0, 20.0])


def test_stationary_path():
    path = Stationary(position=(4.0, 20.0)).path(10, 0.1, AUTHORS, 0, MARGIN)
    np.testing.assert_array_equal(path, np.tile([4.0, 20.0], (10, 1)))


# ---------------------------------------------------------------------------- RangeSensor
def test_sensor_same_seed_same_noise():
    positions = np.array([[3.0, 7.0], [8.0, 17.0], [5.0, 26.0], [1.0, 22.0]])
    first, second, other = RangeSensor(0.2, None, 4), RangeSensor(0.2, None, 4), RangeSensor(0.2, None, 5)
    for k in range(20):
        target = np.array([4.0 + 0.01 * k, 20.0])
        a, b, c = first.measure(positions, target), second.measure(positions, target), other.measure(positions, target)
        np.testing.assert_array_equal(a, b)
        assert not np.array_equal(a, c)


def test_sensor_exact_without_noise():
    positions = np.array([[0.0, 0.0], [3.0, 4.0], [-6.0, 8.0]])
    np.testing.assert_array_equal(RangeSensor(0.0, None, 0).measure(positions, [0.0, 0.0]), [0.0, 5.0, 10.0])


def test_sensor_nan_beyond_range_and_same_draws():
    """No range beyond r_s; the noise is drawn for every robot every step anyway, so the in-range
    values are those of a sensor without a range limit and the same seed."""
    positions = np.array([[0.0, 0.0], [3.0, 4.0], [-6.0, 8.0], [0.0, 5.0000001]])
    limited, unlimited = RangeSensor(0.3, 5.0, 9), RangeSensor(0.3, None, 9)
    for _ in range(10):
        a, b = limited.measure(positions, [0.0, 0.0]), unlimited.measure(positions, [0.0, 0.0])
        assert np.isnan(a[2]) and np.isnan(a[3])  # 10 m and just over 5 m
        assert np.all(np.isfinite(a[:2]))  # 0 m and exactly 5 m: in range
        np.testing.assert_array_equal(a[:2], b[:2])


def test_sensor_noise_statistics():
    sigma = 0.2
    sensor = RangeSensor(sigma, None, 1)
    positions = np.array([[3.0, 7.0], [8.0, 17.0], [5.0, 26.0], [1.0, 22.0], [2.0, 20.0]])
    target = np.array([4.0, 20.0])
    truth = np.linalg.norm(positions - target, axis=1)
    errors = np.concatenate([sensor.measure(positions, target) - truth for _ in range(4000)])
    assert len(errors) == 20000
    assert abs(errors.std() - sigma) < 0.03 * sigma  # sd of the sample sd ~ 0.5 %
    assert abs(errors.mean()) < 4 * sigma / math.sqrt(len(errors))
    # Gaussian: about 68.3 % within one sigma
    assert abs(np.mean(np.abs(errors) < sigma) - 0.6827) < 0.015
