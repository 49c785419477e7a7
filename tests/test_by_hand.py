"""A team assembled by hand (``world`` / ``monitor`` / ``robot --id 0-5``, as docs/emulator.md shows)
behaves like ``spawn``: it stops at convergence unless ``--steps``, and the monitor says Ctime."""

from __future__ import annotations

import json
import os
import subprocess
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from ringtrack.agents import engine
from ringtrack.agents.summary import summarise
from ringtrack.tools.runlog.log import read_log
from ringtrack.world.scenario import load_scenario
from tests.helpers import RINGTRACK


class Team:
    """Role processes started by hand; every one is ended when the test leaves."""

    def __init__(self, folder: Path) -> None:
        self.folder = folder
        self.processes: list[subprocess.Popen[str]] = []

    def start(self, role: str, *arguments: str) -> subprocess.Popen[str]:
        process = subprocess.Popen([*RINGTRACK, role, *arguments], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                   text=True)
        self.processes.append(process)
        return process

    def close(self) -> None:
        for process in self.processes:
            if process.poll() is None:
                process.kill()
            process.communicate()


@pytest.fixture
def team(tmp_path: Path) -> Iterator[Team]:
    started = Team(tmp_path)
    try:
        yield started
    finally:
        started.close()


def endpoints(path: Path, timeout_s: float = 20) -> list[str]:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if path.exists():
            return json.loads(path.read_text())["endpoints"]
        time.sleep(0.05)
    raise AssertionError(f"the world announced no endpoints in {path}")


def by_hand(team: Team, *steps: str) -> tuple[list[int], str, Path]:
    """The by-hand team of docs/emulator.md on loopback (port 0); returns exit codes, the monitor's output and the log."""
    common = ["paper-stationary", "--run", f"{os.getpid() & 0xFFFFFFF:08x}", "--monitor", *steps]
    announce, log = team.folder / "endpoints.json", team.folder / "run.jsonl"
    world = team.start("world", *common, "--listen", "tcp/127.0.0.1:0", "--announce", str(announce))
    connect = ["--connect", endpoints(announce)[0]]
    monitor = team.start("monitor", *common, *connect, "--log", str(log), "--no-dashboard")
    robots = team.start("robot", *common, *connect, "--id", "0-5")
    codes = [process.wait(timeout=240) for process in (world, monitor, robots)]
    return codes, monitor.communicate()[0], log


@pytest.mark.processes
def test_a_team_by_hand_stops_at_convergence_and_the_monitor_reports_ctime(team: Team) -> None:
    ctime = summarise(engine.run(load_scenario("paper-stationary"), until_converged=True)).ctime
    codes, said, log = by_hand(team)
    assert codes == [0, 0, 0]
    assert len(read_log(log).steps) == ctime  # not all of control.max_steps
    assert f"run: converged after {ctime} steps (Ctime = {ctime} steps)" in " ".join(said.split())


@pytest.mark.processes
def test_a_team_by_hand_with_steps_runs_exactly_that_many(team: Team) -> None:
    codes, said, log = by_hand(team, "--steps", "40")
    assert codes == [0, 0, 0]
    assert len(read_log(log).steps) == 40
    assert "run: done after 40 steps;" in " ".join(said.split())
