"""agents/engine.py, world/metrics.py and world/scenario.py against docs/algorithms.md sections 4, 5, 14
and oracles 9, 10, 11, 12; scenario validation messages."""

from __future__ import annotations

import math

import msgspec
import numpy as np
import pytest

from ringtrack.agents import engine
from ringtrack.agents.laws import Trigger
from ringtrack.world.metrics import communications, convergence_step, mean_communication_rate
from ringtrack.world.scenario import (
    Scenario,
    apply_overrides,
    load_scenario,
    parse_scenario,
    resolve,
)
from tests.helpers import (
    AUTHORS_TARGET,
    AUTHORS_VERTICES,
    PAPER_ANGLES_DEG,
    ccw_gaps,
    midpoint_offsets,
    scenario_toml,
)


def random_start(**overrides) -> Scenario:
    """paper-stationary with ``team.angles_deg`` removed: a seeded uniform random start per seed."""
    spec = load_scenario("paper-stationary").spec
    spec = msgspec.structs.replace(spec, team=msgspec.structs.replace(spec.team, angles_deg=None))
    return resolve(apply_overrides(spec, **overrides), "paper-stationary.toml")


def run_batch(scenario: Scenario, seeds, **kwargs) -> engine.History:
    return engine.run(scenario, seeds=seeds, until_converged=True, record_positions=False, **kwargs)


def com_bar_by_hand(history: engine.History) -> np.ndarray:
    """Com-bar = sum_i com(i, Ctime) / (N Ctime), com counting polled steps <= Ctime (step 1 included)."""
    result = []
    robots = history.triggers.shape[2]
    for trial, ctime in enumerate(history.ctime):
        polled = history.triggers[:ctime, trial] != 0
        result.append(polled.sum() / (robots * ctime) if ctime else np.nan)
    return np.array(result)


# ---------------------------------------------------------------------------- oracle 11
@pytest.mark.parametrize(
    ("strategy", "law", "ctime"),
    [("self", "prop", 712), ("self", "deadbeat", 707), ("constant", "prop", 745), ("constant", "deadbeat", 703)],
)
def test_oracle11_paper_example_ctime(strategy, law, ctime):
    scenario = load_scenario("paper-stationary", strategy=strategy, law=law)
    np.testing.assert_allclose(np.degrees(scenario.start_angles(0)), PAPER_ANGLES_DEG, rtol=0, atol=1e-12)
    assert math.degrees(scenario.threshold) == pytest.approx(0.6, rel=1e-12)
    assert math.degrees(scenario.control.omega_max) == pytest.approx(1.0, rel=1e-12)
    assert math.degrees(scenario.control.sigma) == pytest.approx(0.06, rel=1e-12)
    assert scenario.control.dt == 0.1
    history = engine.run(scenario, until_converged=True, record_positions=False)
    assert int(history.ctime[0]) == ctime
    assert history.steps == ctime  # until_converged stops exactly at Ctime
    assert 0.9 * 760 <= history.ctime[0] <= 1.1 * 760  # the paper's figure, +-10%
    # Ctime really is the first step with Cerr < 0.6 deg (memory-based for self, true for constant)
    cerr = history.cerr[:, 0]
    assert cerr[ctime - 1] < 0.6
    assert np.all(cerr[: ctime - 1] >= 0.6)
    expected_cerr = history.cerr_memory if strategy == "self" else history.cerr_true
    np.testing.assert_array_equal(cerr, expected_cerr[:, 0])


# ---------------------------------------------------------------------------- oracle 12
@pytest.mark.parametrize("law", ["prop", "deadbeat"])
def test_oracle12_communication_rates_paper_example(law):
    constant = engine.run(load_scenario("paper-stationary", strategy="constant", law=law), until_converged=True, record_positions=False)
    self_triggered = engine.run(load_scenario("paper-stationary", strategy="self", law=law), until_converged=True, record_positions=False)
    assert constant.com_bar[0] == 1.0
    assert 0.0 < self_triggered.com_bar[0] <= 1.0
    assert self_triggered.com_bar[0] < 0.5
    for history in (constant, self_triggered):
        np.testing.assert_array_equal(history.triggers[0], int(Trigger.START))  # com(i, 1) = 1
        np.testing.assert_allclose(history.com_bar, com_bar_by_hand(history), rtol=1e-15)
    np.testing.assert_array_equal(constant.triggers[1:], int(Trigger.SCHEDULE))
    assert np.all((self_triggered.triggers[1:] & int(Trigger.SCHEDULE | Trigger.START)) == 0)


def test_oracle12_random_starts_batch():
    for strategy in ("self", "constant"):
        history = run_batch(random_start(strategy=strategy, sigma_deg=0.1), range(10))
        np.testing.assert_array_equal(history.triggers[0], int(Trigger.START))
        assert np.all(history.ctime > 0)
        if strategy == "constant":
            assert np.all(history.com_bar == 1.0)
        else:
            assert np.all((history.com_bar > 0) & (history.com_bar <= 1))
        np.testing.assert_allclose(history.com_bar, com_bar_by_hand(history), rtol=1e-15)


# ---------------------------------------------------------------------------- engine bookkeeping
def test_history_is_consistent_with_the_spec_formulas():
    history = engine.run(load_scenario("paper-stationary"), steps=200)
    angles = history.angles[:, 0]
    assert angles.shape == (200, 6)
    np.testing.assert_allclose(history.cerr_true[:, 0], np.degrees(np.abs(midpoint_offsets(angles)).sum(axis=-1)), rtol=0, atol=1e-9)
    assert np.all(ccw_gaps(angles) > 0)
    # angles are unwrapped along time: no step jumps by more than omega_max dt
    assert np.abs(np.diff(angles, axis=0)).max() <= math.radians(0.1) * (1 + 1e-9)
    # positions are the boundary points at those angles about the target
    region = history.scenario.region
    np.testing.assert_allclose(history.positions[:, 0], region.boundary_point(angles, AUTHORS_TARGET), rtol=0, atol=1e-9)


def test_metrics_by_hand():
    cerr = np.array([[5.0, 9.0], [0.6, 9.0], [0.59, 9.0], [0.1, 9.0]])
    np.testing.assert_array_equal(convergence_step(cerr, 0.6), [3, 0])  # strict <, 1-based, 0 = never
    triggers = np.zeros((4, 2, 3), dtype=np.uint8)
    triggers[0] = 16
    triggers[1, 0, 1] = 1
    triggers[2, 0, :] = 2
    triggers[3, 0, 0] = 1
    np.testing.assert_array_equal(communications(triggers, np.array([3, 4])), [[2, 3, 2], [1, 1, 1]])
    rates = mean_communication_rate(triggers, np.array([3, 0]))
    assert rates[0] == pytest.approx(7 / 9, rel=1e-15)
    assert np.isnan(rates[1])


# ---------------------------------------------------------------------------- oracle 9
def test_oracle9_sigma_below_half_step_is_bit_identical_to_zero():
    zero = run_batch(random_start(sigma_deg=0.0), range(30))
    half_step = run_batch(random_start(sigma_deg=0.05), range(30))  # omega_max dt / 2 = 0.05 deg
    assert zero.steps == half_step.steps
    np.testing.assert_array_equal(zero.triggers, half_step.triggers)
    np.testing.assert_array_equal(zero.angles, half_step.angles)
    np.testing.assert_array_equal(zero.offsets, half_step.offsets)
    np.testing.assert_array_equal(zero.cerr_true, half_step.cerr_true)
    np.testing.assert_array_equal(zero.ctime, half_step.ctime)


def test_oracle9_mean_com_bar_non_increasing_in_sigma():
    means = []
    for sigma in (0.0, 0.1, 0.2, 0.5, 1.0):
        history = run_batch(random_start(sigma_deg=sigma), range(30))
        assert np.all(history.ctime > 0)
        means.append(float(np.mean(history.com_bar)))
    assert all(later <= earlier for earlier, later in zip(means, means[1:], strict=False)), means


@pytest.mark.parametrize(("sigma", "period"), [(0.0, 1), (0.05, 1), (0.06, 2), (0.1, 2), (0.2, 4), (0.5, 10), (1.0, 20)])
def test_section4_uniform_start_retriggers_every_max_1_cstar_steps(sigma, period):
    """At the uniform fixed point a robot re-polls every max(1, ceil(2 sigma / (omega dt))) steps."""
    angles = [15.0 + 60.0 * i for i in range(6)]
    text = scenario_toml(AUTHORS_VERTICES, AUTHORS_TARGET, 6, angles, strategy="self", sigma_deg=sigma, max_steps=61)
    history = engine.run(resolve(parse_scenario(text)), record_positions=False)
    polled = history.triggers[:, 0] != 0  # (61, 6)
    expected = (np.arange(61) % period) == 0
    np.testing.assert_array_equal(polled, np.repeat(expected[:, None], 6, axis=1))
    np.testing.assert_allclose(history.angles[-1, 0], history.angles[0, 0], rtol=0, atol=1e-12)


# ---------------------------------------------------------------------------- oracle 10
@pytest.mark.slow
@pytest.mark.parametrize("robots", range(3, 13))
def test_oracle10_convergence_from_random_starts(robots):
    seeds = range(100 * robots, 100 * robots + 20)
    for strategy, sigmas in (("self", (0.0, 0.1, 0.5)), ("constant", (0.0,))):
        for sigma in sigmas:
            scenario = random_start(robots=robots, strategy=strategy, sigma_deg=sigma, max_steps=2500)
            assert scenario.start_angles(seeds[0]).shape == (robots,)
            assert math.degrees(scenario.threshold) == pytest.approx(0.1 * robots, rel=1e-12)
            history = run_batch(scenario, seeds)
            assert history.ctime.min() >= 1, (strategy, sigma, history.ctime)
            assert history.ctime.max() <= 2000, (strategy, sigma, history.ctime)
            assert np.all(ccw_gaps(history.angles).min(axis=-1) > 0)  # order kept in every trial


# ---------------------------------------------------------------------------- stationary experiment (section 14)
def test_stationary_experiment_self_triggered_saves_communication():
    results = {}
    for strategy in ("self", "constant"):
        history = run_batch(random_start(strategy=strategy), range(30))
        assert history.angles.shape[1:] == (30, 6)
        assert np.all(history.ctime > 0), history.ctime
        results[strategy] = history
    assert np.all(results["constant"].com_bar == 1.0)
    ratio = np.mean(results["self"].com_bar) / np.mean(results["constant"].com_bar)
    assert ratio < 0.30
    # same starts for both strategies (seeded by trial seed only)
    np.testing.assert_array_equal(results["self"].angles[0], results["constant"].angles[0])


# ---------------------------------------------------------------------------- authors' quadrilateral with v_max
def test_authors_quadrilateral_speed_cap():
    scenario = load_scenario("authors-quadrilateral")
    assert scenario.control.omega_max == pytest.approx(0.016059, rel=1e-3)
    assert scenario.v_max == 1.0
    history = engine.run(scenario, steps=300)
    region = scenario.region
    s = region.arc_length(history.positions[:, 0])
    moved = np.abs(np.mod(np.diff(s, axis=0) + region.perimeter / 2, region.perimeter) - region.perimeter / 2)
    assert moved.max() <= scenario.v_max * scenario.control.dt * (1 + 1e-9)
    assert np.abs(np.diff(history.angles[:, 0], axis=0)).max() <= scenario.control.omega_max * scenario.control.dt * (1 + 1e-9)


@pytest.mark.parametrize(("name", "strategy", "estimation"), [
    ("authors-moving", "self", "decentralized"),
    ("authors-moving", "belief", "decentralized"),
    ("authors-moving", "relay", "decentralized"),
    ("authors-moving", "constant", "centralized"),
    ("paper-stationary", "self", None),
])
def test_a_trial_is_the_same_alone_and_in_any_batch(name, strategy, estimation):
    """Studies cut their trials into batches (and workers) as they like: a trial's history, bit for
    bit, does not depend on the other trials of its batch."""
    overrides = {"strategy": strategy} | ({"estimation": estimation} if estimation else {})
    scenario = load_scenario(name, **overrides, max_steps=150)
    together = engine.run(scenario, [4, 5, 6, 7], record_positions=True)
    for index, seed in enumerate([4, 5, 6, 7]):
        alone = engine.run(scenario, [seed], record_positions=True)
        for field in ("angles", "positions", "triggers", "offsets", "cerr_true", "terr", "estimates", "sent",
                      "sent_bytes", "energy"):
            np.testing.assert_array_equal(getattr(together, field)[:, index], getattr(alone, field)[:, 0], field)
