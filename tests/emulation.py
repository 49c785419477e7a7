"""Helpers for tests that run teams of real processes over Zenoh."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from ringtrack.agents import engine
from ringtrack.agents.engine import History
from ringtrack.tools.runlog import RunLog, history_from_log, read_log
from ringtrack.tools.spawn import spawn_team
from ringtrack.world.scenario import Scenario, load_scenario

RINGTRACK = [sys.executable, "-m", "ringtrack.tools.cli"]


def lockstep_run(scenario: Scenario, runs: Path) -> tuple[dict, RunLog]:
    """Spawn a lockstep team and return its summary and run log."""
    result = spawn_team(scenario, clock="lockstep", runs=runs, dashboard=False)
    assert result["exit_code"] == 0, result
    return result, read_log(Path(result["log"]))


def engine_twin(log: RunLog) -> History:
    """The in-process engine run of the same scenario, seed and step count as a logged run."""
    return engine.run(log.scenario, seeds=log.header["seed"], steps=len(log.steps))


def assert_equals_engine(log: RunLog) -> History:
    """Angles to 1e-9 and every trigger mask of every robot and step equal to the engine's."""
    logged = history_from_log(log)
    twin = engine_twin(log)
    assert logged.steps == twin.steps
    assert np.max(np.abs(logged.angles - twin.angles)) < 1e-9
    assert np.array_equal(logged.triggers, twin.triggers)
    return logged


def scenario(**overrides: object) -> Scenario:
    return load_scenario("paper-stationary", **overrides)


def processes_mentioning(text: str) -> list[int]:
    """Pids of live processes whose command line contains ``text`` (Linux /proc)."""
    found = []
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit() or int(entry.name) == os.getpid():
            continue
        try:
            command = (entry / "cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
            state = (entry / "stat").read_text().split()[2]
        except OSError:
            continue
        if text in command and state != "Z":
            found.append(int(entry.name))
    return found


def start_spawn(runs: Path, *arguments: str) -> subprocess.Popen[bytes]:
    """``ringtrack spawn`` as a child in its own process group (so a test can signal it like a shell)."""
    return subprocess.Popen(
        [*RINGTRACK, "spawn", "--runs", str(runs), "--no-dashboard", *arguments],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        start_new_session=True,
    )


def wait_for_steps(runs: Path, steps: int, timeout_s: float = 60.0) -> Path:
    """Wait until the single run folder under ``runs`` has a log with at least ``steps`` step records."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        logs = list(runs.glob("*/log.jsonl"))
        if logs and logs[0].read_bytes().count(b'"type":"step"') >= steps:
            return logs[0].parent
        time.sleep(0.05)
    raise AssertionError(f"no log with {steps} steps under {runs} within {timeout_s} s")


def stop_all(process: subprocess.Popen[bytes]) -> None:
    """Last-resort cleanup for a test that failed half-way: kill the spawn and its run's processes."""
    if process.poll() is None:
        os.killpg(process.pid, signal.SIGKILL)
        process.wait()
