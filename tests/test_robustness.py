"""Faults as experiments: robustness sweeps in the engine, their verification over Zenoh, and the
radio model's fates and energy equal in the engine and a lockstep team."""

from __future__ import annotations

import json
import math
import subprocess
from pathlib import Path

import numpy as np
import pytest

from ringtrack.agents import engine
from ringtrack.tools.studies.robustness import Cell, faults_experiment
from ringtrack.world.ranges import link_distance
from ringtrack.world.scenario import load_scenario
from tests.helpers import RINGTRACK, assert_equals_engine, lockstep_run
from tests.test_radio import lossy_scenario

pytestmark = pytest.mark.timeout(600)


@pytest.mark.slow
def test_drop_sweep_slows_convergence_and_raises_com_bar_of_the_self_triggered_strategy() -> None:
    drops = [0.0, 0.2, 0.5]
    result = faults_experiment("paper-stationary", [Cell(drop, 0, None) for drop in drops], trials=30, seed=0)
    triggered = [entry for entry in result.summary if entry.strategy == "self"]
    assert [entry.drop for entry in triggered] == drops
    assert all(entry.converged_mean == 1.0 for entry in triggered)
    ctime = [entry.ctime_mean for entry in triggered]
    com_bar = [entry.com_bar_mean for entry in triggered]
    assert ctime[0] <= ctime[1] <= ctime[2] and ctime[2] - ctime[0] > 10  # 516.4, 520.2, 553.3 steps
    assert com_bar[0] < com_bar[1] < com_bar[2] and com_bar[2] > 1.5 * com_bar[0]  # 0.199, 0.278, 0.381
    constant = [entry for entry in result.summary if entry.strategy == "constant"]
    assert all(entry.com_bar_mean == 1.0 for entry in constant)
    assert [(saving.strategy, saving.baseline) for saving in result.savings] == [("self", "constant")] * len(drops)
    for saving in result.savings:  # self-triggered polls spend far less radio energy
        assert saving.saved_per_robot_j > 0 and saving.saved_share > 0.5
    rows = [row for row in result.rows if row.strategy == "self" and row.drop == 0.5]
    assert len(rows) == 30 and np.mean([row.ctime for row in rows]) == pytest.approx(ctime[2])


@pytest.mark.processes
def test_verify_three_runs_over_zenoh(tmp_path: Path) -> None:
    output = tmp_path / "faults.json"
    completed = subprocess.run(
        [*RINGTRACK, "experiment", "faults", "--drop", "0,0.3", "--outage-steps", "0,40", "--trials", "4",
         "--steps", "120", "--verify", "3", "--json", str(output), "--csv", str(tmp_path / "faults.csv"),
         "--plot", str(tmp_path / "faults.png")],
        capture_output=True, text=True, timeout=500)
    assert completed.returncode == 0, completed.stderr[-3000:]
    result = json.loads(output.read_text())
    verified = result["verify"]
    assert verified["requested"] == 3 and len(verified["runs"]) == 3 and verified["all_equal"] is True
    for check in verified["runs"]:
        assert check["equal"] and check["max_angle_difference"] < 1e-9 and check["triggers_equal"]
        assert check["faults_equal"] and check["energy_equal"] and check["steps_logged"] == check["steps"]
    assert len({(check["cell"], check["strategy"], check["trial"]) for check in verified["runs"]}) == 3
    assert len(result["summary"]) == 4 * 2 and result["swept"] == ["drop", "outage_steps"]
    assert (tmp_path / "faults.png").stat().st_size > 0
    assert (tmp_path / "faults.csv").read_text().count("\n") == 1 + 8


def engine_drops(history: engine.History) -> set[tuple[int, str, int, int, str]]:
    """(step, subject, sender, receiver, reason) of every message the run's fault layer drops,
    enumerated one message at a time from the engine run's polls and positions."""
    scenario = history.scenario
    plan, robots, limit = scenario.faults, scenario.robots, scenario.communication_range or math.inf
    assert history.positions is not None
    drops = set()
    for row in range(history.steps):
        step, positions = row + 1, history.positions[row, 0]
        for robot in range(robots):
            for neighbour in ((robot - 1) % robots, (robot + 1) % robots):
                distance = float(link_distance(positions[robot], positions[neighbour]))
                if distance > limit:
                    drops.add((step, "request", robot, neighbour, "range"))
                    continue
                if not history.triggers[row, 0, robot]:
                    continue
                fate = plan.fate("request", robot, neighbour, step, distance)
                if fate.dropped:
                    drops.add((step, "request", robot, neighbour, fate.reason))
                    continue
                answer = plan.fate("reply", neighbour, robot, step, distance)
                if answer.dropped:
                    drops.add((step, "reply", neighbour, robot, answer.reason))
    return drops


@pytest.mark.processes
def test_radio_fates_and_energy_equal_in_engine_and_lockstep_team(tmp_path: Path) -> None:
    path = lossy_scenario(tmp_path, "[faults]\ndrop = 0.1\nduplicate = 0.1\n", "overhead_bytes = 17\n")
    team = load_scenario(str(path), max_steps=200)
    result, log = lockstep_run(team, tmp_path / "runs")
    assert_equals_engine(log)
    twin = engine.run(team, seeds=log.header["seed"], steps=len(log.steps))
    logged = {(event["step"], event["subject"], event["sender"], event["receiver"], event["reason"])
              for event in log.events if event["event"] == "dropped"}
    expected = engine_drops(twin)
    assert logged == expected and {"radio", "drop"} <= {drop[-1] for drop in expected}
    faults = engine.fault_totals(twin)
    assert {name: result.faults[name] for name in engine.FAULT_COLUMNS} == \
        {name: faults[name] for name in engine.FAULT_COLUMNS}
    assert twin.energy is not None and twin.sent_bytes is not None
    wire = np.array([result.energy.transmit_j, result.energy.receive_j]).T
    assert np.allclose(wire, twin.energy[:, 0].sum(axis=0), rtol=1e-9, atol=0.0)
    assert result.energy.team_j == pytest.approx(float(twin.energy.sum()), rel=1e-9)
    assert result.bytes["robot"] == int(twin.sent_bytes.sum())  # the engine knows every wire size
    assert log.end["energy_j"] == {f"r{robot}": list(wire[robot]) for robot in range(team.robots)}
