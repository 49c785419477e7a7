"""The monitor's display never holds up the monitor (tools/dashboard/views.py LiveView): a stream that blocks
delays only the drawer thread, never whoever refreshes, and a team whose dashboard nobody reads
still completes its run and its log."""

from __future__ import annotations

import fcntl
import io
import os
import re
import select
import subprocess
import threading
import time
from pathlib import Path

import pytest
from rich.console import Console

from ringtrack.tools.dashboard.views import LiveView
from ringtrack.tools.monitor.state import TeamModel
from ringtrack.tools.runlog.log import read_log
from ringtrack.world.scenario import load_scenario
from tests.helpers import RINGTRACK, stop_all
from tests.test_dashboard import prepared_records

pytestmark = pytest.mark.timeout(120)

REFRESH_BUDGET_S = 0.2  # a refresh takes a snapshot of the model and returns (well under 1 ms here)


class BlockedStream(io.StringIO):
    """A text stream whose every write blocks until ``opened`` is set (a pipe nobody reads)."""

    def __init__(self) -> None:
        super().__init__()
        self.opened = threading.Event()
        self.waiting = threading.Event()  # a write is blocked

    def write(self, text: str) -> int:
        self.waiting.set()
        self.opened.wait()
        return super().write(text)


def records(count: int) -> list[dict]:
    """``count`` hand-made step records of a 4-robot team."""
    template = prepared_records(steps=1)[0]
    return [{**template, "step": step, "time": 0.1 * (step - 1)} for step in range(1, count + 1)]


@pytest.mark.parametrize("dashboard", [True, False])
def test_refresh_never_waits_for_a_blocked_stream(dashboard: bool) -> None:
    stream = BlockedStream()
    console = Console(file=stream, force_terminal=dashboard, width=120, height=50)
    model = TeamModel(load_scenario("paper-stationary", robots=4), "lockstep")
    view = LiveView(console, model, dashboard, final_wait_s=0.3)
    slowest = 0.0
    with view:
        for record in records(40):
            model.add(record)
            started = time.monotonic()
            view.refresh()
            slowest = max(slowest, time.monotonic() - started)
            if record["step"] == 1:
                assert stream.waiting.wait(5.0)  # the drawer is now stuck in its first write
        model.status = "done"
        started = time.monotonic()
        view.refresh(True)
    left_after = time.monotonic() - started
    assert slowest < REFRESH_BUDGET_S
    assert 0.3 <= left_after < 0.3 + 1.0  # leaving waits for the last frame, but only final_wait_s
    assert view.drawer.is_alive() and stream.getvalue() == ""  # nothing could be written yet

    stream.opened.set()  # the reader comes back: the drawer writes the latest frame and ends
    view.drawer.join(5.0)
    assert not view.drawer.is_alive()
    written = re.sub(r"\x1b\[[0-9;?]*[A-Za-z]", "", stream.getvalue())  # drop ANSI codes
    if dashboard:
        frames = written.split("paper-stationary · 4 robots")[1:]
        assert 1 <= len(frames) <= 3  # perhaps the stuck one, the latest (the final one), the closing redraw
        assert "step 40/3000" in frames[-1] and "done" in frames[-1]
    else:
        lines = written.strip().splitlines()
        assert len(lines) == 2  # the stuck one and the final one; the others were skipped
        assert lines[0].startswith("step 1/3000") and lines[1].startswith("step 40/3000")


@pytest.mark.processes
def test_a_team_whose_dashboard_nobody_reads_still_completes(tmp_path: Path) -> None:
    """``ringtrack spawn --dashboard | (sleep 45; cat)``: the run completes, exit 0, complete log."""
    steps = 300
    reader, writer = os.pipe()
    fcntl.fcntl(writer, fcntl.F_SETPIPE_SZ, 4096)  # far smaller than one frame of 200 x 60
    with (tmp_path / "spawn.stderr").open("wb") as stderr:
        process = subprocess.Popen(
            [*RINGTRACK, "spawn", "paper-stationary", "--steps", str(steps), "--dashboard", "--runs",
             str(tmp_path / "runs")],
            stdout=writer, stderr=stderr, env={**os.environ, "COLUMNS": "200", "LINES": "60"},
            start_new_session=True,
        )
    try:
        deadline = time.monotonic() + 30.0
        while time.monotonic() < deadline:  # nobody reads the display meanwhile
            logs = list((tmp_path / "runs").glob("*/log.jsonl"))
            if logs and b'"type":"end"' in logs[0].read_bytes():
                break
            time.sleep(0.05)
        else:
            raise AssertionError("the run did not complete while its display was not read")
        assert not select.select([], [writer], [], 0)[1]  # the pipe is full: the display really is stuck
        os.close(writer)
        writer = -1
        shown = b""
        while chunk := os.read(reader, 1 << 16):  # the reader comes back
            shown += chunk
        assert process.wait(30) == 0, (tmp_path / "spawn.stderr").read_text()
    finally:
        os.close(reader)
        if writer >= 0:
            os.close(writer)
        stop_all(process)
    log = read_log(logs[0])
    assert len(log.steps) == steps and [record["step"] for record in log.steps] == list(range(1, steps + 1))
    assert log.end is not None and log.end["reason"] == "done" and log.end["consistent"] is True
    assert f"step {steps}/{steps}".encode() in shown
