"""Reports that must not mislead: who crashed and who was stopped, whose counts a summary shows,
and whose memory it adds up."""

from __future__ import annotations

import json
import os
import signal
import time
from pathlib import Path

import pytest

from ringtrack.bus.counting import totals_by_category
from ringtrack.tools.team.plan import TeamPlan
from ringtrack.tools.team.spawn import spawn_team
from tests.helpers import processes_mentioning, scenario, start_spawn, stop_all, wait_for_steps


def role_pid(folder: Path, role: str) -> int:
    """The pid of the ``role`` process (world, monitor) of the spawn run in ``folder``."""
    deadline = time.monotonic() + 20
    while time.monotonic() < deadline:
        pids = processes_mentioning(f"ringtrack.tools.cli {role} {folder / 'scenario.toml'}")
        if pids:
            return pids[0]
        time.sleep(0.05)
    raise AssertionError(f"no {role} process for {folder}")


@pytest.mark.processes
def test_a_monitor_ended_after_the_world_died_is_no_crash_and_the_summary_counts_what_senders_sent(
        tmp_path: Path) -> None:
    runs = tmp_path / "runs"
    spawn = start_spawn(runs, "--steps", "3000")
    try:
        folder = wait_for_steps(runs, 100)
        monitor, world = role_pid(folder, "monitor"), role_pid(folder, "world")
        os.kill(monitor, signal.SIGSTOP)  # a monitor that cannot stop on its own: the supervisor must kill it
        os.kill(world, signal.SIGKILL)
        stdout, stderr = (stream.decode() for stream in spawn.communicate(timeout=60))
    finally:
        stop_all(spawn)
    assert spawn.returncode == 1
    assert "world exited with -9" in stderr
    assert "monitor exited" not in stderr, stderr  # the supervisor ended it: not a crash
    summary = json.loads((folder / "summary.json").read_text())
    assert summary["failures"] == {"world": -9}
    assert summary["monitor_lost"] is True
    sent = [tuple(row) for name in [f"r{i}" for i in range(6)]
            for row in json.loads((folder / f"{name}.sent.json").read_text())["sent"]]
    robot = totals_by_category(sent)["robot"]["messages"]
    assert robot > 0
    assert summary["messages"]["robot"] == robot
    assert f"robot-to-robot messages {robot} (the senders' counts: the monitor was lost)" in stdout
    assert processes_mentioning(str(folder)) == []


@pytest.mark.processes
def test_the_summary_memory_figure_includes_the_monitor(tmp_path: Path) -> None:
    result = spawn_team(TeamPlan(scenario=scenario(max_steps=20), runs=tmp_path, dashboard=False, quiet=True))
    assert result.exit_code == 0
    assert set(result.rss_kib) == {"world", "monitor", *(f"r{i}" for i in range(6))}
    assert all(kib > 10_000 for kib in result.rss_kib.values())  # Python + Zenoh: tens of MiB each
