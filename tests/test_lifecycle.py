"""What a crash of the team's log writer or of spawn itself leaves behind."""

from __future__ import annotations

import dataclasses
import os
import signal
import time
from pathlib import Path

import pytest

from ringtrack.tools.runlog import read_log
from tests.helpers import assert_equals_engine, processes_mentioning, start_spawn, stop_all, wait_for_steps

pytestmark = [pytest.mark.processes, pytest.mark.timeout(120)]


def _pid_of(folder: Path, role: str) -> int:
    (pid,) = [pid for pid in processes_mentioning(str(folder))
              if Path(f"/proc/{pid}/cmdline").read_bytes().split(b"\0")[3] == role.encode()]
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
    # world may go on a step or two without it, as after any crash. Up to then the run is the engine's.
    whole = [record for record in log.steps if record["live"] == list(range(6))]
    assert len(whole) >= 50 and log.steps[: len(whole)] == whole
    assert_equals_engine(dataclasses.replace(log, steps=whole))
