"""Centralized estimation when robots come and go: the fusion centre (agents/centre.py) fuses the
reports of the robots that are alive, and a robot never waits forever for the centre's estimate."""

from __future__ import annotations

import json
import os
import signal
import time
from pathlib import Path

import msgspec
import numpy as np
import pytest

from ringtrack.agents.centre import FusionCentre
from ringtrack.agents.estimation import Estimator
from ringtrack.agents.node import RobotNode
from ringtrack.bus.keys import FUSION, WORLD
from ringtrack.bus.messages import SCHEMA, Command, Estimate, RangeReport, Reply, Request
from ringtrack.tools.runlog.log import history_from_log, read_log
from ringtrack.world.scenario import load_scenario
from ringtrack.world.state import WorldState
from tests.helpers import command_words, processes_mentioning, short_sighted, start_spawn, stop_all, wait_for_steps

RUN = 0x5EED
SCENARIO = load_scenario("authors-moving", estimation="centralized")
ROBOTS = SCENARIO.robots


def reports(step: int, robots: list[int]) -> list[RangeReport]:
    """Reports of ``robots`` for ``step`` from the scenario's start positions (robot 2 out of range)."""
    positions = SCENARIO.start_positions(SCENARIO.seed)
    ranges = np.linalg.norm(positions - SCENARIO.target, axis=1) + 0.01 * step
    return [RangeReport(SCHEMA, RUN, step, robot, tuple(positions[robot]), None if robot == 2 else float(ranges[robot]))
            for robot in robots]


def expected_estimates(steps: list[list[RangeReport]]) -> list[tuple[tuple[float, float], tuple[float, float, float]]]:
    """The engine's filter stepped over the given reports, one list per estimated step, in robot order."""
    estimator = Estimator(SCENARIO.estimation, SCENARIO.region, SCENARIO.target)
    beliefs = []
    for step in steps:
        ordered = sorted(step, key=lambda report: report.robot)
        estimator.measure(np.array([report.position for report in ordered]),
                          np.array([np.nan if report.range is None else report.range for report in ordered]))
        mean, covariance = estimator.belief
        beliefs.append(((mean[0], mean[1]), (covariance[0, 0], covariance[0, 1], covariance[1, 1])))
    return beliefs


def beliefs_of(estimates: list[Estimate]) -> list[tuple[tuple[float, float], tuple[float, float, float]]]:
    return [(estimate.mean, estimate.covariance) for estimate in estimates]


# ---------------------------------------------------------------------------- the fusion centre (no I/O)
def test_a_step_is_estimated_once_every_robot_has_reported():
    centre = FusionCentre(SCENARIO, RUN)
    first = reports(1, [4, 0, 5, 2, 1, 3])  # any arrival order
    assert all(centre.on_report(report) == [] for report in first[:-1])
    estimates = centre.on_report(first[-1])
    assert [estimate.step for estimate in estimates] == [1]
    assert beliefs_of(estimates) == expected_estimates([first])
    assert centre.on_report(reports(1, [3])[0]) == []  # a duplicate of an estimated step


def test_a_robot_that_leaves_is_no_longer_waited_for():
    centre = FusionCentre(SCENARIO, RUN)
    first = reports(1, [0, 1, 2, 4, 5])
    assert all(centre.on_report(report) == [] for report in first)  # robot 3 has not reported
    estimates = centre.on_leave(3)  # ... and never will: step 1 is estimated from the other five
    assert [estimate.step for estimate in estimates] == [1]
    second = reports(2, [0, 1, 2, 4, 5])
    later = [estimate for report in second for estimate in centre.on_report(report)]
    assert [estimate.step for estimate in later] == [2]  # the next step needs only the five
    assert beliefs_of(estimates + later) == expected_estimates([first, second])
    assert centre.on_leave(3) == []  # leaving twice changes nothing


def test_a_leave_completes_every_pending_step_in_order():
    """Realtime: robots may be a step apart, so several steps can be waiting for the robot that left."""
    centre = FusionCentre(SCENARIO, RUN)
    steps = [reports(step, [0, 1, 2, 4, 5]) for step in (1, 2)]
    assert all(centre.on_report(report) == [] for step in steps for report in step)
    estimates = centre.on_leave(3)
    assert [estimate.step for estimate in estimates] == [1, 2]
    assert beliefs_of(estimates) == expected_estimates(steps)


def test_a_robot_that_returns_is_expected_from_the_step_the_world_brings_it_back():
    centre = FusionCentre(SCENARIO, RUN)
    centre.on_leave(3)
    first = reports(1, [0, 1, 2, 4, 5])  # step 1, measured without robot 3
    estimates = [estimate for report in first for estimate in centre.on_report(report)]
    assert [estimate.step for estimate in estimates] == [1]
    # the world brings robot 3 back at step 2: every report of step 2 says so
    second = [msgspec.structs.replace(report, live=[0, 1, 2, 3, 4, 5]) for report in reports(2, [0, 1, 2, 4, 5])]
    assert all(centre.on_report(report) == [] for report in second)  # step 2 waits for robot 3
    back = centre.on_report(msgspec.structs.replace(reports(2, [3])[0], live=[0, 1, 2, 3, 4, 5]))
    assert [estimate.step for estimate in back] == [2]
    assert beliefs_of(estimates + back) == expected_estimates([first, second + reports(2, [3])])


def test_a_newer_complete_step_gives_up_an_older_incomplete_one():
    centre = FusionCentre(SCENARIO, RUN)
    centre.on_report(reports(1, [0])[0])
    newer = reports(2, list(range(ROBOTS)))
    estimates = [estimate for report in newer for estimate in centre.on_report(report)]
    assert [estimate.step for estimate in estimates] == [2]
    assert centre.on_leave(1) == []  # step 1 is not estimated after step 2
    assert centre.on_report(reports(1, [1])[0]) == []


# ---------------------------------------------------------------------------- a robot's bounded wait
def command_after(outgoing: list, node: RobotNode, world: WorldState) -> Command:
    """The robot's command of the step, answering its poll first if it polled."""
    for _destination, message in outgoing:
        if isinstance(message, Request):
            position = tuple(float(v) for v in world.positions[message.receiver])
            outgoing = node.handle(Reply(SCHEMA, RUN, message.step, message.receiver, message.sender, message.nonce,
                                              position))
    (destination, command), = outgoing
    assert destination == WORLD and isinstance(command, Command)
    return command


def test_a_robot_without_the_centres_estimate_decides_about_the_last_one():
    node, world = RobotNode(0, SCENARIO, RUN), WorldState(SCENARIO, SCENARIO.seed, RUN, 10)
    (destination, report), = node.handle(world.measurement(0))
    assert destination == FUSION and isinstance(report, RangeReport) and node.waiting_for_estimate
    first = Estimate(SCHEMA, RUN, 1, (4.1, 19.9), (0.5, 0.0, 0.5))
    command = command_after(node.handle(first), node, world)
    assert command.centre == first.mean
    world.accept(command)
    world.advance()
    (destination, _), = node.handle(world.measurement(0))
    assert destination == FUSION and node.waiting_for_estimate
    # step 2's estimate does not come in time: the robot decides and commands about step 1's
    command = command_after(node.on_estimate_lost(), node, world)
    assert (command.step, command.centre) == (2, first.mean) and not node.waiting_for_estimate
    assert node.on_estimate_lost() == []  # once per step
    late = Estimate(SCHEMA, RUN, 2, (4.5, 20.5), (0.5, 0.0, 0.5))
    assert node.handle(late) == []  # too late for this step's command ...
    np.testing.assert_array_equal(node.centre, late.mean)  # ... but newer: steered about next
    assert node.handle(first) == []  # an older one is ignored
    np.testing.assert_array_equal(node.centre, late.mean)


def test_before_the_first_estimate_a_robot_steers_by_the_centres_prior():
    """Not by the truth: with a trilateration prior the centre starts at the region's Chebyshev centre."""
    scenario = short_sighted("centralized", "trilateration")
    node, world = RobotNode(0, scenario, RUN), WorldState(scenario, scenario.seed, RUN, 10)
    node.handle(world.measurement(0))
    command = command_after(node.on_estimate_lost(), node, world)
    np.testing.assert_array_equal(command.centre, scenario.region.chebyshev_centre[0])
    assert np.linalg.norm(np.subtract(command.centre, scenario.target)) > 1.0


# ---------------------------------------------------------------------------- multi-process
def _robot_pid(folder: Path, robot: int) -> int:
    found = []
    for pid in processes_mentioning(str(folder)):
        command = command_words(pid)
        if b"robot" in command and command[command.index(b"--id") + 1] == str(robot).encode():
            found.append(pid)
    assert len(found) == 1, found
    return found[0]


def _commanded(centres: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The steps (indices) at which a robot commanded, and the centres (steps, 2) it steered by then
    (a realtime robot that falls behind the clock skips steps: NaN)."""
    steps = np.flatnonzero(~np.isnan(centres).any(axis=-1))
    return steps, centres[steps]


def _moves_per_command(positions: np.ndarray, centres: np.ndarray) -> float:
    """A robot's steps of motion per command of it over a stretch of steps (its positions (steps, 2)
    and centres (steps, 2), NaN where it sent no command). Each command moves it about one step
    towards its goal, whatever the load; a realtime robot on a loaded machine commands on fewer
    steps, and moves on fewer, so the bound is measured per command, not per step."""
    moved = np.linalg.norm(np.diff(positions, axis=0), axis=-1) > 1e-9
    commands = len(_commanded(centres)[0])
    return float(moved.sum() / commands) if commands else 0.0


def _frozen_terr(history: object, robot: int, since: int, steps: slice) -> float:
    """Mean distance over ``steps`` from the target to the centre ``robot`` steered by at step
    ``since``: the error had its estimate stopped following the target there."""
    steps_before, centres = _commanded(history.estimates[: since + 1, 0, robot])
    centre = centres[-1]  # the last it steered by at or before ``since``
    return float(np.nanmean(np.linalg.norm(history.targets[steps, 0] - centre, axis=-1)))


def _changing(centres: np.ndarray) -> float:
    """The share of a robot's consecutive commands whose centres differ."""
    _, values = _commanded(centres)
    return float(np.mean(np.any(np.diff(values, axis=0) != 0.0, axis=-1)))


def _estimates_adopted(centres: np.ndarray) -> int:
    """How many times a robot's centre changed between its consecutive commands."""
    _, values = _commanded(centres)
    return int(np.sum(np.any(np.diff(values, axis=0) != 0.0, axis=-1)))


def _longest_hold(centres: np.ndarray) -> tuple[int, int, int]:
    """The longest run of a robot's consecutive commands about one and the same centre: the step
    indices of its first and last command, and how many commands it holds."""
    steps, values = _commanded(centres)
    best, start = (0, 0, 0), 0
    for index in range(1, len(steps) + 1):
        if index == len(steps) or np.any(values[index] != values[start]):
            if index - start > best[2]:
                best = (int(steps[start]), int(steps[index - 1]), index - start)
            start = index
    return best


# The monitor writes a realtime step it lacks commands for only 2 s after its tick, so when the log
# holds 50 steps the world may be 200 further: the realtime runs leave room for that.
STEPS = {"lockstep": 600, "realtime": 700}


@pytest.mark.processes
@pytest.mark.timeout(240)
@pytest.mark.parametrize("clock", ["lockstep", pytest.param("realtime", marks=pytest.mark.realtime)])
def test_a_killed_robot_does_not_stall_a_centralized_team(tmp_path: Path, clock: str) -> None:
    steps = STEPS[clock]
    pacing = ["--rate", "10"] if clock == "realtime" else []
    runs = tmp_path / "runs"
    process = start_spawn(runs, "authors-moving", "--estimation", "centralized", "--clock", clock, *pacing,
                          "--steps", str(steps))
    try:
        folder = wait_for_steps(runs, 50)
        os.kill(_robot_pid(folder, 3), signal.SIGKILL)
        process.wait(timeout=180)
    finally:
        stop_all(process)
    assert processes_mentioning(str(folder)) == []
    summary = json.loads((folder / "summary.json").read_text())
    assert summary["end_reason"] == "done" and summary["failures"] == {"r3": -9}, summary
    log = read_log(folder / "log.jsonl")
    assert len(log.steps) == steps
    assert [event["robot"] for event in log.events if event["event"] == "left"] == ["r3"]
    after = [index for index, record in enumerate(log.steps) if 3 not in record["live"]]
    assert after == list(range(after[0], steps)) and len(after) >= 150
    history = history_from_log(log)
    others = [0, 1, 2, 4, 5]
    # every other robot keeps moving along the boundary, about a step per command it sends (in
    # lockstep one every step; in realtime as many as the load lets it send); the dead one stays put
    positions = history.positions[after, 0]
    moved = np.linalg.norm(np.diff(positions, axis=0), axis=-1) > 1e-9
    per_command = [_moves_per_command(positions[:, robot], history.estimates[after, 0, robot]) for robot in others]
    assert min(per_command) > 0.5, per_command
    if clock == "lockstep":
        assert moved[:, others].mean(axis=0).min() > 0.8, moved.mean(axis=0)
    assert not moved[:, 3].any()
    # ... steering by the centre's estimate from the five ranges left, which follows the target: far
    # closer to it than the estimate of the kill step would have stayed (the target circles at 1 m)
    last = slice(after[-100], after[-1] + 1)
    assert np.nanmean(history.terr[last, 0]) < 0.5 * min(_frozen_terr(history, robot, after[0], last)
                                                          for robot in others)
    if clock == "lockstep":
        assert all(_changing(history.estimates[after, 0, robot]) > 0.8 for robot in others)
    else:  # each robot adopts every newer estimate it gets; how many reach it in time depends on the load
        # (at least one in the last 100 steps: at load 10-24 a robot was seen adopting a single one)
        assert all(_estimates_adopted(history.estimates[after[-100:], 0, robot]) >= 1 for robot in others)
    if clock == "lockstep":  # every step is estimated once and every live robot commands every step
        assert summary["by_kind"]["estimate"]["messages"] == steps
        assert all(log.steps[index]["trigger"][robot] is not None for index in after for robot in others)


@pytest.mark.processes
@pytest.mark.realtime
@pytest.mark.timeout(240)
def test_realtime_robots_do_not_wait_for_a_stalled_centre(tmp_path: Path) -> None:
    """The fusion centre freezes (SIGSTOP) for a second: the robots go on about their last estimate
    and pick up the centre's estimates again once it resumes."""
    runs = tmp_path / "runs"
    process = start_spawn(runs, "authors-moving", "--estimation", "centralized", "--clock", "realtime",
                          "--rate", "10", "--steps", str(STEPS["realtime"]))
    try:
        folder = wait_for_steps(runs, 50)
        fusion, = [pid for pid in processes_mentioning(str(folder))
                   if b"fusion" in command_words(pid)]
        os.kill(fusion, signal.SIGSTOP)
        time.sleep(1.0)
        os.kill(fusion, signal.SIGCONT)
        process.wait(timeout=180)
    finally:
        stop_all(process)
    assert processes_mentioning(str(folder)) == []
    summary = json.loads((folder / "summary.json").read_text())
    assert summary["exit_code"] == 0 and summary["end_reason"] == "done" and summary["failures"] == {}, summary
    history = history_from_log(read_log(folder / "log.jsonl"))
    centres = history.estimates[:, 0]
    holds = [_longest_hold(centres[:, robot]) for robot in range(ROBOTS)]
    # A second at 10x, 100 steps of 0.1 s, went by without an estimate, and each robot went on
    # commanding and moving meanwhile, about its last one. Without the bounded wait it would not
    # command at all; with the centre up, its estimate changes every step it arrives in time. How
    # many steps a realtime robot commands on depends on the load: the bounds are per command.
    assert all(last - first >= 50 and count >= 2 for first, last, count in holds), holds
    per_command = [_moves_per_command(history.positions[first : last + 1, 0, robot],
                                      centres[first : last + 1, robot])
                   for robot, (first, last, _) in enumerate(holds)]
    assert min(per_command) > 0.5, per_command
    # the centre came back: every robot steered by a newer estimate after its hold, and the robots
    # track the target with its estimates again, far closer than the held estimate would be
    assert all(last < _commanded(centres[:, robot])[0][-1] for robot, (_, last, _) in enumerate(holds)), holds
    final = slice(history.steps - 100, history.steps)
    assert np.nanmean(history.terr[final, 0]) < 0.5 * min(_frozen_terr(history, robot, first, final)
                                                           for robot, (first, _, _) in enumerate(holds))
    # (each robot adopts every newer estimate it gets; how many reach it in time depends on the load:
    # at least one in the last 100 steps, at load 10-24 a robot was seen adopting a single one)
    assert all(_estimates_adopted(centres[-100:, robot]) >= 1 for robot in range(ROBOTS))
