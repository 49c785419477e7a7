"""Large teams on one machine: 64 robot processes, and robots packed several to a process."""

from __future__ import annotations

from pathlib import Path

import pytest

from ringtrack.tools.runlog.log import read_log
from ringtrack.tools.team.plan import TeamPlan
from ringtrack.tools.team.spawn import spawn_team
from tests.helpers import assert_equals_engine, processes_mentioning, scenario

pytestmark = pytest.mark.timeout(300)

HANG_BOUND_S = 120.0  # only catches a hang; the speed itself is measured by `ringtrack bench emulator`


@pytest.mark.processes
def test_sixty_four_robot_processes_start_and_converge_in_lockstep(tmp_path: Path) -> None:
    team = scenario(robots=64, seed=3)
    result = spawn_team(TeamPlan(scenario=team, clock="lockstep", runs=tmp_path, dashboard=False, until_converged=True, quiet=True))
    assert result.exit_code == 0, result.failures
    robots = {name: pid for name, pid in result.pids.items() if name.startswith("r")}
    assert len(robots) == 64 and len(set(robots.values())) == 64  # one OS process per robot
    assert result.startup_s is not None and result.startup_s < HANG_BOUND_S
    assert result.outcome.converged and result.end_reason == "converged"
    log = read_log(Path(result.log))
    assert all(record["live"] == list(range(64)) for record in log.steps)  # every robot live every step
    assert log.end["consistent"] is True
    assert_equals_engine(log)
    assert not processes_mentioning(result.run)


@pytest.mark.processes
def test_robots_packed_per_process_keep_their_own_identity_and_counts(tmp_path: Path) -> None:
    team = scenario(robots=10, seed=5, max_steps=200)
    result = spawn_team(TeamPlan(scenario=team, clock="lockstep", runs=tmp_path, dashboard=False, quiet=True, robots_per_process=4))
    assert result.exit_code == 0, result.failures
    assert set(result.pids) == {"world", "monitor", "r0-3", "r4-7", "r8-9"}  # three robot processes
    log = read_log(Path(result.log))
    assert_equals_engine(log)
    # Each robot is its own participant: it reports its own statistics, which the monitor checks.
    senders = log.end["senders"]
    assert {f"r{i}" for i in range(10)} <= set(senders)
    for robot in range(10):
        sent = {(kind, destination) for kind, source, destination, *_ in senders[f"r{robot}"]}
        assert all(source == f"r{robot}" for _, source, *_ in senders[f"r{robot}"])
        assert ("command", "world") in sent
    assert log.end["consistent"] is True


def test_robots_per_process_must_be_positive(tmp_path: Path) -> None:
    from ringtrack.tools.output.console import UsageError

    with pytest.raises(UsageError, match=r"--robots-per-process 0: give at least 1"):
        spawn_team(TeamPlan(scenario=scenario(max_steps=5), clock="lockstep", runs=tmp_path, dashboard=False, robots_per_process=0))
