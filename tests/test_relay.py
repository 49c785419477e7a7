"""Ranges relayed around the ring (agents/relay.py, the ``relay`` strategy), the information-form
update they use (agents/estimation.py RangeFilters.absorb) and the process noise fitted to a target's
motion (world/target.py matched_process_noise)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from ringtrack.agents import engine
from ringtrack.agents.estimation import RangeFilters
from ringtrack.agents.relay import RangeRelay, RobotRanges, late_variance
from ringtrack.bus.messages import (
    NONCE_BASE,
    SCHEMA,
    RangeReply,
    RangeRequest,
    encode,
    relay_message_bytes,
    relayed_range_bytes,
)
from ringtrack.tools.cli import main
from ringtrack.tools.runlog.log import history_from_log, read_log
from ringtrack.tools.team.plan import TeamPlan
from ringtrack.tools.team.spawn import spawn_team
from ringtrack.world.scenario import load_scenario
from ringtrack.world.scenario_generator import scenario_text
from ringtrack.world.target import Circle, RandomWalk, Stationary, matched_process_noise
from tests.helpers import engine_twin, lockstep_run

SIGMA = 0.2


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), batch=st.integers(1, 4), ranges=st.integers(1, 6))
def test_absorbing_ranges_of_one_variance_is_the_stacked_ekf_update(seed: int, batch: int, ranges: int) -> None:
    """With every variance sigma_z^2, the information-form update equals the Joseph-form stacked EKF
    update (the same linearisation point, another algebra)."""
    rng = np.random.default_rng(seed)
    mean = rng.uniform(-5, 5, (batch, 2))
    root = rng.normal(size=(batch, 2, 2))
    covariance = root @ root.transpose(0, 2, 1) + 0.05 * np.eye(2)
    positions = mean[:, None, :] + rng.uniform(1, 10, (batch, ranges, 1)) * np.stack(
        [np.cos(angle := rng.uniform(0, 2 * math.pi, (batch, ranges))), np.sin(angle)], axis=-1)
    measured = np.linalg.norm(positions - mean[:, None, :], axis=-1) + rng.normal(0, SIGMA, (batch, ranges))
    measured[rng.random((batch, ranges)) < 0.2] = np.nan  # missing ranges are skipped by both
    stacked, informed = (RangeFilters(mean, covariance, 0.0, SIGMA) for _ in range(2))
    stacked.update(positions, measured)
    informed.absorb(positions, measured, np.full(measured.shape, SIGMA**2))
    np.testing.assert_allclose(informed.mean, stacked.mean, rtol=0, atol=1e-9)
    np.testing.assert_allclose(informed.covariance, stacked.covariance, rtol=1e-8, atol=1e-12)


def test_a_late_range_is_widened_by_the_walk_since() -> None:
    assert late_variance(0.2, 0.01, np.array([0, 3]))[1] == pytest.approx(0.04 + 0.03)
    assert late_variance(0.2, 0.01, np.array([0]))[0] == pytest.approx(0.04)


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), robots=st.integers(3, 7), steps=st.integers(1, 30))
def test_every_range_reaches_a_filter_once_one_hop_per_message(seed: int, robots: int, steps: int) -> None:
    """Whatever messages reach whom, each filter takes each range at most once, only ranges some chain
    of messages carried to it, each with its age and widened variance; a range travels one hop per
    message, so a ring whose every link delivers every step hands every range to everyone within
    N / 2 steps."""
    rng = np.random.default_rng(seed)
    relay = RangeRelay(1, robots, steps + robots, window=1)
    still = np.zeros((robots, 2))  # means that do not move: no displacement to compensate
    positions = rng.uniform(-5, 5, (steps + robots + 1, 1, robots, 2))
    values = rng.uniform(1, 9, (steps + robots + 1, 1, robots))
    held = [{(robot, 0)} for robot in range(robots)]  # (source, step) pairs each robot could know: by hand
    taken: list[set[tuple[int, int]]] = [set() for _ in range(robots)]
    for step in range(1, steps + robots + 1):
        origins, ranges, variances = relay.take(step, still, SIGMA, 0.01)
        for robot in range(robots):
            for origin, value, variance in zip(origins[robot], ranges[robot], variances[robot], strict=True):
                if np.isnan(value):
                    continue
                (at,) = np.argwhere(values[:, 0] == value)  # which (step, source) it is
                pair = (int(at[1]), int(at[0]))
                assert pair in held[robot] and pair not in taken[robot] and pair[0] != robot
                np.testing.assert_array_equal(origin, positions[pair[1], 0, pair[0]])
                assert variance == pytest.approx(late_variance(SIGMA, 0.01, np.array([step - pair[1]]))[0])
                taken[robot].add(pair)
        relay.record(step, positions[step], values[step])
        for robot in range(robots):
            held[robot].add((robot, step))
        everyone = step > steps  # the last N steps: every link delivers
        from_predecessor = everyone | (rng.random((1, robots)) < 0.3)
        from_successor = everyone | (rng.random((1, robots)) < 0.3)
        before = [set(known) for known in held]
        for robot in range(robots):
            if from_predecessor[0, robot]:
                held[robot] |= before[(robot - 1) % robots]
            if from_successor[0, robot]:
                held[robot] |= before[(robot + 1) % robots]
        relay.hand_over(from_predecessor, from_successor)
    for robot in range(robots):  # everything up to the step a full half-ring ago has arrived and been taken
        expected = {(source, step) for source in range(robots) if source != robot
                    for step in range(1, steps + 1)}
        assert expected <= taken[robot]


def test_late_ranges_are_moved_by_the_drift_of_the_mean() -> None:
    """A robot whose mean drifted 0.1 m a step over the window moves a range taken 3 steps ago by
    0.3 m: the target has moved that far since, by its own estimate."""
    relay = RangeRelay(1, 2, 10, window=2)
    relay.record(1, np.array([[[0.0, 0.0], [5.0, 0.0]]]), np.array([[1.0, 2.0]]))
    relay.hand_over(np.array([[True, True]]), np.array([[False, False]]))
    for step, x in ((2, 0.0), (3, 0.1)):
        relay.take(step, np.array([[x, 0.0], [0.0, 0.0]]), SIGMA, 0.0)
        relay.applied[:] = 0  # keep robot 0 waiting for robot 1's range
        relay.applied[0, 1, 1] = relay.applied[0, 0, 0] = 1
    origins, ranges, _ = relay.take(4, np.array([[0.2, 0.0], [0.0, 0.0]]), SIGMA, 0.0)
    assert ranges[0, 1] == 2.0
    np.testing.assert_allclose(origins[0, 1], [5.0 + 3 * 0.1, 0.0])


def test_the_process_noise_fitted_to_the_motion() -> None:
    walk = RandomWalk(position=(0.0, 0.0), speed_std=0.3)
    assert matched_process_noise(walk, 0.1, 6, SIGMA) == pytest.approx(0.03**2)
    circle = Circle(centre=(0.0, 0.0), speed=0.1, angular_speed=0.1)
    drift, information = 0.01, 6 / (2 * SIGMA**2)  # m a step; m^-2 a step per axis
    assert matched_process_noise(circle, 0.1, 6, SIGMA) == pytest.approx(drift ** (4 / 3) / information ** (1 / 3))
    assert matched_process_noise(Stationary(position=(0.0, 0.0)), 0.1, 6, SIGMA) == 0.0


def test_auto_process_noise_is_derived_when_a_scenario_loads(tmp_path: Path) -> None:
    (tmp_path / "walk.toml").write_bytes(scenario_text(0, 1))  # generated scenario 1: a random walk
    scenario = load_scenario(str(tmp_path / "walk.toml"))
    spec = scenario.spec
    assert spec.estimation.process_noise == "auto" and isinstance(spec.target, RandomWalk)
    assert scenario.estimation.process_noise == pytest.approx((spec.target.speed_std * spec.control.dt) ** 2)


def test_relayed_ranges_track_as_well_as_the_centralized_filter(tmp_path: Path) -> None:
    """On a generated scenario (a random walk, process noise fitted to it), decentralized robots that
    relay ranges on the self-triggered polls track within 1.2x of the centralized filter on the same
    runs, where robots that share beliefs by covariance intersection do not."""
    (tmp_path / "walk.toml").write_bytes(scenario_text(0, 1))  # generated scenario 1: a random walk
    path = str(tmp_path / "walk.toml")
    settled = slice(300, None)

    def terr(strategy: str, estimation: str) -> float:
        scenario = load_scenario(path, strategy=strategy, estimation=estimation, max_steps=900)
        return float(engine.run(scenario, [0, 1], record_positions=False).terr[settled].mean())

    central = terr("self", "centralized")
    assert terr("relay", "decentralized") <= 1.2 * central < terr("belief", "decentralized")


@settings(max_examples=40, deadline=None)
@given(step=st.integers(1, 70000), sender=st.integers(0, 200), receiver=st.integers(0, 200),
       known=st.lists(st.integers(0, 70000), min_size=1, max_size=20),
       ranges=st.lists(st.tuples(st.integers(0, 200), st.integers(1, 70000), st.booleans()), max_size=40))
def test_relay_messages_are_counted_exactly(step: int, sender: int, receiver: int, known: list[int],
                                            ranges: list[tuple[int, int, bool]]) -> None:
    """The engine's sizes of relay requests and replies equal their encoded bytes."""
    entries = [(source, at, 1.5, -2.25, 3.0 if measured else None) for source, at, measured in ranges]
    entry_bytes = sum(int(relayed_range_bytes(source, at, measured)) for source, at, measured in ranges)
    request = RangeRequest(SCHEMA, NONCE_BASE, step, sender, receiver, NONCE_BASE + 7, known, entries)
    reply = RangeReply(SCHEMA, NONCE_BASE, step, sender, receiver, NONCE_BASE + 7, (0.5, 1.5), None, None, known,
                       entries)
    for kind, message in (("request", request), ("reply", reply)):
        assert relay_message_bytes(kind, step, sender, receiver, np.array(known), len(entries),
                                   entry_bytes) == len(encode(message))


def test_a_process_relays_what_the_engine_relays() -> None:
    """A robot process's relay memory (agents.relay.RobotRanges) fed the engine's messages takes the
    same late ranges, bit for bit, and builds messages of the sizes the engine counts."""
    rng = np.random.default_rng(3)
    robots, steps = 5, 40
    relay = RangeRelay(1, robots, steps, window=3)
    nodes = [RobotRanges(robot, robots, window=3) for robot in range(robots)]
    means = rng.uniform(-1, 1, (steps + 1, robots, 2))
    for step in range(1, steps + 1):
        late = relay.take(step, means[step], SIGMA, 0.01)
        positions, values = rng.uniform(-5, 5, (1, robots, 2)), rng.uniform(1, 9, (1, robots))
        values[rng.random((1, robots)) < 0.2] = np.nan
        for robot, node in enumerate(nodes):
            origins, ranges, variances = node.take(step, means[step, robot], SIGMA, 0.01)
            # the engine pads with NaN (as a range beyond sensing reads): the ranges are the same, in order
            mask = ~np.isnan(late[1][robot])
            kept = ~np.isnan(ranges[0])
            np.testing.assert_array_equal(ranges[0][kept], late[1][robot][mask])
            np.testing.assert_array_equal(origins[0][kept], late[0][robot][mask])
            np.testing.assert_array_equal(variances[0][kept], late[2][robot][mask])
            value = None if np.isnan(values[0, robot]) else float(values[0, robot])
            node.record(step, (float(positions[0, robot, 0]), float(positions[0, robot, 1])), value)
        relay.record(step, positions, values)
        request_bytes, reply_bytes = relay.message_bytes(step)
        polled = rng.random(robots) < 0.4
        from_predecessor = np.zeros((1, robots), dtype=bool)
        from_successor = np.zeros((1, robots), dtype=bool)
        for robot in map(int, np.flatnonzero(polled)):
            for side, neighbour in enumerate(((robot - 1) % robots, (robot + 1) % robots)):
                node, other = nodes[robot], nodes[neighbour]
                known, ranges = node.carried(step, neighbour, node.told.get(neighbour))
                request = RangeRequest(SCHEMA, NONCE_BASE, step, robot, neighbour, NONCE_BASE, known, ranges)
                assert len(encode(request)) == request_bytes[0, robot, side]
                other.hear(robot, step, known, ranges)
                base = [max(a, b) for a, b in zip(other.told.get(robot, known), known, strict=True)]
                known_back, back = other.carried(step, robot, base)
                reply = RangeReply(SCHEMA, NONCE_BASE, step, neighbour, robot, NONCE_BASE, (0.0, 0.0), None, None,
                                   known_back, back)
                assert len(encode(reply)) == reply_bytes[0, robot, side]
                node.hear(neighbour, step, known_back, back)
                (from_predecessor if side == 0 else from_successor)[0, robot] = True
                (from_successor if side == 0 else from_predecessor)[0, neighbour] = True
        relay.hand_over(from_predecessor, from_successor)


@pytest.mark.processes
@pytest.mark.timeout(120)
def test_ringtrack_spawn_runs_the_relay_strategy(tmp_path: Path, capsys) -> None:
    """The command line no longer refuses the strategy: a team of processes runs it."""
    assert main(["spawn", "authors-moving", "--strategy", "relay", "--steps", "5", "--runs", str(tmp_path),
                 "--no-dashboard"]) == 0
    assert "spawn: 5 steps at" in capsys.readouterr().out


@pytest.mark.processes
@pytest.mark.timeout(240)
@pytest.mark.parametrize("drop", [0.0, 0.2])
def test_a_lockstep_team_relays_ranges_like_the_engine(tmp_path: Path, drop: float) -> None:
    """Robots that relay ranges in their requests and replies (RangeRequest, RangeReply) equal the
    engine trigger for trigger, estimate for estimate, byte for byte and joule for joule over 300
    steps, with and without lost messages."""
    steps = 300
    team = load_scenario("authors-moving", strategy="relay", estimation="decentralized", max_steps=steps, drop=drop)
    result, log = lockstep_run(team, tmp_path)
    logged, twin = history_from_log(log), engine_twin(log)
    assert logged.steps == twin.steps == steps
    assert np.array_equal(logged.triggers, twin.triggers)
    assert logged.estimates is not None and twin.estimates is not None
    assert np.array_equal(logged.estimates, twin.estimates)
    assert np.array_equal(logged.covariances, twin.covariances, equal_nan=True)
    assert np.max(np.abs(logged.angles - twin.angles)) < 1e-9
    assert twin.sent_bytes is not None
    assert np.array_equal(np.array([record["sent_bytes"] for record in log.steps]), twin.sent_bytes[:, 0])
    assert result.bytes["robot"] == int(twin.sent_bytes.sum())
    assert twin.energy is not None  # the radio energy of those bytes, per robot
    wire = np.array([result.energy.transmit_j, result.energy.receive_j]).T
    assert np.allclose(wire, twin.energy[:, 0].sum(axis=0), rtol=1e-9, atol=0.0)
    assert result.monitor_equals_senders is True
    kinds = result.by_kind
    polls = int((logged.triggers != 0).sum())
    if drop == 0.0:
        assert kinds["request"]["messages"] == kinds["reply"]["messages"] == 2 * polls
    else:
        assert engine.fault_totals(twin)["dropped"] > 0


@pytest.mark.processes
@pytest.mark.realtime
@pytest.mark.timeout(300)
def test_a_realtime_team_relays_ranges_and_tracks_like_the_engine(tmp_path: Path) -> None:
    """Realtime robots relaying ranges track within 10 % of the engine's mean Terr after step 300 on
    the same scenario and seed (asynchronous: a loaded machine may make robots miss steps, so only
    the tracking is compared)."""
    steps = 450  # at the scenario's own pace (rate 1: a step every dt = 0.1 s), 45 s
    team = load_scenario("authors-moving", strategy="relay", estimation="decentralized", max_steps=steps)
    result = spawn_team(TeamPlan(scenario=team, clock="realtime", rate=1.0, runs=tmp_path, dashboard=False))
    assert result.exit_code == 0
    log = read_log(Path(result.log))
    assert len(log.steps) == steps
    logged = history_from_log(log)
    twin = engine.run(team, seeds=log.header["seed"], steps=steps, record_positions=False)
    settled = slice(300, None)
    assert abs(float(np.nanmean(logged.terr[settled])) - float(twin.terr[settled].mean())) <= \
        0.1 * float(twin.terr[settled].mean())
