"""What a crash of the team's log writer or of spawn itself leaves behind."""

from __future__ import annotations

import dataclasses
import os
import signal
import time
from pathlib import Path

import pytest

from ringtrack.tools.runlog.log import read_log
from tests.helpers import (
    assert_equals_engine,
    command_words,
    processes_mentioning,
    start_spawn,
    stop_all,
    wait_for_steps,
)

pytestmark = [pytest.mark.processes, pytest.mark.timeout(120)]


def _pid_of(folder: Path, role: str) -> int:
    (pid,) = [pid for pid in processes_mentioning(str(folder))
              if command_words(pid)[3] == role.encode()]
    return pid


def test_a_killed_monitor_leaves_a_readable_log_and_a_failed_run(tmp_path: Path) -> None:
    process = start_spawn(tmp_path, "--steps", "100000")
    try:
        folder = wait_for_steps(tmp_path, 50)
        os.kill(_pid_of(folder, "monitor"), signal.SIGKILL)
        code = process.wait(timeout=60)
        stderr = process.stderr.read().decode()
    finally:
        stop_all(process)
    assert code == 1 and "monitor exited with -9" in stderr  # the monitor is critical: the run ends
    assert processes_mentioning(str(folder)) == []
    log = read_log(folder / "log.jsonl")  # every line written before the kill is a whole record
    steps = [record["step"] for record in log.steps]
    assert len(steps) >= 50 and steps == list(range(1, len(steps) + 1)) and log.end is None
    assert_equals_engine(log)


def test_a_killed_spawn_takes_its_team_down_and_leaves_a_readable_log(tmp_path: Path) -> None:
    process = start_spawn(tmp_path, "--steps", "100000")
    try:
        folder = wait_for_steps(tmp_path, 50)
        process.kill()  # SIGKILL: no handler runs; the children see their standard input close
        process.wait()
        deadline = time.monotonic() + 10
        while processes_mentioning(str(folder)) and time.monotonic() < deadline:
            time.sleep(0.05)
    finally:
        stop_all(process)
    assert processes_mentioning(str(folder)) == []
    log = read_log(folder / "log.jsonl")
    steps = [record["step"] for record in log.steps]
    assert len(steps) >= 50 and steps == list(range(1, len(steps) + 1))
    # Every child sees its standard input close on its own: a robot that stops first leaves, and the
    # world may go on a step or two without it, as after any crash. The last step with the whole team
    # live is the one in which the first robot stopped: its neighbours may see its token go (ahead of
    # the world) and answer that step around it. Up to then the run is the engine's.
    whole = [record for record in log.steps if record["live"] == list(range(6))]
    assert len(whole) >= 50 and log.steps[: len(whole)] == whole
    assert_equals_engine(dataclasses.replace(log, steps=whole[:-1]))


STUCK = """
import asyncio, sys, time
from ringtrack.bus.runtime import Interrupts

async def main():
    interrupts = Interrupts(exit_with_parent=True, parent_grace_s=0.5)
    interrupts._install(asyncio.get_running_loop())
    print("ready", flush=True)
    time.sleep(120)  # the loop's thread stuck, as in a Zenoh call that never returns

asyncio.run(main())
"""


@pytest.mark.processes
def test_a_process_stuck_outside_its_loop_still_ends_with_its_parent() -> None:
    """Its parent's end cannot reach a loop whose thread never comes back to it: the watcher thread
    ends the process after the grace, with the exit code of a stopped participant and one line."""
    import subprocess
    import sys

    from ringtrack.bus.runtime import STOPPED

    child = subprocess.Popen([sys.executable, "-c", STUCK], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                             stderr=subprocess.PIPE, text=True)
    try:
        assert child.stdout is not None and child.stdout.readline() == "ready\n"
        assert child.stdin is not None
        child.stdin.close()  # the parent's end, as the child sees it
        assert child.wait(timeout=60) == STOPPED
        assert child.stderr is not None
        assert "ringtrack: the parent exited and this process did not stop within 0.5 s; exiting" in child.stderr.read()
    finally:
        if child.poll() is None:
            child.kill()
            child.wait()
