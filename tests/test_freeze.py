"""A frozen robot (SIGSTOP, then SIGCONT) cannot hang a team, and comes back by a handshake.

Below the liveliness lease (and ``--lockstep-wait``) a lockstep team just waits and equals the
engine; a realtime team goes on and the robot stays in the ring. Above it the robot is seen gone,
the five go on, and on waking it is re-admitted only once it and its ring neighbours reach one
another; a lockstep world that waited ``--lockstep-wait`` for it treats it as gone the same way. In
realtime every robot-to-robot message is accounted for: ``sent + duplicated == delivered + dropped``.
Leases and waits are short here (``--lease``, ``--lockstep-wait``) so that the tests stay fast, though
not so short (2 s) that a process starved of CPU on a loaded machine loses its lease.
"""

from __future__ import annotations

import json
import os
import re
import signal
import time
from collections.abc import Callable
from pathlib import Path

import pytest

from ringtrack.tools.runlog.log import RunLog, read_log
from tests.helpers import assert_equals_engine, processes_mentioning, start_spawn, stop_all, wait_for_steps
from tests.test_centre import _robot_pid

pytestmark = [pytest.mark.processes, pytest.mark.timeout(240)]


def dropped(folder: Path) -> bool:
    """Whether the world has taken r3 out of the ring (it says so on its standard error)."""
    world = (folder / "world.stderr").read_text()
    return "robot r3 left" in world or "r3 sent no command" in world


def freeze(runs: Path, seconds: float, *arguments: str, wake_when: Callable[[Path], bool] | None = None,
           at_step: int = 50) -> tuple[Path, int, str, dict]:
    """Spawn a team, freeze r3 once the log has ``at_step`` steps for ``seconds`` (and then until
    ``wake_when(run folder)``: a lockstep team without r3 runs fast), wake it and let the run end;
    returns the run folder, spawn's exit code, the world's standard error and the summary. The
    robot is always woken and every process ended, also on failure."""
    spawn = start_spawn(runs, *arguments)
    robot = None
    try:
        folder = wait_for_steps(runs, at_step, timeout_s=90)
        robot = _robot_pid(folder, 3)
        os.kill(robot, signal.SIGSTOP)
        time.sleep(seconds)
        deadline = time.monotonic() + 60
        while wake_when is not None and not wake_when(folder) and time.monotonic() < deadline:
            time.sleep(0.05)
        os.kill(robot, signal.SIGCONT)
        spawn.communicate(timeout=150)
    finally:
        if robot is not None:
            try:
                os.kill(robot, signal.SIGCONT)
            except ProcessLookupError:
                pass
        stop_all(spawn)
    assert processes_mentioning(str(folder)) == []
    return folder, spawn.returncode, (folder / "world.stderr").read_text(), json.loads((folder / "summary.json")
                                                                                       .read_text())


def assert_completed(code: int, summary: dict, log: RunLog, steps: int) -> None:
    assert code == 0 and summary["failures"] == {} and summary["stopped"] is None, summary
    assert summary["end_reason"] == "done" and len(log.steps) == steps


def assert_every_message_counted(log: RunLog) -> dict:
    faults = log.end["faults"]
    assert faults["sent"] > 0
    assert faults["sent"] + faults["duplicated"] == faults["delivered"] + faults["dropped"], faults
    return faults


def assert_readmitted_by_handshake(log: RunLog, world: str) -> None:
    """r3 was out of the ring for a while, then back in it to the end; the world admitted it once it
    and both neighbours reached one another, and from then on no step waited for anyone (before the
    handshake, its neighbours' first requests went nowhere and their polls waited out the timeout)."""
    out = [record["step"] for record in log.steps if 3 not in record["live"]]
    assert out and out == list(range(out[0], out[-1] + 1)), out  # one gap
    back = out[-1] + 1
    assert all(record["live"] == list(range(6)) for record in log.steps[back - 1:])
    assert f"robot r3 rejoins at step {back}: it and its ring neighbours reach one another" in world, world
    assert "waits for" not in world.split("rejoins at step")[1], world
    assert all(record["trigger"][3] is not None for record in log.steps[back - 1:])  # it commanded every step
    # a neighbour's request for that step, come before the step's measurement, was held and answered
    assert log.end["notes"].get("ignored_requests", 0) == 0, log.end["notes"]


def test_a_freeze_below_the_lease_is_waited_out_and_the_run_equals_the_engine(tmp_path: Path) -> None:
    folder, code, world, summary = freeze(tmp_path / "runs", 3.0, "--steps", "300", "--lease", "8",
                                          "--lockstep-wait", "8")
    log = read_log(folder / "log.jsonl")
    assert_completed(code, summary, log, 300)
    assert re.search(r"lockstep step \d+ waits for r3\n", world), world  # named, not silently hung
    assert "treated as gone" not in world and "left" not in world
    assert all(record["live"] == list(range(6)) for record in log.steps)
    assert_equals_engine(log)
    assert assert_every_message_counted(log)["lost"] == 0


def test_a_freeze_above_the_lease_drops_the_robot_and_it_rejoins_by_handshake(tmp_path: Path) -> None:
    folder, code, world, summary = freeze(tmp_path / "runs", 2.5, "--steps", "500", "--lease", "2",
                                          wake_when=dropped)
    log = read_log(folder / "log.jsonl")
    assert_completed(code, summary, log, 500)
    assert re.search(r"robot r3 left at step \d+; 5 robots go on", world), world
    assert "robot r3 is back at step" in world
    assert_readmitted_by_handshake(log, world)
    faults = assert_every_message_counted(log)
    print("lockstep freeze above the lease:", " ".join(re.findall(r"(?:left|is back|rejoins) at step \d+", world)),
          {key: faults[key] for key in ("sent", "delivered", "dropped", "lost")})


def test_a_robot_silent_past_the_lockstep_wait_is_named_treated_as_gone_and_rejoins(tmp_path: Path) -> None:
    folder, code, world, summary = freeze(tmp_path / "runs", 2.5, "--steps", "450", "--lease", "30",
                                          "--lockstep-wait", "2.5", wake_when=dropped)
    log = read_log(folder / "log.jsonl")
    assert_completed(code, summary, log, 450)
    gone = re.findall(r"lockstep step (\d+): r3 sent no command within --lockstep-wait 2.5 s; treated as gone, 5 "
                      r"robots go on\n", world)
    assert len(gone) == 1, world
    assert "left at step" not in world  # its lease never ran out: the world's wait decided
    assert_readmitted_by_handshake(log, world)
    assert_every_message_counted(log)


@pytest.mark.realtime
def test_a_realtime_freeze_below_the_lease_keeps_the_robot_and_counts_every_message(tmp_path: Path) -> None:
    folder, code, world, summary = freeze(tmp_path / "runs", 1.5, "--clock", "realtime", "--rate", "5",
                                          "--steps", "400", "--lease", "6")
    log = read_log(folder / "log.jsonl")
    assert_completed(code, summary, log, 400)
    assert all(record["live"] == list(range(6)) for record in log.steps), world
    assert_every_message_counted(log)


@pytest.mark.realtime
def test_a_realtime_freeze_above_the_lease_rejoins_by_handshake_and_counts_every_message(tmp_path: Path) -> None:
    folder, code, world, summary = freeze(tmp_path / "runs", 4.5, "--clock", "realtime", "--rate", "5",
                                          "--steps", "600", "--lease", "2")
    log = read_log(folder / "log.jsonl")
    assert_completed(code, summary, log, 600)
    assert re.search(r"robot r3 left at step \d+; 5 robots go on", world), world
    out = [record["step"] for record in log.steps if 3 not in record["live"]]
    assert out and out == list(range(out[0], out[-1] + 1)), out
    assert all(record["live"] == list(range(6)) for record in log.steps[out[-1]:])
    assert f"robot r3 rejoins at step {out[-1] + 1}: it and its ring neighbours reach one another" in world, world
    faults = assert_every_message_counted(log)
    print("realtime freeze above the lease:", {key: faults[key] for key in ("sent", "delivered", "dropped", "lost")})
