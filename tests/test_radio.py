"""The radio model: loss with distance, exact wire sizes, and the energy of every message."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from ringtrack.agents import engine
from ringtrack.bus.faults import (
    FAULT_COUNTERS,
    REASONS,
    Fate,
    FaultCounter,
    FaultPlan,
    LinkRates,
    Outage,
    link,
    request_traffic,
)
from ringtrack.bus.messages import SCHEMA, Reply, Request, encode, robot_message_bytes
from ringtrack.bus.radio import Radio, airtime_s, loss_probability, message_bits, receive_energy, transmit_energy
from ringtrack.world.ranges import link_distance
from ringtrack.world.scenario import ScenarioError, load_scenario

LOSSY = Radio(model="log-distance", sensitivity_dbm=-68.0, shadowing_db=3.0)
SCENARIOS = Path(__file__).parents[1] / "scenarios"


def lossy_scenario(tmp_path: Path, sections: str = "", radio: str = "") -> Path:
    """paper-stationary with more ``sections`` and a lossy log-distance radio (with more ``radio`` keys)."""
    path = tmp_path / "lossy.toml"
    path.write_text((SCENARIOS / "paper-stationary.toml").read_text() + "\n" + sections
                    + '\n[radio]\nmodel = "log-distance"\nsensitivity_dbm = -68.0\nshadowing_db = 3.0\n' + radio)
    return path


def stated_loss(radio: Radio, distance: float) -> float:
    """The documented model, integrated independently on a fine grid of the shadowing X:
    E[1 / (1 + exp((P_tx - PL(d0) - 10 n log10(d / d0) - X - S) / w))], X ~ N(0, shadowing_db^2)."""
    x = np.linspace(-10 * radio.shadowing_db, 10 * radio.shadowing_db, 200001)
    density = np.exp(-0.5 * (x / radio.shadowing_db) ** 2) / (radio.shadowing_db * math.sqrt(2 * math.pi))
    received = radio.tx_power_dbm - radio.path_loss_d0_db - 10 * radio.exponent * math.log10(distance / radio.d0_m) - x
    per = 1.0 / (1.0 + np.exp((received - radio.sensitivity_dbm) / radio.transition_db))
    return float(np.sum(per * density) * (x[1] - x[0]))


@pytest.mark.parametrize("distance", [4.0, 8.5, 14.0])
def test_log_distance_loss_probability_is_its_formula_at_three_distances(distance: float) -> None:
    expected = stated_loss(LOSSY, distance)
    assert float(loss_probability(LOSSY, distance)) == pytest.approx(expected, abs=1e-9)
    # and the fault layer loses messages over such links at that rate (20000 keyed draws: 10 links of
    # that length, 2000 steps; each step's messages decided as one batch, as the engine does)
    plan = FaultPlan(seed=5, radio=LOSSY)
    senders = np.arange(0, 20, 2)
    lost = np.mean([plan.decide("request", senders, senders + 1, step, distance).reason == REASONS.index("radio")
                    for step in range(1, 2001)])
    assert abs(lost - expected) < 4 * math.sqrt(expected * (1 - expected) / 20000) + 1e-4


def test_loss_rises_with_distance_and_ideal_or_disk_never_lose() -> None:
    distances = np.array([1.0, 5.0, 8.0, 10.0, 20.0, 60.0])
    loss = loss_probability(LOSSY, distances)
    assert np.all(np.diff(loss) > 0) and loss[0] < 1e-6 and loss[-1] > 0.999
    for model in ("ideal", "disk"):
        assert not loss_probability(Radio(model=model), distances).any()
        assert not FaultPlan(radio=Radio(model=model)).active


def test_shadowing_is_one_draw_per_link_and_step() -> None:
    """Both directions and both kinds of a link see the same shadowing: with a PER of exactly 0 or
    1 apart from it (a step transition), a request and the reply over a link share their fate."""
    sharp = Radio(model="log-distance", sensitivity_dbm=-68.0, shadowing_db=6.0, transition_db=1e-6)
    plan = FaultPlan(seed=2, radio=sharp)
    steps = np.arange(1, 5001)
    forth = np.array([plan.fate("request", 3, 4, int(step), 10.0).dropped for step in steps])
    back = np.array([plan.fate("reply", 4, 3, int(step), 10.0).dropped for step in steps])
    assert np.array_equal(forth, back) and 0.2 < forth.mean() < 0.8


def test_batch_fates_equal_the_one_message_fates() -> None:
    plan = FaultPlan(seed=9, default=LinkRates(drop=0.2, duplicate=0.3, delay_s=0.01, jitter_s=0.01),
                     links={link(0, 1): LinkRates(drop=0.9)}, outages=(Outage(frozenset({link(2, 3)}), 3, 6),),
                     radio=LOSSY)
    senders, receivers = np.array([0, 1, 2, 3, 4, 5]), np.array([1, 0, 3, 2, 5, 4])
    distances = np.array([3.0, 3.0, 9.0, 9.0, 11.0, 11.0])
    for step in range(1, 12):
        batch = plan.decide("reply", senders, receivers, step, distances)
        for index, (sender, receiver) in enumerate(zip(senders, receivers, strict=True)):
            one = plan.fate("reply", int(sender), int(receiver), step, float(distances[index]))
            assert one.dropped == bool(batch.dropped[index]) and (one.dropped or one.copies == batch.copies[index])
            assert one.dropped or one.delay_s == batch.delay_s[index]


def test_the_batch_exchange_counts_every_message_as_a_robot_fault_layer_does() -> None:
    """engine.exchange (a step of every trial at once) against FaultCounter and request_traffic
    applied one message at a time, as a robot's fault layer does, with drops, copies, delays, a
    lossy radio and unreachable neighbours."""
    plan = FaultPlan(seed=4, default=LinkRates(drop=0.3, duplicate=0.3, delay_s=0.01, jitter_s=0.01), radio=LOSSY)
    rng = np.random.default_rng(1)
    trials, robots = 4, 7
    for step in range(1, 25):
        polled = rng.random((trials, robots)) < 0.5
        reach_minus = rng.random((trials, robots)) < 0.8  # the link to the predecessor, both ways
        distance_minus = rng.uniform(2.0, 14.0, (trials, robots))
        reach_plus, distance_plus = np.roll(reach_minus, -1, axis=1), np.roll(distance_minus, -1, axis=1)
        outcome = engine.exchange(plan, step, polled, reach_minus, reach_plus, distance_minus, distance_plus)
        for trial in range(trials):
            counter, published = FaultCounter(), 0
            for robot in range(robots):
                for side, reach, distance in ((-1, reach_minus, distance_minus), (1, reach_plus, distance_plus)):
                    reachable = bool(reach[trial, robot])
                    if reachable and not polled[trial, robot]:
                        continue
                    neighbour, metres = (robot + side) % robots, float(distance[trial, robot])
                    fate = plan.fate("request", robot, neighbour, step, metres) if reachable else \
                        Fate(dropped=True, reason="range")
                    copies = 0 if fate.dropped else fate.copies
                    counter.count_sent(copies)
                    counter.count_fate(fate)
                    counter.count_delivered(copies)
                    published += request_traffic(fate)
                    answer = plan.fate("reply", neighbour, robot, step, metres)
                    for _ in range(copies):
                        counter.count_sent(1)
                        counter.count_fate(answer)
                        counter.count_delivered(0 if answer.dropped else answer.copies)
            assert outcome.faults[trial].tolist() == [counter.counts[name] for name in FAULT_COUNTERS]
            assert counter.counts["published"] == published == int(engine.ring_traffic(outcome.requests[trial]).sum())


def test_a_step_without_faults_is_settled_as_the_fault_layer_settles_it() -> None:
    """engine.exchange's shortcut for a step no fault can touch (a clean plan, every neighbour in
    reach, no push) gives what the full settlement gives under a plan that is active but touches
    nothing (an outage of a step long past): the same polls, counts, bytes and joules, bit for bit."""
    clean = FaultPlan()
    idle = FaultPlan(outages=(Outage(frozenset({link(0, 1)}), 1, 1),))
    assert not clean.active and idle.active
    rng = np.random.default_rng(5)
    trials, robots = 3, 6
    every = np.ones((trials, robots), dtype=bool)
    for step in range(2, 40):
        polled = rng.random((trials, robots)) < 0.4
        distance_minus = rng.uniform(2.0, 14.0, (trials, robots))
        distance_plus = np.roll(distance_minus, -1, axis=1)
        for belief in (False, True):
            fast, full = (engine.exchange(plan, step, polled, every, every, distance_minus, distance_plus,
                                          belief=belief) for plan in (clean, idle))
            for name in ("fresh_minus", "fresh_plus", "requests", "faults", "probes", "sent_bytes", "energy",
                         "pushes", "push_delivered"):
                assert np.array_equal(getattr(fast, name), getattr(full, name)), name
                assert getattr(fast, name).dtype == getattr(full, name).dtype, name


@pytest.mark.parametrize("step", [1, 127, 128, 255, 256, 65535, 65536])
def test_wire_sizes_are_exact(step: int) -> None:
    for sender, receiver in ((0, 1), (127, 128), (300, 70000)):
        request = Request(SCHEMA, 2**31 + 12345, step, sender, receiver, 2**32 - 1)
        assert robot_message_bytes("request", step, sender, receiver) == len(encode(request))
        for belief in (False, True):
            extra = ((1.5, -2.0), (0.1, 0.0, 0.2)) if belief else (None, None)
            reply = Reply(SCHEMA, 2**31, step, sender, receiver, 2**31 + 7, (3.25, 17.0), *extra)
            assert robot_message_bytes("reply", step, sender, receiver, belief) == len(encode(reply))


def reference_energy(history: engine.History, trial: int = 0) -> np.ndarray:
    """Each robot's energy (transmit, receive) as the sum over every message of the run of the
    first-order formula, enumerated one message at a time from the run's polls and positions with
    the one-message fates and the encoded size of the actual message."""
    scenario = history.scenario
    plan, radio, robots = scenario.faults, scenario.faults.radio, scenario.robots
    belief = scenario.estimation.mode == "decentralized"
    limit = scenario.communication_range or math.inf
    energy = np.zeros((robots, 2))
    assert history.positions is not None
    for row in range(history.steps):
        step, positions = row + 1, history.positions[row, trial]
        for robot in range(robots):
            for neighbour in ((robot - 1) % robots, (robot + 1) % robots):
                distance = float(link_distance(positions[robot], positions[neighbour]))
                reachable = distance <= limit
                if not (history.triggers[row, trial, robot] or not reachable):
                    continue
                request = Request(SCHEMA, 2**31, step, robot, neighbour, 2**31)
                request_bits = 8 * (len(encode(request)) + radio.overhead_bytes)
                fate = plan.fate("request", robot, neighbour, step, distance)
                if not reachable or fate.dropped:
                    energy[robot, 0] += radio.e_elec * request_bits + radio.eps_amp * request_bits * distance**2
                    continue
                reply = Reply(SCHEMA, 2**31, step, neighbour, robot, 2**31, (0.0, 0.0),
                              *(((0.0, 0.0), (0.0, 0.0, 0.0)) if belief else (None, None)))
                reply_bits = 8 * (len(encode(reply)) + radio.overhead_bytes)
                answer = plan.fate("reply", neighbour, robot, step, distance)
                for _ in range(fate.copies):
                    energy[robot, 0] += radio.e_elec * request_bits + radio.eps_amp * request_bits * distance**2
                    energy[neighbour, 1] += radio.e_elec * request_bits
                    energy[neighbour, 0] += radio.e_elec * reply_bits + radio.eps_amp * reply_bits * distance**2
                    if not answer.dropped:
                        energy[robot, 1] += answer.copies * radio.e_elec * reply_bits
    return energy


@pytest.mark.parametrize(("sections", "radio"), [
    ("", ""),
    ("[faults]\ndrop = 0.2\nduplicate = 0.1\n[limits]\ncommunication_range = 8.5\n", "overhead_bytes = 12\n"),
])
def test_energy_of_a_run_is_the_sum_over_its_messages_of_the_formula(tmp_path: Path, sections: str,
                                                                      radio: str) -> None:
    history = engine.run(load_scenario(str(lossy_scenario(tmp_path, sections, radio)), max_steps=250))
    assert history.energy is not None
    run_energy = history.energy[:, 0].sum(axis=0)
    assert np.allclose(run_energy, reference_energy(history), rtol=1e-12, atol=0.0)
    assert engine.fault_totals(history)["dropped"] > 0


def test_energy_formula_and_overhead() -> None:
    radio = Radio(e_elec=50e-9, eps_amp=100e-12, overhead_bytes=10)
    bits = message_bits(radio, 25)
    assert bits == 280
    assert transmit_energy(radio, bits, 8.0) == pytest.approx(280 * 50e-9 + 280 * 100e-12 * 64.0, rel=1e-15)
    assert receive_energy(radio, bits) == pytest.approx(280 * 50e-9, rel=1e-15)
    timed = Radio(model="log-distance", latency_s=0.002, bandwidth_bps=250e3, overhead_bytes=10)
    assert airtime_s(timed, 25) == pytest.approx(0.002 + 280 / 250e3, rel=1e-15)


def test_radio_section_is_validated(tmp_path: Path) -> None:
    path = tmp_path / "disk.toml"
    path.write_text((SCENARIOS / "paper-stationary.toml").read_text() + '\n[radio]\nmodel = "disk"\n')
    with pytest.raises(ScenarioError, match=r"radio.model = 'disk' needs limits.communication_range"):
        load_scenario(str(path))
    path.write_text((SCENARIOS / "paper-stationary.toml").read_text() + '\n[radio]\nmodel = "cable"\n')
    with pytest.raises(ScenarioError, match=r"radio.model: invalid enum value 'cable'; use one of 'ideal', 'disk'"):
        load_scenario(str(path))
    path.write_text((SCENARIOS / "paper-stationary.toml").read_text() + '\n[radio]\nexponent = -1\n')
    with pytest.raises(ScenarioError, match=r"radio.exponent: expected a finite number > 0"):
        load_scenario(str(path))


@pytest.mark.processes
def test_check_prints_each_ring_link_loss_probability(tmp_path: Path) -> None:
    import subprocess

    from ringtrack.world.ranges import link_lengths, uniform_link_requirement, uniform_ring
    from tests.helpers import RINGTRACK

    path = lossy_scenario(tmp_path)
    completed = subprocess.run([*RINGTRACK, "check", str(path)], capture_output=True, text=True, timeout=120,
                               env={"COLUMNS": "200", "PATH": "/usr/bin:/bin"})
    assert completed.returncode == 0, completed.stderr
    team = load_scenario(str(path))
    rotation = uniform_link_requirement(team.region, team.target, team.robots)[1]
    lengths = link_lengths(uniform_ring(team.region, team.target, team.robots, rotation))
    rows = {line.split()[0]: line.split() for line in completed.stdout.splitlines()
            if line.strip() and line.split()[0].count("-") == 1 and line.split()[0][0].isdigit()}
    assert len(rows) == team.robots
    for robot, length in enumerate(lengths):
        row = rows[f"{robot}-{(robot + 1) % team.robots}"]
        assert float(row[1]) == pytest.approx(length, abs=1e-4)
        assert float(row[2]) == pytest.approx(float(loss_probability(team.faults.radio, length)), rel=1e-3)


def test_dashboard_shows_the_team_energy_from_the_end_record() -> None:
    from rich.console import Console

    from ringtrack.tools.dashboard.dashboard import Dashboard
    from ringtrack.tools.monitor.state import TeamModel
    from tests.test_dashboard import prepared_records

    model = TeamModel(load_scenario("paper-stationary", robots=4), "lockstep")
    for record in prepared_records():
        model.add(record)
    model.add({"type": "end", "energy_j": {"r0": [0.001, 0.002], "r1": [0.004, 0.0]}})
    console = Console(width=160, record=True)
    console.print(Dashboard(model))
    assert "radio energy: team 7.00 mJ, per robot 3.00-4.00 mJ" in console.export_text()
