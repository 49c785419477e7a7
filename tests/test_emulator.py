"""Multi-process teams over Zenoh: each test starts its own processes and ends them."""

from __future__ import annotations

import json
import signal
import subprocess
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from ringtrack.agents import engine
from ringtrack.agents.engine import History, robot_to_robot_sent
from ringtrack.agents.summary import summarise
from ringtrack.bus.counting import per_link, totals_by_category
from ringtrack.bus.messages import EndReason, digest_entries
from ringtrack.tools.runlog.log import RunLog, history_from_log, read_log
from ringtrack.tools.team.plan import TeamPlan
from ringtrack.tools.team.spawn import spawn_team
from ringtrack.world.scenario import load_scenario
from tests.helpers import (
    RINGTRACK,
    SENSING_RANGE,
    assert_equals_engine,
    engine_twin,
    lockstep_run,
    processes_mentioning,
    scenario,
    short_sighted,
    start_spawn,
    stop_all,
    wait_for_steps,
)

pytestmark = [pytest.mark.processes, pytest.mark.timeout(240)]

STEPS = 300


@pytest.mark.parametrize("strategy", ["self", "constant"])
def test_lockstep_team_equals_the_engine(tmp_path: Path, strategy: str) -> None:
    result, log = lockstep_run(scenario(strategy=strategy, max_steps=STEPS), tmp_path)
    logged = assert_equals_engine(log)
    assert len(log.steps) == STEPS

    # Every role is its own OS process.
    pids = result.pids
    assert set(pids) == {"world", "monitor"} | {f"r{i}" for i in range(6)}
    assert len(set(pids.values())) == 8

    # Robot-to-robot traffic happens only at polls: 2 requests + 2 replies per poll, attributed to
    # the step and robot that sent them.
    polled = logged.triggers[:, 0] != 0
    sent = np.array([record["sent_messages"] for record in log.steps])
    assert np.array_equal(sent, robot_to_robot_sent(polled))
    assert result.messages["robot"] == 4 * int(polled.sum())
    assert result.outcome.triggers.total == int(polled.sum())
    if strategy == "constant":
        assert result.messages["robot"] == 4 * 6 * STEPS
    # The world serves one measurement per robot per step and gets one command back; it tells the
    # monitor each step's true state in a digest of up to ten steps (no tick of its own).
    kinds = result.by_kind
    assert kinds["measurement"]["messages"] == kinds["command"]["messages"] == 6 * STEPS
    assert STEPS // digest_entries(6) <= kinds["digest"]["messages"] <= STEPS and "tick" not in kinds


def test_monitor_totals_equal_senders_and_log(tmp_path: Path) -> None:
    _, log = lockstep_run(scenario(max_steps=150), tmp_path, audit=True)  # the monitor observes every message
    end = log.end
    assert end is not None and end["reason"] == "done" and end["late"] == 0 and end["rejected"] == {}
    seen = totals_by_category([tuple(row) for row in end["traffic"]])
    said = totals_by_category([tuple(row) for rows in end["senders"].values() for row in rows])
    assert set(end["senders"]) == {"world"} | {f"r{i}" for i in range(6)}
    for category in ("robot", "world"):
        assert seen[category] == said[category]
    assert end["consistent"] is True
    logged_messages = sum(sum(record["sent_messages"]) for record in log.steps)
    logged_bytes = sum(sum(record["sent_bytes"]) for record in log.steps)
    assert (logged_messages, logged_bytes) == (seen["robot"]["messages"], seen["robot"]["bytes"])


def test_digests_give_the_audited_log_without_copies_of_world_traffic(tmp_path: Path) -> None:
    # By default the monitor takes ticks, measurements and commands from the world's digests (up to ten
    # steps each) and receives no copy of them; with --audit it observes every message. The logs are
    # the same.
    team = scenario(max_steps=150)
    digested, digested_log = lockstep_run(team, tmp_path / "digest")
    audited, audited_log = lockstep_run(team, tmp_path / "audit", audit=True)
    assert 150 // digest_entries(6) <= digested.by_kind["digest"]["messages"] <= 150
    assert "tick" not in digested.by_kind and "digest" not in audited.by_kind
    assert audited.by_kind["tick"]["messages"] == 150
    assert digested_log.steps == audited_log.steps
    assert digested_log.end is not None and audited_log.end is not None
    assert digested_log.end["consistent"] is True and audited_log.end["consistent"] is True
    seen, audited_seen = (per_link([tuple(row) for row in log.end["traffic"]], ("robot", "world"))
                          for log in (digested_log, audited_log))
    assert seen == audited_seen
    assert_equals_engine(digested_log)


def test_two_runs_at_once_do_not_interfere(tmp_path: Path) -> None:
    runs = {"a": scenario(seed=1, robots=5, max_steps=200), "b": scenario(strategy="constant", seed=2, max_steps=200)}
    outcomes: dict[str, object] = {}
    spans: dict[str, tuple[float, float]] = {}

    def run(name: str) -> None:
        started = time.monotonic()
        try:
            outcomes[name] = lockstep_run(runs[name], tmp_path / name)
        except BaseException as error:  # reported below
            outcomes[name] = error
        spans[name] = (started, time.monotonic())

    threads = [threading.Thread(target=run, args=(name,)) for name in runs]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    for name in runs:
        outcome = outcomes[name]
        assert not isinstance(outcome, BaseException), outcome
        result, log = outcome
        assert_equals_engine(log)
        assert result.monitor_equals_senders is True
        assert result.outcome.robots == runs[name].robots
    assert outcomes["a"][0].run != outcomes["b"][0].run
    (a_start, a_end), (b_start, b_end) = spans["a"], spans["b"]
    overlap = min(a_end, b_end) - max(a_start, b_start)
    assert overlap > 0.5 * min(a_end - a_start, b_end - b_start)  # the two teams really ran at once


@pytest.mark.parametrize("stop", [signal.SIGINT, signal.SIGTERM], ids=["ctrl-c", "sigterm"])
def test_stop_leaves_no_process_and_a_readable_log(tmp_path: Path, stop: signal.Signals) -> None:
    process = start_spawn(tmp_path, "--steps", "100000")
    try:
        folder = wait_for_steps(tmp_path, 30)
        assert len(processes_mentioning(str(folder))) == 9  # world, monitor, 6 robots, the launcher that forked them
        sent_at = time.monotonic()
        process.send_signal(stop)
        slowest_poll = 0.0  # s: how late this process got the CPU back, what the load does to the supervisor too
        while processes_mentioning(str(folder)) and time.monotonic() - sent_at < 20:
            polled_at = time.monotonic()
            time.sleep(0.01)
            slowest_poll = max(slowest_poll, time.monotonic() - polled_at)
        team_gone_in = time.monotonic() - sent_at
        printed, complaints = (stream.decode() for stream in process.communicate(timeout=20))
        code = process.returncode
    finally:
        stop_all(process)
    assert code == 130
    # Each process says why it stopped: the supervisor forwards the signal it got.
    logged, said = {signal.SIGINT: ("interrupted (SIGINT)", "interrupted by the user (Ctrl-C)"),
                    signal.SIGTERM: ("interrupted (SIGTERM)", "terminated (SIGTERM)")}[stop]
    assert f"run: {said} after " in printed, printed  # the monitor's report
    assert f"ringtrack: run {said}; every process stopped" in complaints, complaints
    # The supervisor signals, then kills what is left after 1.5 s: the team is gone within 2 s, plus
    # twice the longest this test waited for the CPU meanwhile (a loaded machine delays both alike).
    assert team_gone_in < 2.0 + 2 * slowest_poll, f"the team took {team_gone_in:.2f} s to stop ({slowest_poll=:.2f} s)"
    print(f"{stop.name}: every process of the team gone {team_gone_in:.2f} s after the signal")
    assert processes_mentioning(str(folder)) == []
    log = read_log(folder / "log.jsonl")
    assert log.end["reason"] == logged
    steps = [record["step"] for record in log.steps]
    assert len(steps) >= 30 and steps == list(range(1, len(steps) + 1))
    assert_equals_engine(log)


def test_spawn_stops_at_convergence_like_the_engine(tmp_path: Path) -> None:
    team = scenario(robots=5, seed=4, max_steps=2000, omega_max_deg=3.0)
    result = spawn_team(TeamPlan(scenario=team, runs=tmp_path, dashboard=False, until_converged=True))
    twin = summarise(engine.run(team, until_converged=True, record_positions=False))
    assert result.exit_code == 0 and result.end_reason is EndReason.CONVERGED and result.outcome is not None
    for key in ("ctime", "com_bar", "steps", "triggers"):
        assert getattr(result.outcome, key) == getattr(twin, key), key


@pytest.mark.realtime
def test_realtime_team_runs_and_counts_every_message(tmp_path: Path) -> None:
    result = spawn_team(TeamPlan(scenario=scenario(max_steps=200), clock="realtime", rate=10.0, runs=tmp_path, dashboard=False))
    assert result.exit_code == 0 and result.end_reason == "done"
    assert result.monitor_equals_senders is True
    log = read_log(Path(result.log))
    assert len(log.steps) == 200
    # The world keeps its schedule: it never starts a step early, so 200 steps of 0.1 s at 10x take
    # at least 2 s (how much longer depends on the load; a loaded world drifts but never hurries).
    assert log.end["wall_s"] >= 0.99 * 199 * 0.1 / 10.0
    # Requests go out in pairs; a robot that falls behind the clock may abandon a poll when a newer
    # measurement arrives, so completed polls (those in commands) are a lower bound.
    completed = sum(1 for record in log.steps for trigger in record["trigger"] if trigger)
    requests = result.by_kind["request"]["messages"]
    replies = result.by_kind["reply"]["messages"]
    assert requests % 2 == 0
    assert 2 * completed <= replies <= requests
    # The team moves towards the uniform configuration about as fast per command as in lockstep,
    # where every robot commands every step: a loaded machine lets realtime robots command on fewer
    # steps (measured here as the share of robot-steps with a command), and the team gains less.
    cerr = history_from_log(log).cerr_true[:, 0]
    twin = engine_twin(log).cerr_true[:, 0]
    commanded = np.mean([trigger is not None for record in log.steps for trigger in record["trigger"]])
    assert commanded > 0
    assert cerr[0] - cerr[-1] > 0.5 * commanded * (twin[0] - twin[-1]) > 0


def test_a_team_assembled_by_hand_from_the_role_commands(tmp_path: Path) -> None:
    """``ringtrack world``, ``robot`` and ``monitor`` started one by one, as across hosts."""
    announce, log_path = tmp_path / "world.json", tmp_path / "log.jsonl"
    common = ["paper-stationary", "--robots", "4", "--seed", "7", "--steps", "120", "--run", "00c0ffee", "--monitor"]
    processes = [subprocess.Popen([*RINGTRACK, "world", *common, "--announce", str(announce)],
                                  stderr=subprocess.PIPE)]
    try:
        deadline = time.monotonic() + 30
        while not announce.exists():
            assert time.monotonic() < deadline and processes[0].poll() is None, "the world did not start"
            time.sleep(0.02)
        connect = ["--connect", json.loads(announce.read_text())["endpoints"][0]]
        processes.append(subprocess.Popen([*RINGTRACK, "monitor", *common, *connect, "--log", str(log_path),
                                           "--no-dashboard"], stdout=subprocess.PIPE))
        processes += [subprocess.Popen([*RINGTRACK, "robot", *common, *connect, "--id", str(robot)])
                      for robot in range(4)]
        codes = [process.wait(timeout=120) for process in processes]
    finally:
        for process in processes:
            if process.poll() is None:
                process.kill()
                process.wait()
    assert codes == [0] * 6
    log = read_log(log_path)
    assert len(log.steps) == 120 and log.end["consistent"] is True
    assert_equals_engine(log)
    monitor_output = processes[1].stdout.read().decode()
    assert "monitor vs senders: equal" in monitor_output
    assert "ringtrack.world: run done after 120 steps" in processes[0].stderr.read().decode()


@pytest.mark.parametrize("estimation", ["decentralized", "centralized"])
def test_moving_target_lockstep_equals_the_engine(tmp_path: Path, estimation: str) -> None:
    moving = load_scenario("authors-moving", estimation=estimation, max_steps=STEPS)
    result, log = lockstep_run(moving, tmp_path)
    logged = assert_tracks_like_the_engine(log)
    kinds = result.by_kind
    polls = int((logged.triggers != 0).sum())
    assert kinds["request"]["messages"] == kinds["reply"]["messages"] == 2 * polls
    if estimation == "decentralized":
        # replies carry the neighbour's belief: position, mean and covariance (7 floats of 9 bytes)
        assert kinds["reply"]["bytes"] / kinds["reply"]["messages"] > 7 * 9
        assert "estimation" not in result.messages
    else:
        # every robot reports its range and the fusion centre broadcasts one estimate per step
        assert kinds["range"]["messages"] == 6 * STEPS and kinds["estimate"]["messages"] == STEPS
        assert "fusion" in result.pids and len(set(result.pids.values())) == 9
    assert result.monitor_equals_senders is True


def assert_tracks_like_the_engine(log: RunLog) -> History:
    """Angles, estimates and their covariances to 1e-9, triggers exactly, and Terr to 1e-9 of the
    engine's run."""
    logged, twin = history_from_log(log), engine_twin(log)
    assert logged.steps == twin.steps
    assert np.max(np.abs(logged.angles - twin.angles)) < 1e-9
    assert np.array_equal(logged.triggers, twin.triggers)
    assert np.max(np.abs(logged.estimates - twin.estimates)) < 1e-9
    assert np.allclose(logged.covariances, twin.covariances, rtol=0.0, atol=1e-9, equal_nan=True)
    assert np.max(np.abs(logged.terr - twin.terr)) < 1e-9
    return logged


def test_constant_strategy_with_centralized_estimation_equals_the_engine(tmp_path: Path) -> None:
    steps = 200
    team = load_scenario("authors-moving", estimation="centralized", strategy="constant", max_steps=steps)
    result, log = lockstep_run(team, tmp_path)
    logged = assert_tracks_like_the_engine(log)
    assert np.all(logged.triggers != 0)  # constant: every robot polls every step
    kinds = result.by_kind
    assert kinds["request"]["messages"] == kinds["reply"]["messages"] == 2 * 6 * steps
    assert kinds["range"]["messages"] == 6 * steps and kinds["estimate"]["messages"] == steps
    assert result.monitor_equals_senders is True


@pytest.mark.parametrize(("estimation", "prior"), [("decentralized", "truth"), ("centralized", "trilateration")])
def test_limited_sensing_range_equals_the_engine(tmp_path: Path, estimation: str, prior: str) -> None:
    """Robots beyond the sensing range get no range (the world sends None, filters only predict);
    with a trilateration prior, too few ranges at step 1 leave the centre an uninformative prior."""
    team = short_sighted(estimation, prior, max_steps=200)
    _, log = lockstep_run(team, tmp_path)
    logged = assert_tracks_like_the_engine(log)
    distances = np.linalg.norm(logged.positions[:, 0] - logged.targets[:, 0, None, :], axis=-1)
    out_of_range = distances > SENSING_RANGE
    assert 0.1 < out_of_range.mean() < 0.9  # many robot-steps without a range, many with one
    if prior == "trilateration":
        assert (~out_of_range[0]).sum() < 3  # no fix at step 1
        assert np.nanmean(logged.terr[100:, 0]) < 0.5  # ... yet the centre finds and tracks the target


def test_the_world_caps_boundary_speed_at_v_max_like_the_engine(tmp_path: Path) -> None:
    capped = scenario(v_max=0.05, max_steps=200)  # omega_max stays 1 deg/s; the world caps the motion
    _, log = lockstep_run(capped, tmp_path)
    logged = assert_equals_engine(log)
    uncapped = engine.run(scenario(max_steps=200), record_positions=False)
    assert np.abs(logged.angles - uncapped.angles).max() > 0.1  # the cap did hold robots back
    moved = np.linalg.norm(np.diff(np.array([record["positions"] for record in log.steps]), axis=0), axis=-1)
    assert moved.max() <= 0.05 * capped.control.dt * (1 + 1e-9)  # never faster than v_max (chord <= arc)
