"""spawn's start-up frame (tools/dashboard/startup.py): drawn before any process starts, then handed to the monitor.

These tests assert the order the code guarantees, never a wall-clock bound: the frame is on the
terminal before the first process is started, it shows the start-up state, and spawn and the monitor
never draw at the same time.
"""

from __future__ import annotations

import io
import threading
import time
from pathlib import Path

import pytest
from rich.console import Console

from ringtrack.tools.dashboard.startup import READY, StartupView, started_at, take_over
from ringtrack.tools.dashboard.views import LiveView
from ringtrack.tools.monitor.state import TeamModel, startup_names
from ringtrack.tools.team import supervisor
from ringtrack.tools.team.plan import TeamPlan
from ringtrack.tools.team.spawn import spawn_team
from ringtrack.world.scenario import load_scenario

pytestmark = pytest.mark.timeout(120)
PATIENCE_S = 60.0  # how long a poll waits for what must happen (only a broken build waits that long)


def terminal(width: int = 100, height: int = 30) -> Console:
    """A recording console that says it is a terminal, as spawn's stdout on one."""
    return Console(file=io.StringIO(), record=True, width=width, height=height, force_terminal=True,
                   color_system=None)


def eventually(condition, what: str) -> None:
    deadline = time.monotonic() + PATIENCE_S
    while not condition():
        assert time.monotonic() < deadline, f"never happened: {what}"
        time.sleep(0.01)


class Stop(Exception):
    """Raised by the fake start: the test has seen what it needed."""


def test_the_first_frame_is_drawn_before_any_process_starts(monkeypatch, tmp_path: Path) -> None:
    console = terminal()
    monkeypatch.setattr("ringtrack.tools.team.spawn.out", console)
    started: list[tuple[str, list[str], str]] = []
    counted_from: list[float | None] = []

    def record(name: str, argv) -> None:
        started.append((name, list(argv), console.export_text(clear=False)))
        if name == "monitor":
            counted_from.append(started_at(Path(argv[argv.index("--display-handover") + 1])))

    def fork(self, roles) -> None:
        for name, argv in roles:
            record(name, argv)
        raise Stop()

    monkeypatch.setattr(supervisor.Supervisor, "preload", lambda self: record("launcher", []))
    monkeypatch.setattr(supervisor.Supervisor, "start", lambda self, name, argv, stdout=None: record(name, argv))
    monkeypatch.setattr(supervisor.Supervisor, "fork", fork)
    with pytest.raises(Stop):
        spawn_team(TeamPlan(scenario=load_scenario("paper-stationary"), runs=tmp_path, start="fork"))
    (launcher, _, before_world), (monitor, monitor_argv, _), (world, world_argv, _) = started
    assert (launcher, monitor, world) == ("launcher", "monitor", "world")
    # On the terminal before any process was started: the start-up state of every participant.
    assert "paper-stationary · 6 robots" in before_world and "starting" in before_world.splitlines()[0]
    assert "starting: 0/8 participants up" in before_world
    assert "waiting for: world monitor r0 r1 r2 r3 r4 r5" in before_world
    # The monitor is told where to take the terminal over, and counts from spawn's time.
    handover = Path(monitor_argv[monitor_argv.index("--display-handover") + 1])
    assert handover.parent.parent == tmp_path and "--display-handover" not in world_argv
    assert counted_from[0] is not None
    assert not handover.exists()  # spawn stopped: the terminal is released


def test_no_start_up_frame_without_a_terminal(monkeypatch, tmp_path: Path) -> None:
    console = Console(file=io.StringIO(), record=True, width=100, height=30, force_terminal=False)
    monkeypatch.setattr("ringtrack.tools.team.spawn.out", console)
    started: dict[str, list[str]] = {}

    def start(self, name: str, argv, stdout=None):
        started[name] = list(argv)
        if name == "monitor":
            raise Stop()

    monkeypatch.setattr(supervisor.Supervisor, "start", start)
    with pytest.raises(Stop):
        spawn_team(TeamPlan(scenario=load_scenario("paper-stationary"), runs=tmp_path, start="exec"))
    assert console.export_text() == "" and "--display-handover" not in started["monitor"]


def test_spawn_hands_the_terminal_over_only_when_the_monitor_is_ready(tmp_path: Path) -> None:
    scenario = load_scenario("paper-stationary")
    spawn_console, monitor_console = terminal(), terminal()
    handover = tmp_path / "display.handover"
    with StartupView(spawn_console, scenario, "lockstep", handover) as view:
        assert view.live.is_started and "waiting for: world monitor" in spawn_console.export_text(clear=False)
        assert started_at(handover) == view.model.started
        model = TeamModel(scenario, "lockstep")
        model.expected, model.up = startup_names(scenario), {"monitor"}
        model.started = started_at(handover) or 0.0
        with LiveView(monitor_console, model, dashboard=True, handover=handover):
            eventually(lambda: handover.read_text() == READY, "the monitor says it is ready")
            time.sleep(0.3)  # the monitor's first frame waits: spawn has not started everybody yet
            assert view.live.is_started and monitor_console.export_text(clear=False) == ""
            view.started_all()
            eventually(lambda: not handover.exists(), "spawn releases the terminal")
            assert not view.live.is_started  # spawn's frame is gone before the monitor draws
            eventually(lambda: "participants up" in monitor_console.export_text(clear=False),
                       "the monitor draws its start-up frame")
        assert "1/8 participants up" in monitor_console.export_text()


def test_take_over_gives_up_waiting_after_its_timeout(tmp_path: Path) -> None:
    handover = tmp_path / "display.handover"
    handover.write_text("12.5")
    assert started_at(handover) == 12.5
    assert take_over(handover, timeout_s=0.05) is False and handover.read_text() == READY
    releaser = threading.Timer(0.05, handover.unlink)
    releaser.start()
    assert take_over(handover, timeout_s=PATIENCE_S) is True
    releaser.join()


def test_a_start_up_that_ends_early_still_releases_the_terminal(tmp_path: Path) -> None:
    """Ctrl-C or a failure before every process is started: spawn's frame goes and the monitor may
    draw its last frame and print its report."""
    handover = tmp_path / "display.handover"
    released: list[bool] = []
    with StartupView(terminal(), load_scenario("paper-stationary"), "lockstep", handover) as view:
        monitor = threading.Thread(target=lambda: released.append(take_over(handover, timeout_s=PATIENCE_S)))
        monitor.start()
        eventually(lambda: handover.read_text() == READY, "the monitor says it is ready")
    monitor.join()
    assert released == [True] and not view.live.is_started and not handover.exists()


def test_a_monitor_that_ends_stops_waiting_for_the_terminal(tmp_path: Path) -> None:
    handover = tmp_path / "display.handover"
    handover.write_text("12.5")
    model = TeamModel(load_scenario("paper-stationary"), "lockstep")
    with LiveView(terminal(), model, dashboard=True, handover=handover) as view:
        eventually(lambda: handover.read_text() == READY, "the monitor says it is ready")
    # Nobody released the terminal (its waiting lasts 30 s), yet the drawer ended with the view.
    view.drawer.join(PATIENCE_S)
    assert not view.drawer.is_alive() and handover.exists()
