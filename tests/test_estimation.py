"""agents/estimation.py against docs/algorithms.md section 7 and oracles 14, 15.

The reference EKF below is written from docs/algorithms.md (random-walk predict, stacked range update,
Joseph-form covariance), independently of filterpy, so the tests catch shape or convention slips
(R/Q swapped, broadcasting, sequential instead of stacked updates) as well as numeric ones.
"""

from __future__ import annotations

import math

import msgspec
import numpy as np
import pytest
from hypothesis import Phase, assume, given, settings
from hypothesis import strategies as st

from ringtrack.agents.estimation import (
    SINGULAR_DISTANCE,
    Estimator,
    NoFix,
    RangeFilters,
    trilaterate,
)
from ringtrack.agents.fusion import covariance_intersection, sequential_intersection
from ringtrack.world.geometry import ConvexRegion
from ringtrack.world.params import EstimationParams
from ringtrack.world.ranges import uniform_ring
from ringtrack.world.scenario import ScenarioError, load_scenario, resolve
from tests.helpers import (
    AUTHORS_TARGET,
    AUTHORS_VERTICES,
    region_with_points,
    ring_angles,
)

AUTHORS = ConvexRegion.from_vertices(AUTHORS_VERTICES)
TARGET = np.array(AUTHORS_TARGET)
SIGMA = 0.2  # m, authors' range noise: R = 0.04 I


def exact_ranges(positions: np.ndarray, target: np.ndarray) -> np.ndarray:
    return np.linalg.norm(np.asarray(positions, dtype=float) - target, axis=-1)


def reference_step(x, P, q, sigma, positions, ranges):
    """One EKF round as in docs/algorithms.md section 7: x- = x, P- = P + q I; then, with the usable
    ranges (finite, robot farther than 1e-9 from x-), the stacked update K = P H^T (H P H^T + sigma^2 I)^-1 and the Joseph form."""
    x = np.array(x, dtype=float)
    P = np.array(P, dtype=float) + q * np.eye(2)
    positions = np.asarray(positions, dtype=float).reshape(-1, 2)
    ranges = np.asarray(ranges, dtype=float).reshape(-1)
    offsets = x - positions
    distance = np.hypot(offsets[:, 0], offsets[:, 1])
    keep = np.isfinite(ranges) & (distance > 1e-9)
    if not keep.any():
        return x, P
    H = offsets[keep] / distance[keep, None]
    R = sigma**2 * np.eye(int(keep.sum()))
    S = H @ P @ H.T + R
    K = P @ H.T @ np.linalg.inv(S)
    x = x + K @ (ranges[keep] - distance[keep])
    A = np.eye(2) - K @ H
    P = A @ P @ A.T + K @ R @ K.T
    return x, P


class RangeFilter:
    """One filter as a batch of one (the tests' single-filter view of :class:`RangeFilters`)."""

    def __init__(self, mean, covariance, q, sigma):
        self.batch = RangeFilters(np.asarray(mean, dtype=float)[None], np.asarray(covariance, dtype=float)[None], q,
                                  sigma)

    @property
    def mean(self) -> np.ndarray:
        return self.batch.mean[0]

    @property
    def covariance(self) -> np.ndarray:
        return self.batch.covariance[0]

    def step(self, positions, ranges) -> None:
        self.batch.step(np.asarray(positions, dtype=float)[None], np.asarray(ranges, dtype=float)[None])


def offset(length: float, angle: float) -> np.ndarray:
    return length * np.array([math.cos(angle), math.sin(angle)])


# ---------------------------------------------------------------------------- the filter is the EKF of section 7
@given(
    case=region_with_points(2),
    robots=st.integers(1, 8),
    seed=st.integers(0, 2**32 - 1),
    q=st.sampled_from([0.0, 1e-3, 0.2]),
    sigma=st.sampled_from([0.05, 0.2, 1.0]),
)
def test_filter_matches_the_spec_ekf(case, robots, seed, q, sigma):
    region, (target, prior) = case
    rng = np.random.default_rng(seed)
    angles = np.sort(rng.uniform(0.0, 2.0 * math.pi, robots))
    positions = region.boundary_point(angles, target)
    scale = region.outer_diameter
    covariance = (0.1 * scale) ** 2 * np.eye(2)
    filt = RangeFilter(prior, covariance, q, sigma)
    for _ in range(15):
        ranges = exact_ranges(positions, target) + sigma * rng.normal(size=robots)
        ranges[rng.random(robots) < 0.2] = np.nan  # some robots out of range
        # step by step from the filter's own state (rounding differences compound over a run)
        before_mean, before_covariance = filt.mean.copy(), filt.covariance.copy()
        filt.step(positions, ranges)
        x, P = reference_step(before_mean, before_covariance, q, sigma, positions, ranges)
        np.testing.assert_allclose(filt.mean, x, rtol=0, atol=1e-9 * scale)
        np.testing.assert_allclose(filt.covariance, P, rtol=0, atol=1e-9 * np.trace(P))
        np.testing.assert_array_equal(filt.covariance, filt.covariance.T)
        assert filt.mean.shape == (2,) and filt.covariance.shape == (2, 2)


def test_centralized_update_is_stacked_not_sequential():
    """Section 7: the fusion centre updates once with all N ranges; sequential scalar updates
    relinearize and differ from a poor prior. The filter must agree with the stacked reference."""
    positions = uniform_ring(AUTHORS, TARGET, 6)
    ranges = exact_ranges(positions, TARGET)
    prior = TARGET + np.array([2.5, -1.5])
    filt = RangeFilter(prior, np.eye(2), 0.2, SIGMA)
    filt.step(positions, ranges)
    stacked, _ = reference_step(prior, np.eye(2), 0.2, SIGMA, positions, ranges)
    x, P = prior, np.eye(2)
    for index in range(6):
        x, P = reference_step(x, P, 0.2 if index == 0 else 0.0, SIGMA, positions[index : index + 1], ranges[index : index + 1])
    assert np.linalg.norm(stacked - x) > 1e-3  # the two variants really differ here
    np.testing.assert_allclose(filt.mean, stacked, rtol=0, atol=1e-12)


# ---------------------------------------------------------------------------- filterpy, the independent oracle
def filterpy_ekf(mean, covariance, q):
    """filterpy's ExtendedKalmanFilter set up as section 7 says (F = I, Q = q I)."""
    from filterpy.kalman import ExtendedKalmanFilter

    ekf = ExtendedKalmanFilter(dim_x=2, dim_z=1)
    ekf.F, ekf.Q = np.eye(2), q * np.eye(2)
    ekf.x, ekf.P = np.array(mean, dtype=float).reshape(2, 1), np.array(covariance, dtype=float)
    return ekf


def filterpy_step(ekf, positions, ranges, sigma):
    """One predict and stacked update of filterpy's EKF with the usable ranges (column shapes)."""
    ekf.predict()
    offsets = ekf.x[:, 0] - positions
    distance = np.hypot(offsets[:, 0], offsets[:, 1])
    keep = np.isfinite(ranges) & (distance > SINGULAR_DISTANCE)
    if not keep.any():
        return
    points = positions[keep]

    def h(x):
        return np.linalg.norm(x[:, 0] - points, axis=1).reshape(-1, 1)

    def jacobian(x):
        difference = x[:, 0] - points
        return difference / np.linalg.norm(difference, axis=1, keepdims=True)

    ekf.update(ranges[keep].reshape(-1, 1), jacobian, h, R=sigma**2 * np.eye(int(keep.sum())))


# Each example runs 1 300 steps: found failures are reported as found, not shrunk for minutes.
@settings(max_examples=4, deadline=None, phases=[Phase.explicit, Phase.reuse, Phase.generate])
@given(case=region_with_points(1), robots=st.integers(3, 8), seed=st.integers(0, 2**32 - 1),
       q_share=st.sampled_from([1e-3, 1e-2, 3e-2]), sigma_share=st.sampled_from([2e-3, 1e-2, 5e-2]))
def test_the_batched_filter_agrees_with_filterpy_over_a_long_run(case, robots, seed, q_share, sigma_share):
    """1 300 steps of a random-walk target inside a random region, robots on its boundary creeping
    round it, ranges noisy and some missing. A fusion centre's filter (every range) stays within 1e-9
    (relative to the region and to its covariance) of filterpy's EKF fed the same over the whole run;
    each robot's own filter (its one range: the target's tangential position is unobservable, so two
    runs' rounding differences grow) matches filterpy's step from the same state, every step.

    The noises scale with the region (range sigma up to 5 % of its diameter, process noise up to 3 %
    of it a step): a region a metre across ranged with a metre of noise and walked by half a metre a
    step is no tracking problem, and there two implementations' rounding is amplified past 1e-9."""
    region, (start,) = case
    rng = np.random.default_rng(seed)
    scale = region.outer_diameter
    q, sigma = (q_share * scale) ** 2, sigma_share * scale
    angles = np.sort(rng.uniform(0.0, 2.0 * math.pi, robots))
    prior = region.chebyshev_centre[0]
    covariance = (0.3 * scale) ** 2 * np.eye(2)
    batch = RangeFilters(np.repeat(prior[None], robots + 1, axis=0), np.repeat(covariance[None], robots + 1, axis=0),
                         q, sigma)
    centre = filterpy_ekf(prior, covariance, q)
    target = np.array(start, dtype=float)
    for _ in range(1300):
        step = rng.normal(scale=0.002 * scale, size=2)
        if region.is_interior(target + step, 1e-3 * scale):
            target = target + step
        angles = angles + 0.002
        positions = region.boundary_point(angles, target)
        ranges = np.linalg.norm(positions - target, axis=1) + sigma * rng.normal(size=robots)
        ranges[rng.random(robots) < 0.1] = np.nan
        every = np.full((robots + 1, robots, 2), 1e6)
        every[0], every[1 + np.arange(robots), 0] = positions, positions  # the centre; each robot its own
        measured = np.full((robots + 1, robots), np.nan)
        measured[0], measured[1 + np.arange(robots), 0] = ranges, ranges
        robots_before = [filterpy_ekf(mean, covariance, q) for mean, covariance in
                         zip(batch.mean[1:], batch.covariance[1:], strict=True)]
        batch.step(every, measured)
        filterpy_step(centre, positions, ranges, sigma)
        for robot, oracle in enumerate(robots_before):
            filterpy_step(oracle, positions[robot : robot + 1], ranges[robot : robot + 1], sigma)
        means = np.array([oracle.x[:, 0] for oracle in [centre, *robots_before]])
        covariances = np.array([oracle.P for oracle in [centre, *robots_before]])
        np.testing.assert_allclose(batch.mean, means, rtol=0, atol=1e-9 * scale)
        sizes = np.trace(covariances, axis1=1, axis2=2)[:, None, None]
        assert np.all(np.abs(batch.covariance - covariances) <= 1e-9 * sizes)


@settings(max_examples=20, deadline=None)
@given(case=region_with_points(3), robots=st.integers(1, 8), seed=st.integers(0, 2**32 - 1))
def test_a_filter_gives_the_same_bits_in_any_batch(case, robots, seed):
    """Every quantity is computed elementwise along the batch: a filter alone and the same filter in a
    batch with others end bit for bit equal (what makes a robot process equal the engine)."""
    region, points = case
    rng = np.random.default_rng(seed)
    positions = region.boundary_point(np.sort(rng.uniform(0, 2 * math.pi, robots)), points[0])
    means = np.array(points)
    covariances = np.array([np.diag(rng.uniform(0.1, 4.0, 2)) for _ in points])
    together = RangeFilters(means, covariances, 0.2, SIGMA)
    alone = [RangeFilters(means[i : i + 1], covariances[i : i + 1], 0.2, SIGMA) for i in range(len(points))]
    for _ in range(20):
        ranges = np.linalg.norm(positions - points[0], axis=1) + SIGMA * rng.normal(size=robots)
        ranges[rng.random(robots) < 0.2] = np.nan
        together.step(np.repeat(positions[None], len(points), axis=0), np.repeat(ranges[None], len(points), axis=0))
        for single in alone:
            single.step(positions[None], ranges[None])
    np.testing.assert_array_equal(together.mean, np.concatenate([single.mean for single in alone]))
    np.testing.assert_array_equal(together.covariance, np.concatenate([single.covariance for single in alone]))


# ---------------------------------------------------------------------------- oracle 14
@given(distance=st.floats(0.0, 3.0), direction=st.floats(0.0, 2.0 * math.pi), rotation=st.floats(0.0, 2.0 * math.pi))
def test_oracle14_noiseless_converges_with_authors_process_noise(distance, direction, rotation):
    positions = uniform_ring(AUTHORS, TARGET, 6, rotation)
    ranges = exact_ranges(positions, TARGET)
    filt = RangeFilter(TARGET + offset(distance, direction), np.eye(2), 0.2, SIGMA)
    for _ in range(30):
        filt.step(positions, ranges)
    assert np.linalg.norm(filt.mean - TARGET) < 1e-9


@given(distance=st.floats(0.0, 3.0), direction=st.floats(0.0, 2.0 * math.pi), rotation=st.floats(0.0, 2.0 * math.pi))
def test_oracle14_noiseless_converges_with_small_process_noise(distance, direction, rotation):
    positions = uniform_ring(AUTHORS, TARGET, 6, rotation)
    ranges = exact_ranges(positions, TARGET)
    filt = RangeFilter(TARGET + offset(distance, direction), np.eye(2), 1e-3, SIGMA)
    for _ in range(100):
        filt.step(positions, ranges)
    assert np.linalg.norm(filt.mean - TARGET) < 1e-6


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_oracle14_noiseless_converges_from_scenario_starts(seed):
    """The same with the robots where authors-moving starts them (seeded random boundary points)."""
    positions = load_scenario("authors-moving").start_positions(seed)
    ranges = exact_ranges(positions, TARGET)
    rng = np.random.default_rng(seed)
    for _ in range(5):
        filt = RangeFilter(TARGET + offset(3.0, rng.uniform(0, 2 * math.pi)), np.eye(2), 0.2, SIGMA)
        for _ in range(30):
            filt.step(positions, ranges)
        assert np.linalg.norm(filt.mean - TARGET) < 1e-9


def test_oracle14_noisy_filter_is_consistent():
    """sigma_z = 0.2, Q = 0, R = 0.04 I, x0 ~ N(o, I), P0 = I: the mean NEES e^T P^-1 e at the end of
    each of 200 runs (20 rounds of 6 stacked ranges) is 2 (chi^2 with 2 dof) within [1.6, 2.4]."""
    positions = uniform_ring(AUTHORS, TARGET, 6)
    truth = exact_ranges(positions, TARGET)
    rng = np.random.default_rng(0)
    nees = []
    for _ in range(200):
        filt = RangeFilter(TARGET + rng.normal(size=2), np.eye(2), 0.0, SIGMA)
        for _ in range(20):
            filt.step(positions, truth + SIGMA * rng.normal(size=6))
        error = filt.mean - TARGET
        nees.append(error @ np.linalg.solve(filt.covariance, error))
    assert 1.6 <= np.mean(nees) <= 2.4
    # the covariance really is the posterior of 20 rounds of 6 ranges: about (sigma^2 / (20 * 3)) I
    # for the angle-uniform ring (J = N / (2 sigma^2) I per round, section 12)
    np.testing.assert_allclose(filt.covariance, SIGMA**2 / (20 * 3) * np.eye(2), rtol=0.05, atol=2e-5)


# ---------------------------------------------------------------------------- one range is rank-1
def test_decentralized_single_range_leaves_the_tangential_error():
    """Section 7: one static robot, noiseless ranges: the range residual goes to ~0 while the
    position error stays (the tangential direction is unobservable, its variance grows by q a step)."""
    robot = np.array([[7.0, 20.0]])
    ranges = exact_ranges(robot, TARGET)
    q, rounds = 0.2, 500
    filt = RangeFilter(TARGET + np.array([0.0, 2.5]), np.eye(2), q, SIGMA)
    for _ in range(rounds):
        filt.step(robot, ranges)
    residual = abs(np.linalg.norm(filt.mean - robot[0]) - ranges[0])
    assert residual < 1e-12
    assert np.linalg.norm(filt.mean - TARGET) > 1.0
    largest = np.linalg.eigvalsh(filt.covariance)[-1]
    assert largest == pytest.approx(1.0 + rounds * q, rel=1e-3)


# ---------------------------------------------------------------------------- skipped measurements
def test_nan_range_is_skipped():
    positions = uniform_ring(AUTHORS, TARGET, 3)
    ranges = exact_ranges(positions, TARGET)
    prior = TARGET + np.array([1.0, 0.5])
    with_nan = RangeFilter(prior, np.eye(2), 0.2, SIGMA)
    with_nan.step(positions, np.array([ranges[0], np.nan, ranges[2]]))
    without = RangeFilter(prior, np.eye(2), 0.2, SIGMA)
    without.step(positions[[0, 2]], ranges[[0, 2]])
    # the same to rounding (a skipped range is a zero row of H, not a smaller system)
    np.testing.assert_allclose(with_nan.mean, without.mean, rtol=1e-13)
    np.testing.assert_allclose(with_nan.covariance, without.covariance, rtol=1e-13)
    assert np.all(np.isfinite(with_nan.mean)) and np.all(np.isfinite(with_nan.covariance))


@pytest.mark.parametrize("gap", [0.0, 0.5 * SINGULAR_DISTANCE])
def test_robot_at_the_estimate_is_skipped(gap):
    prior = TARGET + np.array([1.0, 0.5])
    positions = np.vstack([uniform_ring(AUTHORS, TARGET, 3), prior + np.array([gap, 0.0])])
    ranges = exact_ranges(positions, TARGET)
    singular = RangeFilter(prior, np.eye(2), 0.2, SIGMA)
    singular.step(positions, ranges)  # the predicted estimate is the prior itself (F = I)
    without = RangeFilter(prior, np.eye(2), 0.2, SIGMA)
    without.step(positions[:3], ranges[:3])
    np.testing.assert_allclose(singular.mean, without.mean, rtol=1e-13)
    np.testing.assert_allclose(singular.covariance, without.covariance, rtol=1e-13)


@pytest.mark.parametrize(
    ("positions", "ranges"),
    [
        pytest.param(np.array([[7.0, 20.0], [1.5, 21.0]]), np.array([np.nan, np.nan]), id="all-out-of-range"),
        pytest.param(np.array([[4.5, 19.5]]), np.array([0.3]), id="robot-at-estimate"),
        pytest.param(np.zeros((0, 2)), np.zeros(0), id="no-robots"),
    ],
)
def test_no_usable_range_is_prediction_only(positions, ranges):
    prior, covariance = np.array([4.5, 19.5]), np.array([[1.0, 0.2], [0.2, 0.5]])
    filt = RangeFilter(prior, covariance, 0.2, SIGMA)
    filt.step(positions, ranges)
    np.testing.assert_array_equal(filt.mean, prior)
    np.testing.assert_allclose(filt.covariance, covariance + 0.2 * np.eye(2), rtol=0, atol=1e-15)
    filt.step(positions, ranges)
    np.testing.assert_allclose(filt.covariance, covariance + 0.4 * np.eye(2), rtol=0, atol=1e-15)


# ---------------------------------------------------------------------------- oracle 15
@given(case=region_with_points(1), angles=ring_angles(3, 10))
def test_oracle15_trilateration_from_boundary_robots(case, angles):
    region, (target,) = case
    positions = region.boundary_point(angles, target)
    bearings = (positions - target) / exact_ranges(positions, target)[:, None]
    # non-collinear, and not so close to collinear that the geometry itself is ill-posed
    assume(np.linalg.eigvalsh(bearings.T @ bearings)[0] >= 0.05)
    centred = positions - positions.mean(axis=0)
    assume(np.linalg.svd(centred, compute_uv=False)[-1] >= 1e-3 * region.outer_diameter)
    estimate, covariance = trilaterate(positions, exact_ranges(positions, target), SIGMA)
    assert np.linalg.norm(estimate - target) <= 1e-9
    # P0 = 10 sigma^2 (H^T H)^-1 at the estimate, H the unit bearings from the robots
    expected = 10.0 * SIGMA**2 * np.linalg.inv(bearings.T @ bearings)
    np.testing.assert_allclose(covariance, expected, rtol=0, atol=1e-6 * np.trace(expected))


@given(
    target=st.tuples(st.floats(-50, 50), st.floats(-50, 50)),
    robots=st.lists(st.tuples(st.floats(-50, 50), st.floats(-50, 50)), min_size=3, max_size=8),
)
def test_oracle15_trilateration_from_anywhere(target, robots):
    target, positions = np.array(target), np.array(robots)
    distances = exact_ranges(positions, target)
    assume(distances.min() > 0.5)
    bearings = (positions - target) / distances[:, None]
    assume(np.linalg.eigvalsh(bearings.T @ bearings)[0] >= 0.05)
    centred = positions - positions.mean(axis=0)
    assume(np.linalg.svd(centred, compute_uv=False)[-1] >= 1.0)
    estimate, _ = trilaterate(positions, distances, SIGMA)
    assert np.linalg.norm(estimate - target) <= 1e-9


def test_oracle15_trilateration_skips_missing_ranges():
    positions = uniform_ring(AUTHORS, TARGET, 6)
    ranges = exact_ranges(positions, TARGET)
    ranges[[1, 4]] = np.nan
    estimate, covariance = trilaterate(positions, ranges, SIGMA)
    assert np.linalg.norm(estimate - TARGET) <= 1e-9
    assert np.all(np.isfinite(covariance))


@pytest.mark.parametrize("usable", [0, 1, 2])
def test_trilateration_needs_three_ranges(usable):
    positions = uniform_ring(AUTHORS, TARGET, 4)
    ranges = exact_ranges(positions, TARGET)
    ranges[usable:] = np.nan
    with pytest.raises(NoFix) as raised:
        trilaterate(positions, ranges, SIGMA)
    assert str(raised.value) == f"trilateration needs ranges from at least 3 robots, got {usable}"


# ---------------------------------------------------------------------------- Estimator
def params(**changes) -> EstimationParams:
    base = load_scenario("authors-moving").estimation
    return EstimationParams(**{**base.__dict__, **changes})


def test_estimator_prior_truth_and_point():
    truth = np.array([4.2, 19.7])
    estimator = Estimator(params(prior="truth", prior_variance=2.5), AUTHORS, truth)
    mean, covariance = estimator.belief
    np.testing.assert_array_equal(mean, truth)
    np.testing.assert_array_equal(covariance, 2.5 * np.eye(2))
    np.testing.assert_array_equal(estimator.centre, truth)  # inside: not moved
    estimator = Estimator(params(prior=(5.0, 18.0), prior_variance=1.0), AUTHORS, truth)
    np.testing.assert_array_equal(estimator.belief[0], [5.0, 18.0])
    np.testing.assert_array_equal(estimator.belief[1], np.eye(2))


def test_estimator_uses_the_configured_noises():
    estimator = Estimator(params(process_noise=0.05, range_sigma=0.3), AUTHORS, TARGET)
    positions = uniform_ring(AUTHORS, TARGET, 6)
    ranges = exact_ranges(positions, TARGET) + np.array([0.1, -0.2, 0.05, 0.0, 0.3, -0.1])
    estimator.measure(positions, ranges)
    x, P = reference_step(TARGET, np.eye(2), 0.05, 0.3, positions, ranges)
    np.testing.assert_allclose(estimator.belief[0], x, rtol=0, atol=1e-12)
    np.testing.assert_allclose(estimator.belief[1], P, rtol=0, atol=1e-12)


def test_estimator_trilateration_prior_is_adopted_at_the_first_measure():
    estimator = Estimator(params(mode="centralized", prior="trilateration"), AUTHORS, TARGET + np.array([1.0, 1.0]))
    positions = uniform_ring(AUTHORS, TARGET, 6, 0.3)
    first = exact_ranges(positions, TARGET) + np.array([0.1, -0.05, 0.02, 0.0, -0.1, 0.07])
    estimator.measure(positions, first)
    expected_mean, expected_covariance = trilaterate(positions, first, SIGMA)
    np.testing.assert_array_equal(estimator.belief[0], expected_mean)
    np.testing.assert_allclose(estimator.belief[1], expected_covariance, rtol=1e-12)
    assert np.linalg.norm(expected_mean - TARGET) < 0.2  # a fix from these ranges, not the prior
    # later measures are ordinary filter steps from that prior
    second = exact_ranges(positions, TARGET)
    estimator.measure(positions, second)
    x, P = reference_step(expected_mean, expected_covariance, 0.2, SIGMA, positions, second)
    np.testing.assert_allclose(estimator.belief[0], x, rtol=0, atol=1e-12)
    np.testing.assert_allclose(estimator.belief[1], P, rtol=0, atol=1e-12)


@pytest.mark.parametrize(("fusion", "criterion"), [("ci", "trace"), ("ci", "det"), ("sequential", "trace"), ("sequential", "det")])
def test_estimator_fuse_adopts_the_ci_result(fusion, criterion):
    estimator = Estimator(params(mode="decentralized", fusion=fusion, criterion=criterion), AUTHORS, TARGET)
    estimator.measure(np.array([[7.0, 20.0]]), np.array([3.05]))
    own = estimator.belief
    neighbours = [
        (np.array([4.3, 20.4]), np.array([[0.5, 0.1], [0.1, 0.2]])),
        (np.array([3.8, 19.5]), np.array([[0.15, -0.05], [-0.05, 0.6]])),
    ]
    estimator.fuse(*neighbours)
    combine = covariance_intersection if fusion == "ci" else sequential_intersection
    expected = combine([own[0], *(m for m, _ in neighbours)], [own[1], *(c for _, c in neighbours)], criterion)
    np.testing.assert_allclose(estimator.belief[0], expected.mean, rtol=0, atol=1e-12)
    np.testing.assert_allclose(estimator.belief[1], expected.covariance, rtol=0, atol=1e-12)
    # the fused belief is smaller than every input (by the criterion) and it is what the robot steers by
    size = np.trace if criterion == "trace" else np.linalg.det
    assert size(estimator.belief[1]) <= min(size(own[1]), *(size(c) for _, c in neighbours)) * (1 + 1e-12)
    np.testing.assert_array_equal(estimator.centre, estimator.belief[0])
    # the next measure predicts from the fused belief
    fused_mean, fused_covariance = estimator.belief
    estimator.measure(np.array([[7.0, 20.0]]), np.array([3.0]))
    x, P = reference_step(fused_mean, fused_covariance, 0.2, SIGMA, np.array([[7.0, 20.0]]), np.array([3.0]))
    np.testing.assert_allclose(estimator.belief[0], x, rtol=0, atol=1e-12)
    np.testing.assert_allclose(estimator.belief[1], P, rtol=0, atol=1e-12)


@pytest.mark.parametrize("outside", [(12.0, 20.0), (-3.0, 30.0), (3.0, 7.0), (4.0, -100.0)])
@pytest.mark.parametrize("update", ["fuse", "measure"])
def test_the_estimate_itself_is_kept_inside_by_the_margin(outside, update):
    """Whatever an update or a fusion gives, the filter's own mean (what it predicts from, replies with
    and fuses) ends ``margin`` metres inside, pulled straight towards the Chebyshev centre, and the
    robot steers about exactly that mean."""
    estimator = Estimator(params(prior=tuple(TARGET)), AUTHORS, TARGET)
    margin = estimator.batch.params.margin
    assert margin == 0.1  # the scenario default, metres
    if update == "fuse":
        estimator.fuse((np.array(outside), 1e-6 * np.eye(2)), None)  # a confident neighbour far outside
    else:
        estimator.batch.filters.adopt(np.array(outside), 1e-6 * np.eye(2))  # as if the last update left it there
        estimator.batch.filters.process_noise = 0.0
        estimator.measure(np.array([[8.0, 17.0]]), [np.nan])  # prediction only: the mean stays put, then is kept in
    before = np.array(estimator.centre)
    mean, covariance = estimator.belief
    np.testing.assert_array_equal(estimator.centre, mean)
    heights = AUTHORS.heights(mean)
    assert heights.min() >= margin * (1 - 1e-9)  # inside by the margin, and not farther in than needed
    assert heights.min() <= margin + 1e-9 * AUTHORS.outer_diameter
    chebyshev, _ = AUTHORS.chebyshev_centre
    a, b = mean - chebyshev, np.array(outside) - chebyshev
    assert abs(a[0] * b[1] - a[1] * b[0]) <= 1e-9 * np.linalg.norm(a) * np.linalg.norm(b)  # pulled straight in
    assert a @ b > 0
    assert np.all(np.linalg.eigvalsh(covariance) > 0)
    estimator.batch.keep_inside()  # idempotent: a mean already inside is left exactly as it is
    np.testing.assert_array_equal(estimator.centre, before)


def test_a_mean_inside_is_never_touched():
    estimator = Estimator(params(prior=tuple(TARGET)), AUTHORS, TARGET)
    estimator.batch.filters.adopt(np.array([4.1234567891, 19.87654321]), np.eye(2))
    estimator.batch.keep_inside()
    np.testing.assert_array_equal(estimator.centre, [4.1234567891, 19.87654321])


def test_trilateration_refuses_collinear_robots():
    positions = np.array([[0.0, 0.0], [1.0, 1.0], [2.0, 2.0], [3.0, 3.0]])
    ranges = np.linalg.norm(positions - np.array([0.5, 2.0]), axis=1)
    with pytest.raises(NoFix, match="^trilateration needs robots that are not all on one line$"):
        trilaterate(positions, ranges, 0.2)


@given(edge=st.integers(0, 3), fractions=st.lists(st.floats(0.0, 1.0), min_size=3, max_size=5, unique=True))
def test_trilateration_refuses_robots_on_one_boundary_edge(edge, fractions):
    """Robots placed on one edge (as the world places them, by arc length) are collinear only up to
    rounding, which numpy's default rank test often takes for rank 2: still no fix (the target would
    be ambiguous, mirrored across the edge)."""
    corners = [*(AUTHORS.arc_length(vertex) for vertex in AUTHORS.vertices), AUTHORS.perimeter]
    positions = AUTHORS.point_at(corners[edge] + np.array(fractions) * (corners[edge + 1] - corners[edge]))
    gaps = np.linalg.norm(positions[:, None] - positions[None, :], axis=-1) + np.eye(len(positions))
    assume(gaps.min() > 1e-3)
    with pytest.raises(NoFix, match="^trilateration needs robots that are not all on one line$"):
        trilaterate(positions, exact_ranges(positions, TARGET), SIGMA)


def uninformative(region: ConvexRegion = AUTHORS) -> tuple[np.ndarray, np.ndarray]:
    """The trilateration fallback prior: the Chebyshev centre, D_out^2 I."""
    return region.chebyshev_centre[0], region.outer_diameter**2 * np.eye(2)


def test_estimator_trilateration_prior_starts_uninformative():
    estimator = Estimator(params(mode="centralized", prior="trilateration"), AUTHORS, TARGET)
    mean, covariance = uninformative()
    np.testing.assert_array_equal(estimator.belief[0], mean)  # not the truth
    np.testing.assert_array_equal(estimator.belief[1], covariance)
    assert np.all(AUTHORS.heights(mean) > 0) and covariance[0, 0] >= np.max(
        np.linalg.norm(AUTHORS.vertices - mean, axis=1)) ** 2  # it covers the whole region


@pytest.mark.parametrize("case", ["two ranges", "no range", "one edge"])
def test_estimator_without_a_fix_at_the_first_measure_updates_the_uninformative_prior(case):
    """Too few ranges, or robots all on one edge, at the first step: the step is an ordinary filter
    step from the uninformative prior, and later steps never trilaterate (the filter is running)."""
    estimator = Estimator(params(mode="centralized", prior="trilateration"), AUTHORS, TARGET)
    positions = uniform_ring(AUTHORS, TARGET, 6, 0.3)
    if case == "one edge":
        first, second = AUTHORS.vertices[0], AUTHORS.vertices[1]
        positions[:3] = first + np.array([[0.2], [0.4], [0.7]]) * (second - first)
    ranges = exact_ranges(positions, TARGET) + np.array([0.1, -0.05, 0.02, 0.0, -0.1, 0.07])
    ranges[{"two ranges": [2, 3, 4, 5], "no range": slice(None), "one edge": [3, 4, 5]}[case]] = np.nan
    estimator.measure(positions, ranges)
    x, P = reference_step(*uninformative(), 0.2, SIGMA, positions, ranges)
    np.testing.assert_allclose(estimator.belief[0], x, rtol=0, atol=1e-9)
    np.testing.assert_allclose(estimator.belief[1], P, rtol=0, atol=1e-9 * np.trace(P))
    second = exact_ranges(positions, TARGET)  # every range now: still a filter step, not a fix
    before = estimator.belief
    estimator.measure(positions, second)
    x, P = reference_step(*before, 0.2, SIGMA, positions, second)
    np.testing.assert_allclose(estimator.belief[0], x, rtol=0, atol=1e-9)
    np.testing.assert_allclose(estimator.belief[1], P, rtol=0, atol=1e-9 * np.trace(P))


def test_a_margin_that_leaves_no_room_is_refused():
    spec = load_scenario("counterexample-square", estimation="centralized").spec  # a unit square: D_in / 2 = 0.5 m
    spec = msgspec.structs.replace(spec, estimation=msgspec.structs.replace(spec.estimation, margin=0.5))
    with pytest.raises(ScenarioError) as raised:
        resolve(spec)
    assert str(raised.value).endswith(
        "estimation.margin 0.5 m leaves no room: the region's inscribed radius (D_in / 2) is 0.5 m; "
        "give a margin below it (default 0.1)")
