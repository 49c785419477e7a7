"""world/ring.py, agents/laws.py, agents/controller.py (and whole rings through agents/engine.py)
against docs/algorithms.md sections 2-6, 12 and oracles 3, 4, 5, 6, 7, 8, 12, 13."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from ringtrack.agents import engine
from ringtrack.agents.controller import MidpointController
from ringtrack.agents.laws import (
    Trigger,
    angular_step,
    fresh_step,
    guarded_step,
    trigger_reasons,
    uncertainty_bound,
)
from ringtrack.agents.strategy import strategy_for
from ringtrack.world.geometry import angle_of
from ringtrack.world.metrics import convergence_error, range_information, true_offsets
from ringtrack.world.params import ControlParams
from ringtrack.world.ranges import uniform_ring
from ringtrack.world.ring import (
    local_frame,
    midpoint,
    midpoint_errors,
    neighbours_in_ring,
    predecessor_values,
    ring_gaps,
    ring_neighbours,
    successor_values,
    wrap,
)
from tests.helpers import (
    TWO_PI,
    ccw_gaps,
    examples,
    lyapunov,
    midpoint_offsets,
    region_with_points,
    ring_angles,
    scenario_from,
)

DEG = math.pi / 180.0

omegas_deg = st.sampled_from([1.0, 5.0, 30.0])
dts = st.sampled_from([0.1, 0.5, 1.0])
laws = st.sampled_from(["prop", "deadbeat"])
sigmas_deg = st.sampled_from([0.0, 0.01, 0.05, 0.06, 0.1, 0.2, 0.5, 1.0, 5.0])


def new_controller(region, params, positions, strategy: str = "self") -> MidpointController:
    """A team controller that, like the engine's, starts knowing nothing but its own positions, with
    the trigger rule of ``strategy``."""
    return MidpointController(region, params, positions, rule=strategy_for(strategy).triggers)


def exchange(controller: MidpointController, reasons, positions) -> None:
    """Robots with a nonzero trigger mask get both neighbours' step-start positions (age 0)."""
    polled = np.asarray(reasons) != 0
    controller.receive(np.roll(positions, 1, axis=0), np.roll(positions, -1, axis=0), polled, polled)


def params_for(omega_deg: float, dt: float, law: str = "prop", sigma_deg: float = 0.0) -> ControlParams:
    return ControlParams(omega_max=omega_deg * DEG, dt=dt, sigma=sigma_deg * DEG, law=law)


# ---------------------------------------------------------------------------- oracle 3
@given(ring_angles(3, 30), st.data())
def test_oracle3_local_frame_offsets(angles, data):
    robots = len(angles)
    # neighbours' angles arrive "in any representation": add arbitrary multiples of 2 pi
    shifts = np.array(data.draw(st.lists(st.integers(-3, 3), min_size=robots, max_size=robots)))
    received = angles + TWO_PI * shifts
    theta = angles + TWO_PI * np.array(data.draw(st.lists(st.integers(-2, 2), min_size=robots, max_size=robots)))
    m_minus, m_plus = local_frame(theta, np.roll(received, 1), np.roll(received, -1))
    d_plus, d_minus = m_plus - theta, theta - m_minus
    assert np.all((d_plus > 0) & (d_plus < TWO_PI))
    assert np.all((d_minus > 0) & (d_minus < TWO_PI))
    assert d_plus.sum() == pytest.approx(TWO_PI, abs=1e-12)
    assert d_minus.sum() == pytest.approx(TWO_PI, abs=1e-12)
    np.testing.assert_allclose(d_minus, np.roll(d_plus, 1), rtol=0, atol=1e-12)
    np.testing.assert_allclose(d_plus, ccw_gaps(angles), rtol=0, atol=1e-12)
    np.testing.assert_allclose(ring_gaps(received), ccw_gaps(angles), rtol=0, atol=1e-12)
    # V_i - theta_i = (d^+ - d^-)/4, sum e_i = 0
    errors = midpoint(m_minus, theta, m_plus) - theta
    np.testing.assert_allclose(errors, (d_plus - d_minus) / 4.0, rtol=0, atol=1e-12)
    np.testing.assert_allclose(midpoint_errors(received), (d_plus - d_minus) / 4.0, rtol=0, atol=1e-12)
    assert abs(errors.sum()) <= 1e-12
    assert abs(midpoint_errors(received).sum()) <= 1e-12


def test_oracle3_by_hand():
    # successor behind in raw numbers is still placed ahead: theta = 350 deg, successor at 10 deg
    m_minus, m_plus = local_frame(math.radians(350), math.radians(300), math.radians(10))
    assert math.degrees(m_plus) == pytest.approx(370.0)
    assert math.degrees(m_minus) == pytest.approx(300.0)
    assert wrap(-0.5) == pytest.approx(TWO_PI - 0.5)
    errors = midpoint_errors(np.radians([0.0, 90.0, 120.0]))
    np.testing.assert_allclose(np.degrees(errors), [(90 - 240) / 4, (30 - 90) / 4, (240 - 30) / 4])


# ---------------------------------------------------------------------------- oracle 4
@given(st.integers(3, 40), st.floats(-10.0, 10.0), omegas_deg, dts, laws, st.data())
def test_oracle4_uniform_ring_is_a_fixed_point_of_every_law(robots, rotation, omega, dt, law, data):
    params = params_for(omega, dt, law)
    theta = rotation + TWO_PI * np.arange(robots) / robots
    errors = midpoint_errors(theta)
    assert np.abs(errors).max() <= 1e-12
    assert np.abs(fresh_step(errors, params)).max() <= 1e-12
    ages = st.lists(st.integers(0, 100), min_size=robots, max_size=robots)
    c_minus, c_plus = np.array(data.draw(ages)), np.array(data.draw(ages))
    ubd = uncertainty_bound(c_minus, c_plus, params)
    assert np.abs(guarded_step(errors, ubd, params.max_step)).max() <= 1e-12
    m_minus, m_plus = local_frame(theta, np.roll(theta, 1), np.roll(theta, -1))
    fresh = np.array(data.draw(st.lists(st.booleans(), min_size=robots, max_size=robots)))
    step = angular_step(theta, m_minus, m_plus, c_minus, c_plus, fresh, params)
    assert np.abs(step).max() <= 1e-12


@settings(max_examples=examples(30))
@given(region_with_points(1, pull_max=0.9), st.integers(3, 12), st.floats(-math.pi, math.pi), laws, st.sampled_from(["self", "constant"]))
def test_oracle4_uniform_ring_stays_put_through_the_controller(case, robots, rotation, law, strategy):
    region, (centre,) = case
    params = params_for(1.0, 0.1, law, 0.06)
    positions = uniform_ring(region, centre, robots, rotation)
    controller = new_controller(region, params, positions, strategy)
    theta0 = angle_of(positions, centre)
    for k in range(1, 8):
        reasons = controller.observe(k, positions, centre)
        exchange(controller, reasons, positions)
        goal = controller.goal()
        step = np.mod(angle_of(goal, centre) - angle_of(positions, centre) + math.pi, TWO_PI) - math.pi
        assert np.abs(step).max() <= 1e-12
        positions = goal
    assert np.abs(np.mod(angle_of(positions, centre) - theta0 + math.pi, TWO_PI) - math.pi).max() <= 1e-12


# ---------------------------------------------------------------------------- oracles 5 and 6 (whole rings)
def spec_fresh_step(angles: np.ndarray, dt: float, omega_deg: float, law: str) -> np.ndarray:
    """docs/algorithms.md section 3, written out independently of agents.laws: e_i = (d_i^+ - d_i^-) / 4,
    prop: dt * sat_omega(e); deadbeat: sign(e) min(omega dt, |e|)."""
    omega = math.radians(omega_deg)
    gaps = ccw_gaps(angles)
    errors = (gaps - np.roll(gaps, 1, axis=-1)) / 4.0
    if law == "prop":
        return dt * np.clip(errors, -omega, omega)
    return np.sign(errors) * np.minimum(omega * dt, np.abs(errors))


def check_monotone_ring_history(history, expect_robots: int, dt: float, omega_deg: float, law: str) -> None:
    angles = history.angles  # (K, 1, N), radians about the target, unwrapped in time
    assert angles.shape[1:] == (1, expect_robots)
    # step 1: everyone has exact information and takes the fresh-information law (both strategies)
    np.testing.assert_allclose(angles[1, 0] - angles[0, 0], spec_fresh_step(angles[0, 0], dt, omega_deg, law),
                               rtol=0, atol=1e-9)
    gaps = ccw_gaps(angles[:, 0])
    # strict cyclic order preserved every step, no co-location
    assert gaps.min() > 0.0
    np.testing.assert_allclose(gaps.sum(axis=-1), TWO_PI, rtol=0, atol=1e-9)
    # Cerr_true (L1 of e, radians) non-increasing
    cerr = np.abs(midpoint_offsets(angles[:, 0])).sum(axis=-1)
    assert np.max(np.diff(cerr)) <= 1e-12
    # the engine's logged Cerr_true (degrees) is the same quantity
    np.testing.assert_allclose(history.cerr_true[:, 0], np.degrees(cerr), rtol=0, atol=1e-9)
    # Lyapunov H = (1/12) sum (d^+)^3 non-increasing, never below its minimum (2 pi)^3 / (12 N^2)
    h = lyapunov(angles[:, 0])
    assert np.all(h[1:] <= h[:-1] * (1 + 1e-12))
    assert h.min() >= TWO_PI**3 / (12 * expect_robots**2) * (1 - 1e-12)


@settings(max_examples=examples(40))
@given(region_with_points(1, pull_max=0.9), ring_angles(3, 30), dts, omegas_deg, laws)
def test_oracle5_constant_law_is_monotone(case, angles, dt, omega, law):
    region, (centre,) = case
    scenario = scenario_from(
        region.vertices, centre, len(angles), np.degrees(angles),
        strategy="constant", law=law, dt=dt, omega_max_deg=omega, max_steps=150,
    )
    history = engine.run(scenario, record_positions=False)
    check_monotone_ring_history(history, len(angles), dt, omega, law)
    assert np.all(history.triggers != 0)  # constant: everyone polls every step
    # and moves by the law at every step, not only at the first
    for k in (1, len(history.angles) // 2, len(history.angles) - 2):
        np.testing.assert_allclose(history.angles[k + 1, 0] - history.angles[k, 0],
                                   spec_fresh_step(history.angles[k, 0], dt, omega, law), rtol=0, atol=1e-9)


@pytest.mark.slow
@settings(max_examples=examples(50))
@given(region_with_points(1, pull_max=0.9), ring_angles(3, 30, min_weight=1e-4), dts, omegas_deg, laws, sigmas_deg)
def test_oracle6_self_triggered_law_is_monotone_and_keeps_order(case, angles, dt, omega, law, sigma):
    region, (centre,) = case
    scenario = scenario_from(
        region.vertices, centre, len(angles), np.degrees(angles),
        strategy="self", law=law, dt=dt, omega_max_deg=omega, sigma_deg=sigma, max_steps=200,
    )
    history = engine.run(scenario, record_positions=False)
    check_monotone_ring_history(history, len(angles), dt, omega, law)


@pytest.mark.parametrize("law", ["prop", "deadbeat"])
@pytest.mark.parametrize("dt", [0.1, 0.5, 1.0])
@pytest.mark.parametrize("omega", [1.0, 5.0, 30.0])
def test_oracle5_constant_law_grid_on_angle_rings(law, dt, omega):
    """Every (dt, omega, law) of oracle 5 on fixed random rings (N = 4, 7, 30), synchronous updates
    theta <- theta + step(e) driven directly with the law functions, 300 steps."""
    params = params_for(omega, dt, law)
    rng = np.random.default_rng(5)
    for robots in (4, 7, 30):
        theta = np.sort(rng.uniform(0.0, TWO_PI, robots))
        cerr, h = [], []
        for _ in range(300):
            errors = midpoint_errors(theta)
            cerr.append(np.abs(errors).sum())
            h.append(lyapunov(theta))
            gaps = ccw_gaps(theta)
            assert gaps.min() > 0 and gaps.sum() == pytest.approx(TWO_PI, abs=1e-9)
            step = fresh_step(errors, params)
            assert np.abs(step).max() <= params.max_step * (1 + 1e-15)
            theta = theta + step
        assert np.max(np.diff(cerr)) <= 1e-12
        assert np.all(np.array(h[1:]) <= np.array(h[:-1]) * (1 + 1e-12))


def test_oracle5_uniform_minimum_of_lyapunov():
    for robots in (3, 6, 17):
        uniform = TWO_PI * np.arange(robots) / robots + 0.3
        assert lyapunov(uniform) == pytest.approx(TWO_PI**3 / (12 * robots**2), rel=1e-12)


# ---------------------------------------------------------------------------- oracle 7 (Lemma 1)
@given(
    st.floats(-10.0, 10.0),
    st.floats(1e-3, 3.0),
    st.floats(1e-3, 3.0),
    st.integers(0, 60),
    st.integers(0, 60),
    st.floats(1e-3, 1.0),
    st.floats(0.01, 2.0),
    st.floats(-1.0, 1.0),
)
def test_oracle7_guarded_step_moves_towards_any_admissible_midpoint(theta, gap_minus, gap_plus, c_minus, c_plus, omega, dt, where):
    params = ControlParams(omega_max=omega, dt=dt)
    m_minus, m_plus = theta - gap_minus, theta + gap_plus
    g_v = (m_minus + 2 * theta + m_plus) / 4
    ubd = omega * (c_minus + c_plus) * dt / 4
    v_true = g_v + where * ubd  # any V with |V - gV| <= ubd
    step = angular_step(theta, m_minus, m_plus, c_minus, c_plus, False, params)
    after = theta + step
    assert abs(after - v_true) <= abs(theta - v_true) + 1e-12
    assert min(theta, v_true) - 1e-12 <= after <= max(theta, v_true) + 1e-12
    assert abs(step) <= omega * dt * (1 + 1e-15)
    # the three regimes of section 4
    distance = abs(g_v - theta)
    if distance >= ubd + omega * dt + 1e-12:
        assert abs(step) == pytest.approx(omega * dt, rel=1e-12)
    elif distance <= ubd - 1e-12:
        assert step == 0.0
    elif distance > ubd + 1e-12:
        assert abs(step) == pytest.approx(distance - ubd, abs=1e-12)


@given(st.floats(-10.0, 10.0), st.floats(1e-3, 3.0), st.floats(1e-3, 3.0), st.floats(1e-3, 1.0), st.floats(0.01, 1.0), laws)
def test_oracle7_fresh_laws_stay_between_theta_and_exact_midpoint(theta, gap_minus, gap_plus, omega, dt, law):
    params = ControlParams(omega_max=omega, dt=dt, law=law)
    v_exact = (theta - gap_minus + 2 * theta + theta + gap_plus) / 4
    step = float(angular_step(theta, theta - gap_minus, theta + gap_plus, 0, 0, True, params))
    after = theta + step
    assert min(theta, v_exact) - 1e-12 <= after <= max(theta, v_exact) + 1e-12
    assert abs(step) <= omega * dt * (1 + 1e-15)
    offset = v_exact - theta
    if law == "prop":
        assert step == pytest.approx(dt * math.copysign(min(omega, abs(offset)), offset), abs=1e-12)
    else:
        assert step == pytest.approx(math.copysign(min(omega * dt, abs(offset)), offset), abs=1e-12)


# ---------------------------------------------------------------------------- oracle 8 (ubd soundness)
@given(
    st.floats(-10.0, 10.0),
    st.floats(0.3, 3.0),
    st.floats(0.3, 3.0),
    st.integers(0, 40),
    st.integers(0, 40),
    st.floats(1e-3, 0.5),
    st.floats(0.01, 0.5),
    st.floats(-1.0, 1.0),
    st.floats(-1.0, 1.0),
)
def test_oracle8_uncertainty_bound_is_sound(theta, gap_minus, gap_plus, c_minus, c_plus, omega, dt, w_minus, w_plus):
    params = ControlParams(omega_max=omega, dt=dt)
    m_minus, m_plus = theta - gap_minus, theta + gap_plus
    ubd = float(uncertainty_bound(c_minus, c_plus, params))
    assert ubd == pytest.approx(omega * (c_minus * dt + c_plus * dt) / 4, rel=1e-14, abs=0)
    # neighbours moved by at most omega * tau since they were heard
    true_minus = m_minus + w_minus * omega * c_minus * dt
    true_plus = m_plus + w_plus * omega * c_plus * dt
    v_true = midpoint(true_minus, theta, true_plus)
    g_v = midpoint(m_minus, theta, m_plus)
    assert abs(v_true - g_v) <= ubd + 1e-12
    # and the bound is attained when both move at full speed the same way
    extreme = midpoint(m_minus + omega * c_minus * dt, theta, m_plus + omega * c_plus * dt)
    assert abs(extreme - g_v) == pytest.approx(ubd, abs=1e-12)


@settings(max_examples=examples(25))
@given(region_with_points(1, pull_max=0.9), ring_angles(3, 12, min_weight=1e-2), laws, sigmas_deg, dts, omegas_deg)
def test_oracle8_uncertainty_bound_is_sound_inside_a_running_ring(case, angles, law, sigma, dt, omega):
    """Drive MidpointController like the engine does and check |V_true - gV| <= ubd for every robot
    and step, from the controller's own memory and ages; also oracle 12 at controller level."""
    region, (centre,) = case
    params = params_for(omega, dt, law, sigma)
    positions = region.boundary_point(angles, centre)
    controller = new_controller(region, params, positions)
    polls = np.zeros(len(angles), dtype=int)
    for k in range(1, 150):
        reasons = controller.observe(k, positions, centre)
        if k == 1:
            np.testing.assert_array_equal(reasons, int(Trigger.START))
        else:
            np.testing.assert_array_equal(controller.predecessor_age, controller.successor_age)
            assert np.all(controller.predecessor_age >= 1)
            gap = np.abs(true_offsets(positions, centre) - controller.guaranteed_offset)
            ubd = uncertainty_bound(controller.predecessor_age, controller.successor_age, params)
            assert np.all(gap <= ubd + 1e-12)
        polls += reasons != 0
        exchange(controller, reasons, positions)
        np.testing.assert_array_equal(controller.predecessor_age[reasons != 0], 0)
        np.testing.assert_array_equal(controller.successor_age[reasons != 0], 0)
        goal = controller.goal()
        if k == 1:  # after the step-1 exchange every robot knows its exact offset
            np.testing.assert_allclose(controller.guaranteed_offset, true_offsets(positions, centre), rtol=0, atol=1e-12)
        step = np.mod(angle_of(goal, centre) - angle_of(positions, centre) + math.pi, TWO_PI) - math.pi
        assert np.abs(step).max() <= params.max_step * (1 + 1e-9)
        positions = goal
    assert np.all(polls >= 1)


# ---------------------------------------------------------------------------- trigger rule (section 4)
def test_trigger_rule_by_hand():
    params = ControlParams(omega_max=1.0, dt=0.5, sigma=0.0)
    # ages 1: tau = 0.5, ubd = 1 * (0.5 + 0.5) / 4 = 0.25, phi = 0.5
    assert trigger_reasons(0.0, -1.0, 1.0, 1, 1, params) == Trigger.UNCERTAINTY  # |gV - theta| = 0 <= ubd
    assert trigger_reasons(0.0, -1.0, 2.0, 1, 1, params) == Trigger.UNCERTAINTY  # tie |gV - theta| = 0.25 = ubd
    assert trigger_reasons(0.0, -1.0, 2.2, 1, 1, params) == 0
    sigma = ControlParams(omega_max=1.0, dt=0.5, sigma=0.3)
    assert trigger_reasons(0.0, -1.0, 1.0, 1, 1, sigma) == 0  # ubd 0.25 < sigma 0.3
    assert trigger_reasons(0.0, -1.0, 0.4, 1, 1, sigma) == Trigger.SUCCESSOR  # 0.4 - 0.5 <= 0
    assert trigger_reasons(0.0, -0.4, 1.0, 1, 1, sigma) == Trigger.PREDECESSOR  # -0.4 + 0.5 >= 0
    both = trigger_reasons(0.0, -0.5, 0.5, 1, 1, params)
    assert both == Trigger.UNCERTAINTY | Trigger.SUCCESSOR | Trigger.PREDECESSOR


@given(
    st.floats(-5.0, 5.0), st.floats(1e-3, 3.0), st.floats(1e-3, 3.0), st.integers(0, 40), st.integers(0, 40),
    st.floats(1e-3, 1.0), st.floats(0.01, 1.0), st.floats(0.0, 0.05),
)
def test_trigger_rule_matches_spec_formulas(theta, gap_minus, gap_plus, c_minus, c_plus, omega, dt, sigma):
    params = ControlParams(omega_max=omega, dt=dt, sigma=sigma)
    m_minus, m_plus = theta - gap_minus, theta + gap_plus
    tau_minus, tau_plus = c_minus * dt, c_plus * dt
    g_v = (m_minus + 2 * theta + m_plus) / 4
    ubd = omega * (tau_minus + tau_plus) / 4
    t1 = ubd - max(abs(g_v - theta), sigma)
    t2 = theta - (m_plus - omega * tau_plus)
    t3 = (m_minus + omega * tau_minus) - theta
    reasons = int(trigger_reasons(theta, m_minus, m_plus, c_minus, c_plus, params))
    for margin, flag in ((t1, Trigger.UNCERTAINTY), (t2, Trigger.SUCCESSOR), (t3, Trigger.PREDECESSOR)):
        if abs(margin) > 1e-12:  # away from floating-point ties
            assert bool(reasons & flag) == (margin > 0)


# ---------------------------------------------------------------------------- oracle 12 (controller level)
@pytest.mark.parametrize("strategy", ["self", "constant"])
def test_oracle12_everyone_polls_at_step_1_and_constant_polls_every_step(strategy):
    from ringtrack.world.geometry import ConvexRegion

    region = ConvexRegion.from_vertices([[3, 7], [8, 17], [5, 26], [1, 22]])
    centre = np.array([4.0, 20.0])
    params = params_for(1.0, 0.1, "prop", 0.06)
    positions = region.boundary_point(np.radians([69.8979, 75.0730, 83.1024, 108.1016, 170.1016, 303.8982]), centre)
    controller = new_controller(region, params, positions, strategy)
    triggered = []
    for k in range(1, 60):
        reasons = controller.observe(k, positions, centre)
        triggered.append(reasons.copy())
        exchange(controller, reasons, positions)
        positions = controller.goal()
    triggered = np.array(triggered)
    np.testing.assert_array_equal(triggered[0], int(Trigger.START))
    if strategy == "constant":
        np.testing.assert_array_equal(triggered[1:], int(Trigger.SCHEDULE))
    else:
        assert np.all((triggered[1:] & int(Trigger.SCHEDULE)) == 0)
        assert 0 < np.count_nonzero(triggered[1:]) < triggered[1:].size


# ---------------------------------------------------------------------------- oracle 13 (FIM)
def pairwise_sin_squared(theta: np.ndarray) -> float:
    i, j = np.triu_indices(len(theta), k=1)
    return float(np.sum(np.sin(theta[i] - theta[j]) ** 2))


@given(
    st.lists(st.tuples(st.floats(-math.pi, math.pi), st.floats(0.1, 50.0)), min_size=2, max_size=20),
    st.floats(-10.0, 10.0), st.floats(-10.0, 10.0), st.floats(0.01, 5.0),
)
def test_oracle13_fisher_information_determinant(bearings, tx, ty, sigma):
    theta = np.array([b for b, _ in bearings])
    distance = np.array([d for _, d in bearings])
    target = np.array([tx, ty])
    positions = target + distance[:, None] * np.stack([np.cos(theta), np.sin(theta)], axis=1)
    fim = range_information(positions, target, sigma)
    assert fim.shape == (2, 2)
    np.testing.assert_allclose(fim, fim.T, rtol=0, atol=1e-12 * fim.trace())
    assert fim.trace() == pytest.approx(len(theta) / sigma**2, rel=1e-12)
    det = np.linalg.det(fim)
    scale = sigma**-4
    expected = scale * pairwise_sin_squared(theta)
    n = len(theta)
    assert det == pytest.approx(expected, rel=1e-12, abs=1e-12 * scale * n**2)
    resultant = abs(np.sum(np.exp(2j * theta))) ** 2
    assert det == pytest.approx(scale * (n**2 / 4 - resultant / 4), rel=1e-12, abs=1e-12 * scale * n**2)
    assert det <= n**2 / (4 * sigma**4) * (1 + 1e-12)


@given(region_with_points(1), st.integers(3, 30), st.floats(-math.pi, math.pi), st.floats(0.01, 5.0))
def test_oracle13_uniform_ring_has_isotropic_information(case, robots, rotation, sigma):
    region, (centre,) = case
    positions = uniform_ring(region, centre, robots, rotation)
    fim = range_information(positions, centre, sigma)
    expected = robots / (2 * sigma**2)
    np.testing.assert_allclose(fim, expected * np.eye(2), rtol=0, atol=1e-12 * expected)
    assert np.linalg.det(fim) == pytest.approx(robots**2 / (4 * sigma**4), rel=1e-12)


def test_oracle13_non_unique_maximiser_and_two_robots():
    sigma = 0.2
    theta = np.array([0.0, 0.3, math.pi / 2, math.pi / 2 + 0.3])
    positions = np.stack([np.cos(theta), np.sin(theta)], axis=1) * 3.0
    assert np.linalg.det(range_information(positions, (0.0, 0.0), sigma)) == pytest.approx(16 / (4 * sigma**4), rel=1e-12)
    antipodal = np.array([[1.0, 0.0], [-2.0, 0.0]])
    assert abs(np.linalg.det(range_information(antipodal, (0.0, 0.0), sigma))) <= 1e-9
    right = np.array([[1.0, 0.0], [0.0, 2.0]])
    assert np.linalg.det(range_information(right, (0.0, 0.0), sigma)) == pytest.approx(1 / sigma**4, rel=1e-12)


# ---------------------------------------------------------------------------- metrics helpers
def test_convergence_error_is_degrees_of_l1():
    offsets = np.radians([[1.0, -2.0, 0.5], [0.0, 0.0, 0.0]])
    np.testing.assert_allclose(convergence_error(offsets), [3.5, 0.0])


@given(shape=st.lists(st.integers(1, 5), min_size=1, max_size=3), data=st.data())
def test_ring_neighbour_values_are_the_rolls_of_the_ring(shape: list[int], data: st.DataObject) -> None:
    """What each robot's successor / predecessor holds, along any axis: np.roll by -1 / +1, exactly."""
    values = np.arange(np.prod(shape), dtype=float).reshape(shape)
    axis = data.draw(st.integers(-len(shape), len(shape) - 1))
    np.testing.assert_array_equal(successor_values(values, axis), np.roll(values, -1, axis=axis))
    np.testing.assert_array_equal(predecessor_values(values, axis), np.roll(values, 1, axis=axis))


@given(st.sets(st.integers(0, 40), max_size=40), st.integers(0, 40))
def test_ring_neighbours_are_the_nearest_alive_ids_before_and_after_in_cyclic_order(alive, robot):
    """The bisection over the sorted ids names the same neighbours as the definition, the robot in
    the ring or not."""
    others = sorted(alive - {robot})
    expected = (robot, robot) if not others else (
        max((other for other in others if other < robot), default=others[-1]),
        min((other for other in others if other > robot), default=others[0]),
    )
    assert neighbours_in_ring(robot, sorted(alive)) == expected
    assert ring_neighbours(robot, alive) == expected
