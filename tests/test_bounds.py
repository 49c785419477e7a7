"""world/bounds.py: the posterior Cramér-Rao bound of range-only tracking (docs/algorithms.md section
19) against closed forms, a matrix-by-matrix oracle written with numpy.linalg, and its properties."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from ringtrack.world.bounds import posterior_information, random_walk_bound, range_information
from ringtrack.world.target import RandomWalk


def ring(robots: int, radius: float, centre=(0.0, 0.0), phase: float = 0.3) -> np.ndarray:
    """``robots`` points evenly spaced on a circle (metres)."""
    angles = phase + 2.0 * math.pi * np.arange(robots) / robots
    return np.asarray(centre) + radius * np.stack([np.cos(angles), np.sin(angles)], axis=1)


def test_a_ring_of_n_robots_adds_n_over_two_sigma_squared_per_step():
    """Static target (Q = 0), N robots evenly around it: sum u u^T = N/2 I, so J(k) = (1/p0 + k N/(2 sigma^2)) I
    and the bound is trace J(k)^-1 = 2 / (1/p0 + k N / (2 sigma^2))."""
    robots, sigma, p0, steps = 6, 0.2, 1.0, 50
    positions = np.broadcast_to(ring(robots, 7.0, (2.0, -1.0)), (steps, robots, 2))
    targets = np.broadcast_to([2.0, -1.0], (steps, 2))
    np.testing.assert_allclose(range_information(positions[0], targets[0], sigma), robots / (2 * sigma**2) * np.eye(2),
                               rtol=1e-12, atol=1e-9)
    k = np.arange(1, steps + 1)
    np.testing.assert_allclose(random_walk_bound(positions, targets, sigma, 0.0, p0),
                               2.0 / (1.0 / p0 + k * robots / (2 * sigma**2)), rtol=1e-12)


def test_a_random_walk_tends_to_the_riccati_fixed_point():
    """F = I, Q = q I, m = N/(2 sigma^2) per step: J = (q + 1/J)^-1 + m has the positive root of
    q J^2 - m q J - m = 0, J = (m q + sqrt(m^2 q^2 + 4 m q)) / (2 q); the bound tends to 2 / J."""
    robots, sigma, q = 4, 0.5, 0.01
    m = robots / (2 * sigma**2)
    fixed = (m * q + math.sqrt(m**2 * q**2 + 4 * m * q)) / (2 * q)
    positions = np.broadcast_to(ring(robots, 5.0), (400, robots, 2))
    bound = random_walk_bound(positions, np.zeros((400, 2)), sigma, q, 1.0)
    assert bound[-1] == pytest.approx(2.0 / fixed, rel=1e-12)


def test_robots_beyond_the_sensing_range_add_nothing():
    near, far = ring(3, 2.0), ring(5, 30.0)
    together = np.concatenate([near, far])
    np.testing.assert_array_equal(range_information(together, [0.0, 0.0], 0.2, max_range=10.0),
                                  range_information(near, [0.0, 0.0], 0.2))
    assert not range_information(far, [0.0, 0.0], 0.2, max_range=10.0).any()


def test_the_random_walks_step_covariance_is_speed_std_dt_squared():
    assert RandomWalk(position=(0.0, 0.0), speed_std=0.5).step_covariance(0.1) == pytest.approx(0.0025, rel=1e-15)


def oracle(measured: np.ndarray, p0: np.ndarray, f: np.ndarray, q: np.ndarray) -> np.ndarray:
    """The recursion with numpy.linalg, one matrix at a time."""
    information, out = np.linalg.inv(p0), []
    for step in measured:
        information = np.linalg.inv(q + f @ np.linalg.inv(information) @ f.T) + step
        out.append(information)
    return np.array(out)



@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), robots=st.integers(1, 8), q=st.floats(0.0, 0.5))
def test_the_recursion_equals_a_matrix_oracle(seed: int, robots: int, q: float):
    rng = np.random.default_rng(seed)
    steps = 30
    positions = rng.uniform(-10, 10, (steps, robots, 2))
    targets = rng.uniform(-3, 3, (steps, 2))
    measured = range_information(positions, targets, 0.3)
    f = np.array([[1.0, 0.1], [-0.2, 0.9]])
    p0 = np.array([[2.0, 0.3], [0.3, 1.0]])
    np.testing.assert_allclose(posterior_information(measured, p0, f, q * np.eye(2) + 0.01 * np.eye(2)),
                               oracle(measured, p0, f, q * np.eye(2) + 0.01 * np.eye(2)), rtol=1e-9, atol=1e-9)


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), robots=st.integers(1, 8), extra=st.integers(1, 4), q=st.floats(0.0, 0.5),
       p0=st.floats(0.01, 10.0))
def test_more_robots_never_loosen_the_bound_and_a_static_target_never_exceeds_its_prior(
        seed: int, robots: int, extra: int, q: float, p0: float):
    rng = np.random.default_rng(seed)
    steps = 40
    positions = rng.uniform(-10, 10, (steps, robots + extra, 2))
    targets = np.cumsum(rng.normal(0, 0.1, (steps, 2)), axis=0)
    fewer = random_walk_bound(positions[:, :robots], targets, 0.2, q, p0)
    more = random_walk_bound(positions, targets, 0.2, q, p0)
    assert np.all(more <= fewer * (1 + 1e-12))
    static = random_walk_bound(positions[:, :robots], np.zeros((steps, 2)), 0.2, 0.0, p0)
    assert np.all(static <= 2 * p0 * (1 + 1e-12))
    assert np.all(np.diff(static) <= 1e-12)  # information only accumulates


def test_a_trials_bound_does_not_depend_on_its_batch():
    rng = np.random.default_rng(4)
    positions, targets = rng.uniform(-9, 9, (100, 5, 6, 2)), rng.uniform(-1, 1, (100, 5, 2))
    batch = random_walk_bound(positions, targets, 0.2, 0.01, 1.0)
    for trial in range(5):
        alone = random_walk_bound(positions[:, trial:trial + 1], targets[:, trial:trial + 1], 0.2, 0.01, 1.0)
        np.testing.assert_array_equal(alone[:, 0], batch[:, trial])
