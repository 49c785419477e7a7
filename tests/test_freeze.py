"""A frozen robot (SIGSTOP, then SIGCONT) cannot hang a lockstep team: below the liveliness lease
the team waits and equals the engine; above it, the world names the robot it waits for and goes on
without it after ``--lockstep-wait``, its neighbours' polls giving up after half of that."""

from __future__ import annotations

import json
import os
import signal
import time
from pathlib import Path

import pytest

from ringtrack.tools.runlog import read_log
from tests.helpers import assert_equals_engine, processes_mentioning, start_spawn, stop_all, wait_for_steps
from tests.test_centre import _robot_pid


def freeze(runs: Path, seconds: float, *arguments: str) -> tuple[Path, int, str]:
    """Spawn a lockstep team, freeze r3 for ``seconds`` at step 50; returns the run folder, spawn's
    exit code and the world's standard error."""
    spawn = start_spawn(runs, "--steps", "400", *arguments)
    try:
        folder = wait_for_steps(runs, 50)
        robot = _robot_pid(folder, 3)
        os.kill(robot, signal.SIGSTOP)
        time.sleep(seconds)
        os.kill(robot, signal.SIGCONT)
        spawn.communicate(timeout=120)
    finally:
        stop_all(spawn)
    assert processes_mentioning(str(folder)) == []
    return folder, spawn.returncode, (folder / "world.stderr").read_text()


@pytest.mark.processes
@pytest.mark.timeout(200)
def test_a_freeze_below_the_lease_is_waited_out_and_the_run_equals_the_engine(tmp_path: Path) -> None:
    folder, code, world = freeze(tmp_path / "runs", 3.0)
    assert code == 0
    assert "waits for r3" in world  # named, not silently hung
    log = read_log(folder / "log.jsonl")
    assert len(log.steps) == 400 and all(record["live"] == list(range(6)) for record in log.steps)
    assert_equals_engine(log)


@pytest.mark.processes
@pytest.mark.timeout(200)
def test_a_freeze_above_the_lease_does_not_hang_the_lockstep_team(tmp_path: Path) -> None:
    started = time.monotonic()
    folder, code, world = freeze(tmp_path / "runs", 14.0, "--lockstep-wait", "4")
    assert time.monotonic() - started < 100  # the 60 s stall guard never fired
    summary = json.loads((folder / "summary.json").read_text())
    assert summary["stopped"] is None and summary["end_reason"] == "done", summary
    assert "waits for r3" in world and "r3 sent no command" in world, world
    log = read_log(folder / "log.jsonl")
    assert len(log.steps) == 400
    assert any(3 not in record["live"] for record in log.steps)  # it was treated as gone
    # The woken robot is not re-admitted yet: having lost the world for longer than its lease, it
    # stops on its own (exit 1), and that is the only failure of the run.
    assert set(summary["failures"]) <= {"r3"} and code == int(bool(summary["failures"]))
