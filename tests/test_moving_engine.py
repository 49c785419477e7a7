"""agents/engine.py with a moving target (docs/algorithms.md sections 5, 7, 8, 9 and the moving-target
sanity values of section 14) on scenarios/authors-moving.toml."""

from __future__ import annotations

from functools import cache

import numpy as np
import pytest

from ringtrack.agents import engine
from ringtrack.agents.centre import FusionCentre
from ringtrack.agents.estimation import Estimators
from ringtrack.bus.messages import SCHEMA, RangeReport
from ringtrack.world.scenario import load_scenario
from ringtrack.world.sensing import RangeSensor
from tests.helpers import SENSING_RANGE, short_sighted

SEEDS = [0, 1, 2]
STEPS = 400
SETTLED = 100  # steps 1..100 are the transient; statistics over steps 101..STEPS


def run(estimation: str, strategy: str, steps: int = STEPS) -> engine.History:
    scenario = load_scenario("authors-moving", estimation=estimation, strategy=strategy)
    assert scenario.moving
    return engine.run(scenario, seeds=SEEDS, steps=steps, record_positions=True)


@pytest.fixture(scope="module")
def centralized_self() -> engine.History:
    return run("centralized", "self")


@pytest.fixture(scope="module")
def centralized_constant() -> engine.History:
    return run("centralized", "constant")


@pytest.fixture(scope="module")
def decentralized_self() -> engine.History:
    return run("decentralized", "self")


def neighbour_disagreement(history: engine.History) -> np.ndarray:
    """Mean over steps and robots of ||o_i - o_{i+1}||, the distance between neighbouring robots'
    estimates (per trial, metres)."""
    estimates = history.estimates
    assert estimates is not None
    return np.linalg.norm(estimates - np.roll(estimates, -1, axis=2), axis=-1).mean(axis=(0, 2))


def poll_rate(history: engine.History) -> np.ndarray:
    """Fraction of robot-steps in which a robot polled its neighbours, per trial."""
    return (history.triggers != 0).mean(axis=(0, 2))


# ---------------------------------------------------------------------------- (d) Terr is what section 5 defines
@pytest.mark.parametrize("mode", ["centralized", "decentralized"])
def test_terr_is_the_mean_distance_of_the_estimates(mode, centralized_self, decentralized_self):
    """Section 5: Terr = ||o_hat - o|| (centralized), (1/N) sum_i ||o_hat_i - o|| (decentralized)."""
    history = centralized_self if mode == "centralized" else decentralized_self
    assert history.estimates.shape == (STEPS, len(SEEDS), 6, 2)
    assert history.targets.shape == (STEPS, len(SEEDS), 2)
    expected = np.linalg.norm(history.estimates - history.targets[:, :, None, :], axis=-1).mean(axis=-1)
    np.testing.assert_allclose(history.terr, expected, rtol=0, atol=1e-12)
    # the targets are the scenario's circle, the same for every trial
    path = history.scenario.target_path(0, STEPS)
    for trial in range(len(SEEDS)):
        np.testing.assert_array_equal(history.targets[:, trial], path)
    if mode == "centralized":  # one fusion centre: every robot steers by the same estimate
        np.testing.assert_array_equal(history.estimates, np.repeat(history.estimates[:, :, :1], 6, axis=2))
        np.testing.assert_allclose(history.terr, np.linalg.norm(history.estimates[:, :, 0] - history.targets, axis=-1), atol=1e-12)
    else:  # robots keep their own estimates
        assert np.linalg.norm(history.estimates - history.estimates[:, :, :1], axis=-1).max() > 1e-3
    # estimates are where the robots steer: inside the region
    assert np.all(history.scenario.region.is_interior(history.estimates))


# ---------------------------------------------------------------------------- (a) centralized accuracy
def test_centralized_terr_below_spec_level(centralized_self):
    """Section 14: centralized Terr 0.137 m (mean over steps 300..1300); here below 0.2 m after step 100."""
    settled = centralized_self.terr[SETTLED:]
    assert np.all(settled.mean(axis=0) < 0.2)
    assert settled.mean() < 0.2
    # and not trivially: the error is that of a 0.2 m range noise, not zero
    assert settled.mean() > 0.02
    # the first step is an update from the prior at the true target with P0 = I: small already
    assert np.all(centralized_self.terr[0] < 0.5)


def test_centralized_estimate_tracks_the_moving_target(centralized_self):
    """The estimate follows the 1 m circle: it moves about as far as the target does over the run."""
    estimates = centralized_self.estimates[:, :, 0]
    targets = centralized_self.targets
    target_spread = np.linalg.norm(targets[SETTLED:] - targets[SETTLED:].mean(axis=0), axis=-1).mean(axis=0)
    estimate_spread = np.linalg.norm(estimates[SETTLED:] - estimates[SETTLED:].mean(axis=0), axis=-1).mean(axis=0)
    np.testing.assert_allclose(estimate_spread, target_spread, rtol=0.25)


# ---------------------------------------------------------------------------- (b) fusion makes neighbours agree
def test_fusion_makes_neighbouring_estimates_agree(decentralized_self, monkeypatch):
    """The decentralized estimates of neighbouring robots agree more with CI fusion than without
    (the same run with Estimators.fuse a no-op): one range each is rank-1 (section 7)."""
    monkeypatch.setattr(Estimators, "fuse", lambda self, told: None)
    unfused = run("decentralized", "self")
    fused_gap, unfused_gap = neighbour_disagreement(decentralized_self), neighbour_disagreement(unfused)
    assert np.all(fused_gap < unfused_gap)
    assert fused_gap.mean() < 0.6 * unfused_gap.mean()
    # the triggers really fused something: the runs differ, and fusion also lowers Terr
    assert not np.array_equal(decentralized_self.estimates, unfused.estimates)
    assert decentralized_self.terr[SETTLED:].mean() < unfused.terr[SETTLED:].mean()


def test_decentralized_fusion_happens_only_at_polls(decentralized_self, monkeypatch):
    """Section 7: CI fusion is done by the triggering robot only, with its own belief and both ring
    neighbours': one robot fusing per poll, each with two neighbour beliefs (step 1: every robot
    polls). Counting the robots fusing does not change the run."""
    assert np.all(decentralized_self.triggers[0] != 0)  # round 1 counts as a poll for everyone
    told_per_robot = []
    original = Estimators.fuse

    def counting(self, told):
        told_per_robot.extend(told.present.sum(axis=1)[told.present.any(axis=1)].tolist())
        original(self, told)

    monkeypatch.setattr(Estimators, "fuse", counting)
    history = run("decentralized", "self", steps=50)
    assert len(told_per_robot) == int((history.triggers != 0).sum())
    assert set(told_per_robot) == {2}  # own belief plus both ring neighbours
    np.testing.assert_array_equal(history.estimates, decentralized_self.estimates[:50])


# ---------------------------------------------------------------------------- (c) constant vs self-triggered
def test_self_triggered_tracks_as_well_as_constant_with_fewer_polls(centralized_self, centralized_constant):
    constant_terr = centralized_constant.terr[SETTLED:].mean(axis=0)
    self_terr = centralized_self.terr[SETTLED:].mean(axis=0)
    assert np.all(constant_terr < 0.2) and np.all(self_terr < 0.2)
    assert np.all((0.5 < self_terr / constant_terr) & (self_terr / constant_terr < 2.0))
    np.testing.assert_array_equal(poll_rate(centralized_constant), 1.0)  # constant: every robot every step
    assert np.all(poll_rate(centralized_self) < 0.3)  # section 14: Com-bar self ~ 0.10-0.14
    assert np.all(poll_rate(centralized_self) > 0.0)


# ---------------------------------------------------------------------------- section 14 reference values (1300 rounds)
@cache
def reference_run(estimation: str, strategy: str, seeds: tuple[int, ...] = tuple(SEEDS)) -> engine.History:
    """The scenario's full 1300 rounds, run once for the tests of this section that share it."""
    scenario = load_scenario("authors-moving", estimation=estimation, strategy=strategy)
    return engine.run(scenario, seeds=list(seeds), record_positions=False)


@pytest.mark.slow
def test_section14_centralized_terr_reference():
    """Section 14: centralized Terr 0.137 m as the mean over rounds 300..1300 (constant and self alike)."""
    for strategy in ("self", "constant"):
        history = reference_run("centralized", strategy)
        assert history.steps == 1300
        assert history.terr[299:].mean() == pytest.approx(0.137, rel=0.2)


@pytest.mark.slow
def test_decentralized_tracking_against_centralized():
    """The decentralized reference of docs/algorithms.md section 14 (0.437 m) is not reproduced (see docs/results.md: the
    self-triggered robots poll 3-7 % of steps and single-range beliefs drift between polls). What is
    asserted is what docs/results.md reports: decentralized filters fused every step (constant strategy)
    track as well as 0.3 m, and self-triggered decentralized tracking is worse than centralized, as
    in the paper. Fusing every step is one CI per robot and step, the costliest run of the suite: it
    runs the first seed only (the figure of docs/results.md, 0.172 m from step 300, is of that seed)."""
    fused_every_step = reference_run("decentralized", "constant", seeds=tuple(SEEDS[:1]))
    assert fused_every_step.steps == 1300
    assert fused_every_step.terr[299:].mean() < 0.3
    decentralized, centralized = reference_run("decentralized", "self"), reference_run("centralized", "self")
    assert decentralized.terr[299:].mean() > 2 * centralized.terr[299:].mean()


# ---------------------------------------------------------------------------- a trilateration prior without a fix
def test_trilateration_prior_without_a_fix_at_step_one():
    """With a short sensing range fewer than three robots may measure at step 1: the engine does not
    fail, the centre starts from the uninformative prior, and the team still finds and tracks the
    target (and the fusion centre, fed the same ranges, estimates exactly what the engine does)."""
    scenario = short_sighted("centralized", "trilateration")
    history = engine.run(scenario, seeds=SEEDS, steps=300)
    in_range = np.linalg.norm(history.positions - history.targets[:, :, None, :], axis=-1) <= SENSING_RANGE
    without_fix = np.flatnonzero(in_range[0].sum(axis=-1) < 3)
    assert len(without_fix) > 0
    assert np.all(np.nanmean(history.terr[100:], axis=0) < 0.5)
    for trial in without_fix:
        seed = SEEDS[trial]
        centre = FusionCentre(scenario, run=1)
        sensor = RangeSensor(scenario.spec.sensing.range_sigma, SENSING_RANGE, seed)
        for step in range(1, 41):
            positions = history.positions[step - 1, trial]
            ranges = sensor.measure(positions, history.targets[step - 1, trial])
            reports = [RangeReport(SCHEMA, 1, step, robot, tuple(position), None if np.isnan(z) else float(z))
                       for robot, (position, z) in enumerate(zip(positions, ranges, strict=True))]
            (estimate,) = [estimate for report in reports for estimate in centre.on_report(report)]
            steered = scenario.region.clamp_interior(np.array(estimate.mean), scenario.estimation.margin)
            np.testing.assert_array_equal(steered, history.estimates[step - 1, trial, 0])  # as a robot steers
